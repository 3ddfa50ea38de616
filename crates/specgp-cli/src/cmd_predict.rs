//! `specgp predict` (materialise a predicted material) and `specgp evaluate` (reconstruction and
//! leave-one-out errors), plus the `MODEL.toml@X,Y` source of `specgp sample`.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::console::quantity;
use anyhow::{Context, bail};
use brdf_io::{Channels, Lookup};
use indicatif::{ProgressBar, ProgressStyle};
use predict::evaluate::{EvalOptions, Stage, evaluate as run_evaluation};
use predict::{PredictedMaterial, Predictor, PredictorKind};

/// Arguments of `specgp predict`.
#[derive(Debug, clap::Args)]
pub struct PredictArgs {
    /// Model file (TOML) written by `specgp fit`.
    pub model: PathBuf,
    /// Latent point X,Y[,...] to predict at.
    #[arg(
        long,
        allow_hyphen_values = true,
        conflicts_with = "lerp",
        required_unless_present = "lerp"
    )]
    pub at: Option<String>,
    /// Linear interpolation NAME1,NAME2,A: a y1 + (1 - a) y2 of two training materials'
    /// values in the model's transformed space (the paper's blend of BRDF values for a `raw`
    /// model, a blend of log values for a `log` one). Names may contain commas (A, a number, is
    /// the last field; the rest must split into two of the model's names in exactly one way);
    /// a name is matched as given, else without spaces at its ends.
    #[arg(long)]
    pub lerp: Option<String>,
    /// Output file: `.sbrdf` (one material), `.npy` (1 x D f32), `.binary` (MERL RGB;
    /// spectral data are converted to linear sRGB under D65) or `.bsdf` (an RGL file for
    /// Mitsuba 3 and pbrt-v4, sampled from the lazy prediction; see `specgp convert`); `-`
    /// writes `.npy` to standard output (redirected to a file).
    #[arg(long)]
    pub out: PathBuf,
    /// Wavelengths START:END:STEP or a comma list in nm (linear interpolation between stored
    /// wavelengths; default: the stored ones).
    #[arg(long)]
    pub wavelengths: Option<String>,
    /// Use the exact predictor (the paper's; reproduces training materials; default).
    #[arg(long, conflicts_with = "smooth")]
    pub exact: bool,
    /// Use the smooth predictor (noise-free posterior mean).
    #[arg(long)]
    pub smooth: bool,
    /// Print the predictive variance at the point (on standard output; on standard error with
    /// `--out -`).
    #[arg(long)]
    pub variance: bool,
    /// Read the dataset from this store instead of the path recorded in the model.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
    /// Build (once, next to the dataset: `DATA.sbrdf.<transform>.sbrdf`) and use the sidecar
    /// store of forward-transformed values: no logarithms per lookup under `log`. `sample`,
    /// `render MODEL@X,Y` and `map --thumbnails` use an existing sidecar automatically.
    #[arg(long)]
    pub sidecar: bool,
    #[command(flatten)]
    pub rgl: crate::cmd_convert::RglArgs,
    /// How the prediction is looked up between the grid's bin centres, for a `.bsdf` output and
    /// for the energy check of every output: `linear` (multilinear, the default) or `log` (ln f
    /// interpolated; see `specgp sample --lookup`).
    #[arg(long, default_value = "linear")]
    pub lookup: brdf_io::Lookup,
}

