//! `cargo xtask pipeline CONFIG`: data -> fit -> predict -> evaluate -> figures, then
//! `report.md` and `results.json` (every number of the report) in the output directory.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::config::PipelineConfig;
use crate::data::build_store;
use crate::error::{Error, Result};
use crate::report;

/// What happened to one stage.
#[derive(Debug, Clone, Serialize)]
pub struct StageStatus {
    /// Stage name.
    pub name: String,
    /// `done`, `skipped` (by the config) or `not available` (the crate has not landed).
    pub status: String,
    /// Wall-clock seconds (0 when not run).
    pub seconds: f64,
}

/// The data stage's numbers.
#[derive(Debug, Clone, Serialize)]
pub struct DataResults {
    /// `synth`, `nbrdf`, `merl` or `rgl`.
    pub kind: String,
    /// Store file (relative to the output directory).
    pub store: String,
    /// Number of materials N.
    pub n_materials: usize,
    /// Angular grid `TH,TD,PD`.
    pub grid: String,
    /// Number of channels.
    pub n_channels: usize,
    /// Channel labels.
    pub channels: Vec<String>,
    /// Values per material D.
    pub d: usize,
    /// Stored value type.
    pub dtype: String,
    /// Store size in bytes.
    pub store_bytes: u64,
    /// Values outside the valid range reported by the import (0 for synthetic data).
    pub import_outliers: usize,
    /// Negative values clamped by the import.
    pub import_negatives_clamped: usize,
    /// Seconds to build the store.
    pub seconds: f64,
}

/// The fit stage's numbers.
#[derive(Debug, Clone, Serialize)]
pub struct FitResults {
    /// Where the fit settings came from.
    pub config: String,
    /// Model file (relative to the output directory).
    pub model: String,
    /// Optimiser.
    pub optimizer: String,
    /// Transform.
    pub transform: String,
    /// Latent dimension q.
    pub latent_dim: usize,
    /// Final log-likelihood (the model file's `fit.log_likelihood`).
    pub log_likelihood: f64,
    /// Log-likelihood at the PCA start.
    pub initial_log_likelihood: f64,
    /// Optimiser iterations.
    pub iterations: u64,
    /// Objective evaluations.
    pub evaluations: u64,
    /// Why the optimiser stopped.
    pub stop_reason: String,
    /// Kernel signal variance s^2.
    pub signal_variance: f64,
    /// Length-scale(s).
    pub length_scale: Vec<f64>,
    /// Noise mu.
    pub noise: f64,
    /// Condition number estimate of K.
    pub condition_number: f64,
    /// Fraction of variance in the first q principal components.
    pub pca_explained: f64,
    /// Seconds of the Gram pass.
    pub gram_seconds: f64,
    /// Seconds of the optimisation.
    pub optimize_seconds: f64,
    /// Total wall-clock seconds of the stage.
    pub seconds: f64,
}

/// One material's latent point.
#[derive(Debug, Clone, Serialize)]
pub struct LatentRow {
    /// Material name.
    pub name: String,
    /// Latent coordinates.
    pub coords: Vec<f64>,
}

/// Mean errors of one kind of material.
#[derive(Debug, Clone, Serialize)]
pub struct KindRow {
    /// `diffuse`, `glossy` or `metallic`.
    pub kind: String,
    /// Number of materials.
    pub n: usize,
    /// Mean Eq. 22 reconstruction RMSE of the exact predictor (BRDF space).
    pub reconstruction_exact: f64,
    /// Mean Eq. 22 reconstruction RMSE of the smooth predictor (BRDF space).
    pub reconstruction_smooth: f64,
    /// Mean Eq. 22 leave-one-out RMSE of the GP (BRDF space; NaN without leave-one-out).
    pub loo_gp: f64,
}

/// The kind of a synthetic preset family: diffuse, glossy (coated, plastic, fabric) or metallic.
pub fn kind_of(family: brdf_synth::Family) -> &'static str {
    use brdf_synth::Family as F;
    match family {
        F::Felt | F::Paper | F::Cardboard | F::WallPaint | F::Leaf | F::Diffuser => "diffuse",
        F::Vinyl | F::Satin | F::CarPaint => "glossy",
        F::PaintedMetal | F::Metal | F::Iridescent => "metallic",
    }
}

