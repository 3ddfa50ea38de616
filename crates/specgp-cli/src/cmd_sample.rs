//! `specgp sample SOURCE --dirs DIRS.csv --out VALUES.csv [--wavelengths]`: BRDF values f (1/sr)
//! at given direction pairs.
//!
//! Sources plug in through [`brdf_io::BrdfSource`]; [`open_source`] maps a SOURCE argument to one:
//! - `FILE.bsdf`: an RGL file (spectral files may be evaluated at `--wavelengths`);
//! - `FILE.binary`: a MERL file (nearest cell, as MERL's own lookup);
//! - `DATA.sbrdf:MATERIAL`: a stored material (multilinear interpolation on the store's grid,
//!   or logarithmic with `--lookup log`; `--wavelengths` interpolates between stored
//!   wavelengths);
//! - `MODEL.toml@X,Y`: the GP prediction (exact predictor) at a latent point, evaluated lazily
//!   (nothing materialised; `--wavelengths` interpolates between stored wavelengths).
//!
//! Further kinds add one arm to [`open_source`].

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use brdf_io::lookup::WithLookup;
use brdf_io::{BrdfSource, Channels, Lookup, Vec3};
use predict::PredictorKind;

/// A BRDF source argument with the options every command that reads one takes (`sample`,
/// `convert`).
#[derive(Debug, clap::Args)]
pub struct SourceArgs {
    /// The BRDF: an RGL `.bsdf` file, a MERL `.binary` file, `DATA.sbrdf:MATERIAL` or
    /// `MODEL.toml@X1,...,Xq` (lazy GP prediction at a latent point, all q coordinates; the
    /// exact predictor, which returns a training material at its own point, unless --smooth).
    pub source: String,
    /// Wavelengths START:END:STEP or a comma list in nm, inside the stored range (spectral
    /// sources; linear interpolation between stored wavelengths; default: the stored ones).
    /// Not for MERL files.
    #[arg(long)]
    pub wavelengths: Option<String>,
    /// With a model point: the smooth predictor (the noise-free posterior mean, continuous in
    /// the latent point) instead of the exact one.
    #[arg(long)]
    pub smooth: bool,
    #[command(flatten)]
    pub lookup: LookupArg,
}

/// The `--lookup` option of the commands that read a SOURCE.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct LookupArg {
    /// How stored and predicted materials are looked up between the grid's bin centres:
    /// `linear` (multilinear, the default) or `log` (ln f interpolated: exact for diffuse
    /// materials, and glossy ones gain no energy at grazing angles; BENCHMARKS.md "albedo").
    /// RGL, MERL and Neural-BRDF files have their own evaluation: `log` is refused for them.
    #[arg(long = "lookup", default_value = "linear")]
    pub lookup: Lookup,
}

impl LookupArg {
    /// `source` (opened from SOURCE `spec`) looked up this way.
    pub fn apply(
        self,
        source: Box<dyn BrdfSource>,
        spec: &str,
    ) -> anyhow::Result<Box<dyn BrdfSource>> {
        if self.lookup == Lookup::Multilinear && source.lookup() == Lookup::Multilinear {
            return Ok(source);
        }
        let source = WithLookup::new(source, self.lookup)
            .with_context(|| format!("--lookup {}: {spec}", self.lookup))?;
        Ok(Box::new(source))
    }
}

impl SourceArgs {
    /// The file the source reads (the store of `DATA.sbrdf:MATERIAL`, the model of
    /// `MODEL.toml@X`), for checks that an output does not replace it.
    pub fn file(&self) -> PathBuf {
        crate::paths::source_file(&self.source)
    }

    /// Opens the source ([`open_source`]).
    pub fn open(&self) -> anyhow::Result<Box<dyn BrdfSource>> {
        let wavelengths = self
            .wavelengths
            .as_deref()
            .map(Channels::parse_wavelengths)
            .transpose()?;
        let source = open_source(
            &self.source,
            wavelengths.as_ref(),
            predictor_kind(self.smooth),
        )?;
        self.lookup.apply(source, &self.source)
    }
}

