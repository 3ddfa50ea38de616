//! `specgp locate MODEL.toml TARGET... [--json OUT]`: where materials that are not in the
//! training set sit in a model's latent space (the inverse of `predict`).
//!
//! TARGET is a dataset store on the model's grid and channels (`DATA.sbrdf`: every material;
//! `DATA.sbrdf:MATERIAL`: one), an RGL `.bsdf` file or a MERL `.binary` file; files are
//! resampled onto the model's grid and channels as `import rgl|merl` does by default.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
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
    /// Starting points of the latent search per target (the training points that reconstruct it
    /// best; 1..=1000).
    #[arg(long, default_value_t = 3, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=1000))]
    pub starts: usize,
    /// Write the locations as JSON (`-`: standard output; the table then goes to standard error).
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

/// How to import a file so that it matches the model, for error messages.
fn import_hint(grid: &AngularGrid, channels: &Channels) -> String {
    match channels {
        Channels::Rgb => format!("`specgp import ... --grid {grid}`"),
        Channels::Spectral(_) => format!(
            "`specgp import ... --grid {grid} --wavelengths {}`",
            channels_arg(channels)
        ),
    }
}

/// The targets named by one TARGET argument, on `pred`'s grid and channels.
fn read_targets(pred: &Predictor, spec: &str) -> anyhow::Result<Vec<Target>> {
    let (grid, channels) = (pred.grid(), pred.channels());
    let (store_path, only) = match brdf_io::store::parse_store_spec(spec) {
        Some((path, name)) => (Some(path), Some(name)),
        None if spec.ends_with(".sbrdf") => (Some(PathBuf::from(spec)), None),
        None => (None, None),
    };
    if let Some(path) = store_path {
        let store =
            brdf_io::Store::open(&path).with_context(|| format!("opening target {spec}"))?;
        if store.grid() != grid || store.channels() != channels {
            bail!(
                "target {}: grid {} with channels {}, but the model's data are on grid {grid} \
                 with channels {}; import the material with {}",
                path.display(),
                store.grid(),
                channels_arg(store.channels()),
                channels_arg(channels),
                import_hint(grid, channels)
            );
        }
        let indices: Vec<usize> = match &only {
            Some(name) => vec![
                store
                    .material_index(name)
                    .with_context(|| format!("target {spec}"))?,
            ],
            None => (0..store.n_materials()).collect(),
        };
        // One pass over the store for all of them.
        let (n, d) = (store.n_materials(), store.d());
        let mut values: Vec<Vec<f32>> = indices.iter().map(|_| vec![0f32; d]).collect();
        store.for_each_chunk(|range, block| {
            for (k, i) in range.enumerate() {
                for (v, &m) in values.iter_mut().zip(&indices) {
                    v[i] = block[k * n + m];
                }
            }
        })?;
        let names = store.names();
        return Ok(indices
            .into_iter()
            .zip(values)
            .map(|(m, values)| Target {
                name: names[m].to_owned(),
                values,
            })
            .collect());
    }
    let path = Path::new(spec);
    let name = path
        .file_stem()
        .map_or_else(|| spec.to_owned(), |s| s.to_string_lossy().into_owned());
    let values = match path.extension().and_then(|e| e.to_str()) {
        Some("bsdf") => {
            let bsdf = brdf_io::rgl::RglBsdf::open(path)?;
            let (values, report) = bsdf.resample(grid, channels).with_context(|| {
                format!(
                    "target {spec}: resampling onto the model's grid {grid} and channels {}",
                    channels_arg(channels)
                )
            })?;
            report.ensure_finite(spec)?;
            values
        }
        Some("binary") => {
            if *channels != Channels::Rgb {
                bail!(
                    "target {spec} is a MERL file (R,G,B), but the model's data are spectral \
                     (channels {})",
                    channels_arg(channels)
                );
            }
            let brdf = brdf_io::merl::read_merl(path)?;
            brdf.resample(grid, brdf_io::merl::Resampling::Average).0
        }
        _ => bail!(
            "unknown TARGET {spec:?}: expected DATA.sbrdf, DATA.sbrdf:MATERIAL, an RGL .bsdf file \
             or a MERL .binary file"
        ),
    };
    Ok(vec![Target { name, values }])
}

/// Reads the TARGET arguments `specs` and locates them in `pred`'s latent space (`starts`
/// starting points each), with a progress bar.
pub fn locate_targets(
    pred: &Predictor,
    specs: &[String],
    starts: usize,
) -> anyhow::Result<Vec<Location>> {
    let mut targets = Vec::new();
    for spec in specs {
        targets.extend(read_targets(pred, spec)?);
    }
    let pb = crate::cmd_predict::bar(0, "locating");
    let located = locate(pred, &targets, starts, &|done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    })?;
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
    }
    let pred = Predictor::open_with_dataset(&args.model, args.dataset.as_deref())
        .with_context(|| format!("opening model {}", args.model.display()))?;
    let located = locate_targets(&pred, &args.targets, args.starts)?;

    let mut table = crate::cmd_predict::table_output(args.json.as_deref());
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
    writeln!(
        table,
        "{:<28} {:>11} {:>11}  {:<28} {:>11} {:>11} {:>8}  point",
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
            "{:<28} {:>11.4e} {:>11.4e}  {:<28} {:>11.4e} {:>11.4e} {:>8.3}  {}",
            l.name,
            l.brdf_rmse,
            l.model_rmse,
            l.nearest,
            l.nearest_brdf_rmse,
            l.nearest_model_rmse,
            l.variance_fraction,
            l.point
                .iter()
                .map(|v| v.to_string())
                .collect::<Vec<_>>()
                .join(",")
        )?;
    }
    table.flush()?;
    drop(table);
    for l in located
        .iter()
        .filter(|l| l.variance_fraction > predict::PointSupport::FAR)
    {
        eprintln!(
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
