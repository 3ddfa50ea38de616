//! The [`Predictor`] (a model plus its dataset store) and the [`PredictedMaterial`] it returns.
//!
//! A predicted material is a coefficient vector `c` over the N stored materials: its value at
//! a flat index `d` is `inverse(sum_i c_i forward(stored_i[d]))`, computed per lookup from the
//! N stored values at `d` (one contiguous read). Nothing is materialised.

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

pub use brdf_io::ChannelSelection;
use brdf_io::store::Store;
use brdf_io::{AngularGrid, BrdfSource, Channels, HalfDiff, Vec3};
use faer::Par;
use gp_core::fastmath::Lanes;
use gp_core::{GpRegression, KernelParams, LengthScale};
use gplvm::{Model, Transform};

use crate::error::{Error, Result};

/// `v` as written by `{}` (the shortest form that reads back the same), or in exponent form
/// when that is long (beyond 1e6 or below 1e-4 in magnitude): labels hold latent points and
/// factors, and `1e308` should not become 309 digits.
fn short_number(v: f64) -> String {
    if v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// How well the training materials support a prediction at a latent point
/// ([`Predictor::support`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PointSupport {
    /// The training material nearest to the point.
    pub nearest: String,
    /// Its distance in length-scales (each axis divided by its length-scale).
    pub distance: f64,
    /// The smooth predictor's variance at the point over the prior variance `s^2 + mu` (plus
    /// any jitter the factorisation needed): near 0
    /// at a training material, near 1 far from all of them, where the prediction is close to
    /// the data mean.
    pub variance_fraction: f64,
}

impl PointSupport {
    /// Above this variance fraction a point counts as far from every material (the materials
    /// explain less than a tenth of the prior variance there).
    pub const FAR: f64 = 0.9;

    /// Whether the point is far from every material ([`PointSupport::FAR`]).
    pub fn is_far(&self) -> bool {
        Self::is_far_fraction(self.variance_fraction)
    }

    /// Whether a point with this variance fraction is far from every material: strictly above
    /// [`PointSupport::FAR`].
    pub fn is_far_fraction(variance_fraction: f64) -> bool {
        variance_fraction > Self::FAR
    }
}

/// Which GP posterior mean is used (DESIGN.md section 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PredictorKind {
    /// The paper's predictor: `k*` includes the noise term at a coinciding training point, so
    /// training materials are reproduced exactly.
    #[default]
    Exact,
    /// The noise-free posterior mean, continuous in the latent point.
    Smooth,
}

impl From<PredictorKind> for gp_core::Predictor {
    fn from(k: PredictorKind) -> Self {
        match k {
            PredictorKind::Exact => gp_core::Predictor::Exact,
            PredictorKind::Smooth => gp_core::Predictor::Smooth,
        }
    }
}

impl std::fmt::Display for PredictorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Exact => "exact",
            Self::Smooth => "smooth",
        })
    }
}

#[derive(Clone)]
struct Inner {
    /// Sidecar store of forward-transformed values (see [`Predictor::with_transformed_store`]).
    forward_store: Option<Arc<Store>>,
    /// Forward-transformed values of the cells lazy lookups have read, kept for the next
    /// lookups (see [`Predictor::with_forward_cache`]).
    forward_cells: Option<Arc<ForwardCells>>,
    model: Model,
    model_path: PathBuf,
    store: Arc<Store>,
    gp: GpRegression,
    n: usize,
    grid: AngularGrid,
    channels: Channels,
    transform: Transform,
}

/// Most memory [`Predictor::with_forward_cache`] may take (all cells kept): 512 MiB.
pub const FORWARD_CACHE_MAX_BYTES: u64 = 512 << 20;

/// Forward-transformed values per angular cell (all stored channels x N materials, f64),
/// computed on first use ([`Predictor::with_forward_cache`]).
struct ForwardCells {
    cells: Vec<OnceLock<Box<[f64]>>>,
}

/// A fitted model bound to its dataset store: GP weights, variances and predicted materials.
///
/// `Send + Sync` and cheap to clone (an `Arc`): clone one per thread or share a reference.
#[derive(Clone)]
pub struct Predictor {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Predictor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Predictor")
            .field("model", &self.inner.model_path)
            .field("dataset", &self.inner.store.path())
            .field("n", &self.inner.n)
            .finish()
    }
}

/// Kernel hyperparameters of a model.
pub fn kernel_params(model: &Model) -> Result<KernelParams> {
    let h = &model.hyperparameters;
    let ls = match h.length_scale.as_slice() {
        [l] => LengthScale::Isotropic(*l),
        many => LengthScale::Ard(many.to_vec()),
    };
    Ok(KernelParams::new(h.signal_variance, ls, h.noise)?)
}

/// Default path of the sidecar store of `transform`ed values of the dataset at `dataset`:
/// `DATA.sbrdf.<transform>.sbrdf` next to it ([`Predictor::transformed_store_path`]). The
/// offset is written in its shortest form, in exponent form when that is long (`log-0.01`,
/// `log-1e-300`): as `{}` it took 300 digits for 1e-300, a file name the file system refuses.
pub fn transformed_store_path(dataset: &Path, transform: Transform) -> PathBuf {
    let tag = match transform {
        Transform::Raw => "raw".to_owned(),
        Transform::Log { offset } => format!("log-{}", short_number(offset)),
    };
    let mut name = dataset.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{tag}.sbrdf"));
    dataset.with_file_name(name)
}

impl Predictor {
    /// Loads the model file at `model_path` and opens the dataset store it records.
    ///
    /// A missing store is an [`Error::DatasetMissing`] naming both paths; a store whose checksum,
    /// grid, channels, material count or D differ from the model's is an
    /// [`Error::DatasetMismatch`].
    pub fn open(model_path: &Path) -> Result<Self> {
        Self::open_with_dataset(model_path, None)
    }