/// Arguments of `specgp sample`.
#[derive(Debug, clap::Args)]
pub struct SampleArgs {
    #[command(flatten)]
    pub from: SourceArgs,
    /// CSV of direction pairs, one `wi_x,wi_y,wi_z,wo_x,wo_y,wo_z` row each (local frame,
    /// z = normal; a header line is allowed).
    #[arg(long)]
    pub dirs: PathBuf,
    /// Output CSV (`.csv`): a header naming the channels, then one row of values (1/sr) per
    /// pair (`-`: standard output).
    #[arg(long)]
    pub out: PathBuf,
}

/// The predictor a `--smooth` flag names.
pub fn predictor_kind(smooth: bool) -> PredictorKind {
    if smooth {
        PredictorKind::Smooth
    } else {
        PredictorKind::Exact
    }
}

/// Opens the BRDF named by a SOURCE argument, evaluated at `wavelengths` when given; a model
/// point by the predictor `kind` (the smooth one is refused for other sources).
pub fn open_source(
    spec: &str,
    wavelengths: Option<&Channels>,
    kind: PredictorKind,
) -> anyhow::Result<Box<dyn BrdfSource>> {
    if let Some(m) = crate::cmd_predict::open_model_source(spec, wavelengths, kind) {
        return Ok(Box::new(m?));
    }
    if kind == PredictorKind::Smooth {
        bail!("--smooth applies to a model point (MODEL.toml@X1,...,Xq), not to {spec:?}");
    }
    if let Some((path, name)) = brdf_io::store::parse_store_spec(spec) {
        let mut m = brdf_io::store::StoreMaterial::open(&path, &name)
            .with_context(|| format!("opening {spec}"))?;
        if let Some(ch) = wavelengths {
            m = m.with_wavelengths(ch)?;
        }
        return Ok(Box::new(m));
    }
    let path = Path::new(spec);
    // Any case: `PW.BSDF` is an RGL file too.
    let ext = ["bsdf", "binary", "sbrdf", "toml"]
        .into_iter()
        .find(|e| brdf_io::has_extension(path, e));
    match ext {
        Some("bsdf") => {
            let mut bsdf = brdf_io::rgl::RglBsdf::open(path)?;
            if let Some(ch) = wavelengths {
                bsdf = bsdf.with_channels(ch)?;
            }
            Ok(Box::new(bsdf))
        }
        Some("binary") => {
            if wavelengths.is_some() {
                bail!("--wavelengths: the MERL file {spec:?} is RGB; it has no wavelengths");
            }
            Ok(Box::new(brdf_io::merl::read_merl(path)?))
        }
        Some("sbrdf") => {
            let names = brdf_io::Store::open(path)
                .map(|s| {
                    s.header()
                        .materials
                        .iter()
                        .map(|m| m.name.clone())
                        .collect::<Vec<_>>()
                        .join(", ")
                })
                .unwrap_or_default();
            bail!(
                "SOURCE {spec:?} is a dataset store: name one of its materials as \
                 {spec}:MATERIAL{}",
                if names.is_empty() {
                    String::new()
                } else {
                    format!(" (it holds: {names})")
                }
            )
        }
        Some("toml") => bail!(
            "SOURCE {spec:?} is a model: name a latent point as {spec}@X1,...,Xq (all q \
             coordinates; `specgp latent {spec}` lists the materials' points)"
        ),
        _ => bail!(
            "unknown SOURCE {spec:?}: expected an RGL .bsdf file, a MERL .binary file, \
             DATA.sbrdf:MATERIAL or MODEL.toml@X1,...,Xq"
        ),
    }
}

