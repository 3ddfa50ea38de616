//! `specgp locate MODEL.toml TARGET... [--json OUT]`: where materials that are not in the
//! training set sit in a model's latent space (the inverse of `predict`).
//!
//! TARGET is a dataset store on the model's grid and channels (`DATA.sbrdf`: every material;
//! `DATA.sbrdf:MATERIAL`: one), an RGL `.bsdf` file or a MERL `.binary` file; files are
//! resampled onto the model's grid and channels as `import rgl|merl` does by default.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use brdf_io::store::Store;
use brdf_io::{AngularGrid, Channels};
use predict::Predictor;
use predict::locate::{Location, Target, locate};

/// Arguments of `specgp locate`.
#[derive(Debug, clap::Args)]
pub struct LocateArgs {
    /// Model file (TOML) written by `specgp fit`.
    pub model: PathBuf,
    /// Materials to locate: DATA.sbrdf (all its materials), DATA.sbrdf:MATERIAL, an RGL .bsdf
    /// file or a MERL .binary file (resampled onto the model's grid and channels with `import`'s
    /// defaults).
    #[arg(required = true)]
    pub targets: Vec<String>,
    /// Starts of the latent search per target (1..=1000): this many training points,
    /// midpoints of pairs of them, points half a length-scale off a training point and
    /// quasi-random points of the region they span, of each kind those that reconstruct it
    /// best.
    #[arg(long, default_value_t = 3, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1000))]
    pub starts: usize,
    /// Write the locations as JSON (`.json`; `-`: standard output, the table then goes to
    /// standard error).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Read the model's dataset from this store instead of the path recorded in the model.
    #[arg(long)]
    pub dataset: Option<PathBuf>,
}

/// `--wavelengths` (or `R,G,B`) as `import` takes it, for error messages.
fn channels_arg(channels: &Channels) -> String {
    match channels {
        Channels::Rgb => "R,G,B".into(),
        Channels::Spectral(w) => {
            let step = w.get(1).map(|b| b - w[0]);
            let uniform = step.is_some_and(|s| {
                w.windows(2)
                    .all(|p| ((p[1] - p[0]) - s).abs() <= 1e-9 * s.abs().max(1.0))
            });
            match step {
                Some(s) if uniform => format!("{}:{}:{s}", w[0], w[w.len() - 1]),
                _ => channels.labels().join(","),
            }
        }
    }
}

/// How to make a store that matches the model, for error messages.
fn import_hint(grid: &AngularGrid, channels: &Channels) -> String {
    match channels {
        Channels::Rgb => format!("`--grid {grid}`"),
        Channels::Spectral(_) => {
            format!("`--grid {grid} --wavelengths {}`", channels_arg(channels))
        }
    }
}

/// Targets are read and located this many at a time (memory: a target holds D values).
const TARGET_BATCH: usize = 32;

/// One material named by the TARGET arguments, before its values are read.
enum Pending {
    /// Material `index` of a target store (checked against the model, checksum verified).
    Stored { store: Arc<Store>, index: usize },
    /// An RGL `.bsdf` or MERL `.binary` file.
    File(String),
}

/// The materials one TARGET argument names, checked against `pred`'s grid and channels.
fn pending_targets(pred: &Predictor, spec: &str) -> anyhow::Result<Vec<Pending>> {
    let (grid, channels) = (pred.grid(), pred.channels());
    let (store_path, only) = match brdf_io::store::parse_store_spec(spec) {
        Some((path, name)) => (Some(path), Some(name)),
        None if brdf_io::has_extension(spec, "sbrdf") => (Some(PathBuf::from(spec)), None),
        None => (None, None),
    };
    let Some(path) = store_path else {
        let path = Path::new(spec);
        if !["bsdf", "binary"]
            .iter()
            .any(|e| brdf_io::has_extension(path, e))
        {
            bail!(
                "unknown TARGET {spec:?}: expected DATA.sbrdf, DATA.sbrdf:MATERIAL, an RGL .bsdf \
                 file or a MERL .binary file"
            );
        }
        return Ok(vec![Pending::File(spec.to_owned())]);
    };
    let store = Store::open(&path).with_context(|| format!("opening target {spec}"))?;
    if store.grid() != grid || store.channels() != channels {
        bail!(
            "target {}: grid {} with channels {}, but the model's data are on grid {grid} with \
             channels {}; make the store with {} (`specgp import` or `specgp synth`)",
            path.display(),
            store.grid(),
            channels_arg(store.channels()),
            channels_arg(channels),
            import_hint(grid, channels)
        );
    }
    // Lookups do not re-hash a payload; a target is read whole, so verify it as `export` does.
    store
        .verify_checksum()
        .with_context(|| format!("target {}", path.display()))?;
    let indices: Vec<usize> = match &only {
        Some(name) => vec![
            store
                .material_index(name)
                .with_context(|| format!("target {spec}"))?,
        ],
        None => (0..store.n_materials()).collect(),
    };
    let store = Arc::new(store);
    Ok(indices
        .into_iter()
        .map(|index| Pending::Stored {
            store: store.clone(),
            index,
        })
        .collect())
}