/// Errors by kind of material for a synthetic dataset (empty for other data).
pub fn by_kind(config: &PipelineConfig, e: &predict::evaluate::Evaluation) -> Vec<KindRow> {
    let crate::config::DataSource::Synth { seed, .. } = &config.data.source else {
        return Vec::new();
    };
    let families: std::collections::HashMap<String, brdf_synth::Family> = brdf_synth::preset(*seed)
        .into_iter()
        .map(|m| (m.name, m.family))
        .collect();
    ["diffuse", "glossy", "metallic"]
        .iter()
        .map(|kind| {
            let idx: Vec<usize> = e
                .reconstruction
                .iter()
                .enumerate()
                .filter(|(_, r)| families.get(&r.name).map(|f| kind_of(*f)) == Some(*kind))
                .map(|(i, _)| i)
                .collect();
            let mean = |f: &dyn Fn(usize) -> f64| {
                idx.iter().map(|&i| f(i)).sum::<f64>() / idx.len().max(1) as f64
            };
            KindRow {
                kind: (*kind).to_string(),
                n: idx.len(),
                reconstruction_exact: mean(&|i| e.reconstruction[i].exact_rmse),
                reconstruction_smooth: mean(&|i| e.reconstruction[i].smooth_rmse),
                loo_gp: e.loo.as_ref().map_or(f64::NAN, |l| {
                    mean(&|i| {
                        l[i].methods
                            .iter()
                            .find(|m| m.method == predict::evaluate::Method::Gp)
                            .map_or(f64::NAN, |m| m.brdf_rmse)
                    })
                }),
            }
        })
        .filter(|r| r.n > 0)
        .collect()
}

/// Everything a pipeline run measured (`results.json`).
#[derive(Debug, Clone, Serialize)]
pub struct Results {
    /// Config name.
    pub name: String,
    /// Config description.
    pub description: String,
    /// Config file.
    pub config_file: String,
    /// The output directory the run published to, as given.
    #[serde(default)]
    pub out_dir: String,
    /// The config as parsed.
    pub config: crate::config::PipelineParams,
    /// Stages in order.
    pub stages: Vec<StageStatus>,
    /// Data stage.
    pub data: DataResults,
    /// Fit stage.
    pub fit: FitResults,
    /// Latent coordinates of the training materials.
    pub latent: Vec<LatentRow>,
    /// Predictions at the configured latent points (predict stage).
    pub predictions: Vec<crate::stages::PredictionRow>,
    /// The stored materials' largest directional albedo (predict stage, beside the
    /// predictions' own).
    pub stored_albedo: Vec<crate::stages::StoredAlbedo>,
    /// Reconstruction and leave-one-out errors (evaluate stage; `None` if not run).
    pub evaluation: Option<predict::evaluate::Evaluation>,
    /// Errors grouped by kind of material (synthetic data only: the preset's families).
    pub by_kind: Vec<KindRow>,
    /// Measured files outside the training set placed in the latent space (locate stage).
    pub located: Vec<predict::locate::Location>,
    /// Figures and rendered (Delta E) errors (render stage; `None` if not run).
    pub figures: Option<crate::figures::Figures>,
    /// Total wall-clock seconds.
    pub total_seconds: f64,
}

/// The project root: the parent of the xtask crate's directory, as this process runs it. That is
/// `CARGO_MANIFEST_DIR` of the environment, which `cargo run` (so `cargo xtask`) and `cargo
/// test` set to the checkout they run, and only without it the directory the binary was
/// compiled in (`env!`): a binary built from another checkout (a shared `CARGO_TARGET_DIR`)
/// would otherwise read that checkout's configs and write its `out/`.
pub fn project_root() -> PathBuf {
    root_of(std::env::var_os("CARGO_MANIFEST_DIR"))
}