/// Parses DIRS.csv text: rows of six numbers; blank lines and `#` comments are skipped, and a
/// first line in which no field is a number is a header (a first line with some numbers is a
/// row, so a typo in it is an error, not a silently skipped header). Errors name the file and
/// the line. Directions with components beyond 1e100 (or all below 1e-100) are rescaled.
pub fn parse_dirs(text: &str, path: &Path) -> anyhow::Result<Vec<(Vec3, Vec3)>> {
    let mut pairs = Vec::new();
    let mut header: Option<(usize, &str)> = None;
    let mut first = true;
    let (mut not_unit, mut not_unit_count) = (None, 0usize);
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed: Vec<Option<f64>> = fields.iter().map(|f| f.parse::<f64>().ok()).collect();
        let where_ = || format!("{} line {}", path.display(), k + 1);
        if std::mem::take(&mut first) && parsed.iter().all(Option::is_none) {
            // Six numbers separated by blanks or semicolons are a row in the wrong format, not
            // a header.
            let numbers = line
                .split(|c: char| c.is_whitespace() || c == ';')
                .filter(|f| !f.is_empty())
                .map(str::parse::<f64>)
                .collect::<Result<Vec<_>, _>>();
            if numbers.is_ok_and(|n| n.len() == 6) {
                bail!(
                    "{}: six numbers not separated by commas in {line:?}; expected \
                     wi_x,wi_y,wi_z,wo_x,wo_y,wo_z",
                    where_()
                );
            }
            header = Some((k + 1, line));
            continue;
        }
        if let Some(bad) = fields.iter().zip(&parsed).find(|(_, v)| v.is_none()) {
            bail!(
                "{}: expected six numbers wi_x,wi_y,wi_z,wo_x,wo_y,wo_z, got {:?} in {line:?}",
                where_(),
                bad.0
            );
        }
        let nums: Vec<f64> = parsed.into_iter().flatten().collect();
        if nums.len() != 6 {
            bail!(
                "{}: expected six numbers wi_x,wi_y,wi_z,wo_x,wo_y,wo_z, got {} fields",
                where_(),
                nums.len()
            );
        }
        if nums.iter().any(|x| !x.is_finite()) {
            bail!("{}: non-finite direction component in {line:?}", where_());
        }
        // Directions whose squared length would over- or underflow are scaled by their largest
        // component (the sources normalise; ordinary rows pass through unchanged).
        let unit = |v: Vec3| -> Option<Vec3> {
            let m = v[0].abs().max(v[1].abs()).max(v[2].abs());
            if m == 0.0 {
                return None;
            }
            Some(if (1e-100..=1e100).contains(&m) {
                v
            } else {
                v.map(|x| x / m)
            })
        };
        let (Some(wi), Some(wo)) = (
            unit([nums[0], nums[1], nums[2]]),
            unit([nums[3], nums[4], nums[5]]),
        ) else {
            bail!("{}: zero-length direction in {line:?}", where_());
        };
        let off_unit = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>().sqrt() - 1.0).abs() > 1e-3;
        if off_unit(&nums[..3]) || off_unit(&nums[3..]) {
            not_unit.get_or_insert(k + 1);
            not_unit_count += 1;
        }
        pairs.push((wi, wo));
    }
    if let Some(line) = not_unit {
        // The format asks for unit vectors; a scaled one is read as its direction, which is
        // what a user meant unless the file is in another convention (e.g. angles).
        tracing::warn!(
            "{}: {not_unit_count} of {} direction pairs are not unit vectors (the first at line \
             {line}); each is read as its direction",
            path.display(),
            pairs.len()
        );
    }
    if pairs.is_empty() {
        match header {
            Some((k, line)) => bail!(
                "{}: no direction pairs: line {k} ({line:?}) has no number, so it was read as a \
                 header, and no row of six numbers follows",
                path.display()
            ),
            None => bail!("{}: no direction pairs (empty file)", path.display()),
        }
    }
    Ok(pairs)
}