    /// As [`open`](Self::open), reading the store from `dataset` when given (a moved store).
    pub fn open_with_dataset(model_path: &Path, dataset: Option<&Path>) -> Result<Self> {
        let model = Model::load(model_path)?;
        let path = match dataset {
            Some(p) => p.to_owned(),
            None => model.dataset_path(model_path),
        };
        if !path.is_file() {
            return Err(Error::DatasetMissing {
                model: model_path.to_owned(),
                dataset: path,
                given: dataset.is_some(),
            });
        }
        let store = Arc::new(Store::open(&path)?);
        Self::with_store(model, model_path, store)
    }

    /// Binds an in-memory `model` (read from `model_path`, used in messages) to `store`,
    /// validating that they belong together and that the model's sizes agree (as
    /// [`Model::load`] checks them: a model built or edited in memory may not), with errors
    /// naming `model_path`.
    pub fn with_store(model: Model, model_path: &Path, store: Arc<Store>) -> Result<Self> {
        let mismatch = |what: String| Error::DatasetMismatch {
            model: model_path.to_owned(),
            dataset: store.path().to_owned(),
            what,
        };
        if store.grid().to_string() != model.dataset.grid {
            return Err(mismatch(format!(
                "grid differs (model {}, store {})",
                model.dataset.grid,
                store.grid()
            )));
        }
        if store.channels().labels() != model.dataset.channels {
            let (m, st) = (&model.dataset.channels, store.channels().labels());
            let first = m.iter().zip(&st).position(|(a, b)| a != b);
            return Err(mismatch(match first {
                Some(k) => format!(
                    "channels differ (channel {k}: model {}, store {})",
                    m[k], st[k]
                ),
                None => format!(
                    "channels differ (model {} channels, store {})",
                    m.len(),
                    st.len()
                ),
            }));
        }
        let n = store.n_materials();
        if n != model.materials.len() || store.d() != model.dataset.d {
            return Err(mismatch(format!(
                "size differs (model {} materials x D = {}, store {n} x {})",
                model.materials.len(),
                model.dataset.d,
                store.d()
            )));
        }
        for (i, (m, s)) in model.materials.iter().zip(store.names()).enumerate() {
            if m.name != s {
                return Err(mismatch(format!(
                    "material {i} is {:?} in the model and {s:?} in the store",
                    m.name
                )));
            }
        }
        // Last: a store of another grid, channels or materials is named for what differs.
        let checksum = store.header().checksum.to_string();
        if checksum != model.dataset.checksum {
            return Err(mismatch(format!(
                "checksum differs (model {}, store {checksum}): the store was rewritten since the \
                 fit, or is another store of the same grid and materials",
                model.dataset.checksum
            )));
        }
        if let Some(m) = model
            .materials
            .iter()
            .find(|m| m.coords.iter().any(|v| !v.is_finite()))
        {
            return Err(Error::InvalidPoint {
                point: m.coords.clone(),
                reason: format!(
                    "material {:?} of model {} has a non-finite latent point",
                    m.name,
                    model_path.display()
                ),
            });
        }
        // As Model::load checks a file: a model built or edited in memory may not hold (a
        // material with too few coordinates panicked building the latent matrix, too many
        // were silently cut to q, a Gram matrix of the wrong size gave wrong errors).
        model.check(model_path)?;
        let invalid = |reason: String| {
            Error::Model(gplvm::Error::File {
                path: model_path.to_owned(),
                reason,
            })
        };
        let params = kernel_params(&model).map_err(|e| invalid(format!("hyperparameters: {e}")))?;
        let gp = GpRegression::new(model.latent_matrix().as_ref(), params, Par::Seq)
            .map_err(|e| invalid(format!("its latent points and hyperparameters: {e}")))?;
        Ok(Self {
            inner: Arc::new(Inner {
                forward_store: None,
                forward_cells: None,
                transform: model.transform,
                grid: *store.grid(),
                channels: store.channels().clone(),
                n,
                gp,
                store,
                model_path: model_path.to_owned(),
                model,
            }),
        })
    }

    /// Default path of the sidecar store of forward-transformed values:
    /// `DATA.sbrdf.<transform>.sbrdf` next to the dataset (e.g. `synth.sbrdf.log-0.01.sbrdf`).
    pub fn transformed_store_path(&self) -> PathBuf {
        transformed_store_path(self.inner.store.path(), self.inner.transform)
    }

    fn transformed_source(&self) -> String {
        let h = self.inner.store.header();
        format!(
            "forward-transformed values ({}) of dataset checksum {}",
            self.inner.transform, h.checksum
        )
    }