/// Arguments of `specgp evaluate`.
#[derive(Debug, clap::Args)]
pub struct EvaluateArgs {
    /// Model file (TOML) written by `specgp fit`.
    pub model: PathBuf,
    /// Also run leave-one-out over every material: GP, nearest material, linear interpolation
    /// and PCA.
    #[arg(long)]
    pub loo: bool,
    /// Write the full results (per material and summary) as JSON (`.json`; `-`: standard
    /// output, the table then goes to standard error).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// With --loo: starts of the latent search per held-out material (1..=1000): this many
    /// training points of the refit, midpoints of pairs of them, points half a length-scale off
    /// a training point and quasi-random points of the region they span, of each kind those
    /// that reconstruct it best (at most the N - 1 training points).
    #[arg(long, default_value_t = 3, requires = "loo", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1000))]
    pub starts: usize,
    /// With --loo: refit each leave-one-out model from the PCA start (a fresh fit) instead of
    /// warm-starting from the full model's latent points.
    #[arg(long, requires = "loo")]
    pub cold: bool,
    /// With --loo: cap on the optimiser iterations of each leave-one-out refit (0: the model's
    /// own configuration).
    #[arg(long, default_value_t = 200, requires = "loo")]
    pub refit_iterations: u64,
    /// Read the dataset from this store instead of the path recorded in the model.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
}

/// `v` in the shortest form that reads back exactly: plain digits from 1e-4 to 1e6 (`0.25`,
/// `40`), else with an exponent (`1e100`, `-2.5e-7`; plain digits would run to a hundred
/// and more).
pub fn format_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        v.to_string()
    } else {
        format!("{v:e}")
    }
}

/// A latent point as `X1,X2,...` in the shortest form that [`parse_point`] reads back exactly
/// (for `MODEL.toml@X1,...` and `--at`; [`format_number`]).
pub fn format_point(x: &[f64]) -> String {
    x.iter()
        .map(|v| format_number(*v))
        .collect::<Vec<_>>()
        .join(",")
}

/// Parses a latent point `X,Y[,...]`.
pub fn parse_point(s: &str) -> anyhow::Result<Vec<f64>> {
    if s.trim().is_empty() {
        bail!("the latent point is empty: expected its coordinates X1,...,Xq");
    }
    s.split(',')
        .map(|t| {
            t.trim()
                .parse::<f64>()
                .with_context(|| format!("latent point {s:?}: {t:?} is not a number"))
        })
        .collect()
}

/// Reads `--lerp NAME1,NAME2,A` against the model's material `names`: the indices of the two
/// materials and A. A is the last comma field and must be a number; names may contain commas,
/// so the rest is split at each of its commas, and the one split whose halves both name
/// materials is taken (a half is matched as given, else trimmed of spaces at its ends, so
/// `a, b, 0.5` still reads). Several such splits are an ambiguity, refused naming each
/// reading. With none, the error is `unknown(NAME)` for the half that names no material
/// (where the other half does).
fn parse_lerp(
    spec: &str,
    names: &[&str],
    unknown: impl Fn(&str) -> anyhow::Error,
) -> anyhow::Result<(usize, usize, f64)> {
    let syntax = || format!("--lerp {spec:?}: expected NAME1,NAME2,A");
    let Some((rest, a)) = spec.rsplit_once(',') else {
        bail!("{}", syntax());
    };
    let a = a.trim();
    let Ok(t) = a.parse::<f64>() else {
        bail!(
            "{}: A = {a:?} is not a number (A, the weight of NAME1, is the last field)",
            syntax()
        );
    };
    let find = |name: &str| {
        let at = |n: &str| names.iter().position(|m| *m == n);
        at(name).or_else(|| at(name.trim()))
    };
    let splits: Vec<(&str, &str)> = rest
        .match_indices(',')
        .map(|(i, _)| (&rest[..i], &rest[i + 1..]))
        .collect();
    let Some(&(first, _)) = splits.first() else {
        bail!("{}: two material names before A", syntax());
    };
    let mut readings: Vec<(usize, usize)> = Vec::new();
    for (x, y) in &splits {
        if let (Some(i), Some(j)) = (find(x), find(y))
            && !readings.contains(&(i, j))
        {
            readings.push((i, j));
        }
    }
    match readings.as_slice() {
        [(i, j)] => Ok((*i, *j, t)),
        [] => {
            let bad = splits
                .iter()
                .find_map(|(x, y)| match (find(x), find(y)) {
                    (Some(_), None) => Some(*y),
                    (None, Some(_)) => Some(*x),
                    _ => None,
                })
                .unwrap_or(first);
            Err(unknown(bad.trim()))
        }
        several => bail!(
            "--lerp {spec:?} is ambiguous: the model's material names (which may contain \
             commas) read it as {}",
            several
                .iter()
                .map(|(i, j)| format!("NAME1 {:?} and NAME2 {:?}", names[*i], names[*j]))
                .collect::<Vec<_>>()
                .join(" or as ")
        ),
    }
}

