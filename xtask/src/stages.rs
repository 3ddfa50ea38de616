//! The predict and evaluate stages, through the predict crate.

use std::path::Path;
use std::time::Instant;

use brdf_io::lookup::WithLookup;
use predict::evaluate::{EvalOptions, Evaluation, Stage, evaluate};
use predict::{Predictor, PredictorKind};
use serde::Serialize;

use crate::config::{PipelineConfig, PredictorChoice};
use crate::data::bar;
use crate::error::{Error, Result};

/// One prediction at a latent point.
#[derive(Debug, Clone, Serialize)]
pub struct PredictionRow {
    /// What the point is (`point 1`, `mid(a, b)`).
    pub label: String,
    /// Latent coordinates.
    pub point: Vec<f64>,
    /// `exact` or `smooth`.
    pub predictor: String,
    /// Predictive variance of one transformed value.
    pub variance: f64,
    /// Microseconds to compute the N coefficients (the lazy prediction itself).
    pub weights_us: f64,
    /// Microseconds per lazy lookup of one angular cell, all channels (mean over many cells).
    pub lookup_us: f64,
    /// Mean of the predicted values over the looked-up cells (1/sr).
    pub lookup_mean: f64,
    /// Materialised file (relative to the output directory), when asked.
    pub file: Option<String>,
    /// Size of the materialised file in bytes (0 when not materialised).
    pub file_bytes: u64,
    /// Seconds to materialise all D values (0 when not materialised).
    pub materialize_seconds: f64,
    /// The prediction as an RGL `.bsdf` file (relative to the output directory), when asked.
    pub bsdf: Option<BsdfFile>,
    /// Its largest directional albedo ([`grid_albedo`]).
    pub albedo: AlbedoPeak,
}

/// A prediction written as an RGL `.bsdf` file (`[predict] bsdf = true`).
#[derive(Debug, Clone, Serialize)]
pub struct BsdfFile {
    /// File name, relative to the output directory.
    pub file: String,
    /// Size in bytes.
    pub bytes: u64,
    /// Seconds to write it (sampling the lazy prediction, checking, refining).
    pub seconds: f64,
    /// Incident elevations of the file (after refinement).
    pub theta_samples: usize,
    /// Value-table side.
    pub resolution: usize,
    /// The writer's check: cos-weighted relative RMS error against the prediction.
    pub check_rms: f64,
    /// The writer's check: largest relative error of the directional albedo (0-88 degrees).
    pub albedo_error: f64,
}

/// The largest directional albedo of a source over [`ALBEDO_THETAS_DEG`] and every channel
/// (`specgp albedo`): above 1 it reflects more light than it receives.
#[derive(Debug, Clone, Serialize)]
pub struct AlbedoPeak {
    /// The albedo.
    pub value: f64,
    /// Its incident elevation in degrees.
    pub angle_deg: f64,
    /// Its channel (`550`, `G`).
    pub channel: String,
}

/// A stored material's [`AlbedoPeak`].
#[derive(Debug, Clone, Serialize)]
pub struct StoredAlbedo {
    /// The material.
    pub material: String,
    /// Its largest directional albedo.
    pub peak: AlbedoPeak,
}

/// Incident elevations (degrees) of the energy check: the RGL writer's albedo check's, 0-88.
pub use brdf_io::rgl::ALBEDO_THETAS_DEG;

/// The energy check's quadrature on the predictor's grid ([`ALBEDO_THETAS_DEG`], 96 x 96 half
/// vectors), built once for the stored materials and the predictions.
pub fn grid_albedo(pred: &Predictor) -> Result<brdf_io::albedo::GridAlbedo> {
    brdf_io::albedo::GridAlbedo::new(
        pred.grid(),
        &ALBEDO_THETAS_DEG,
        brdf_io::albedo::DEFAULT_RESOLUTION,
    )
    .map_err(|e| Error::stage("predict", pred.model().dataset.path.clone(), e))
}