    /// Writes the sidecar store of forward-transformed values `forward(f)` (f32, same layout,
    /// names and grid) to `path`, streaming the dataset once. With it
    /// ([`with_transformed_store`](Self::with_transformed_store)) a lookup under `log` costs
    /// what it costs under `raw`: N multiply-adds, no logarithms. The transformed values are
    /// rounded to f32 (2^-24 relative), so a prediction `t* = sum_i c_i t_i` moves by up to
    /// `B = sum_i |c_i| max|t| 2^-24` and `f* = c (e^t* - 1)` by `(|f*| + c) B`: ~1e-6 relative
    /// on ordinary values, more on values far below the offset `c`, and the exact predictor
    /// reproduces a training material to ~1e-7 instead of exactly (tested bound).
    pub fn build_transformed_store(
        &self,
        path: &Path,
        progress: impl FnMut(usize, usize),
    ) -> Result<()> {
        let mut progress = progress;
        let store = &self.inner.store;
        let info = brdf_io::StoreInfo {
            grid: *store.grid(),
            channels: store.channels().clone(),
        };
        let options = brdf_io::StoreOptions {
            chunk_len: Some(store.header().layout.chunk_len),
            ..brdf_io::StoreOptions::default()
        };
        let mut w = brdf_io::StoreWriter::create(path, info, options)?;
        let source = self.transformed_source();
        let names: Vec<(&str, &str)> = store
            .names()
            .into_iter()
            .map(|n| (n, source.as_str()))
            .collect();
        w.declare_materials(&names)?;
        let t = self.inner.transform;
        let nc = store.channels().len();
        let n = self.inner.n;
        let mask = store.validity_mask();
        let total = store.n_chunks();
        let mut out = Vec::new();
        let mut k = 0;
        let mut result = Ok(());
        store.for_each_chunk(|range, block| {
            if result.is_err() {
                return;
            }
            out.clear();
            for (j, d) in range.clone().enumerate() {
                let valid = mask[d / nc];
                out.extend(block[j * n..(j + 1) * n].iter().map(|v| {
                    if valid {
                        t.forward(f64::from(*v)) as f32
                    } else {
                        0.0
                    }
                }));
            }
            result = w.write_block(range, &out);
            k += 1;
            progress(k, total);
        })?;
        result?;
        w.finish()?;
        Ok(())
    }

    /// This predictor reading forward-transformed values from the sidecar store at `path`
    /// (written by [`build_transformed_store`](Self::build_transformed_store); checked against
    /// the dataset's checksum, transform, names, grid and channels).
    pub fn with_transformed_store(&self, path: &Path) -> Result<Self> {
        let side = Store::open(path)?;
        let store = &self.inner.store;
        let source = self.transformed_source();
        let ok = side.grid() == store.grid()
            && side.channels() == store.channels()
            && side.names() == store.names()
            && side.header().materials.iter().all(|m| m.source == source);
        if !ok {
            return Err(Error::DatasetMismatch {
                model: self.inner.model_path.clone(),
                dataset: path.to_owned(),
                what: format!(
                    "not the forward-transformed sidecar of {} (expected source {source:?})",
                    store.path().display()
                ),
            });
        }
        let mut inner = (*self.inner).clone();
        inner.forward_store = Some(Arc::new(side));
        Ok(Self {
            inner: Arc::new(inner),
        })
    }

    /// This predictor keeping, in memory, the forward-transformed values of every angular cell a
    /// lazy lookup ([`PredictedMaterial::eval_cell`]) reads, for all materials predicted from it
    /// (its clones share them): many renders of predicted materials (thumbnails, sheets, paths)
    /// then take each cell's logarithms once instead of once per render, with the same values
    /// bit for bit (f64, unlike the f32 sidecar). A no-op under `raw`, with a sidecar in use, or
    /// when keeping every cell would take more than [`FORWARD_CACHE_MAX_BYTES`]
    /// ([`Predictor::forward_cache_bytes`]; a render touches about half the cells).
    pub fn with_forward_cache(&self) -> Self {
        self.with_forward_cache_within(FORWARD_CACHE_MAX_BYTES)
    }

    /// As [`Predictor::with_forward_cache`], with `max_bytes` in place of
    /// [`FORWARD_CACHE_MAX_BYTES`]: a no-op when keeping every cell would take more.
    pub fn with_forward_cache_within(&self, max_bytes: u64) -> Self {
        let inner = &*self.inner;
        if inner.transform == Transform::Raw
            || inner.forward_store.is_some()
            || inner.forward_cells.is_some()
            || self.forward_cache_bytes() > max_bytes
        {
            return self.clone();
        }
        let mut inner = inner.clone();
        inner.forward_cells = Some(Arc::new(ForwardCells {
            cells: (0..inner.grid.len()).map(|_| OnceLock::new()).collect(),
        }));
        Self {
            inner: Arc::new(inner),
        }
    }

    /// Memory a forward cache keeping every cell would take: cells x channels x N x 8 bytes
    /// (saturating).
    pub fn forward_cache_bytes(&self) -> u64 {
        let inner = &*self.inner;
        (inner.grid.len() as u64)
            .saturating_mul(inner.channels.len() as u64)
            .saturating_mul(inner.n as u64)
            .saturating_mul(8)
    }

    /// Whether lazy lookups keep the forward-transformed values of the cells they read
    /// ([`Predictor::with_forward_cache`]).
    pub fn keeps_forward_values(&self) -> bool {
        self.inner.forward_cells.is_some()
    }

    /// Whether lookups read the forward-transformed sidecar store.
    pub fn uses_transformed_store(&self) -> bool {
        self.inner.forward_store.is_some()
    }

    /// The store lookups read (the sidecar when in use, else the dataset) and whether its
    /// values are already transformed.
    pub(crate) fn lookup_store(&self) -> (&Arc<Store>, bool) {
        match &self.inner.forward_store {
            Some(s) => (s, true),
            None => (&self.inner.store, false),
        }
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.inner.model
    }

    /// The model file the model was read from (named in errors).
    pub(crate) fn model_path(&self) -> &Path {
        &self.inner.model_path
    }

    /// The dataset store.
    pub fn store(&self) -> &Arc<Store> {
        &self.inner.store
    }

    /// The GP conditioned on the model's latent points.
    pub fn gp(&self) -> &GpRegression {
        &self.inner.gp
    }

    /// Number of training materials N.
    pub fn n_materials(&self) -> usize {
        self.inner.n
    }

    /// Latent dimension q.
    pub fn latent_dim(&self) -> usize {
        self.inner.model.latent_dim
    }

    /// The dataset's angular grid.
    pub fn grid(&self) -> &AngularGrid {
        &self.inner.grid
    }