/// Reads the values of a batch of pending targets: the materials of one store in one pass
/// over it ([`Target::from_store`]), files resampled onto `pred`'s grid and channels
/// ([`Target::from_file`], its report printed).
fn read_targets(pred: &Predictor, batch: &[Pending]) -> anyhow::Result<Vec<Target>> {
    let mut targets: Vec<Option<Target>> = batch.iter().map(|_| None).collect();
    for (k, p) in batch.iter().enumerate() {
        match p {
            Pending::Stored { store, .. } if targets[k].is_none() => {
                // Every material of this store in the batch, in one pass.
                let same: Vec<(usize, usize)> = batch
                    .iter()
                    .enumerate()
                    .filter_map(|(j, p)| match p {
                        Pending::Stored { store: s, index } if Arc::ptr_eq(s, store) => {
                            Some((j, *index))
                        }
                        _ => None,
                    })
                    .collect();
                let indices: Vec<usize> = same.iter().map(|&(_, m)| m).collect();
                for ((j, _), t) in same.iter().zip(Target::from_store(store, &indices)?) {
                    targets[*j] = Some(t);
                }
            }
            Pending::Stored { .. } => {}
            Pending::File(spec) => {
                let (t, report) = Target::from_file(Path::new(spec), pred.grid(), pred.channels())?;
                errln!("resampled {spec}: {report}");
                targets[k] = Some(t);
            }
        }
    }
    Ok(targets.into_iter().flatten().collect())
}

/// Reads the TARGET arguments `specs` and locates them in `pred`'s latent space (`starts`
/// starting points each), [`TARGET_BATCH`] at a time, with a progress bar.
pub fn locate_targets(
    pred: &Predictor,
    specs: &[String],
    starts: usize,
) -> anyhow::Result<Vec<Location>> {
    let mut pending = Vec::new();
    for spec in specs {
        pending.extend(pending_targets(pred, spec)?);
    }
    let pb = crate::cmd_predict::bar(0, "locating");
    let batches = pending.len().div_ceil(TARGET_BATCH);
    let mut located = Vec::with_capacity(pending.len());
    for (b, batch) in pending.chunks(TARGET_BATCH).enumerate() {
        let targets = read_targets(pred, batch)?;
        located.extend(locate(pred, &targets, starts, &|done, total| {
            pb.set_length((total * batches) as u64);
            pb.set_position((b * total + done) as u64);
        })?);
    }
    pb.finish_and_clear();
    Ok(located)
}

/// Runs `specgp locate`.
pub fn locate_command(args: &LocateArgs) -> anyhow::Result<()> {
    let target_files: Vec<PathBuf> = args
        .targets
        .iter()
        .map(|t| crate::paths::source_file(t))
        .collect();
    if let Some(json) = &args.json {
        let mut inputs = crate::paths::model_inputs(&args.model, args.dataset.as_deref());
        inputs.extend(target_files.iter().map(PathBuf::as_path));
        crate::paths::ensure_output_is_not_an_input(json, &inputs)?;
        crate::paths::ensure_extension(json, "json", "a JSON file")?;
    }
    let pred = Predictor::open_with_dataset(&args.model, args.dataset.as_deref())
        .with_context(|| format!("opening model {}", args.model.display()))?;
    let located = locate_targets(&pred, &args.targets, args.starts)?;

    let mut table = crate::console::table_output(args.json.as_deref());
    writeln!(
        table,
        "{} target(s) in model {} (transform {}, q = {}). Eq. 22 RMSE against the target of \
         the prediction at the point found (exact predictor, as render and predict use) and of \
         the closest training material, in BRDF space and in the model's transformed space \
         (which the search minimises); var frac: the predictive variance left at the point",
        located.len(),
        args.model.display(),
        pred.transform(),
        pred.latent_dim()
    )?;
    // Name columns as wide as their longest entry (at least 28), so long names keep the
    // columns aligned.
    let wide = |names: &mut dyn Iterator<Item = usize>| names.max().unwrap_or(0).max(28);
    let (w1, w2) = (
        wide(&mut located.iter().map(|l| l.name.chars().count())),
        wide(&mut located.iter().map(|l| l.nearest.chars().count())),
    );
    writeln!(
        table,
        "{:<w1$} {:>11} {:>11}  {:<w2$} {:>11} {:>11} {:>8}  point",
        "target",
        "brdf rmse",
        "model rmse",
        "closest material",
        "its brdf",
        "its model",
        "var frac"
    )?;
    for l in &located {
        writeln!(
            table,
            "{:<w1$} {:>11.4e} {:>11.4e}  {:<w2$} {:>11.4e} {:>11.4e} {:>8.3}  {}",
            l.name,
            l.brdf_rmse,
            l.model_rmse,
            l.nearest,
            l.nearest_brdf_rmse,
            l.nearest_model_rmse,
            l.variance_fraction,
            crate::cmd_predict::format_point(&l.point)
        )?;
    }
    table.flush()?;
    drop(table);
    for l in located.iter().filter(|l| l.is_far()) {
        errln!(
            "warning: {} lies far from every training material (the GP explains {:.0} % of the \
             prior variance at its point): its location says little",
            l.name,
            100.0 * (1.0 - l.variance_fraction)
        );
    }
    if let Some(path) = &args.json {
        let report = serde_json::json!({
            "model": args.model.display().to_string(),
            "dataset": pred.store().path().display().to_string(),
            "transform": pred.transform().to_string(),
            "latent_dim": pred.latent_dim(),
            "n_angles": pred.grid().len(),
            "locations": located,
        });
        let text = serde_json::to_string_pretty(&report)?;
        brdf_io::output::write_file_atomic(path, text.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_arguments_read_back_as_the_same_channels() {
        for spec in ["360:1000:20", "400,450,520", "400:700:2.5"] {
            let ch = Channels::parse_wavelengths(spec).unwrap();
            let arg = channels_arg(&ch);
            assert_eq!(
                Channels::parse_wavelengths(&arg).unwrap(),
                ch,
                "{spec} -> {arg}"
            );
        }
        assert_eq!(channels_arg(&Channels::Rgb), "R,G,B");
        assert_eq!(
            channels_arg(&Channels::parse_wavelengths("360:1000:20").unwrap()),
            "360:1000:20"
        );
    }
}
