//! The model file: a TOML document recording everything needed to use and audit a fit.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::config::{FitConfig, FitParams, MAX_LATENT_DIM};
use crate::error::{Error, Result};
use crate::transform::Transform;

/// Format tag written into every model file.
pub const MODEL_FORMAT: &str = "specgp-gplvm";
/// Version of the model file format.
pub const MODEL_VERSION: u32 = 1;

/// The dataset a model was fitted on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetRef {
    /// Path of the store, as given when fitting (absolute when it could be resolved).
    pub path: PathBuf,
    /// The store's payload checksum (algorithm:value).
    pub checksum: String,
    /// Number of materials N.
    pub n_materials: usize,
    /// Values per material D (all cells).
    pub d: usize,
    /// Values per material that carry data (above-horizon cells x channels): the D of the
    /// likelihood.
    pub d_effective: usize,
    /// Angular grid, `TH,TD,PD`.
    pub grid: String,
    /// Channel labels.
    pub channels: Vec<String>,
}

/// Kernel hyperparameters of the fitted model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hyperparameters {
    /// RBF variance s^2.
    pub signal_variance: f64,
    /// RBF length-scale(s): one value (isotropic) or one per latent axis (ARD).
    pub length_scale: Vec<f64>,
    /// Noise mu.
    pub noise: f64,
}

/// How the fit went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitReport {
    /// Optimiser used.
    pub optimizer: String,
    /// Final log-likelihood (with the prior term when the prior is on).
    pub log_likelihood: f64,
    /// Log-likelihood at the PCA start.
    pub initial_log_likelihood: f64,
    /// Euclidean norm of the gradient of the log-likelihood at the optimum (of L itself, not
    /// of the per-value objective -L / (N D) the optimiser minimises) with respect to the
    /// optimised parameters: the latent coordinates and, when learnt, log s^2 and
    /// log(mu - min_noise) (the noise floor's parametrisation, so a noise near its floor
    /// contributes little); the length-scale is never learnt ([`crate::fit::LEARNT`]).
    pub gradient_norm: f64,
    /// Jitter the Cholesky factorisation of K needed at the optimum.
    pub jitter: f64,
    /// 2-norm condition number of K (+ jitter) at the optimum: exact (eigenvalues) up to 2000
    /// materials, the Cholesky factor's 1-norm estimate beyond. A fit above 1e12 warns.
    pub condition_number: f64,
    /// Optimiser iterations (summed over restarts).
    pub iterations: u64,
    /// Objective evaluations (summed over restarts).
    pub evaluations: u64,
    /// Why the winning run stopped.
    pub stop_reason: String,
    /// Seconds spent in the Gram pass.
    pub gram_seconds: f64,
    /// Seconds spent optimising.
    pub optimize_seconds: f64,
    /// Share of the variance in the first q principal components.
    pub pca_explained: f64,
}

/// One material's place in the latent space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LatentMaterial {
    /// Material name (as in the store).
    pub name: String,
    /// Latent coordinates (q values).
    pub coords: Vec<f64>,
}

/// A fitted GPLVM.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Model {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// [`MODEL_VERSION`].
    pub version: u32,
    /// The dataset.
    pub dataset: DatasetRef,
    /// Data transform applied before fitting.
    pub transform: Transform,
    /// Variance divisor: the likelihood sees centred transformed data divided by
    /// sqrt(`data_scale`).
    pub data_scale: f64,
    /// Whether the standard-normal prior on the latent points is part of the likelihood.
    pub prior: bool,
    /// Latent dimension q.
    pub latent_dim: usize,
    /// Kernel hyperparameters.
    pub hyperparameters: Hyperparameters,
    /// Fit diagnostics.
    pub fit: FitReport,
    /// The configuration the fit used.
    pub config: FitParams,
    /// The materials and their latent coordinates.
    pub materials: Vec<LatentMaterial>,
    /// The uncentred Gram matrix of the transformed (unscaled) data, row by row: centring,
    /// subsets (leave-one-out) and errors of any linear predictor follow from it.
    pub gram: Vec<Vec<f64>>,
}

/// Largest latent coordinate a model file may hold (squared distances stay finite).
pub const MAX_COORDINATE: f64 = 1e100;

impl Model {
    /// Where the dataset store is, for the model read from `model_file`: the recorded path,
    /// taken relative to the model file's directory when it is relative (`fit` records
    /// absolute paths; an edited or moved model may hold a relative one). When nothing is at
    /// that path but a file of the same name is beside the model (a model moved or copied
    /// together with its store), that file. (Whichever is used, the recorded checksum is
    /// checked against it when it is opened.)
    pub fn dataset_path(&self, model_file: &Path) -> PathBuf {
        let p = &self.dataset.path;
        let dir = model_file.parent().unwrap_or(Path::new("."));
        let recorded = if p.is_relative() {
            dir.join(p)
        } else {
            p.clone()
        };
        if !recorded.exists()
            && let Some(beside) = p.file_name().map(|name| dir.join(name))
            && beside.is_file()
        {
            return beside;
        }
        recorded
    }