    /// The dataset's channels.
    pub fn channels(&self) -> &Channels {
        &self.inner.channels
    }

    /// The model's data transform.
    pub fn transform(&self) -> Transform {
        self.inner.transform
    }

    /// Index of the training material called `name`.
    pub fn material_index(&self, name: &str) -> Result<usize> {
        self.inner
            .model
            .materials
            .iter()
            .position(|m| m.name == name)
            .ok_or_else(|| {
                let names: Vec<&str> = self
                    .inner
                    .model
                    .materials
                    .iter()
                    .map(|m| m.name.as_str())
                    .collect();
                let closest = brdf_io::error::closest_name(name, &names).map(str::to_owned);
                Error::InvalidArgument {
                    reason: format!(
                        "no material {name:?} in model {}{} (it holds: {})",
                        self.inner.model_path.display(),
                        brdf_io::error::did_you_mean(&closest),
                        names.join(", ")
                    ),
                }
            })
    }

    fn check_point(&self, x: &[f64]) -> Result<()> {
        if x.len() != self.latent_dim() {
            return Err(Error::InvalidPoint {
                point: x.to_vec(),
                reason: format!(
                    "the latent space of model {} has {} dimensions: give all {} coordinates, \
                     e.g. {}",
                    self.inner.model_path.display(),
                    self.latent_dim(),
                    self.latent_dim(),
                    vec!["0"; self.latent_dim()].join(",")
                ),
            });
        }
        if let Some(j) = x.iter().position(|v| !v.is_finite()) {
            return Err(Error::InvalidPoint {
                point: x.to_vec(),
                reason: format!(
                    "coordinate {} is {}: a point in the latent space of model {} must have \
                     finite coordinates",
                    j + 1,
                    x[j],
                    self.inner.model_path.display()
                ),
            });
        }
        if let Some(v) = x.iter().find(|v| v.abs() > gplvm::model::MAX_COORDINATE) {
            return Err(Error::InvalidPoint {
                point: x.to_vec(),
                reason: format!(
                    "coordinate {v:e} is beyond +-{:e} (the bound of model files, such as {})",
                    gplvm::model::MAX_COORDINATE,
                    self.inner.model_path.display()
                ),
            });
        }
        Ok(())
    }

    /// GP posterior weights `w = K^-1 k*` at latent point `x` (length N).
    pub fn gp_weights(&self, x: &[f64], kind: PredictorKind) -> Result<Vec<f64>> {
        self.check_point(x)?;
        Ok(self.inner.gp.weights(x, kind.into())?)
    }

    /// Coefficients `c` of the posterior mean as a combination of the stored rows (transformed
    /// space): `y* = m + sum_i w_i (y_i - m) = sum_i c_i y_i`, `c_i = w_i + (1 - sum_j w_j) / N`.
    /// The data scale of the model cancels.
    pub fn coefficients(&self, x: &[f64], kind: PredictorKind) -> Result<Vec<f64>> {
        let w = self.gp_weights(x, kind)?;
        Ok(weights_to_coefficients(&w))
    }

    /// Predictive variance at `x` in model units: `s^2 + mu - k*^T K^-1 k*` for the centred
    /// transformed data divided by sqrt(`data_scale`). Multiply by `model().data_scale` for the
    /// variance of one transformed value ([`variance_transformed`](Self::variance_transformed)).
    pub fn variance(&self, x: &[f64]) -> Result<f64> {
        self.check_point(x)?;
        Ok(self.inner.gp.variance(x)?)
    }

    /// [`variance`](Self::variance) with the `k*` of the predictor `kind`: the same except at a
    /// training point, where the exact predictor (which returns that material) has variance 0.
    pub fn variance_of(&self, x: &[f64], kind: PredictorKind) -> Result<f64> {
        self.check_point(x)?;
        Ok(self.inner.gp.variance_of(x, kind.into())?)
    }

    /// Predictive variance of one transformed value (the units of `transform.forward(f)`) of
    /// the predictor `kind`: [`variance_of`](Self::variance_of) times `data_scale`.
    pub fn variance_transformed(&self, x: &[f64], kind: PredictorKind) -> Result<f64> {
        Ok(self.variance_of(x, kind)? * self.inner.model.data_scale)
    }

    /// The prior variance in model units, which [`variance`](Self::variance) tends to far from
    /// every material: `s^2 + mu` plus any jitter the factorisation needed (it counts as noise;
    /// see `gp_core::regression`).
    pub fn prior_variance(&self) -> f64 {
        self.inner.model.hyperparameters.signal_variance + self.inner.gp.effective_noise()
    }