/// [`project_root`] for the xtask crate's directory `manifest_dir` (`None` or empty: the one
/// the binary was compiled in).
fn root_of(manifest_dir: Option<std::ffi::OsString>) -> PathBuf {
    let manifest = manifest_dir
        .filter(|d| !d.is_empty())
        .map_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")), PathBuf::from);
    match manifest.parent() {
        Some(parent) if parent.as_os_str().is_empty() => PathBuf::from("."),
        Some(parent) => parent.to_owned(),
        None => manifest,
    }
}

/// Writes `bytes` to `path` atomically ([`brdf_io::output::write_file_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    brdf_io::output::write_file_atomic(path, bytes).map_err(|e| Error::stage("write", path, e))
}

/// Whether `name` is a file the pipeline writes into its output directory (an earlier run's
/// copy that a new run does not produce is stale: it would describe other data).
pub fn is_pipeline_output(name: &str) -> bool {
    const FILES: [&str; 9] = [
        "data.sbrdf",
        "model.toml",
        "report.md",
        "results.json",
        "latent.png",
        "sheet.png",
        "comparison.png",
        "paths.png",
        "predictions.png",
    ];
    FILES.contains(&name)
        || name
            .strip_prefix("prediction-")
            .and_then(|rest| rest.split_once('.'))
            .is_some_and(|(k, ext)| {
                !k.is_empty()
                    && k.bytes().all(|b| b.is_ascii_digit())
                    && ["npy", "sbrdf", "binary", "bsdf"].contains(&ext)
            })
}

/// The files a run of `config` reads: the config itself, its fit config, its data files and the
/// files it locates.
fn inputs(config: &PipelineConfig) -> Vec<PathBuf> {
    let mut v = vec![config.path.clone()];
    if let Some(f) = &config.params.fit_config {
        v.push(config.root.join(f));
    }
    match &config.data.source {
        crate::config::DataSource::Synth { .. } => {}
        crate::config::DataSource::Nbrdf { weights, names, .. } => {
            v.extend([weights.clone(), names.clone()]);
        }
        crate::config::DataSource::Merl { files }
        | crate::config::DataSource::Rgl { files, .. } => {
            v.extend(files.iter().cloned());
        }
    }
    v.extend(config.locate.iter().cloned());
    v
}

/// An error naming the config and the key when an input file the run reads (data files, the
/// Neural-BRDF weights and names, files to locate) is not a file: checked before the output
/// directory is touched, rather than in the data stage after the earlier files' import.
fn check_inputs(config: &PipelineConfig) -> Result<()> {
    let p = &config.params;
    let mut keyed: Vec<(String, &Path, &Path)> = Vec::new();
    match &config.data.source {
        crate::config::DataSource::Synth { .. } => {}
        crate::config::DataSource::Nbrdf { weights, names, .. } => {
            if let (Some(w), Some(n)) = (&p.data.weights, &p.data.names) {
                keyed.push(("data.weights".into(), w, weights));
                keyed.push(("data.names".into(), n, names));
            }
        }
        crate::config::DataSource::Merl { files }
        | crate::config::DataSource::Rgl { files, .. } => {
            for (i, (given, f)) in p.data.files.iter().zip(files).enumerate() {
                keyed.push((format!("data.files[{i}]"), given, f));
            }
        }
    }
    for (i, (given, f)) in p.locate.files.iter().zip(&config.locate).enumerate() {
        keyed.push((format!("locate.files[{i}]"), given, f));
    }
    for (key, given, path) in keyed {
        let what = match std::fs::metadata(path) {
            Ok(m) if m.is_file() => continue,
            Ok(_) => "is not a file",
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "does not exist",
            Err(_) => "cannot be read",
        };
        let relative = if given.is_relative() {
            format!(
                " (a relative path in a config is relative to the project root {})",
                config.root.display()
            )
        } else {
            String::new()
        };
        return Err(Error::Config {
            path: config.path.clone(),
            reason: format!("{key}: {} {what}{relative}", path.display()),
        });
    }
    Ok(())
}

