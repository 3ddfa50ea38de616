//! `cargo xtask pipeline CONFIG [--out DIR]` and `cargo xtask bench [--config FILE]`.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use clap::Parser;
use xtask::{PipelineConfig, project_root};

#[derive(Debug, Parser)]
#[command(name = "xtask", about = "specgp pipelines and benchmarks")]
struct Cli {
    /// Log progress (tracing, info level; RUST_LOG overrides).
    #[arg(short, long, global = true)]
    verbose: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Data -> fit -> predict -> evaluate -> figures -> DIR/report.md + DIR/results.json.
    Pipeline {
        /// Pipeline config (`configs/NAME.toml`).
        config: PathBuf,
        /// Output directory (default `out/NAME`).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Run time against error sweeps -> DIR/bench.md, bench.json, bench.png.
    Bench {
        /// Bench config.
        #[arg(long, default_value = "configs/bench.toml")]
        config: PathBuf,
        /// Output directory (default `out/bench`).
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// A path as given, or relative to the project root when it does not exist as given; an
/// error naming both places when it is in neither (it named the root's only).
fn locate(path: &Path, root: &Path) -> anyhow::Result<PathBuf> {
    if path.exists() || path.is_absolute() {
        return Ok(path.to_owned());
    }
    let in_root = root.join(path);
    if in_root.exists() {
        return Ok(in_root);
    }
    let here = std::env::current_dir().map_or_else(|_| ".".into(), |d| d.display().to_string());
    anyhow::bail!(
        "{}: no such file here ({here}) or in the project root ({})",
        path.display(),
        root.display()
    )
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(if cli.verbose { "info" } else { "warn" })
    });
    // As specgp's: colours only on a terminal (redirected logs stay plain text), and without
    // --verbose only warnings, as "WARN message" (no timestamp or module path).
    let fmt = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .log_internal_errors(false);
    if cli.verbose {
        fmt.init();
    } else {
        fmt.without_time().with_target(false).init();
    }
    if let Err(err) = brdf_io::output::remove_unfinished_outputs_on_signal("xtask") {
        tracing::warn!("{err}");
    }
    match run(&cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(cli: &Cli) -> anyhow::Result<()> {
    let root = project_root();
    match &cli.command {
        Command::Pipeline { config, out } => {
            let path = locate(config, &root)?;
            let config = PipelineConfig::load(&path, &root)?;
            let out = out
                .clone()
                .unwrap_or_else(|| root.join("out").join(&config.params.name));
            let results = xtask::run(&config, &out)
                .with_context(|| format!("pipeline {}", path.display()))?;
            eprintln!(
                "pipeline {}: {}, log-likelihood {:.6e}, {:.1} s; report {}",
                results.name,
                xtask::report::quantity(results.data.n_materials, "material"),
                results.fit.log_likelihood,
                results.total_seconds,
                out.join("report.md").display()
            );
        }
        Command::Bench { config, out } => {
            let path = locate(config, &root)?;
            let bench = xtask::bench::BenchConfig::load(&path)?;
            let out = out
                .clone()
                .unwrap_or_else(|| root.join("out").join("bench"));
            let rows = xtask::bench::run(&bench, &path, &out)
                .with_context(|| format!("bench {}", path.display()))?;
            eprintln!(
                "bench: {} points, {} on the Pareto front; {}",
                rows.len(),
                rows.iter().filter(|r| r.pareto).count(),
                out.join("bench.md").display()
            );
        }
    }
    Ok(())
}