/// Direction pairs per parallel task of [`sample_csv`] (a grid source is told their cells
/// together, so that one stored on a disk reads them at once).
const PAIRS_PER_TASK: usize = 256;

/// Evaluates `source` at every pair (in parallel) and returns the CSV text (header of channel
/// labels, then a row per pair in order). An error names the first pair that failed.
pub fn sample_csv(source: &dyn BrdfSource, pairs: &[(Vec3, Vec3)]) -> anyhow::Result<String> {
    use rayon::prelude::*;
    use std::fmt::Write as _;
    let labels = source.channels().labels();
    let rows = |first: usize, block: &[(Vec3, Vec3)]| -> anyhow::Result<String> {
        brdf_io::source::will_need_pairs(source, block);
        let (mut text, mut buf) = (String::new(), vec![0.0; labels.len()]);
        for (k, (wi, wo)) in block.iter().enumerate() {
            source
                .eval(*wi, *wo, &mut buf)
                .with_context(|| format!("evaluating direction pair {}", first + k + 1))?;
            for (c, v) in buf.iter().enumerate() {
                let sep = if c == 0 { "" } else { "," };
                let _ = write!(text, "{sep}{v:e}"); // (writing to a String cannot fail)
            }
            text.push('\n');
        }
        Ok(text)
    };
    let blocks: Vec<anyhow::Result<String>> = pairs
        .par_chunks(PAIRS_PER_TASK)
        .enumerate()
        .map(|(b, block)| rows(b * PAIRS_PER_TASK, block))
        .collect();
    let mut out = labels.join(",");
    out.push('\n');
    for block in blocks {
        out.push_str(&block?);
    }
    Ok(out)
}