/// An error when publishing into `out` would replace or delete one of the run's inputs (a
/// config or data file kept in the output directory under an output's name).
fn ensure_inputs_survive(config: &PipelineConfig, out: &Path) -> Result<()> {
    let Ok(out_dir) = out.canonicalize() else {
        return Ok(()); // a new directory holds no input
    };
    for input in inputs(config) {
        let (Some(parent), Some(name)) = (input.parent(), input.file_name()) else {
            continue;
        };
        let parent = if parent.as_os_str().is_empty() {
            Path::new(".")
        } else {
            parent
        };
        if parent.canonicalize().is_ok_and(|p| p == out_dir)
            && is_pipeline_output(&name.to_string_lossy())
        {
            return Err(Error::Config {
                path: config.path.clone(),
                reason: format!(
                    "the run would overwrite its input {} (the output directory {} receives a \
                     file of that name); choose another --out",
                    input.display(),
                    out.display()
                ),
            });
        }
    }
    Ok(())
}

/// Runs the pipeline of `config` into `out` (created if needed) and writes `report.md` and
/// `results.json` there. The run writes into a staging directory inside `out` and publishes
/// its files together at the end ([`brdf_io::output::StagingDir`]): a failed or interrupted run
/// leaves `out` as it was, and a successful one removes the earlier run's outputs it does not
/// produce. The model records its dataset as `data.sbrdf` beside it.
///
/// When `out` does not exist, the run stages in its nearest existing ancestor and moves the new
/// directory (with any missing parents) there in one rename at the end, so that a failed or
/// interrupted run leaves no directory behind either.
pub fn run(config: &PipelineConfig, out: &Path) -> Result<Results> {
    check_inputs(config)?;
    ensure_inputs_survive(config, out)?;
    run_staged(out, is_pipeline_output, |dir| run_in(config, dir, out))
}

/// Runs `body` on a staging directory for the output directory `out` and publishes what it
/// wrote there: into `out` when it exists ([`brdf_io::output::StagingDir::publish`], removing
/// the earlier run's files for which `is_output` holds and that this run did not write), else
/// by moving the new directory (with any missing parents) into place in one rename, so that a
/// failed or interrupted run leaves `out` as it was, or absent. Errors name paths under `out`,
/// not the staging directory ([`Error::published`]).
pub(crate) fn run_staged<T>(
    out: &Path,
    is_output: impl Fn(&str) -> bool,
    body: impl FnOnce(&Path) -> Result<T>,
) -> Result<T> {
    let output_err = |path: &Path, e: &dyn std::fmt::Display| Error::stage("output", path, e);
    match std::fs::metadata(out) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(output_err(
                out,
                &"exists and is not a directory (--out names the directory the run writes into)",
            ));
        }
        Err(e) if is_missing(&e) => {
            if let Some((base, missing)) = missing_dirs(out)? {
                let stage = brdf_io::output::StagingDir::create(&base)
                    .map_err(|e| output_err(&base, &e))?;
                let inner = missing
                    .iter()
                    .fold(stage.path().to_owned(), |p, name| p.join(name));
                std::fs::create_dir_all(&inner).map_err(|e| Error::io(&inner, e))?;
                let value = body(&inner).map_err(|e| e.published(&inner, out))?;
                let (from, to) = (stage.path().join(&missing[0]), base.join(&missing[0]));
                std::fs::rename(&from, &to).map_err(|e| Error::io(&to, e))?;
                return Ok(value);
            }
        }
        Err(e) => return Err(Error::io(out, e)),
    }
    let stage = brdf_io::output::StagingDir::create(out).map_err(|e| output_err(out, &e))?;
    let value = body(stage.path()).map_err(|e| e.published(stage.path(), out))?;
    stage.publish(is_output).map_err(|e| output_err(out, &e))?;
    Ok(value)
}

/// Whether a path's metadata failed because it is not there (or a parent is a file).
fn is_missing(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory
    )
}