/// A progress bar on standard error: `what`, elapsed time, position and what is left.
pub(crate) fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{what} [{{elapsed_precise}}] {{bar:40}} {{pos}}/{{len}} ({{eta}} left)"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb
}

/// Opens `MODEL.toml@X,Y` (by the predictor `kind`) as a lazy predicted material, or `None`
/// when `spec` does not have that form.
pub fn open_model_source(
    spec: &str,
    wavelengths: Option<&Channels>,
    kind: PredictorKind,
) -> Option<anyhow::Result<PredictedMaterial>> {
    let (model, point) = spec.rsplit_once('@')?;
    if !brdf_io::has_extension(model, "toml") {
        return None;
    }
    Some((|| {
        if point.trim().is_empty() {
            let q = gplvm::Model::load(Path::new(model)).map(|m| m.latent_dim);
            let example = match q {
                Ok(q) => format!(
                    "all {q} coordinates, e.g. {model}@{}",
                    vec!["0"; q].join(",")
                ),
                Err(_) => format!("all its coordinates, as {model}@X1,...,Xq"),
            };
            bail!(
                "{spec}: no latent point after the '@' of model {model}: give {example} (`specgp \
                 latent {model}` lists the materials' points)"
            );
        }
        let x = parse_point(point).with_context(|| format!("model {model}"))?;
        let pred =
            open_model_of_source(Path::new(model)).with_context(|| format!("opening {model}"))?;
        warn_if_far(&pred, &x)?;
        let mut m = with_existing_sidecar(pred)?.predict(&x, kind)?;
        if let Some(w) = wavelengths {
            m = m.with_wavelengths(w)?;
        }
        Ok(m)
    })())
}

/// Opens the model of a `MODEL.toml@X` source. The commands that read such sources (`sample`,
/// `render`, `convert`) have no `--dataset` option, which the library's message for a moved
/// dataset suggests: say instead how to point the model file at it.
fn open_model_of_source(model: &Path) -> anyhow::Result<Predictor> {
    match Predictor::open(model) {
        Err(predict::Error::DatasetMissing {
            model,
            dataset,
            given: false,
        }) => bail!(
            "model {}: its dataset {} is not a file (moved or deleted?); set `path` in the \
             model file's [dataset] table to the store's new path (a relative path is read from \
             the model file's directory), or move the store back",
            model.display(),
            dataset.display()
        ),
        result => Ok(result?),
    }
}

/// Warns when latent point `x` is far from every training material: the GP's prediction
/// there is close to the data mean, whatever the coordinates (a typo such as 9 for 0.9 would
/// otherwise pass silently).
pub fn warn_if_far(pred: &Predictor, x: &[f64]) -> anyhow::Result<()> {
    let s = pred.support(x)?;
    if s.is_far() {
        // Far can be very far (a typo of 1e100): exponents rather than a hundred digits.
        let distance = if s.distance < 1e6 {
            format!("{:.1}", s.distance)
        } else {
            format!("{:.1e}", s.distance)
        };
        tracing::warn!(
            "latent point {} is far from every material (nearest: {}, {distance} length-scales \
             away; {:.0} % of the prior variance is left there): the prediction is close to the \
             mean of the data",
            format_point(x),
            s.nearest,
            100.0 * s.variance_fraction.min(1.0)
        );
    }
    Ok(())
}