    /// How well the training materials support a prediction at `x`: the nearest material, its
    /// distance in length-scales, and the share of the prior variance left at `x`.
    pub fn support(&self, x: &[f64]) -> Result<PointSupport> {
        self.check_point(x)?;
        let h = &self.inner.model.hyperparameters;
        let axis = |j: usize| {
            h.length_scale
                .get(j)
                .or(h.length_scale.first())
                .copied()
                .unwrap_or(1.0)
        };
        let (nearest, distance) = self
            .inner
            .model
            .materials
            .iter()
            .map(|m| {
                let d2: f64 = m
                    .coords
                    .iter()
                    .zip(x)
                    .enumerate()
                    .map(|(j, (a, b))| ((a - b) / axis(j)).powi(2))
                    .sum();
                (m.name.as_str(), d2.sqrt())
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .ok_or_else(|| Error::InvalidPoint {
                point: x.to_vec(),
                reason: "the model has no materials".into(),
            })?;
        let prior = self.prior_variance();
        Ok(PointSupport {
            nearest: nearest.to_string(),
            distance,
            variance_fraction: self.variance(x)? / prior,
        })
    }

    /// The GP prediction at latent point `x`.
    pub fn predict(&self, x: &[f64], kind: PredictorKind) -> Result<PredictedMaterial> {
        let c = self.coefficients(x, kind)?;
        let label = format!(
            "gp-{kind}@{}",
            x.iter()
                .map(|v| short_number(*v))
                .collect::<Vec<_>>()
                .join(",")
        );
        self.from_coefficients(c, label)
    }

    /// The paper's linear interpolation `y = a y1 + (1 - a) y2` between two training materials,
    /// taken in the model's transformed space (the values themselves for `raw`, as in the
    /// paper; `ln(1 + f/c)` for `log`).
    pub fn lerp(&self, name1: &str, name2: &str, a: f64) -> Result<PredictedMaterial> {
        if !a.is_finite() {
            return Err(Error::InvalidArgument {
                reason: format!("interpolation factor must be finite, got {a}"),
            });
        }
        let (i, j) = (self.material_index(name1)?, self.material_index(name2)?);
        let mut c = vec![0.0; self.inner.n];
        c[i] += a;
        c[j] += 1.0 - a;
        self.from_coefficients(c, format!("lerp({name1},{name2},{})", short_number(a)))
    }

    /// A training material itself (coefficient vector `e_i`).
    pub fn training(&self, name: &str) -> Result<PredictedMaterial> {
        let i = self.material_index(name)?;
        let mut c = vec![0.0; self.inner.n];
        c[i] = 1.0;
        self.from_coefficients(c, name.to_owned())
    }

    /// Any linear predictor: the material `inverse(sum_i c_i forward(y_i))`.
    pub fn from_coefficients(&self, c: Vec<f64>, label: String) -> Result<PredictedMaterial> {
        if c.len() != self.inner.n {
            return Err(Error::InvalidArgument {
                reason: format!("{} coefficients for {} materials", c.len(), self.inner.n),
            });
        }
        if c.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidArgument {
                reason: "non-finite coefficient".into(),
            });
        }
        let selection = ChannelSelection::all(&self.inner.channels);
        Ok(PredictedMaterial {
            pred: self.clone(),
            coef: c.into(),
            selection: Arc::new(selection),
            label,
        })
    }
}

/// `c_i = w_i + (1 - sum_j w_j) / N`: GP weights on centred rows as coefficients on raw rows.
pub fn weights_to_coefficients(w: &[f64]) -> Vec<f64> {
    let n = w.len().max(1) as f64;
    let shift = (1.0 - w.iter().sum::<f64>()) / n;
    w.iter().map(|v| v + shift).collect()
}

/// A predicted BRDF: coefficients over the stored materials, evaluated lazily.
///
/// Each value costs one read of the N stored values at its index and N multiply-adds (plus N
/// forward transforms and one inverse under `log`); a thread-local scratch buffer avoids
/// allocations. `Send + Sync`, cheap to clone. Implements [`BrdfSource`] (f in 1/sr; values of
/// a linear predictor may be slightly negative where it extrapolates: they are not clamped).
#[derive(Clone)]
pub struct PredictedMaterial {
    pred: Predictor,
    coef: Arc<[f64]>,
    selection: Arc<ChannelSelection>,
    label: String,
}

impl std::fmt::Debug for PredictedMaterial {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PredictedMaterial")
            .field("label", &self.label)
            .field("channels", &self.selection.channels.len())
            .finish()
    }
}

impl PredictedMaterial {
    /// The predictor it comes from.
    pub fn predictor(&self) -> &Predictor {
        &self.pred
    }

    /// Its coefficients over the stored materials (transformed space).
    pub fn coefficients(&self) -> &[f64] {
        &self.coef
    }

    /// A short description (`gp-exact@X,Y`, `lerp(a,b,0.3)`, a material name).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The output channels.
    pub fn channels(&self) -> &Channels {
        &self.selection.channels
    }

    /// The channel selection in use.
    pub fn selection(&self) -> &ChannelSelection {
        &self.selection
    }

    /// The same material evaluated at `wavelengths` (linear interpolation between stored
    /// wavelengths; a wavelength outside the stored range is an error).
    pub fn with_wavelengths(&self, wavelengths: &Channels) -> Result<Self> {
        let sel = ChannelSelection::new(
            self.pred.inner.store.path(),
            &self.pred.inner.channels,
            wavelengths,
        )?;
        Ok(Self {
            selection: Arc::new(sel),
            ..self.clone()
        })
    }

    /// The predicted value at flat index `d` of the stored dimension order
    /// (`angular_index * n_channels + channel`), in 1/sr.
    pub fn value_at(&self, d: usize) -> Result<f64> {
        let n = self.pred.inner.n;
        SCRATCH.with(|scratch| {
            let mut scratch = scratch.borrow_mut();
            let (raw, wide, _) = &mut *scratch;
            raw.resize(n, 0.0);
            let (store, transformed) = self.pred.lookup_store();
            store.values_at(d, raw)?;
            let mut v = [0.0];
            self.combine_block(raw, transformed, wide, &mut v);
            self.check_finite(&v, d)?;
            Ok(v[0])
        })
    }

    /// Values of the output channels at angular cell `a` (flat angular index) into `out`.
    ///
    /// One read of the cell's block of stored values (the span of stored channels the selection
    /// uses, all N materials: contiguous in the store) and one vectorised batch of transforms
    /// and dot products; the same arithmetic as [`PredictedMaterial::value_at`], so the values
    /// are bit-identical.
    pub fn eval_cell(&self, a: usize, out: &mut [f64]) -> Result<()> {
        self.check_out(out)?;
        Self::eval_cell_each(&[self], a, out)
    }