/// The largest value of `table` (0 for an empty table).
fn peak_of(table: &brdf_io::albedo::AlbedoTable) -> AlbedoPeak {
    let peak = table.peak().unwrap_or(brdf_io::albedo::AlbedoPeak {
        value: 0.0,
        angle_deg: 0.0,
        channel: 0,
    });
    AlbedoPeak {
        value: peak.value,
        angle_deg: peak.angle_deg,
        channel: table
            .channels
            .labels()
            .get(peak.channel)
            .cloned()
            .unwrap_or_default(),
    }
}

/// The largest directional albedo of every material of the predictor's store, in store order,
/// with `weights` ([`grid_albedo`]).
pub fn stored_albedo(
    pred: &Predictor,
    weights: &brdf_io::albedo::GridAlbedo,
    lookup: brdf_io::Lookup,
) -> Result<Vec<StoredAlbedo>> {
    let path = pred.model().dataset.path.clone();
    let err = |e: brdf_io::Error| Error::stage("predict", &path, e);
    let store = pred.store();
    (0..store.n_materials())
        .map(|i| {
            let source = brdf_io::store::StoreMaterial::by_index(store.clone(), i);
            let source = WithLookup::new(source.map_err(err)?, lookup).map_err(err)?;
            Ok(StoredAlbedo {
                material: store.names()[i].to_owned(),
                peak: peak_of(&weights.table(&source).map_err(err)?),
            })
        })
        .collect()
}

fn kind(choice: PredictorChoice) -> PredictorKind {
    match choice {
        PredictorChoice::Exact => PredictorKind::Exact,
        PredictorChoice::Smooth => PredictorKind::Smooth,
    }
}

/// Opens the model at `model_path` with its store.
pub fn open(model_path: &Path) -> Result<Predictor> {
    Predictor::open(model_path).map_err(|e| Error::stage("predict", model_path, e))
}

/// Microseconds per lazy lookup of one cell (all channels) over up to `count` cells spread over
/// the grid, and the mean looked-up value.
pub fn time_lookups(m: &predict::PredictedMaterial, count: usize) -> Result<(f64, f64)> {
    let pred = m.predictor();
    let cells = pred.grid().len();
    let nc = m.channels().len();
    let mut out = vec![0.0; nc];
    let step = (cells / count.max(1)).max(1);
    let mut sum = 0.0;
    let mut k = 0usize;
    let start = Instant::now();
    for a in (0..cells).step_by(step).take(count) {
        m.eval_cell(a, &mut out)
            .map_err(|e| Error::stage("predict", pred.model().dataset.path.clone(), e))?;
        sum += out.iter().sum::<f64>();
        k += 1;
    }
    let us = start.elapsed().as_secs_f64() * 1e6 / k.max(1) as f64;
    Ok((us, sum / (k * nc).max(1) as f64))
}