/// For an output directory `out` that does not exist: its nearest existing ancestor and the
/// names of the directories to create below it, outermost first. `None` when the missing part
/// is not plain names (`..`), where the directories are created up front as before.
fn missing_dirs(out: &Path) -> Result<Option<(PathBuf, Vec<std::ffi::OsString>)>> {
    let mut missing = Vec::new();
    let mut base = out;
    loop {
        if base.as_os_str().is_empty() {
            base = Path::new(".");
        }
        match std::fs::metadata(base) {
            Ok(m) if m.is_dir() => break,
            Ok(_) => {
                return Err(Error::stage(
                    "output",
                    out,
                    format!("{} is not a directory", base.display()),
                ));
            }
            Err(e) if is_missing(&e) => {}
            Err(e) => return Err(Error::io(base, e)),
        }
        match base.components().next_back() {
            Some(std::path::Component::Normal(name)) => missing.push(name.to_owned()),
            _ => return Ok(None),
        }
        base = base.parent().unwrap_or(Path::new("."));
    }
    missing.reverse();
    Ok(Some((base.to_owned(), missing)))
}

/// The stages of [`run`], writing into `out` (the staging directory; `published` is where the
/// files will be).
fn run_in(config: &PipelineConfig, out: &Path, published: &Path) -> Result<Results> {
    let total = Instant::now();
    let mut stages = Vec::new();

    // Data.
    let store_path = out.join("data.sbrdf");
    tracing::info!(store = %store_path.display(), kind = config.data.source.kind(), "data");
    let (import, data_seconds) = build_store(&config.data, &store_path)?;
    let store =
        brdf_io::Store::open(&store_path).map_err(|e| Error::stage("data", &store_path, e))?;
    let names: Vec<String> = store
        .header()
        .materials
        .iter()
        .map(|m| m.name.clone())
        .collect();
    config.check_midpoints(&names)?;
    let data = DataResults {
        kind: config.data.source.kind().into(),
        store: "data.sbrdf".into(),
        n_materials: store.n_materials(),
        grid: store.grid().to_string(),
        n_channels: store.channels().len(),
        channels: store.channels().labels(),
        d: store.d(),
        dtype: config.data.dtype.name().into(),
        store_bytes: store.file_bytes(),
        import_outliers: import.outliers,
        import_negatives_clamped: import.negatives_clamped,
        seconds: data_seconds,
    };
    drop(store);
    stages.push(StageStatus {
        name: "data".into(),
        status: "done".into(),
        seconds: data_seconds,
    });

    // Fit.
    let model_path = out.join("model.toml");
    let fit_start = Instant::now();
    tracing::info!(config = %config.fit_source, "fit");
    let mut model = gplvm::fit_store(&store_path, &config.fit)
        .map_err(|e| Error::stage("fit", &store_path, e))?;
    // Beside the model (relative to its directory): the files move out of the staging directory.
    model.dataset.path = PathBuf::from("data.sbrdf");
    model
        .save(&model_path)
        .map_err(|e| Error::stage("fit", &model_path, e))?;
    let fit_seconds = fit_start.elapsed().as_secs_f64();
    let fit = FitResults {
        config: config.fit_source.clone(),
        model: "model.toml".into(),
        optimizer: model.fit.optimizer.clone(),
        transform: model.transform.to_string(),
        latent_dim: model.latent_dim,
        log_likelihood: model.fit.log_likelihood,
        initial_log_likelihood: model.fit.initial_log_likelihood,
        iterations: model.fit.iterations,
        evaluations: model.fit.evaluations,
        stop_reason: model.fit.stop_reason.clone(),
        signal_variance: model.hyperparameters.signal_variance,
        length_scale: model.hyperparameters.length_scale.clone(),
        noise: model.hyperparameters.noise,
        condition_number: model.fit.condition_number,
        pca_explained: model.fit.pca_explained,
        gram_seconds: model.fit.gram_seconds,
        optimize_seconds: model.fit.optimize_seconds,
        seconds: fit_seconds,
    };
    stages.push(StageStatus {
        name: "fit".into(),
        status: "done".into(),
        seconds: fit_seconds,
    });
    let latent = model
        .materials
        .iter()
        .map(|m| LatentRow {
            name: m.name.clone(),
            coords: m.coords.clone(),
        })
        .collect();

    // Predict.
    let t = Instant::now();
    let pred = crate::stages::open(&model_path)?;
    let albedo_weights = crate::stages::grid_albedo(&pred)?;
    let predictions = crate::stages::predict_points(&pred, config, out, &albedo_weights)?;
    let stored_albedo = if predictions.is_empty() {
        Vec::new()
    } else {
        crate::stages::stored_albedo(&pred, &albedo_weights, config.lookup)?
    };
    stages.push(StageStatus {
        name: "predict".into(),
        status: if predictions.is_empty() {
            "skipped".into()
        } else {
            "done".into()
        },
        seconds: t.elapsed().as_secs_f64(),
    });

    // Evaluate.
    let t = Instant::now();
    let mut evaluation = crate::stages::run_evaluate(&pred, config.params.evaluate.loo)?;
    // The store beside the published results, not the staging path (deleted after publishing).
    evaluation.dataset = "data.sbrdf".into();
    let evaluation = Some(evaluation);
    stages.push(StageStatus {
        name: "evaluate".into(),
        status: "done".into(),
        seconds: t.elapsed().as_secs_f64(),
    });

    // Locate.
    let t = Instant::now();
    let located = if config.locate.is_empty() {
        Vec::new()
    } else {
        crate::stages::locate_files(&pred, &config.locate, config.params.locate.starts)?
    };
    stages.push(StageStatus {
        name: "locate".into(),
        status: if located.is_empty() {
            "skipped"
        } else {
            "done"
        }
        .into(),
        seconds: t.elapsed().as_secs_f64(),
    });

    // Render.
    let t = Instant::now();
    let figures = if config.params.render.enabled {
        Some(crate::figures::render_figures(
            &pred,
            &predictions,
            evaluation.as_ref(),
            config,
            &located,
            out,
        )?)
    } else {
        None
    };
    stages.push(StageStatus {
        name: "render".into(),
        status: if figures.is_some() { "done" } else { "skipped" }.into(),
        seconds: t.elapsed().as_secs_f64(),
    });

    let results = Results {
        name: config.params.name.clone(),
        description: config.params.description.clone(),
        config_file: config.path.display().to_string(),
        out_dir: published.display().to_string(),
        config: config.params.clone(),
        stages,
        data,
        fit,
        latent,
        predictions,
        stored_albedo,
        by_kind: evaluation
            .as_ref()
            .map_or_else(Vec::new, |e| by_kind(config, e)),
        evaluation,
        located,
        figures,
        total_seconds: total.elapsed().as_secs_f64(),
    };
    let json = serde_json::to_string_pretty(&results)
        .map_err(|e| Error::stage("report", out.join("results.json"), e))?;
    write_atomic(&out.join("results.json"), json.as_bytes())?;
    write_atomic(
        &out.join("report.md"),
        report::markdown(&results).as_bytes(),
    )?;
    Ok(results)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Outputs are the run's fixed files and `prediction-K.EXT` for a number K and the four
    /// formats: other files in the output directory are the user's.
    #[test]
    fn pipeline_outputs_are_recognised_by_name() {
        for name in [
            "report.md",
            "data.sbrdf",
            "prediction-1.npy",
            "prediction-12.bsdf",
        ] {
            assert!(is_pipeline_output(name), "{name}");
        }
        for name in [
            "notes.md",
            "prediction-.npy",
            "prediction-x.npy",
            "prediction-1x.sbrdf",
            "prediction-1.txt",
            "prediction-1",
        ] {
            assert!(!is_pipeline_output(name), "{name}");
        }
    }

    /// The root comes from the run-time `CARGO_MANIFEST_DIR` (a binary built in another
    /// checkout used the compile-time one), falling back to the compile-time one.
    #[test]
    fn project_root_is_resolved_at_run_time() {
        assert_eq!(
            root_of(Some("/elsewhere/checkout/xtask".into())),
            Path::new("/elsewhere/checkout")
        );
        let compiled = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
        assert_eq!(root_of(None), compiled);
        assert_eq!(root_of(Some("".into())), compiled);
        assert_eq!(root_of(Some("xtask".into())), Path::new("."));
    }
}