    /// Whether `other` evaluates its cells from the same stored values as this material (the
    /// same predictor, or a clone of it, and the same output channels), so
    /// [`PredictedMaterial::eval_cell_each`] evaluates both at once.
    pub fn shares_cells(&self, other: &PredictedMaterial) -> bool {
        Arc::ptr_eq(&self.pred.inner, &other.pred.inner)
            && (Arc::ptr_eq(&self.selection, &other.selection) || self.selection == other.selection)
    }

    /// Values of the output channels at angular cell `a` for each of `materials` into `out`,
    /// material after material (`materials.len()` x channels values): the cell's stored
    /// values are read, and transformed, once for all of them (renders of many predictions of
    /// one scene were bound by reading memory: each read the same cells again). Each
    /// material's values are bit-identical to its own [`PredictedMaterial::eval_cell`]. The
    /// materials must share their cells ([`PredictedMaterial::shares_cells`]); an error
    /// names the first material whose values are not finite.
    pub fn eval_cell_each(
        materials: &[&PredictedMaterial],
        a: usize,
        out: &mut [f64],
    ) -> Result<()> {
        let Some(head) = materials.first() else {
            return Err(Error::InvalidArgument {
                reason: "a batch of predicted cells needs at least one material".into(),
            });
        };
        if let Some(m) = materials.iter().find(|m| !head.shares_cells(m)) {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "the predictions {} and {} do not share their cells (another model or \
                     other output channels): evaluate them apart",
                    head.label, m.label
                ),
            });
        }
        let width = head.selection.taps().len();
        if out.len() != width * materials.len() {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "output has {} slots for {} materials of {width} channels",
                    out.len(),
                    materials.len()
                ),
            });
        }
        let inner = &*head.pred.inner;
        // Before `a * nc`: a huge index wrapped onto another cell's values (a panic in debug
        // builds).
        if a >= inner.grid.len() {
            return Err(Error::CellOutOfRange {
                cell: a,
                cells: inner.grid.len(),
            });
        }
        let (nc, n) = (inner.channels.len(), inner.n);
        let sel = &*head.selection;
        let (first, last) = sel.span();
        let t = inner.transform;
        SCRATCH.with(|scratch| {
            let mut scratch = scratch.borrow_mut();
            let (raw, wide, vals) = &mut *scratch;
            let span = last + 1 - first;
            vals.resize(span, 0.0);
            // Each material: its dot products over the rows, the inverse transform, its
            // channels, checked (`combine_block`'s arithmetic).
            let mut each = |rows: Rows<'_>| -> Result<()> {
                for (m, out) in materials.iter().zip(out.chunks_exact_mut(width)) {
                    rows.dots(&m.coef, vals);
                    t.inverse_in_place(vals);
                    sel.apply(vals, first, out);
                    m.check_finite(out, a * width)?;
                }
                Ok(())
            };
            if let Some(cells) = &inner.forward_cells {
                // The cell's forward-transformed values, all channels, computed once: the
                // transform is elementwise, so these are the bits combine_block computes.
                let cell = match cells.cells[a].get() {
                    Some(cell) => cell,
                    None => {
                        let block = inner.store.values_in_ref(a * nc..(a + 1) * nc, raw)?;
                        let mut t = vec![0.0; block.len()].into_boxed_slice();
                        inner.transform.forward_batch(block, &mut t);
                        cells.cells[a].get_or_init(|| t)
                    }
                };
                each(Rows::Forward(&cell[first * n..(last + 1) * n]))
            } else {
                let (store, transformed) = head.pred.lookup_store();
                let block = store.values_in_ref(a * nc + first..a * nc + last + 1, raw)?;
                debug_assert_eq!(block.len(), span * n);
                each(Rows::of(block, t, transformed, wide))
            }
        })
    }

    /// An error naming the first non-finite value of `values` (the output values from flat
    /// output index `first`), if any: stored NaN or infinity, or an overflowing prediction,
    /// must not pass silently into pictures and files. On that error path the store the
    /// lookups read (the dataset or its sidecar) is scanned: a damaged stored value is
    /// reported with its file, material and index; otherwise the prediction overflowed.
    pub(crate) fn check_finite<T: Copy + Into<f64>>(
        &self,
        values: &[T],
        first: usize,
    ) -> Result<()> {
        let Some(k) = values.iter().position(|v| !(*v).into().is_finite()) else {
            return Ok(());
        };
        let (store, _) = self.pred.lookup_store();
        if let Some(e) = crate::evaluate::damaged_value(store)? {
            return Err(e);
        }
        Err(Error::NonFiniteValue {
            what: format!("value {} of the prediction {}", first + k, self.label),
            value: values[k].into(),
            cause: format!(
                "every value stored in {} is finite (checked), so the prediction overflowed: \
                 the point or blend lies far outside the training materials",
                store.path().display()
            ),
        })
    }

    /// A hint that [`PredictedMaterial::eval_cell`] of cell `a` follows soon: starts fetching
    /// its stored values into the cache (see [`brdf_io::store::Store::prefetch`]); no effect
    /// for a cell outside the grid.
    pub fn prefetch_cell(&self, a: usize) {
        if let Some(range) = self.stored_range(a) {
            self.pred.lookup_store().0.prefetch(range);
        }
    }

    /// A hint that [`PredictedMaterial::eval_cell`] of each of `cells` (in this order)
    /// follows: on a store read from the disk, starts reading their stored values (see
    /// [`brdf_io::store::Store::will_need`]); no effect for cells outside the grid.
    pub fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        let store = self.pred.lookup_store().0;
        store.will_need(cells.filter_map(|a| self.stored_range(a)));
    }

    /// The stored values (flat indices of the lookup store) that cell `a` reads: its selected
    /// channels' span; `None` for a cell outside the grid or one already predicted (a
    /// materialised cell cache reads nothing).
    fn stored_range(&self, a: usize) -> Option<std::ops::Range<usize>> {
        if a >= self.pred.inner.grid.len() {
            return None;
        }
        if let Some(cells) = &self.pred.inner.forward_cells
            && cells.cells[a].get().is_some()
        {
            return None;
        }
        let nc = self.pred.inner.channels.len();
        let (first, last) = self.selection.span();
        Some(a * nc + first..a * nc + last + 1)
    }

    fn check_out(&self, out: &[f64]) -> Result<()> {
        if out.len() != self.selection.taps().len() {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "output has {} slots for {} channels",
                    out.len(),
                    self.selection.taps().len()
                ),
            });
        }
        Ok(())
    }

    /// Values at half/difference angles `hd`: multilinear interpolation of predicted cell values
    /// with [`AngularGrid::interpolation_stencil`] (as `DATA.sbrdf:MATERIAL` sources do).
    ///
    /// Non-finite angles are an error: the stencil of a NaN angle has NaN weights, and the
    /// lookup returned NaN values as if they were a prediction.
    pub fn eval_half_diff(&self, hd: &HalfDiff, out: &mut [f64]) -> Result<()> {
        self.check_out(out)?;
        if ![hd.theta_h, hd.theta_d, hd.phi_d]
            .iter()
            .all(|v| v.is_finite())
        {
            return Err(Error::InvalidArgument {
                reason: format!(
                    "half/difference angles of a lookup of the prediction {} must be finite, \
                     got theta_h {}, theta_d {}, phi_d {}",
                    self.label, hd.theta_h, hd.theta_d, hd.phi_d
                ),
            });
        }
        let stencil = self.pred.inner.grid.interpolation_stencil(hd);
        if self.pred.lookup_store().0.paged_on_demand() {
            // A store read from the disk cell by cell: the stencil's reads go out together.
            for &(a, w) in &stencil {
                if w != 0.0 {
                    self.prefetch_cell(a);
                }
            }
        }
        out.iter_mut().for_each(|o| *o = 0.0);
        let mut cell = [0.0f64; 8];
        let mut heap = Vec::new();
        let buf: &mut [f64] = if out.len() <= 8 {
            &mut cell[..out.len()]
        } else {
            heap.resize(out.len(), 0.0);
            &mut heap
        };
        for (a, w) in stencil {
            if w == 0.0 {
                continue;
            }
            self.eval_cell(a, buf)?;
            for (o, v) in out.iter_mut().zip(buf.iter()) {
                *o += w * v;
            }
        }
        Ok(())
    }

    /// Values for the direction pair (wi, wo) (local frame, z = normal); 0 when either
    /// direction is at or below the horizon or the pair is degenerate.
    pub fn eval_dirs(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> Result<()> {
        match HalfDiff::from_dirs(wi, wo) {
            Some(hd) if wi[2] > 0.0 && wo[2] > 0.0 => self.eval_half_diff(&hd, out),
            _ => {
                self.check_out(out)?;
                out.iter_mut().for_each(|o| *o = 0.0);
                Ok(())
            }
        }
    }

    /// `out[j] = inverse(sum_i c_i forward(block[j * N + i]))` for consecutive rows of N stored
    /// values (`transformed`: the block already holds forward-transformed values, from the
    /// sidecar store). The one arithmetic of every lookup and materialisation path (vectorised
    /// batches: [`Transform::forward_batch`], [`gp_core::fastmath::dot`] per row,
    /// [`Transform::inverse_in_place`]), so all of them agree bit for bit. `wide` is scratch.
    fn combine_block(
        &self,
        block: &[f32],
        transformed: bool,
        wide: &mut Vec<f64>,
        out: &mut [f64],
    ) {
        let t = self.pred.inner.transform;
        Rows::of(block, t, transformed, wide).dots(&self.coef, out);
        t.inverse_in_place(out);
    }

    /// The values of one chunk (`block[(d - range.start) * N + i]`) under this material, 0 at
    /// below-horizon indices (`mask` per angular cell, `nc` channels); `transformed`: the block
    /// holds forward-transformed values (sidecar store).
    pub(crate) fn combine_chunk(
        &self,
        range: std::ops::Range<usize>,
        block: &[f32],
        transformed: bool,
        mask: &[bool],
        nc: usize,
    ) -> Vec<f64> {
        let mut out = vec![0.0; range.len()];
        self.combine_block(block, transformed, &mut Vec::new(), &mut out);
        for (o, d) in out.iter_mut().zip(range) {
            if !mask[d / nc] {
                *o = 0.0;
            }
        }
        out
    }
}