/// Logs (info, `-v`) that lookups read the sidecar `side` (every command that reads one): its
/// f32 transformed values move results by ~1e-6 relative, so an output that changes after
/// `predict --sidecar` has a visible cause. Not a progress message: opening it reads only its
/// header, and errors in its values name it anyway.
fn announce_sidecar(side: &Path) {
    tracing::info!(
        "reading the sidecar {} (transformed values in f32: ~1e-6 relative)",
        side.display()
    );
}

/// `pred` reading the forward-transformed sidecar store next to its dataset when one exists
/// (non-raw transforms; built by `specgp predict --sidecar`): no logarithms per lookup.
pub fn with_existing_sidecar(pred: Predictor) -> anyhow::Result<Predictor> {
    let side = pred.transformed_store_path();
    if pred.transform() != gplvm::Transform::Raw && side.is_file() {
        // A damaged or stale sidecar is not worth failing for: the dataset store has the same
        // values (`predict --sidecar` rebuilds it).
        return Ok(match pred.with_transformed_store(&side) {
            Ok(p) => {
                announce_sidecar(&side);
                p
            }
            Err(e) => {
                tracing::warn!(
                    "the sidecar {} is unusable ({e}); reading the dataset store instead \
                     (`specgp predict --sidecar` rebuilds it)",
                    side.display()
                );
                pred
            }
        });
    }
    Ok(pred)
}