/// Runs `specgp sample`.
pub fn sample(args: &SampleArgs) -> anyhow::Result<()> {
    crate::paths::ensure_output_is_not_an_input(&args.out, &[&args.dirs, &args.from.file()])?;
    crate::paths::ensure_extension(&args.out, "csv", "a CSV file")?;
    let source = args.from.open()?;
    let text = std::fs::read_to_string(&args.dirs)
        .with_context(|| format!("reading {}", args.dirs.display()))?;
    let pairs = parse_dirs(&text, &args.dirs)?;
    let csv = sample_csv(source.as_ref(), &pairs)
        .with_context(|| format!("sampling {} at {}", args.from.source, args.dirs.display()))?;
    brdf_io::output::write_file_atomic(&args.out, csv.as_bytes())?;
    tracing::info!(pairs = pairs.len(), out = %args.out.display(), "sampled {}", args.from.source);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_rows_with_header_and_reports_bad_lines() {
        let p = Path::new("d.csv");
        let text =
            "wi_x,wi_y,wi_z,wo_x,wo_y,wo_z\n0,0,1, 0.6,0,0.8\n\n# comment\n0.6,0,0.8,0,0,1\n";
        let pairs = parse_dirs(text, p).unwrap();
        assert_eq!(pairs.len(), 2);
        assert_eq!(pairs[0].1, [0.6, 0.0, 0.8]);
        // Huge and tiny components: the same unit directions.
        let big = parse_dirs("1e300,0,1e300,0,0,1e-300\n", p).unwrap();
        assert_eq!(big[0], ([1.0, 0.0, 1.0], [0.0, 0.0, 1.0]));
        let e = parse_dirs("0,0,1,0,0,1\n0,0,1,0,x,1\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("d.csv line 2"), "{e}");
        let e = parse_dirs("0,0,1,0,0\n", p).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("5 fields"), "{e}");
        let e = parse_dirs("0,0,0,0,0,1\n", p).unwrap_err().to_string();
        assert!(e.contains("zero-length"), "{e}");
        assert!(parse_dirs("a,b\n", p).is_err());
        // A typo in the first row is an error, not a header (rows would no longer line up).
        let e = parse_dirs("0,0,1,0,0,abc\n0,0,1,0,0,1\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("d.csv line 1") && e.contains("\"abc\""), "{e}");
        for text in ["0;0;1;0;0;1\n", "0 0 1 0.6 0 0.8\n"] {
            let e = parse_dirs(text, p).unwrap_err().to_string();
            assert!(
                e.contains("line 1") && e.contains("not separated by commas"),
                "{e}"
            );
        }
        let e = parse_dirs("# angles\nx;y\n", p).unwrap_err().to_string();
        assert!(
            e.contains("line 2 (\"x;y\")") && e.contains("read as a header"),
            "{e}"
        );
        let e = parse_dirs("\n# only a comment\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("empty file"), "{e}");
    }

    /// A source whose value is `wi_x` (one channel) and which fails where `wi_x` is negative.
    struct FailsWhereNegative;

    impl BrdfSource for FailsWhereNegative {
        fn channels(&self) -> Channels {
            Channels::spectral(vec![500.0]).unwrap()
        }
        fn eval(&self, wi: Vec3, _wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
            if wi[0] < 0.0 {
                return Err(brdf_io::Error::InvalidArgument {
                    reason: format!("negative at {}", wi[0]),
                });
            }
            out[0] = wi[0];
            Ok(())
        }
    }

    /// Pairs evaluated in parallel tasks come out as rows in order, and an error names the
    /// first failing pair, whichever task fails first.
    #[test]
    fn rows_keep_the_order_and_errors_name_the_first_failing_pair() {
        let n = 3 * PAIRS_PER_TASK + 7;
        let pair = |x: f64| ([x, 0.0, 1.0], [0.0, 0.0, 1.0]);
        let mut pairs: Vec<_> = (0..n).map(|k| pair(k as f64)).collect();
        let csv = sample_csv(&FailsWhereNegative, &pairs).unwrap();
        let rows: Vec<&str> = csv.lines().collect();
        assert_eq!(rows.len(), n + 1);
        assert_eq!(rows[0], "500");
        for (k, row) in rows[1..].iter().enumerate() {
            assert_eq!(row.parse::<f64>().unwrap(), k as f64, "row {k}");
        }
        // Failures in the second and the last task: the second task's names the pair.
        let first = PAIRS_PER_TASK + 5;
        pairs[first] = pair(-1.0);
        pairs[n - 1] = pair(-2.0);
        let e = format!("{:#}", sample_csv(&FailsWhereNegative, &pairs).unwrap_err());
        assert!(
            e.contains(&format!("evaluating direction pair {}: ", first + 1))
                && e.contains("negative at -1"),
            "{e}"
        );
    }

    #[test]
    fn samples_a_real_rgl_file() {
        let Some(file) = shared_data::path("rgl-rgb/paper_white_rgb.bsdf") else {
            return;
        };
        let src = open_source(file.to_str().unwrap(), None, PredictorKind::Exact).unwrap();
        let pairs = vec![
            ([0.0, 0.0, 1.0], [0.6, 0.0, 0.8]),
            ([0.0, 0.0, 1.0], [0.0, 0.6, -0.8]),
        ];
        let csv = sample_csv(src.as_ref(), &pairs).unwrap();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], "R,G,B");
        let g: f64 = lines[1].split(',').nth(1).unwrap().parse().unwrap();
        let mut want = [0.0; 3];
        src.eval(pairs[0].0, pairs[0].1, &mut want).unwrap();
        assert_eq!(g, want[1]);
        assert!(g > 0.1 && g < 0.6, "white paper f ~ albedo/pi, got {g}");
        assert_eq!(lines[2], "0e0,0e0,0e0", "below the horizon");
        let e = open_source(
            file.to_str().unwrap(),
            Some(&Channels::spectral(vec![500.0]).unwrap()),
            PredictorKind::Exact,
        );
        assert!(e.is_err());
        assert!(open_source("x.png", None, PredictorKind::Exact).is_err());
    }
}
