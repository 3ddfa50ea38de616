//! `specgp`: the command-line front end of the specgp toolkit.
//!
//! The command-line contract lives in `../shared/docs/CLI.md`; every subcommand prints a clear
//! error (what, which file, why) and exits with code 1 on failure.

use brdf_io::{AngularGrid, Channels};
use clap::{Parser, Subcommand};

// First: its printing macros (`outln!`, `errln!`) are used by the modules below.
#[macro_use]
mod console;
mod cmd_albedo;
mod cmd_convert;
mod cmd_data;
mod cmd_fit;
mod cmd_locate;
mod cmd_predict;
mod cmd_render;
mod cmd_sample;
mod cmd_synth;
mod paths;

/// The `specgp` command line (its `--help` summary is the package description, `about`).
#[derive(Debug, Parser)]
#[command(name = "specgp", version, about, long_about = None)]
struct Cli {
    /// Print tracing logs to stderr (-v: info, -vv: debug, -vvv: trace).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,

    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Describe a grid: angular cells, cells above the horizon, values per material (D) and bytes.
    Grid(GridArgs),
    /// Import measured BRDF files into a dataset store (`.sbrdf`).
    Import(cmd_data::ImportArgs),
    /// Describe a dataset store (materials, grid, channels, D, bytes, layout, checksum) or a
    /// model file (`.toml`: the fit, and whether its dataset is still there; a damaged dataset
    /// fails the command, a missing or replaced one is reported).
    Info(cmd_data::InfoArgs),
    /// Export materials of a dataset store as an N x D `.npy` matrix (streamed).
    Export(cmd_data::ExportArgs),
    /// Evaluate a BRDF source (f in 1/sr) at the direction pairs of a CSV file.
    Sample(cmd_sample::SampleArgs),
    /// Directional albedo of a BRDF source (the fraction of the light from one direction it
    /// reflects) at incident elevations: is it energy-conserving?
    Albedo(cmd_albedo::AlbedoArgs),
    /// Write a BRDF source as an RGL `.bsdf` file (Mitsuba 3 and pbrt-v4 `measured` material).
    Convert(cmd_convert::ConvertArgs),
    /// Write the embedded default dataset: 51 synthetic spectral materials on a grid.
    Synth(cmd_synth::SynthArgs),
    /// Fit a GPLVM latent space to a dataset store and write the model (TOML).
    Fit(cmd_fit::FitArgs),
    /// Show the latent coordinates and log-likelihood of a model (as the fit recorded them; `info MODEL` checks the dataset is still there).
    Latent(cmd_fit::LatentArgs),
    /// Render a sphere preview of a BRDF source (spectral -> sRGB PNG).
    Render(cmd_render::RenderArgs),
    /// Draw the latent space: materials labelled, shaded by the predictive standard deviation, thumbnails.
    Map(cmd_render::MapArgs),
    /// Materialise a predicted material (GP at a latent point, or linear interpolation).
    Predict(cmd_predict::PredictArgs),
    /// Reconstruction and leave-one-out errors of a model (GP and baselines).
    Evaluate(cmd_predict::EvaluateArgs),
    /// Find where materials outside the training set sit in the latent space (the inverse of predict).
    Locate(cmd_locate::LocateArgs),
}

/// Arguments of `specgp grid`.
#[derive(Debug, clap::Args)]
struct GridArgs {
    /// Angular resolution TH,TD,PD.
    #[arg(long, default_value = "90,90,180")]
    grid: AngularGrid,
    /// Wavelengths START:END:STEP or a comma list in nm; RGB when absent.
    #[arg(long)]
    wavelengths: Option<String>,
}

fn grid_command(args: &GridArgs) -> anyhow::Result<()> {
    let channels = match &args.wavelengths {
        Some(spec) => Channels::parse_wavelengths(spec)?,
        None => Channels::Rgb,
    };
    let cells = args.grid.len();
    let valid = args.grid.validity_mask().iter().filter(|v| **v).count();
    let d = cells * channels.len();
    outln!("grid           {}", args.grid);
    outln!("angular cells  {cells}");
    outln!(
        "above horizon  {valid} ({:.1} %)",
        100.0 * valid as f64 / cells as f64
    );
    outln!("channels       {}", channels.len());
    outln!("D              {d}");
    outln!("bytes (f32)    {}", d * 4);
    Ok(())
}

