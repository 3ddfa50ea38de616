//! `specgp albedo SOURCE [--angles LIST] [--out TABLE.csv]`: the directional albedo of a BRDF
//! source (the fraction of the light from one direction that it reflects, per channel) at
//! incident elevations, and whether it conserves energy (albedo <= 1 everywhere).
//!
//! (A fluorescent material may exceed 1 in a channel, shifting light from other wavelengths;
//! a BRDF cannot represent that shift, so a renderer still gains energy.)
//!
//! A GP prediction is a blend of measured materials (of their logarithms under the `log`
//! transform), which nothing keeps physically plausible: this is the check before a predicted
//! material goes into a renderer. The table on standard output gives per elevation the
//! luminous albedo Y (D65; the sRGB luminance for RGB sources) and the smallest and largest
//! channel; `--out` writes every channel as CSV.

use std::path::PathBuf;

use anyhow::{Context, bail};
use brdf_io::albedo::{
    AlbedoTable, DEFAULT_RESOLUTION, GridAlbedo, directional_albedo, gains_energy,
};
use brdf_io::{AngularGrid, BrdfSource, Channels};

use crate::cmd_sample::SourceArgs;

/// Incident elevations of the table by default (degrees), as `--angles` takes them.
pub const DEFAULT_ANGLES: &str = "0,10,20,30,40,50,60,70,75,80,85,88";

/// [`DEFAULT_ANGLES`] as numbers.
pub const DEFAULT_ANGLES_DEG: [f64; 12] = [
    0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 75.0, 80.0, 85.0, 88.0,
];

/// Arguments of `specgp albedo`.
#[derive(Debug, clap::Args)]
pub struct AlbedoArgs {
    #[command(flatten)]
    pub from: SourceArgs,
    /// Incident elevations in degrees, in [0, 90): START:END:STEP or a comma list.
    #[arg(long, default_value = DEFAULT_ANGLES)]
    pub angles: String,
    /// Output CSV (`.csv`) of every channel: a header `angle_deg,<channels>`, one row per
    /// elevation (`-`: standard output; the table then goes to standard error).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Half vectors per axis of the quadrature (resolution x resolution; 2..=1024).
    #[arg(long, default_value_t = DEFAULT_RESOLUTION)]
    pub resolution: usize,
}

/// Parses `--angles`: START:END:STEP (END included, and on the step) or a comma list
/// ([`brdf_io::grid::parse_values`]), each in [0, 90) degrees.
pub fn parse_angles(spec: &str) -> anyhow::Result<Vec<f64>> {
    let bad = |why: String| {
        anyhow::anyhow!(
            "--angles {spec:?}: {why} (expected START:END:STEP or a comma list, in degrees)"
        )
    };
    let angles = brdf_io::grid::parse_values(spec, 10_000, "angles").map_err(bad)?;
    if let Some(a) = angles.iter().find(|a| !(0.0..90.0).contains(*a)) {
        return Err(bad(format!(
            "{a} is outside [0, 90): at 90 degrees the light grazes the surface"
        )));
    }
    Ok(angles)
}