    /// Latent coordinates as an N x q matrix.
    pub fn latent_matrix(&self) -> faer::Mat<f64> {
        faer::Mat::from_fn(self.materials.len(), self.latent_dim, |i, k| {
            self.materials[i].coords[k]
        })
    }

    /// The uncentred Gram matrix as an N x N matrix.
    pub fn gram_matrix(&self) -> faer::Mat<f64> {
        let n = self.gram.len();
        faer::Mat::from_fn(n, n, |i, j| self.gram[i][j])
    }

    /// Reads and validates a model file.
    pub fn load(path: &Path) -> Result<Self> {
        let err = |reason: String| Error::File {
            path: path.to_owned(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| {
            err(if e.kind() == std::io::ErrorKind::InvalidData {
                "not a model file (not UTF-8 text)".into()
            } else {
                e.to_string()
            })
        })?;
        let model: Model =
            toml::from_str(&text).map_err(|e| err(format!("not a model file: {e}")))?;
        model.check(path)?;
        Ok(model)
    }

    /// Validates a model read from (or standing for) the file `path`, as [`Model::load`] does:
    /// format and version, sizes (materials, latent coordinates, Gram matrix), finite values, a
    /// Gram matrix of real data, the transform, hyperparameters the kernel accepts, the fit
    /// configuration's q and prior, and the data scale. Errors name `path`. A model built or
    /// edited in memory is checked with this before it predicts.
    pub fn check(&self, path: &Path) -> Result<()> {
        let err = |reason: String| Error::File {
            path: path.to_owned(),
            reason,
        };
        let model = self;
        if model.format != MODEL_FORMAT || model.version != MODEL_VERSION {
            return Err(err(format!(
                "format {} version {} is not {MODEL_FORMAT} version {MODEL_VERSION}",
                model.format, model.version
            )));
        }
        // Before any size is compared with it: q comes from the file.
        if !(1..=MAX_LATENT_DIM).contains(&model.latent_dim) {
            return Err(err(format!(
                "latent_dim = {}: must be in 1..={MAX_LATENT_DIM} (as a fit allows)",
                model.latent_dim
            )));
        }
        let (n, q) = (model.materials.len(), model.latent_dim);
        let sizes = |what: String| Err(err(format!("inconsistent sizes: {what}")));
        if n != model.dataset.n_materials {
            return sizes(format!(
                "{n} materials, the dataset record says {}",
                model.dataset.n_materials
            ));
        }
        if let Some(m) = model.materials.iter().find(|m| m.coords.len() != q) {
            return sizes(format!(
                "material {:?} has {} latent coordinates; the model's latent_dim is {q}",
                m.name,
                m.coords.len()
            ));
        }
        if model.gram.len() != n || model.gram.iter().any(|r| r.len() != n) {
            return sizes(format!(
                "the Gram matrix is not {n} x {n} (one row and column per material)"
            ));
        }
        let finite = model
            .materials
            .iter()
            .flat_map(|m| &m.coords)
            .chain(model.gram.iter().flatten());
        if finite.into_iter().any(|v| !v.is_finite()) {
            return Err(err(
                "non-finite coordinates or Gram entries (NaN or infinite)".into(),
            ));
        }
        // Squared latent distances must stay finite (64 axes of (2e100)^2 do).
        if let Some(v) = model
            .materials
            .iter()
            .flat_map(|m| &m.coords)
            .find(|v| v.abs() > MAX_COORDINATE)
        {
            return Err(err(format!(
                "latent coordinate {v:e} is beyond +-{MAX_COORDINATE:e}"
            )));
        }
        // A Gram matrix of real data: symmetric (written from a symmetric matrix, and TOML
        // round-trips f64 exactly), non-negative diagonal, |G_ij| <= sqrt(G_ii G_jj).
        let g = &model.gram;
        for i in 0..n {
            if g[i][i] < 0.0 {
                return Err(err(format!(
                    "Gram diagonal entry {i} is negative ({:e}): not a Gram matrix",
                    g[i][i]
                )));
            }
            for j in 0..i {
                if g[i][j] != g[j][i] {
                    return Err(err(format!(
                        "Gram matrix not symmetric at ({i}, {j}): {:e} vs {:e}",
                        g[i][j], g[j][i]
                    )));
                }
                let bound = (g[i][i] * g[j][j]).sqrt() * (1.0 + 1e-9);
                if g[i][j].abs() > bound {
                    return Err(err(format!(
                        "Gram entry ({i}, {j}) = {:e} exceeds sqrt(G_ii G_jj) = {:e}: not a Gram \
                         matrix",
                        g[i][j],
                        bound / (1.0 + 1e-9)
                    )));
                }
            }
        }
        model
            .transform
            .check()
            .map_err(|e| err(format!("transform: {e}")))?;
        // The recorded configuration names the transform the fit used: an edit of one without
        // the other would make every prediction silently wrong.
        match model.config.transform.parse::<Transform>() {
            Ok(t) if t == model.transform => {}
            _ => {
                return Err(err(format!(
                    "transform {} disagrees with the fit configuration's transform = {:?}",
                    model.transform, model.config.transform
                )));
            }
        }
        if !(model.data_scale.is_finite() && model.data_scale > 0.0) {
            return Err(err(format!(
                "data_scale must be finite and > 0, got {}",
                model.data_scale
            )));
        }
        let h = &model.hyperparameters;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(positive(h.signal_variance)
            && positive(h.noise)
            && !h.length_scale.is_empty()
            && h.length_scale.iter().all(|l| positive(*l)))
        {
            return Err(err(format!(
                "hyperparameters must be finite and > 0, got signal_variance {}, length_scale \
                 {:?}, noise {}",
                h.signal_variance, h.length_scale, h.noise
            )));
        }
        if h.length_scale.len() != 1 && h.length_scale.len() != model.latent_dim {
            return Err(err(format!(
                "{} length-scales for latent_dim {}: one (isotropic) or one per latent axis",
                h.length_scale.len(),
                model.latent_dim
            )));
        }
        // The kernel's own bounds (length-scales within 1e-150..1e150): such a model used to
        // load and fail when a predictor was built, in an error naming no file.
        let length_scale = match h.length_scale.as_slice() {
            [l] => gp_core::kernel::LengthScale::Isotropic(*l),
            many => gp_core::kernel::LengthScale::Ard(many.to_vec()),
        };
        gp_core::KernelParams::new(h.signal_variance, length_scale, h.noise)
            .map_err(|e| err(format!("hyperparameters: {e}")))?;
        // The recorded configuration is the fit's (a fit writes its q and prior into both):
        // a leave-one-out refit uses it, so an edit of one without the other would refit
        // another model.
        if model.config.latent_dim != model.latent_dim {
            return Err(err(format!(
                "latent_dim {} disagrees with the fit configuration's latent_dim = {}",
                model.latent_dim, model.config.latent_dim
            )));
        }
        if model.config.prior != model.prior {
            return Err(err(format!(
                "prior = {} disagrees with the fit configuration's prior = {}",
                model.prior, model.config.prior
            )));
        }
        let d_eff = model.dataset.d_effective;
        if d_eff == 0 || d_eff > model.dataset.d {
            return Err(err(format!(
                "d_effective = {d_eff} must be in 1..={} (the dataset's D)",
                model.dataset.d
            )));
        }
        // The data scale is what the fit derived from the Gram matrix (its centred trace per
        // value, or 1): an edit of either alone would make every error and variance silently
        // wrong.
        let (_, expected) = crate::fit::scaled_centred_gram(
            model.gram_matrix().as_ref(),
            d_eff,
            model.config.data_scaling,
        )
        .map_err(|e| err(format!("the Gram matrix gives no data_scale: {e}")))?;
        // Centring cancels ~n eps of the uncentred trace; beyond that, 1e-9 relative.
        let uncentred: f64 = (0..n).map(|i| g[i][i]).sum::<f64>() / (n as f64 * d_eff as f64);
        let tolerance = 1e-9 * expected.abs() + 64.0 * n as f64 * f64::EPSILON * uncentred;
        if (model.data_scale - expected).abs() > tolerance {
            return Err(err(format!(
                "data_scale {:e} disagrees with the Gram matrix ({expected:e} for data_scaling \
                 {:?}): an edited Gram matrix or scale",
                model.data_scale, model.config.data_scaling
            )));
        }
        Ok(())
    }

    /// The recorded fit configuration, validated as a fit validates it (for refits such as
    /// leave-one-out); an invalid one is an error naming `model_file`, the file this model was
    /// read from. (Not checked by [`Model::load`]: files written before a rule was added still
    /// load and predict.)
    pub fn fit_config(&self, model_file: &Path) -> Result<FitConfig> {
        self.config.clone().check().map_err(|e| Error::File {
            path: model_file.to_owned(),
            reason: format!("fit configuration: {e}"),
        })
    }

    /// Writes the model as TOML, atomically ([`brdf_io::output::write_file_atomic`]).
    pub fn save(&self, path: &Path) -> Result<()> {
        let err = |reason: String| Error::File {
            path: path.to_owned(),
            reason,
        };
        let text = toml::to_string_pretty(self).map_err(|e| err(e.to_string()))?;
        // brdf-io's error names the path itself (wrapping it in `Error::File` said it twice).
        brdf_io::output::write_file_atomic(path, text.as_bytes())?;
        Ok(())
    }
}