/// Runs `specgp predict`.
pub fn predict(args: &PredictArgs) -> anyhow::Result<()> {
    // What --lerp would ignore: it has no predictor to choose, nor a variance.
    if args.lerp.is_some() {
        for (given, flag) in [
            (args.smooth, "--smooth"),
            (args.exact, "--exact"),
            (args.variance, "--variance"),
        ] {
            if given {
                bail!(
                    "{flag} applies to a latent point (--at), not to --lerp (a linear \
                     interpolation of two training materials: no GP predictor, no variance)"
                );
            }
        }
    }
    let inputs = crate::paths::model_inputs(&args.model, args.dataset.as_deref());
    crate::paths::ensure_output_is_not_an_input(&args.out, &inputs)?;
    let bsdf = brdf_io::has_extension(&args.out, "bsdf");
    if !bsdf && let Some(flag) = args.rgl.given() {
        bail!(
            "{flag} applies to a `.bsdf` output, not to {}",
            args.out.display()
        );
    }
    // The format is known from the name: refuse an unknown one before any work.
    crate::paths::refuse_binary_on_terminal(&args.out, "a predicted material")?;
    if !bsdf && predict::OutputFormat::from_path(&args.out).is_err() {
        bail!(
            "{}: unknown output format: expected a .sbrdf, .npy, .binary or .bsdf file (or - \
             for .npy on standard output)",
            args.out.display()
        );
    }
    let point = args.at.as_deref().map(parse_point).transpose()?;
    let mut pred = Predictor::open_with_dataset(&args.model, args.dataset.as_deref())
        .with_context(|| format!("opening model {}", args.model.display()))?;
    // The materials of --lerp, before any sidecar is built.
    let lerp = match &args.lerp {
        Some(spec) if point.is_none() => {
            let names: Vec<&str> = pred
                .model()
                .materials
                .iter()
                .map(|m| m.name.as_str())
                .collect();
            let (i, j, t) = parse_lerp(spec, &names, |name| {
                // A name with spaces at its ends is matched only as given: point at it.
                if let Some(padded) = names.iter().find(|n| n.trim() == name) {
                    return anyhow::anyhow!(
                        "--lerp {spec:?}: no material {name:?} in model {}; did you mean \
                         {padded:?}? (its name has spaces at its ends: give them)",
                        args.model.display()
                    );
                }
                pred.material_index(name)
                    .map_or_else(anyhow::Error::from, |_| {
                        anyhow::anyhow!("--lerp {spec:?}: no material {name:?}")
                    })
            })?;
            Some((names[i].to_owned(), names[j].to_owned(), t))
        }
        _ => None,
    };
    if args.sidecar {
        let side = pred.transformed_store_path();
        // An existing sidecar is used when it opens and belongs to this dataset; a damaged or
        // stale one (another dataset, an interrupted copy) is rebuilt, not an error.
        let existing = side
            .is_file()
            .then(|| pred.clone().with_transformed_store(&side));
        pred = match existing {
            Some(Ok(p)) => {
                announce_sidecar(&side);
                p
            }
            stale => {
                if let Some(Err(e)) = stale {
                    errln!("the sidecar is unusable ({e}); rebuilding it");
                }
                let pb = bar(pred.store().n_chunks() as u64, "sidecar");
                pred.build_transformed_store(&side, |done, _| pb.set_position(done as u64))
                    .with_context(|| format!("writing {}", side.display()))?;
                pb.finish_and_clear();
                errln!("wrote the forward-transformed sidecar {}", side.display());
                pred.with_transformed_store(&side)?
            }
        };
    }
    let kind = crate::cmd_sample::predictor_kind(args.smooth);
    let mut material = match (point, lerp) {
        (Some(x), _) => {
            warn_if_far(&pred, &x)?;
            if args.variance {
                // Per transformed value first (the units of the data), then the share of the
                // prior variance (how much the materials constrain the point).
                let v = pred.variance_of(&x, kind)?;
                let per_value = v * pred.model().data_scale;
                let share = 100.0 * v / pred.prior_variance();
                // Three significant digits (0.0312 %, 45.3 %, 100 %).
                let digits = (2.0 - share.log10().floor()).clamp(0.0, 6.0) as usize;
                let line = format!(
                    "variance {per_value:e} per transformed value of the {kind} predictor (std \
                     {:e}, transform {}); {share:.digits$} % of the prior variance (in model \
                     units {v:e} of {:e})",
                    per_value.sqrt(),
                    pred.transform(),
                    pred.prior_variance()
                );
                // On standard error when the .npy goes to standard output (`--out -`).
                if args.out == Path::new(brdf_io::output::STDOUT) {
                    errln!("{line}");
                } else {
                    outln!("{line}");
                }
            }
            pred.predict(&x, kind)?
        }
        (None, Some((a, b, t))) => pred.lerp(&a, &b, t)?,
        (None, None) => bail!("give --at X,Y or --lerp NAME1,NAME2,A"),
    };
    if let Some(spec) = &args.wavelengths {
        material = material.with_wavelengths(&Channels::parse_wavelengths(spec)?)?;
    }
    let looked_up = brdf_io::lookup::WithLookup::new(&material, args.lookup)?;
    if bsdf {
        return crate::cmd_convert::write_bsdf(&looked_up, material.label(), &args.out, &args.rgl);
    }
    let spectral_merl =
        brdf_io::has_extension(&args.out, "binary") && material.channels() != &Channels::Rgb;
    // The energy check of what is written. Under multilinear lookups the albedo is linear in
    // the values, so it is summed from them as they are written, with no read of its own (which
    // costs 15-25 s on the paper's 58 GB grid from the disk); otherwise cell by cell first.
    let weights = (args.lookup == Lookup::Multilinear && !spectral_merl)
        .then(|| crate::cmd_albedo::energy_check_weights(pred.grid()))
        .flatten();
    if weights.is_none() {
        crate::cmd_albedo::warn_on_energy_gain(&looked_up, material.label());
    }
    let mut check = weights
        .as_ref()
        .map(|w| w.stream(material.channels().clone()));
    let pb = bar(pred.store().n_chunks() as u64, "predict");
    let report = if spectral_merl {
        write_spectral_merl(&material, &args.out, &pb)
    } else {
        let progress = |done, _| pb.set_position(done as u64);
        material
            .materialize_with(&args.out, progress, |range, values| {
                if let Some(stream) = &mut check
                    && let Err(e) = stream.push(range, values)
                {
                    tracing::debug!("energy check of {} skipped: {e}", material.label());
                    check = None;
                }
                Ok(())
            })
            .map_err(anyhow::Error::from)
    }
    .with_context(|| format!("writing {}", args.out.display()))?;
    pb.finish_and_clear();
    if let Some(stream) = check {
        crate::cmd_albedo::warn_on_energy_gain_in(stream.finish(), material.label());
    }
    errln!(
        "wrote {}: {} ({} values, {}, {:.2} s)",
        report.path.display(),
        material.label(),
        report.values,
        report
            .bytes
            .map_or_else(|| "size unknown".to_owned(), |b| format!("{b} bytes")),
        report.seconds
    );
    if report.negatives > 0 {
        // (A linear blend has no GP in it: its weight beyond [0, 1] extrapolates.)
        let unconstrained = if args.lerp.is_some() {
            "a blend with a weight outside [0, 1] is not constrained to be non-negative"
        } else {
            "the GP mean is not constrained to be non-negative"
        };
        errln!(
            "warning: {} {} values are negative (min {:e} 1/sr): {}",
            report.negatives,
            if spectral_merl {
                "linear sRGB"
            } else {
                "predicted"
            },
            report.min_value,
            match (report.format == predict::OutputFormat::Merl, spectral_merl) {
                (true, true) => "negative predicted spectra or out-of-gamut colours; the MERL \
                                 file stores 0 there"
                    .to_owned(),
                (true, false) => format!("{unconstrained}; the MERL file stores 0 there"),
                _ => unconstrained.to_owned(),
            }
        );
    }
    Ok(())
}