/// Luminance weights of `channels` (Y of the CIE 1931 observer under D65, Y = 1 for a perfect
/// white diffuser; linear sRGB's Y for RGB), or why there are none.
pub fn luminance_weights(channels: &Channels) -> Result<Vec<f64>, String> {
    match channels {
        Channels::Rgb => Ok([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .map(|e| render::colour::linear_srgb_to_xyz(e)[1])
            .to_vec()),
        Channels::Spectral(w) => {
            if let Some(why) = render::colour::coverage_warning(w, render::Illuminant::D65) {
                return Err(why);
            }
            render::SpectralWeights::new(w, render::Illuminant::D65)
                .map(|s| s.y)
                .map_err(|e| e.to_string())
        }
    }
}

/// The CSV text of a table: `angle_deg,<channel labels>`, then one row per elevation.
pub fn albedo_csv(table: &AlbedoTable) -> String {
    let mut out = format!("angle_deg,{}\n", table.channels.labels().join(","));
    for (k, a) in table.angles_deg.iter().enumerate() {
        let row: Vec<String> = table.row(k).iter().map(|v| format!("{v:e}")).collect();
        out.push_str(&format!("{a},{}\n", row.join(",")));
    }
    out
}

/// The printed table: per elevation Y (when the channels give one), the smallest and the
/// largest channel with their labels.
pub fn albedo_report(table: &AlbedoTable, luminance: Option<&[f64]>) -> String {
    let mut out = String::new();
    out.push_str(&format!(
        "{:>9}  {:>8}  {:>21}  {:>21}\n",
        "angle deg",
        if luminance.is_some() { "Y" } else { "" },
        "smallest (channel)",
        "largest (channel)"
    ));
    for (k, a) in table.angles_deg.iter().enumerate() {
        let row = table.row(k);
        let y = luminance.map_or_else(String::new, |w| {
            format!("{:.4}", w.iter().zip(row).map(|(w, v)| w * v).sum::<f64>())
        });
        let at = |best: fn(f64, f64) -> bool| {
            let mut i = 0;
            for (j, v) in row.iter().enumerate() {
                if best(*v, row[i]) {
                    i = j;
                }
            }
            format!("{:.4} ({})", row[i], table.channels.name(i))
        };
        out.push_str(&format!(
            "{a:>9}  {y:>8}  {:>21}  {:>21}\n",
            at(|v, b| v < b),
            at(|v, b| v > b)
        ));
    }
    out
}

/// Runs `specgp albedo`.
pub fn albedo(args: &AlbedoArgs) -> anyhow::Result<()> {
    let angles = parse_angles(&args.angles)?;
    if !(2..=1024).contains(&args.resolution) {
        bail!("--resolution {}: expected 2..=1024", args.resolution);
    }
    if let Some(out) = &args.out {
        crate::paths::ensure_output_is_not_an_input(out, &[&args.from.file()])?;
        crate::paths::ensure_extension(out, "csv", "a CSV file")?;
        crate::paths::ensure_output_directory(out)?;
    }
    let source = args.from.open()?;
    let start = std::time::Instant::now();
    // Well under a second by default; about 1-2 s at --resolution 1024 (measured: an RGL file
    // 0.95 s, a paper-grid model point 1.8 s).
    let spinner = indicatif::ProgressBar::new_spinner();
    spinner.set_message(format!(
        "integrating {} at {} elevations",
        args.from.source,
        angles.len()
    ));
    spinner.enable_steady_tick(std::time::Duration::from_millis(120));
    let table = directional_albedo(source.as_ref(), &angles, args.resolution);
    spinner.finish_and_clear();
    let table = table.with_context(|| format!("directional albedo of {}", args.from.source))?;
    let seconds = start.elapsed().as_secs_f64();
    if let Some(out) = &args.out {
        brdf_io::output::write_file_atomic(out, albedo_csv(&table).as_bytes())?;
    }
    let luminance = luminance_weights(&table.channels);
    let to_stderr = args
        .out
        .as_deref()
        .is_some_and(|p| p == std::path::Path::new(brdf_io::output::STDOUT));
    let print = |line: &str| {
        if to_stderr {
            errln!("{line}");
        } else {
            outln!("{line}");
        }
    };
    let channels = match &table.channels {
        Channels::Rgb => "R, G, B".to_owned(),
        Channels::Spectral(w) => format!(
            "{} wavelengths, {}-{} nm",
            w.len(),
            w.first().copied().unwrap_or(0.0),
            w.last().copied().unwrap_or(0.0)
        ),
    };
    // Files with their own evaluation are always multilinear here; a grid source looked up
    // another way says so (the numbers depend on it).
    let lookup = match source.lookup() {
        brdf_io::Lookup::Multilinear => String::new(),
        other => format!("{other} lookups between bin centres; "),
    };
    print(&format!(
        "directional albedo of {} ({channels}; {lookup}{r} x {r} half vectors, {seconds:.2} s)",
        args.from.source,
        r = args.resolution
    ));
    for line in albedo_report(&table, luminance.as_deref().ok()).lines() {
        print(line);
    }
    if let Err(why) = &luminance {
        print(&format!("no luminance: {why}"));
    }
    if let Some(warning) = energy_warning(&table, &args.from.source) {
        tracing::warn!("{warning}");
    } else if let Some(peak) = table.peak() {
        print(&format!(
            "largest albedo {:.4} at {} degrees ({}): energy-conserving at these elevations",
            peak.value,
            peak.angle_deg,
            table.channels.name(peak.channel)
        ));
    }
    Ok(())
}

/// The warning for a table whose largest albedo gains energy ([`gains_energy`]), naming the
/// source `what`; `None` when it conserves energy.
pub fn energy_warning(table: &AlbedoTable, what: &str) -> Option<String> {
    let peak = table.peak().filter(|p| gains_energy(p.value))?;
    Some(format!(
        "{what} reflects more light than it receives: albedo {:.4} at {} degrees ({}); not \
         physically plausible unless the material fluoresces (a path tracer gains energy at \
         each bounce; `specgp albedo` tells more)",
        peak.value,
        peak.angle_deg,
        table.channels.name(peak.channel)
    ))
}

/// Logs [`energy_warning`] for `source` (named `what`) at the default elevations, the check
/// `predict` and `convert` run on what they write. A check that fails is logged at debug
/// level only: it never stops an output.
pub fn warn_on_energy_gain(source: &dyn BrdfSource, what: &str) {
    warn_on_energy_gain_in(energy_check(source), what);
}

/// The albedo table [`warn_on_energy_gain`] checks.
pub fn energy_check(source: &dyn BrdfSource) -> brdf_io::Result<AlbedoTable> {
    directional_albedo(source, &DEFAULT_ANGLES_DEG, DEFAULT_RESOLUTION)
}

/// Logs [`energy_warning`] for the table of [`warn_on_energy_gain`]'s check of `what`, or at
/// debug level why the check failed.
pub fn warn_on_energy_gain_in(table: brdf_io::Result<AlbedoTable>, what: &str) {
    match table {
        Ok(table) => {
            if let Some(warning) = energy_warning(&table, what) {
                tracing::warn!("{warning}");
            }
        }
        Err(e) => tracing::debug!("energy check of {what} skipped: {e}"),
    }
}

/// The cell weights of [`warn_on_energy_gain`]'s check on `grid`, to sum the check from a
/// material's values as they stream past ([`GridAlbedo::stream`]); `None` (logged at debug
/// level) where they cannot be made.
pub fn energy_check_weights(grid: &AngularGrid) -> Option<GridAlbedo> {
    GridAlbedo::new(grid, &DEFAULT_ANGLES_DEG, DEFAULT_RESOLUTION)
        .map_err(|e| tracing::debug!("energy check weights of grid {grid}: {e}"))
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_parse_as_ranges_and_lists_within_the_hemisphere() {
        assert_eq!(
            parse_angles("0:80:20").unwrap(),
            vec![0.0, 20.0, 40.0, 60.0, 80.0]
        );
        assert_eq!(parse_angles("5, 89.5").unwrap(), vec![5.0, 89.5]);
        assert_eq!(parse_angles(DEFAULT_ANGLES).unwrap(), DEFAULT_ANGLES_DEG);
        for (spec, words) in [
            ("0:90:10", "90 is outside [0, 90)"),
            ("-1", "-1 is outside"),
            ("0:85:10", "not START plus a whole number"),
            ("0:80", "exactly three fields"),
            ("10:0:5", "END >= START"),
            ("0,x", "\"x\" is not a number"),
        ] {
            let e = parse_angles(spec).unwrap_err().to_string();
            assert!(e.contains(words) && e.contains(spec), "{spec}: {e}");
        }
    }

    /// Energy gain is an albedo strictly above 1 + ENERGY_MARGIN: a white diffuser at 1 and
    /// the margin itself pass, just above it warns naming the source, elevation and channel.
    #[test]
    fn energy_warnings_start_just_above_the_margin() {
        use brdf_io::albedo::ENERGY_MARGIN;
        let table = |v: f64| AlbedoTable {
            angles_deg: vec![0.0, 70.0],
            channels: Channels::parse_wavelengths("500,600").unwrap(),
            values: vec![0.5, 0.5, 0.25, v],
        };
        for quiet in [1.0, 1.0 + ENERGY_MARGIN, 0.999] {
            assert_eq!(energy_warning(&table(quiet), "s"), None, "{quiet}");
        }
        let w = energy_warning(&table(1.0 + 1.1 * ENERGY_MARGIN), "x.bsdf").unwrap();
        assert!(
            w.starts_with(
                "x.bsdf reflects more light than it receives: albedo 1.0055 at 70 degrees (600 nm)"
            ),
            "{w}"
        );
    }

    #[test]
    fn luminance_weights_give_one_for_white() {
        let rgb = luminance_weights(&Channels::Rgb).unwrap();
        // The sRGB matrix's Y row, rounded to 7 digits: 0.2126729 + 0.7151522 + 0.072175.
        assert!((rgb.iter().sum::<f64>() - 1.0).abs() < 1e-6, "{rgb:?}");
        assert!(rgb[1] > rgb[0] && rgb[0] > rgb[2]);
        let spectral = Channels::parse_wavelengths("360:780:20").unwrap();
        let w = luminance_weights(&spectral).unwrap();
        assert!(
            (w.iter().sum::<f64>() - 1.0).abs() < 1e-9,
            "{}",
            w.iter().sum::<f64>()
        );
        let ir = Channels::parse_wavelengths("800:1000:100").unwrap();
        assert!(luminance_weights(&ir).unwrap_err().contains("800-1000 nm"));
    }

    #[test]
    fn report_and_csv_name_the_extreme_channels() {
        let table = AlbedoTable {
            angles_deg: vec![0.0, 60.0],
            channels: Channels::Rgb,
            values: vec![0.5, 0.25, 0.75, 1.25, 0.125, 0.5],
        };
        let csv = albedo_csv(&table);
        assert_eq!(
            csv,
            "angle_deg,R,G,B\n0,5e-1,2.5e-1,7.5e-1\n60,1.25e0,1.25e-1,5e-1\n"
        );
        let w = [0.25, 0.5, 0.25];
        let report = albedo_report(&table, Some(&w));
        let lines: Vec<&str> = report.lines().collect();
        assert_eq!(lines.len(), 3);
        // Y = 0.25 * 0.5 + 0.5 * 0.25 + 0.25 * 0.75 = 0.4375.
        assert!(
            lines[1].contains("0.4375") && lines[1].contains("0.2500 (G)"),
            "{report}"
        );
        assert!(lines[1].contains("0.7500 (B)"), "{report}");
        assert!(
            lines[2].contains("0.1250 (G)") && lines[2].contains("1.2500 (R)"),
            "{report}"
        );
        assert!(
            !albedo_report(&table, None)
                .lines()
                .nth(1)
                .unwrap()
                .contains("0.4375")
        );
    }
}
