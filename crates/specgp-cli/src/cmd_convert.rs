//! `specgp convert SOURCE --out FILE.bsdf`: any BRDF source (a stored or predicted material, a
//! MERL or RGL file) as an isotropic RGL `.bsdf` file, which Mitsuba 3 and pbrt-v4 render
//! (`measured` material); see `brdf_io::rgl::write_rgl`. `specgp predict --out FILE.bsdf`
//! writes a prediction the same way.

use std::path::{Path, PathBuf};

use anyhow::Context;
use brdf_io::rgl::{RglWriteOptions, write_rgl_then};
use brdf_io::{BrdfSource, Channels};

/// Arguments of `specgp convert`.
#[derive(Debug, clap::Args)]
pub struct ConvertArgs {
    #[command(flatten)]
    pub from: crate::cmd_sample::SourceArgs,
    /// Output RGL file (`.bsdf`; spectral sources give `spectra` and `wavelengths`, RGB
    /// sources an `rgb` table).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub rgl: RglArgs,
}

/// Resolution of a written RGL file (`convert`, and `predict --out FILE.bsdf`).
#[derive(Debug, Clone, clap::Args)]
pub struct RglArgs {
    /// Incident elevations of a written `.bsdf` file (2..=1024; cosine-spaced, 0-90 degrees).
    /// Default: 32, refined (see --tolerance). Clear-coated materials (car paint, vinyl) need
    /// 128 with --resolution 128 for their albedo at grazing incidence (a ~400 MB file).
    #[arg(long)]
    pub theta_samples: Option<usize>,
    /// Side of a written `.bsdf` file's value tables (2..=1024; points of the warped square
    /// per incident elevation). Default: 32, refined (see --tolerance).
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Check error (cos-weighted relative RMS against the source at 4096 direction pairs, or
    /// relative error of the directional albedo at incidence 0-88 degrees, whichever is
    /// larger) above which a written `.bsdf` file is refined: the incident elevations, the
    /// tables' side or both doubled (up to 64 each) while that cuts the error by a quarter.
    /// Giving --theta-samples or --resolution writes those sizes as they are.
    #[arg(
        long,
        default_value_t = brdf_io::rgl::DEFAULT_TOLERANCE,
        conflicts_with_all = ["resolution", "theta_samples"],
        allow_negative_numbers = true
    )]
    pub tolerance: f64,
    /// Description stored in a written `.bsdf` file (default: the source).
    #[arg(long)]
    pub description: Option<String>,
}

impl RglArgs {
    /// The first RGL option given on the command line (the tolerance counts when it is not
    /// the default), for commands that refuse options their output would ignore.
    pub fn given(&self) -> Option<&'static str> {
        if self.theta_samples.is_some() {
            Some("--theta-samples")
        } else if self.resolution.is_some() {
            Some("--resolution")
        } else if self.description.is_some() {
            Some("--description")
        } else if self.tolerance != brdf_io::rgl::DEFAULT_TOLERANCE {
            Some("--tolerance")
        } else {
            None
        }
    }
}

/// Writes `source` (named `label`) as an RGL file at `out` and reports it on stderr.
pub fn write_bsdf(
    source: &dyn BrdfSource,
    label: &str,
    out: &Path,
    args: &RglArgs,
) -> anyhow::Result<()> {
    let start = std::time::Instant::now();
    let default = RglWriteOptions::default();
    let options = RglWriteOptions {
        theta_samples: args.theta_samples.unwrap_or(default.theta_samples),
        resolution: args.resolution.unwrap_or(default.resolution),
        tolerance: (args.resolution.is_none() && args.theta_samples.is_none())
            .then_some(args.tolerance),
        description: args.description.clone().unwrap_or_else(|| label.to_owned()),
        ..default
    };
    // Sampling, checking and refining take up to ~10 s for sharp lobes (128 x 128 tables).
    let spinner = indicatif::ProgressBar::new_spinner();
    spinner.set_message(format!(
        "writing {} (sampling the source, checking, refining)",
        out.display()
    ));
    spinner.enable_steady_tick(std::time::Duration::from_millis(120));
    // The energy check through the writer's cells: a prediction's are not evaluated again.
    let written = write_rgl_then(source, out, &options, crate::cmd_albedo::energy_check);
    spinner.finish_and_clear();
    let (summary, energy) = written.with_context(|| format!("writing {}", out.display()))?;
    let channels = match source.channels() {
        Channels::Rgb => "R,G,B".to_owned(),
        c => format!("{} wavelengths", c.len()),
    };
    errln!(
        "wrote {}: {label} as an RGL BSDF ({} incident elevations, {r} x {r} values each, \
         {channels}; {} bytes, {:.2} s); check against the source: {:.2} % cos-weighted RMS \
         error at {} direction pairs, directional albedo within {:.2} % at incidence 0-88 \
         degrees",
        out.display(),
        summary.theta_samples,
        brdf_io::output::output_len(out).map_or_else(|| "?".to_owned(), |b| b.to_string()),
        start.elapsed().as_secs_f64(),
        100.0 * summary.check_rms,
        brdf_io::rgl::CHECK_PAIRS,
        100.0 * summary.albedo_error,
        r = summary.resolution,
    );
    if summary.check() > args.tolerance {
        if options.tolerance.is_some() {
            errln!(
                "warning: the check error is above --tolerance {}: finer tables did not reduce \
                 it by a quarter (or reached 64 x 64); larger ones may (--theta-samples 128 \
                 --resolution 128: sharp coats over a diffuse base need them at grazing \
                 incidence)",
                args.tolerance,
            );
        } else {
            // Sizes given: written as asked, but a poor file must not pass without a word.
            errln!(
                "warning: the check error is above --tolerance {} with the sizes given \
                 (--theta-samples {} --resolution {}); larger tables, or neither option (sizes \
                 refined until the check passes), would fit the source better",
                args.tolerance,
                summary.theta_samples,
                summary.resolution,
            );
        }
    }
    if summary.negative_clamped > 0 {
        errln!(
            "warning: {} of {} source values are negative (stored as 0: a renderer needs a \
             non-negative BRDF)",
            summary.negative_clamped,
            summary.values
        );
    }
    crate::cmd_albedo::warn_on_energy_gain_in(energy, label);
    Ok(())
}

/// Runs `specgp convert`.
pub fn convert(args: &ConvertArgs) -> anyhow::Result<()> {
    crate::paths::ensure_output_is_not_an_input(&args.out, &[&args.from.file()])?;
    crate::paths::ensure_extension(&args.out, "bsdf", "an RGL tensor file")?;
    crate::paths::refuse_binary_on_terminal(&args.out, "an RGL tensor file")?;
    let source = args.from.open()?;
    write_bsdf(source.as_ref(), &args.from.source, &args.out, &args.rgl)
}