/// Streams a spectral prediction, converts every cell to linear sRGB (CIE 1931 2-degree
/// observer under D65, white diffuser -> Y = 1; `render::ColourPipeline`, DESIGN.md section 6)
/// and writes a MERL `.binary` file (values in 1/sr) on MERL's own grid.
fn write_spectral_merl(
    material: &PredictedMaterial,
    out: &Path,
    pb: &ProgressBar,
) -> anyhow::Result<predict::MaterializeReport> {
    let start = std::time::Instant::now();
    let weights = render::ColourPipeline::new(render::Illuminant::D65)
        .channel_weights(material.channels())?;
    let grid = *material.predictor().grid();
    let nc = material.channels().len();
    let mut rgb = Vec::with_capacity(3 * grid.len());
    let mut cell = vec![0.0f64; nc];
    let mut filled = 0;
    material.stream_values(
        |_, values| {
            for v in values {
                cell[filled] = f64::from(*v);
                filled += 1;
                if filled == nc {
                    for w in &weights {
                        rgb.push(w.iter().zip(&cell).map(|(a, b)| a * b).sum::<f64>() as f32);
                    }
                    filled = 0;
                }
            }
            Ok(())
        },
        |done, _| pb.set_position(done as u64),
    )?;
    // What the MERL file clamps to 0: negative linear sRGB, from negative predicted spectra or
    // from out-of-gamut colours of positive ones.
    let mut count = predict::NegativeCount::default();
    count.add(&rgb);
    let merl = brdf_io::merl::MerlBrdf::on_merl_grid(grid, &rgb)?;
    brdf_io::merl::write_merl(out, &merl)?;
    Ok(predict::MaterializeReport {
        path: out.to_owned(),
        format: predict::OutputFormat::Merl,
        values: merl.values().len(),
        bytes: brdf_io::output::output_len(out),
        seconds: start.elapsed().as_secs_f64(),
        negatives: count.negatives,
        min_value: count.min_value,
    })
}