/// The rows of N values a cell's dot products read: stored (f32) or forward-transformed (f64).
#[derive(Clone, Copy)]
enum Rows<'a> {
    Stored(&'a [f32]),
    Forward(&'a [f64]),
}

impl<'a> Rows<'a> {
    /// The rows of stored `block` under transform `t`: the block itself when it needs none
    /// (`raw`, or `transformed`: read from the sidecar), else its forward transform, computed
    /// into `wide`.
    fn of(block: &'a [f32], t: Transform, transformed: bool, wide: &'a mut Vec<f64>) -> Self {
        if transformed || t == Transform::Raw {
            Rows::Stored(block)
        } else {
            wide.resize(block.len(), 0.0);
            t.forward_batch(block, wide);
            Rows::Forward(wide)
        }
    }

    /// `out[j] = dot(c, row j)` ([`row_dots`]).
    fn dots(self, c: &[f64], out: &mut [f64]) {
        match self {
            Rows::Stored(rows) => row_dots(c, rows, out),
            Rows::Forward(rows) => row_dots(c, rows, out),
        }
    }
}

thread_local! {
    /// Scratch of the lazy lookups: stored values, transformed values, results.
    static SCRATCH: RefCell<(Vec<f32>, Vec<f64>, Vec<f64>)> =
        const { RefCell::new((Vec::new(), Vec::new(), Vec::new())) };
}

/// `out[j] = dot(c, rows[j])` for the consecutive rows of `c.len()` values in `rows`
/// ([`gp_core::fastmath::dot`]: the same arithmetic on every CPU), compiled for AVX2 + FMA when
/// the CPU has them (selected at run time).
fn row_dots<T: Lanes>(c: &[f64], rows: &[T], out: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above), the only requirement
            // of a `#[target_feature]` function.
            unsafe { row_dots_avx2(c, rows, out) };
            return;
        }
    }
    row_dots_body(c, rows, out);
}