/// Predicts at every configured point (explicit points, then midpoints of named pairs).
pub fn predict_points(
    pred: &Predictor,
    config: &PipelineConfig,
    out: &Path,
    weights: &brdf_io::albedo::GridAlbedo,
) -> Result<Vec<PredictionRow>> {
    let model = pred.model();
    let mut points: Vec<(String, Vec<f64>)> = config
        .predict
        .points
        .iter()
        .enumerate()
        .map(|(i, x)| (format!("point {}", i + 1), x.clone()))
        .collect();
    for [a, b] in &config.predict.midpoints {
        let find = |name: &str| {
            model
                .materials
                .iter()
                .find(|m| m.name == name)
                .map(|m| m.coords.clone())
                .ok_or_else(|| Error::Config {
                    path: config.path.clone(),
                    reason: format!(
                        "predict.midpoints: {} in the data",
                        crate::config::no_material_named(
                            name,
                            &model.materials.iter().map(|m| &m.name).collect::<Vec<_>>()
                        )
                    ),
                })
        };
        let (xa, xb) = (find(a)?, find(b)?);
        let mid = xa.iter().zip(&xb).map(|(p, q)| 0.5 * (p + q)).collect();
        points.push((format!("mid({a}, {b})"), mid));
    }
    let k = kind(config.predict.predictor);
    let mut rows = Vec::new();
    for (i, (label, x)) in points.into_iter().enumerate() {
        let err = |e: predict::Error| Error::stage("predict", out.join("model.toml"), e);
        let t = Instant::now();
        let m = pred.predict(&x, k).map_err(err)?;
        let weights_us = t.elapsed().as_secs_f64() * 1e6;
        let looked_up = WithLookup::new(&m, config.lookup)
            .map_err(|e| Error::stage("predict", out.join("model.toml"), e))?;
        // The variance of the predictor used (the exact one's is 0 at a training point).
        let variance = pred.variance_transformed(&x, k).map_err(err)?;
        let (lookup_us, lookup_mean) = time_lookups(&m, 4096)?;
        let albedo = peak_of(
            &weights
                .table(&looked_up)
                .map_err(|e| Error::stage("predict", out.join("model.toml"), e))?,
        );
        let (file, file_bytes, materialize_seconds) = if config.predict.materialize {
            let name = format!("prediction-{}.npy", i + 1);
            let r = m.materialize(&out.join(&name), |_, _| {}).map_err(err)?;
            (Some(name), r.bytes.unwrap_or(0), r.seconds)
        } else {
            (None, 0, 0.0)
        };
        let bsdf = if config.predict.bsdf {
            let name = format!("prediction-{}.bsdf", i + 1);
            let path = out.join(&name);
            let t = Instant::now();
            // The writer's starting sizes (32 incident elevations, 32 x 32 tables: 6.6 MB at 33
            // wavelengths, ~0.3 s), checked but not refined: refinement can take a prediction to
            // 50 MB and 4 s, which the pipeline's figures do not need; `specgp predict --out
            // X.bsdf` refines.
            let options = brdf_io::rgl::RglWriteOptions {
                description: format!("specgp prediction: {label}"),
                tolerance: None,
                ..Default::default()
            };
            let summary = brdf_io::rgl::write_rgl(&looked_up, &path, &options)
                .map_err(|e| Error::stage("predict", &path, e))?;
            Some(BsdfFile {
                bytes: brdf_io::output::output_len(&path).unwrap_or(0),
                file: name,
                seconds: t.elapsed().as_secs_f64(),
                theta_samples: summary.theta_samples,
                resolution: summary.resolution,
                check_rms: summary.check_rms,
                albedo_error: summary.albedo_error,
            })
        } else {
            None
        };
        rows.push(PredictionRow {
            label,
            point: x,
            predictor: k.to_string(),
            variance,
            weights_us,
            lookup_us,
            lookup_mean,
            file,
            file_bytes,
            materialize_seconds,
            bsdf,
            albedo,
        });
    }
    Ok(rows)
}

/// Places the measured `files` (outside the training set) in the latent space (predict crate,
/// as `specgp locate`): resampled onto the model's grid and channels as `import` does, then
/// located with `starts` starting points each.
pub fn locate_files(
    pred: &Predictor,
    files: &[std::path::PathBuf],
    starts: usize,
) -> Result<Vec<predict::locate::Location>> {
    let mut targets = Vec::new();
    for f in files {
        let (t, report) = predict::locate::Target::from_file(f, pred.grid(), pred.channels())
            .map_err(|e| Error::stage("locate", f, e))?;
        tracing::info!(file = %f.display(), "resampled for locate: {report}");
        targets.push(t);
    }
    let pb = bar(0, "locate");
    let r = predict::locate::locate(pred, &targets, starts, &|done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
    })
    .map_err(|e| Error::stage("locate", pred.model().dataset.path.clone(), e));
    pb.finish_and_clear();
    r
}

/// Reconstruction errors and, with `loo`, leave-one-out errors (predict crate).
pub fn run_evaluate(pred: &Predictor, loo: bool) -> Result<Evaluation> {
    let n = pred.n_materials() as u64;
    let pb = bar(n, "evaluate");
    let options = EvalOptions {
        loo,
        ..EvalOptions::default()
    };
    let r = evaluate(pred, &options, &|stage, done, total| {
        if stage == Stage::Refits {
            pb.set_length(total as u64);
            pb.set_position(done as u64);
        }
    })
    .map_err(|e| Error::stage("evaluate", pred.model().dataset.path.clone(), e));
    pb.finish_and_clear();
    r
}