fn init_tracing(verbosity: u8) {
    let level = match verbosity {
        0 => "warn",
        1 => "info",
        2 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_env("SPECGP_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    // Colours only on a terminal: redirected logs stay plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    // Without `log_internal_errors(false)` a log line that cannot be written (stderr closed or
    // full) is reported with `eprintln!`, which panics; losing the line is better.
    let fmt = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(ansi)
        .log_internal_errors(false);
    if verbosity == 0 {
        // Without -v only warnings show: "WARN message", no timestamp or module path.
        fmt.without_time().with_target(false).init();
    } else {
        fmt.init();
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    // Every command logs its start and end at `-v` (info), its arguments at `-vv` (debug).
    let name = format!("{:?}", cli.command);
    let name = name.split('(').next().unwrap_or("command").to_lowercase();
    tracing::debug!(command = ?cli.command, "arguments");
    tracing::info!("{name}: start");
    let start = std::time::Instant::now();
    // A print that failed (other than into a closed pipe) fails the command once its files
    // are written.
    let result = run_command(cli.command).and_then(|()| console::finish_stdout());
    let seconds = start.elapsed().as_secs_f64();
    match &result {
        Ok(()) => tracing::info!(seconds, "{name}: done"),
        Err(e) => tracing::info!(seconds, "{name}: failed: {e:#}"),
    }
    result
}

fn run_command(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Grid(args) => grid_command(&args),
        Command::Fit(args) => cmd_fit::fit(&args),
        Command::Latent(args) => cmd_fit::latent(&args),
        Command::Render(args) => cmd_render::render(&args),
        Command::Map(args) => cmd_render::map(&args),
        Command::Predict(args) => cmd_predict::predict(&args),
        Command::Evaluate(args) => cmd_predict::evaluate(&args),
        Command::Locate(args) => cmd_locate::locate_command(&args),
        Command::Import(args) => cmd_data::import(&args),
        Command::Info(args) => cmd_data::info(&args),
        Command::Export(args) => cmd_data::export(&args),
        Command::Sample(args) => cmd_sample::sample(&args),
        Command::Albedo(args) => cmd_albedo::albedo(&args),
        Command::Convert(args) => cmd_convert::convert(&args),
        Command::Synth(args) => cmd_synth::synth(&args),
    }
}

/// Whether `err` comes from writing into a pipe that its reader closed (`specgp sample ...
/// --out - | head`): not an error. The I/O error may be the cause itself or inside a
/// `brdf_io::Error::Io` (outputs written through `brdf_io::output`). Printed tables and
/// reports never return such errors (`console`): the command goes on to write its files.
fn is_broken_pipe(err: &anyhow::Error) -> bool {
    let broken = |io: &std::io::Error| io.kind() == std::io::ErrorKind::BrokenPipe;
    err.chain().any(|e| {
        e.downcast_ref::<std::io::Error>().is_some_and(broken)
            || matches!(
                e.downcast_ref::<brdf_io::Error>(),
                Some(brdf_io::Error::Io { error, .. }) if broken(error)
            )
    })
}

fn main() -> std::process::ExitCode {
    // Usage errors exit with 1 like every other error (CLI.md); --help and --version exit 0.
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) => {
            // --help or --version that cannot be printed (other than into a closed pipe) fail.
            let failed = match err.print() {
                Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe && !err.use_stderr() => {
                    errln!("error: writing to standard output: {e}");
                    true
                }
                _ => false,
            };
            let code = if err.use_stderr() || failed { 1 } else { 0 };
            return std::process::ExitCode::from(code);
        }
    };
    init_tracing(cli.verbose);
    if let Err(err) = brdf_io::output::remove_unfinished_outputs_on_signal("specgp") {
        tracing::warn!("{err}");
    }
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // A closed pipe (`specgp sample ... --out - | head`) is not an error.
        Err(err) if is_broken_pipe(&err) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            // Best effort: standard error may be closed too; the exit code says it anyway.
            errln!("error: {}", error_message(&err));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined by ": ", as `{err:#}` prints them, except that a cause
/// starting with a name the message already holds (a file's path, which both a command's
/// context and the file error under it give) drops that repetition: "writing out.npy" over
/// "out.npy: No space left on device" reads "writing out.npy: No space left on device".
fn error_message(err: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in err.chain().map(ToString::to_string) {
        if message.is_empty() {
            message = cause;
            continue;
        }
        // The shortest "NAME: " the cause starts with that the message holds as whole words.
        let named = cause
            .match_indices(": ")
            .map(|(i, _)| i)
            .find(|&i| holds_name(&message, &cause[..i]));
        message.push_str(": ");
        message.push_str(named.map_or(cause.as_str(), |i| &cause[i + 2..]));
    }
    message
}

/// Whether `message` holds `name` delimited like a word: after the start, a space or `(`, and
/// before the end, a space, `:`, `,` or `)`.
fn holds_name(message: &str, name: &str) -> bool {
    !name.is_empty()
        && message.match_indices(name).any(|(i, _)| {
            let before = message[..i].chars().next_back();
            let after = message[i + name.len()..].chars().next();
            matches!(before, None | Some(' ' | '('))
                && matches!(after, None | Some(' ' | ':' | ',' | ')'))
        })
}

#[cfg(test)]
mod tests {
    use super::error_message;
    use anyhow::Context;

    #[test]
    fn error_messages_name_a_path_once() {
        let io = || Err::<(), _>(anyhow::anyhow!("/tmp/x y.npy: No space left on device"));
        // A path (with a space in it) that the context ends with.
        let err = io().context("writing /tmp/x y.npy").unwrap_err();
        assert_eq!(
            error_message(&err),
            "writing /tmp/x y.npy: No space left on device"
        );
        // A path the message holds further back.
        let err = io()
            .context("/tmp/x y.npy: writing the synthetic dataset failed")
            .context("synth")
            .unwrap_err();
        assert_eq!(
            error_message(&err),
            "synth: /tmp/x y.npy: writing the synthetic dataset failed: No space left on device"
        );
        // Causes that do not repeat a name are joined as `{:#}` does, and a repetition must be
        // a whole word ("a.npy" does not hold the word "npy").
        let err = io().context("writing /tmp/other.npy").unwrap_err();
        assert_eq!(error_message(&err), format!("{err:#}"));
        let err = Err::<(), _>(anyhow::anyhow!("npy: bad header"))
            .context("reading a.npy")
            .context("loading")
            .unwrap_err();
        assert_eq!(
            error_message(&err),
            "loading: reading a.npy: npy: bad header"
        );
    }
}