/// [`row_dots`] with AVX2: [`ROWS_AT_ONCE`] rows at a time by
/// [`gp_core::fastmath::dot_rows_avx2`], the rest by [`gp_core::fastmath::dot_avx2`] (explicit
/// 4-lane vectors, the arithmetic of [`gp_core::fastmath::dot`] exactly), so results are
/// bit-identical to [`row_dots_body`].
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_dots_avx2<T: Lanes>(c: &[f64], rows: &[T], out: &mut [f64]) {
    let n = c.len();
    let whole = (rows.len() / n).min(out.len());
    let mut k = 0;
    while k + ROWS_AT_ONCE <= whole {
        // SAFETY: AVX2 and FMA are available (this function's contract); rows from k on hold
        // at least ROWS_AT_ONCE rows of n values (k + ROWS_AT_ONCE <= whole).
        let dots =
            unsafe { gp_core::fastmath::dot_rows_avx2::<T, ROWS_AT_ONCE>(c, &rows[k * n..]) };
        out[k..k + ROWS_AT_ONCE].copy_from_slice(&dots);
        k += ROWS_AT_ONCE;
    }
    for (o, row) in out[k..].iter_mut().zip(rows[k * n..].chunks_exact(n)) {
        // SAFETY: AVX2 and FMA are available (this function's contract); `row` has c.len()
        // values.
        *o = unsafe { gp_core::fastmath::dot_avx2(c, row) };
    }
}

/// Rows whose dot products [`row_dots_avx2`] computes together (interleaved chains).
const ROWS_AT_ONCE: usize = 8;

#[inline(always)]
fn row_dots_body<T: Copy + Into<f64>>(c: &[f64], rows: &[T], out: &mut [f64]) {
    for (o, row) in out.iter_mut().zip(rows.chunks_exact(c.len())) {
        *o = gp_core::fastmath::dot(c, row);
    }
}

impl BrdfSource for PredictedMaterial {
    fn channels(&self) -> Channels {
        self.selection.channels.clone()
    }

    fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) -> brdf_io::Result<()> {
        self.eval_dirs(wi, wo, out).map_err(to_source_error)
    }

    fn grid(&self) -> Option<brdf_io::AngularGrid> {
        Some(self.pred.inner.grid)
    }

    fn eval_cell(&self, a: usize, out: &mut [f64]) -> brdf_io::Result<()> {
        PredictedMaterial::eval_cell(self, a, out).map_err(to_source_error)
    }

    fn prefetch_cell(&self, a: usize) {
        PredictedMaterial::prefetch_cell(self, a);
    }

    fn will_need_cells(&self, cells: &mut dyn Iterator<Item = usize>) {
        PredictedMaterial::will_need_cells(self, cells);
    }

    fn takes_cell_hints(&self) -> bool {
        self.pred.lookup_store().0.takes_will_need()
    }

    fn cell_source(&self) -> Option<&dyn std::any::Any> {
        Some(self)
    }
}

/// This crate's error as a [`BrdfSource`] error (store errors pass through).
fn to_source_error(e: Error) -> brdf_io::Error {
    match e {
        Error::Store(e) => e,
        other => brdf_io::Error::InvalidArgument {
            reason: other.to_string(),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values of mixed sign and magnitude.
    fn values(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let u = (s >> 11) as f64 / (1u64 << 53) as f64;
                (u - 0.3) * 10f64.powi((s % 7) as i32 - 3)
            })
            .collect()
    }

    #[test]
    fn row_dots_are_bit_identical_to_the_portable_dot() {
        // 21 rows: two blocks of ROWS_AT_ONCE and five rows one by one.
        for n in (1..=13).chain([51, 100]) {
            let c = values(n, n as u64);
            let rows64 = values(n * 21, 7 + n as u64);
            let rows32: Vec<f32> = rows64.iter().map(|&v| v as f32).collect();
            let (mut fast, mut portable) = (vec![0.0; 21], vec![0.0; 21]);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            row_dots(&c, &rows64, &mut fast);
            row_dots_body(&c, &rows64, &mut portable);
            assert_eq!(bits(&fast), bits(&portable), "f64, n = {n}");
            row_dots(&c, &rows32, &mut fast);
            row_dots_body(&c, &rows32, &mut portable);
            assert_eq!(bits(&fast), bits(&portable), "f32, n = {n}");
            let direct: Vec<f64> = rows32
                .chunks(n)
                .map(|r| gp_core::fastmath::dot(&c, r))
                .collect();
            assert_eq!(bits(&fast), bits(&direct), "f32, n = {n}");
            // Fewer output slots than rows: only the first rows, the others untouched.
            let mut few = [-1.0; 10];
            row_dots(&c, &rows32, &mut few[..9]);
            assert_eq!(bits(&few[..9]), bits(&direct[..9]), "n = {n}");
            assert_eq!(few[9], -1.0);
        }
    }
}