/// Runs `specgp evaluate`.
pub fn evaluate(args: &EvaluateArgs) -> anyhow::Result<()> {
    if let Some(json) = &args.json {
        let inputs = crate::paths::model_inputs(&args.model, args.dataset.as_deref());
        crate::paths::ensure_output_is_not_an_input(json, &inputs)?;
        crate::paths::ensure_extension(json, "json", "a JSON file")?;
    }
    let pred = Predictor::open_with_dataset(&args.model, args.dataset.as_deref())
        .with_context(|| format!("opening model {}", args.model.display()))?;
    let options = EvalOptions {
        loo: args.loo,
        starts: args.starts,
        warm_start: !args.cold,
        refit_iterations: (args.refit_iterations > 0).then_some(args.refit_iterations),
    };
    let bars: Mutex<(Option<ProgressBar>, Option<ProgressBar>)> = Mutex::new((None, None));
    let progress = |stage: Stage, done: usize, total: usize| {
        let mut b = bars.lock().unwrap_or_else(|p| p.into_inner());
        let slot = match stage {
            Stage::Refits => &mut b.0,
            Stage::Pass => &mut b.1,
        };
        let pb = slot.get_or_insert_with(|| {
            bar(
                total as u64,
                match stage {
                    Stage::Refits => "leave-one-out refits",
                    Stage::Pass => "error pass",
                },
            )
        });
        pb.set_position(done as u64);
        if done == total {
            pb.finish_and_clear();
        }
    };
    let ev = run_evaluation(&pred, &options, &progress)?;
    // The table goes to standard error when the JSON goes to standard output.
    let mut table = crate::console::table_output(args.json.as_deref());
    writeln!(
        table,
        "{}, transform {}, q = {}, Eq. 22 RMSE (divided by {} angular cells)",
        quantity(ev.n_materials, "material"),
        ev.transform,
        ev.latent_dim,
        ev.n_angles
    )?;
    writeln!(
        table,
        "{:<24} {:>12} {:>12} {:>12} {:>12} {:>10}",
        "method", "brdf mean", "brdf median", "model mean", "model median", "gp better"
    )?;
    for s in &ev.summary {
        writeln!(
            table,
            "{:<24} {:>12.5e} {:>12.5e} {:>12.5e} {:>12.5e} {:>10}",
            s.method,
            s.brdf_mean,
            s.brdf_median,
            s.model_mean,
            s.model_median,
            s.gp_better
                .map_or(String::new(), |k| format!("{k}/{}", ev.n_materials))
        )?;
    }
    // Per material (the contract's "RMSE per material"): BRDF-space RMSE of each method.
    let loo_methods: Vec<String> = ev
        .loo
        .as_ref()
        .and_then(|rows| rows.first())
        .map(|r| {
            r.methods
                .iter()
                .map(|m| format!("loo {}", m.method.name()))
                .collect()
        })
        .unwrap_or_default();
    let width = ev
        .reconstruction
        .iter()
        .map(|r| r.name.len())
        .max()
        .unwrap_or(0)
        .max("material".len());
    write!(table, "\nper material, brdf RMSE\n{:<width$}", "material")?;
    for head in ["exact", "smooth"]
        .iter()
        .copied()
        .chain(loo_methods.iter().map(String::as_str))
    {
        write!(table, " {head:>16}")?;
    }
    writeln!(table)?;
    for r in &ev.reconstruction {
        write!(
            table,
            "{:<width$} {:>16.5e} {:>16.5e}",
            r.name, r.exact_rmse, r.smooth_rmse
        )?;
        let loo = ev.loo.iter().flatten().find(|row| row.name == r.name);
        if let Some(row) = loo {
            for m in &row.methods {
                write!(table, " {:>16.5e}", m.brdf_rmse)?;
            }
        }
        writeln!(table)?;
    }
    if args.loo {
        writeln!(
            table,
            "leave-one-out refits and searches {:.2} s, error pass {:.2} s",
            ev.loo_seconds, ev.pass_seconds
        )?;
    }
    table.flush()?;
    drop(table);
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&ev)?;
        brdf_io::output::write_file_atomic(path, text.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_points_and_recognises_model_sources() {
        assert_eq!(parse_point("0.5,-1e-3").unwrap(), vec![0.5, -1e-3]);
        let x = [
            0.1 + 0.2,
            -1e-300,
            12345.678,
            1e100,
            0.0,
            1e-4,
            9.5e5,
            2.5e-7,
            -1e6,
        ];
        assert_eq!(parse_point(&format_point(&x)).unwrap(), x);
        assert_eq!(
            format_point(&x),
            "0.30000000000000004,-1e-300,12345.678,1e100,0,0.0001,950000,2.5e-7,-1e6"
        );
        let e = parse_point("0.5,x").unwrap_err().to_string();
        assert!(e.contains("\"x\" is not a number"), "{e}");
        let e = parse_point(" ").unwrap_err().to_string();
        assert!(e.contains("the latent point is empty"), "{e}");
        // A model point names its model, also when the point is missing or not a number.
        for (spec, want) in [
            (
                "/nonexistent/m.toml@",
                "/nonexistent/m.toml@: no latent point after the '@' of model \
                 /nonexistent/m.toml: give all its coordinates",
            ),
            (
                "/nonexistent/m.toml@0.5,x",
                "model /nonexistent/m.toml: latent point \"0.5,x\": \"x\" is not a number",
            ),
        ] {
            let e = open_model_source(spec, None, PredictorKind::Exact)
                .unwrap()
                .unwrap_err();
            assert!(format!("{e:#}").contains(want), "{e:#}");
        }
        assert!(open_model_source("data.sbrdf:felt", None, PredictorKind::Exact).is_none());
        assert!(open_model_source("file.bsdf", None, PredictorKind::Exact).is_none());
        let e = open_model_source("/nonexistent/m.toml@0,0", None, PredictorKind::Exact)
            .unwrap()
            .unwrap_err();
        assert!(format!("{e:#}").contains("/nonexistent/m.toml"), "{e:#}");
    }

    #[test]
    fn lerp_names_may_contain_commas_and_spaces() {
        let names = ["a", "a,b", "b,c", "c", "gp-exact@0.1,0.2", " pad "];
        let unknown = |n: &str| anyhow::anyhow!("unknown {n:?}");
        let read = |spec: &str| parse_lerp(spec, &names, unknown);
        // The plain syntax, with spaces around the fields.
        assert_eq!(read("a,c,0.25").unwrap(), (0, 3, 0.25));
        assert_eq!(read(" a , c , -1e-1").unwrap(), (0, 3, -0.1));
        // Names with commas, where one split reads.
        assert_eq!(read("gp-exact@0.1,0.2,c,0.5").unwrap(), (4, 3, 0.5));
        assert_eq!(read("c,gp-exact@0.1,0.2,1").unwrap(), (3, 4, 1.0));
        assert_eq!(read("a,b,a,0.5").unwrap(), (1, 0, 0.5));
        // A name with spaces at its ends, as given; trimmed, it is not a name.
        assert_eq!(read(" pad ,c,0.5").unwrap(), (5, 3, 0.5));
        assert_eq!(
            read("pad,c,0.5").unwrap_err().to_string(),
            "unknown \"pad\""
        );
        // Two readings: refused, naming both.
        let e = read("a,b,c,0.5").unwrap_err().to_string();
        assert!(
            e.contains("is ambiguous")
                && e.contains("NAME1 \"a\" and NAME2 \"b,c\"")
                && e.contains("NAME1 \"a,b\" and NAME2 \"c\""),
            "{e}"
        );
        // The unknown half is the one reported (the other names a material).
        assert_eq!(
            read("c,metal,0.5").unwrap_err().to_string(),
            "unknown \"metal\""
        );
        assert_eq!(
            read("metal, c,0.5").unwrap_err().to_string(),
            "unknown \"metal\""
        );
        // Also when the material follows the second comma: all before it is the unknown half.
        assert_eq!(
            read("x,y,c,0.5").unwrap_err().to_string(),
            "unknown \"x,y\""
        );
        // Syntax: A last, a number; two names before it.
        for (bad, want) in [
            ("a,c", "A = \"c\" is not a number"),
            ("a,c,x", "A = \"x\" is not a number"),
            ("a,0.5", "two material names before A"),
            ("a", "expected NAME1,NAME2,A"),
        ] {
            let e = read(bad).unwrap_err().to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
    }
}
