//! Pipeline configs (`configs/NAME.toml`): parsed with unknown keys rejected, then validated by
//! [`PipelineParams::check`] into a [`PipelineConfig`]. Paths in a config are relative to the
//! project root.

use std::path::{Path, PathBuf};

use brdf_io::store::Dtype;
use brdf_io::{AngularGrid, Channels};
use gplvm::{FitConfig, FitParams};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// A pipeline config as written in TOML, before validation.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PipelineParams {
    /// Short name (the default output directory is `out/NAME`).
    pub name: String,
    /// One line saying what the run is for (quoted in the report).
    #[serde(default)]
    pub description: String,
    /// Where the materials come from.
    pub data: DataParams,
    /// A fit config file (`configs/fit/*.toml`); exclusive with `[fit]`.
    #[serde(default)]
    pub fit_config: Option<PathBuf>,
    /// Fit parameters inline (the keys of `gplvm::FitParams`); exclusive with `fit_config`.
    #[serde(default)]
    pub fit: Option<FitParams>,
    /// Latent points to predict at.
    #[serde(default)]
    pub predict: PredictParams,
    /// Error measures.
    #[serde(default)]
    pub evaluate: EvaluateParams,
    /// Figures.
    #[serde(default)]
    pub render: RenderParams,
    /// Materials outside the training set to place in the latent space.
    #[serde(default)]
    pub locate: LocateParams,
    /// How stored and predicted materials are looked up between the grid's bin centres, in
    /// the figures, the energy section and the `.bsdf` exports: `linear` (multilinear, the
    /// default) or `log` (`specgp render --lookup log`, BENCHMARKS.md "albedo").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lookup: Option<String>,
}

/// The `[data]` table.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DataParams {
    /// `synth`, `nbrdf`, `merl` or `rgl`.
    pub kind: String,
    /// Angular resolution `TH,TD,PD`.
    pub grid: String,
    /// Wavelengths `START:END:STEP` or a comma list (synth; rgl: default the files' own).
    #[serde(default)]
    pub wavelengths: Option<String>,
    /// Seed of the synthetic preset (synth only).
    #[serde(default)]
    pub seed: Option<u64>,
    /// Stored value type, `f32` or `f16`.
    #[serde(default)]
    pub dtype: Option<String>,
    /// Input files (merl, rgl).
    #[serde(default)]
    pub files: Vec<PathBuf>,
    /// The `(N, 675)` weights `.npy` (nbrdf).
    #[serde(default)]
    pub weights: Option<PathBuf>,
    /// Material names, one per weights row (nbrdf).
    #[serde(default)]
    pub names: Option<PathBuf>,
    /// Only these materials (synth and nbrdf; default all).
    #[serde(default)]
    pub only: Option<Vec<String>>,
}

/// The `[predict]` table.
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PredictParams {
    /// Latent points, each of the model's latent dimension.
    #[serde(default)]
    pub points: Vec<Vec<f64>>,
    /// Pairs of material names: predict at the midpoint of their latent points.
    #[serde(default, deserialize_with = "pairs")]
    pub midpoints: Vec<[String; 2]>,
    /// `exact` (reproduces training materials) or `smooth` (no noise term in k*).
    #[serde(default)]
    pub predictor: Option<String>,
    /// Materialise every prediction to `.npy` (timed).
    #[serde(default)]
    pub materialize: bool,
    /// Write every prediction as an RGL `.bsdf` file (Mitsuba 3, pbrt-v4) at the writer's
    /// starting sizes, checked against the prediction (not refined; timed).
    #[serde(default)]
    pub bsdf: bool,
}

/// `predict.midpoints`: a list of pairs. Read as lists and checked, because serde reads a fixed
/// size array from the first elements of a longer list and ignores the rest (a third name was
/// silently dropped).
fn pairs<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Vec<[String; 2]>, D::Error> {
    let lists = Vec::<Vec<String>>::deserialize(d)?;
    lists
        .into_iter()
        .enumerate()
        .map(|(i, list)| {
            <[String; 2]>::try_from(list).map_err(|list| {
                serde::de::Error::custom(format!(
                    "predict.midpoints[{i}] names {} material(s) {list:?}; each midpoint is a \
                     pair [\"A\", \"B\"]",
                    list.len()
                ))
            })
        })
        .collect()
}

/// The `[evaluate]` table.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EvaluateParams {
    /// Leave-one-out errors (GP, linear interpolation, PCA).
    #[serde(default = "yes")]
    pub loo: bool,
}

impl Default for EvaluateParams {
    fn default() -> Self {
        Self { loo: true }
    }
}

/// The `[locate]` table: measured files outside the training set, placed in the fitted latent
/// space as `specgp locate` does (report section "Located materials").
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LocateParams {
    /// RGL `.bsdf` or MERL `.binary` files (relative to the project root).
    #[serde(default)]
    pub files: Vec<PathBuf>,
    /// Starting points of the latent search per file (1..=1000; default 3).
    #[serde(default = "default_starts")]
    pub starts: usize,
}

impl Default for LocateParams {
    fn default() -> Self {
        Self {
            files: Vec::new(),
            starts: default_starts(),
        }
    }
}

fn default_starts() -> usize {
    3
}

/// The `[render]` table.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RenderParams {
    /// Render figures at all.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Sphere size in pixels (16..=2048; default 128).
    #[serde(default = "default_size")]
    pub size: u32,
    /// At most this many training materials in the comparison sheet (1..=64; default 8).
    #[serde(default = "default_sheet")]
    pub sheet_materials: usize,
    /// The spheres' environment, as `specgp render --env`: `table` (the default), `fast`,
    /// `per-pixel` or `studio` (a sky over a dark floor, in which metals show what they
    /// reflect; slower).
    #[serde(default = "default_env")]
    pub env: String,
}

impl Default for RenderParams {
    fn default() -> Self {
        Self {
            enabled: true,
            size: default_size(),
            sheet_materials: default_sheet(),
            env: default_env(),
        }
    }
}

impl RenderParams {
    /// The environment of `env` (checked by the config's validation).
    pub fn env_mode(&self) -> std::result::Result<render::EnvMode, String> {
        self.env.parse().map_err(|_| {
            format!(
                "render.env {:?}: expected {}",
                self.env,
                render::ENV_MODE_NAMES
            )
        })
    }
}

fn yes() -> bool {
    true
}
fn default_size() -> u32 {
    128
}
fn default_sheet() -> usize {
    8
}
fn default_env() -> String {
    "table".into()
}

/// Where the materials come from (validated).
#[derive(Debug, Clone, PartialEq)]
pub enum DataSource {
    /// The embedded synthetic preset (brdf-synth).
    Synth {
        /// Wavelength axis.
        channels: Channels,
        /// Preset seed.
        seed: u64,
        /// Only these preset materials (all when `None`).
        only: Option<Vec<String>>,
    },
    /// Neural-BRDF networks evaluated on the grid.
    Nbrdf {
        /// Weights `.npy`.
        weights: PathBuf,
        /// Names file.
        names: PathBuf,
        /// Only these materials.
        only: Option<Vec<String>>,
    },
    /// MERL `.binary` files.
    Merl {
        /// The files.
        files: Vec<PathBuf>,
    },
    /// RGL `.bsdf` files.
    Rgl {
        /// The files.
        files: Vec<PathBuf>,
        /// Wavelengths (the first file's own channels when `None`).
        channels: Option<Channels>,
    },
}

impl DataSource {
    /// `synth`, `nbrdf`, `merl` or `rgl`.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Synth { .. } => "synth",
            Self::Nbrdf { .. } => "nbrdf",
            Self::Merl { .. } => "merl",
            Self::Rgl { .. } => "rgl",
        }
    }
}

/// Validated data settings.
#[derive(Debug, Clone, PartialEq)]
pub struct DataConfig {
    /// The source.
    pub source: DataSource,
    /// Angular grid.
    pub grid: AngularGrid,
    /// Stored value type.
    pub dtype: Dtype,
}

/// Which GP predictor to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PredictorChoice {
    /// k* includes the noise term at training points: training materials are reproduced.
    Exact,
    /// k* without the noise term.
    Smooth,
}

/// Validated prediction settings.
#[derive(Debug, Clone, PartialEq)]
pub struct PredictConfig {
    /// Explicit latent points.
    pub points: Vec<Vec<f64>>,
    /// Midpoints of pairs of named materials.
    pub midpoints: Vec<[String; 2]>,
    /// The predictor.
    pub predictor: PredictorChoice,
    /// Materialise every prediction.
    pub materialize: bool,
    /// Write every prediction as an RGL `.bsdf` file.
    pub bsdf: bool,
}

/// A validated pipeline config.
#[derive(Debug, Clone)]
pub struct PipelineConfig {
    /// The config file it came from.
    pub path: PathBuf,
    /// The directory its relative paths were resolved against (the project root).
    pub root: PathBuf,
    /// The parameters as written (recorded in `results.json`).
    pub params: PipelineParams,
    /// Data settings.
    pub data: DataConfig,
    /// Fit settings.
    pub fit: FitConfig,
    /// Where the fit settings came from (a file, `[fit]` or the defaults).
    pub fit_source: String,
    /// Prediction settings.
    pub predict: PredictConfig,
    /// Files to locate (resolved against the project root).
    pub locate: Vec<PathBuf>,
    /// The lookup between bin centres (`lookup`; multilinear by default).
    pub lookup: brdf_io::Lookup,
}

impl PipelineConfig {
    /// Reads and validates `path`; relative paths inside are resolved against `root`.
    pub fn load(path: &Path, root: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let params: PipelineParams = toml::from_str(&text).map_err(|e| Error::Config {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        params.check(path, root)
    }
}

impl PipelineParams {
    /// Validates every value; `path` names the config in errors, `root` anchors its paths.
    pub fn check(self, path: &Path, root: &Path) -> Result<PipelineConfig> {
        let bad = |reason: String| Error::Config {
            path: path.to_owned(),
            reason,
        };
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(bad(format!(
                "name must be non-empty ASCII letters, digits, '-' or '_', got {:?}",
                self.name
            )));
        }
        let d = &self.data;
        let grid: AngularGrid = d
            .grid
            .parse()
            .map_err(|e| bad(format!("data.grid {:?}: {e}", d.grid)))?;
        let dtype: Dtype = match &d.dtype {
            None => Dtype::F32,
            Some(s) => s
                .parse()
                .map_err(|e| bad(format!("data.dtype {s:?}: {e}")))?,
        };
        let wavelengths = |spec: &str| {
            Channels::parse_wavelengths(spec)
                .map_err(|e| bad(format!("data.wavelengths {spec:?}: {e}")))
        };
        let resolve = |p: &Path| root.join(p);
        let not_for = |key: &str, present: bool| {
            if present {
                Err(bad(format!("data.{key} is not used by kind {:?}", d.kind)))
            } else {
                Ok(())
            }
        };
        // The synthetic materials' names (known before any data is written).
        let mut synth_names: Option<Vec<String>> = None;
        // The materials of merl and rgl files (their stems).
        let mut file_names: Option<Vec<String>> = None;
        let source = match d.kind.as_str() {
            "synth" => {
                not_for("files", !d.files.is_empty())?;
                not_for("weights", d.weights.is_some())?;
                not_for("names", d.names.is_some())?;
                let spec = d
                    .wavelengths
                    .as_deref()
                    .unwrap_or(brdf_synth::DEFAULT_WAVELENGTHS);
                let preset: Vec<String> =
                    brdf_synth::preset(0).into_iter().map(|m| m.name).collect();
                if let Some(only) = &d.only {
                    if let Some(missing) = only.iter().find(|n| !preset.contains(n)) {
                        return Err(bad(format!(
                            "data.only: no preset material named {missing:?}"
                        )));
                    }
                    check_only(only).map_err(bad)?;
                }
                synth_names = Some(d.only.clone().unwrap_or(preset));
                let channels = wavelengths(spec)?;
                brdf_synth::dataset::wavelengths_of(&channels)
                    .map_err(|e| bad(format!("data.wavelengths {spec:?}: {e}")))?;
                DataSource::Synth {
                    channels,
                    seed: d.seed.unwrap_or(0),
                    only: d.only.clone(),
                }
            }
            "nbrdf" => {
                not_for("files", !d.files.is_empty())?;
                not_for("wavelengths", d.wavelengths.is_some())?;
                not_for("seed", d.seed.is_some())?;
                let weights = d
                    .weights
                    .as_deref()
                    .ok_or_else(|| bad("data.weights is required for kind \"nbrdf\"".into()))?;
                let names = d
                    .names
                    .as_deref()
                    .ok_or_else(|| bad("data.names is required for kind \"nbrdf\"".into()))?;
                if let Some(only) = &d.only {
                    check_only(only).map_err(bad)?;
                }
                DataSource::Nbrdf {
                    weights: resolve(weights),
                    names: resolve(names),
                    only: d.only.clone(),
                }
            }
            "merl" | "rgl" => {
                not_for("weights", d.weights.is_some())?;
                not_for("names", d.names.is_some())?;
                not_for("seed", d.seed.is_some())?;
                not_for("only", d.only.is_some())?;
                if d.files.len() < 3 {
                    return Err(bad(format!(
                        "data.files must list at least 3 files for kind {:?}, got {}",
                        d.kind,
                        d.files.len()
                    )));
                }
                // A material is named after its file's stem (`data::build_store`): two files
                // with one stem failed in the data stage, after the earlier files' import.
                let stems: Vec<String> = d.files.iter().map(|f| crate::data::stem(f)).collect();
                if let Some((j, i)) = (0..stems.len()).find_map(|j| {
                    stems[..j]
                        .iter()
                        .position(|s| *s == stems[j])
                        .map(|i| (j, i))
                }) {
                    return Err(bad(format!(
                        "data.files[{j}] ({}) and data.files[{i}] ({}) give one material name \
                         {:?} (materials are named after their files' stems)",
                        d.files[j].display(),
                        d.files[i].display(),
                        stems[j]
                    )));
                }
                file_names = Some(stems);
                let files = d.files.iter().map(|f| resolve(f)).collect();
                if d.kind == "merl" {
                    not_for("wavelengths", d.wavelengths.is_some())?;
                    DataSource::Merl { files }
                } else {
                    DataSource::Rgl {
                        files,
                        channels: d.wavelengths.as_deref().map(wavelengths).transpose()?,
                    }
                }
            }
            other => {
                return Err(bad(format!(
                    "data.kind {other:?}: expected synth, nbrdf, merl or rgl"
                )));
            }
        };

        // The store's size, known before anything is written: a typo in the grid or the
        // wavelengths must not start streaming hundreds of GB.
        let n_materials = match &source {
            DataSource::Synth { only, .. } => {
                Some(only.as_ref().map_or(brdf_synth::N_MATERIALS, Vec::len))
            }
            DataSource::Nbrdf { only, .. } => only.as_ref().map(Vec::len),
            DataSource::Merl { files } | DataSource::Rgl { files, .. } => Some(files.len()),
        };
        let n_channels = match &source {
            DataSource::Synth { channels, .. } => Some(channels.len()),
            DataSource::Nbrdf { .. } | DataSource::Merl { .. } => Some(3),
            DataSource::Rgl { channels, .. } => channels.as_ref().map(Channels::len),
        };
        if let (Some(n), Some(c)) = (n_materials, n_channels) {
            let bytes = (grid.len() as u128) * (c as u128) * (n as u128) * (dtype.size() as u128);
            if bytes > MAX_STORE_BYTES as u128 {
                return Err(bad(format!(
                    "the dataset store would take {:.1} GB ({n} materials x {} cells x {c} \
                     channels x {} bytes), over the {} GB a pipeline may write; choose a coarser \
                     data.grid or fewer data.wavelengths",
                    bytes as f64 / 1e9,
                    grid.len(),
                    dtype.size(),
                    MAX_STORE_BYTES / 1_000_000_000
                )));
            }
        }

        let (fit_params, fit_source) = match (&self.fit_config, &self.fit) {
            (Some(_), Some(_)) => {
                return Err(bad(
                    "give either fit_config = \"FILE\" or a [fit] table, not both".into(),
                ));
            }
            (Some(file), None) => {
                let p =
                    FitParams::from_toml_file(&resolve(file)).map_err(|e| bad(e.to_string()))?;
                (p, file.display().to_string())
            }
            (None, Some(p)) => (p.clone(), "[fit] table".to_string()),
            (None, None) => (FitParams::default(), "FitParams::default()".to_string()),
        };
        let fit = fit_params
            .check()
            .map_err(|e| bad(format!("fit ({fit_source}): {e}")))?;
        let q = fit.params.latent_dim;

        let p = &self.predict;
        for (i, x) in p.points.iter().enumerate() {
            if x.len() != q {
                return Err(bad(format!(
                    "predict.points[{i}] has {} coordinates, the latent dimension is {q}",
                    x.len()
                )));
            }
            if x.iter().any(|v| !v.is_finite()) {
                return Err(bad(format!("predict.points[{i}] is not finite: {x:?}")));
            }
            if let Some(v) = x.iter().find(|v| v.abs() > MAX_POINT_COORDINATE) {
                return Err(bad(format!(
                    "predict.points[{i}] has the coordinate {v:e}, beyond +-{MAX_POINT_COORDINATE:e} \
                     (a quarter of the +-{:e} of model files, so that the latent map's padded \
                     extent around it stays within that bound)",
                    gplvm::model::MAX_COORDINATE
                )));
            }
        }
        let predictor = match p.predictor.as_deref() {
            None | Some("exact") => PredictorChoice::Exact,
            Some("smooth") => PredictorChoice::Smooth,
            Some(other) => {
                return Err(bad(format!(
                    "predict.predictor {other:?}: expected exact or smooth"
                )));
            }
        };
        if self.render.size < 16 || self.render.size > 2048 {
            return Err(bad(format!(
                "render.size must be in 16..=2048, got {}",
                self.render.size
            )));
        }
        self.render.env_mode().map_err(bad)?;
        if !(1..=64).contains(&self.render.sheet_materials) {
            return Err(bad(format!(
                "render.sheet_materials must be in 1..=64, got {}",
                self.render.sheet_materials
            )));
        }
        if self.render.enabled {
            let k = n_materials.map_or(self.render.sheet_materials, |n| {
                self.render.sheet_materials.min(n)
            });
            check_figure_sizes(
                self.render.size as usize,
                k,
                p.midpoints.len(),
                p.points.len() + p.midpoints.len(),
            )
            .map_err(bad)?;
        }
        let l = &self.locate;
        if !(1..=1000).contains(&l.starts) {
            return Err(bad(format!(
                "locate.starts must be in 1..=1000, got {}",
                l.starts
            )));
        }
        if let Some(f) = l
            .files
            .iter()
            .find(|f| !brdf_io::has_extension(f, "bsdf") && !brdf_io::has_extension(f, "binary"))
        {
            return Err(bad(format!(
                "locate.files: {} is not an RGL .bsdf or a MERL .binary file",
                f.display()
            )));
        }
        let locate = l.files.iter().map(|f| resolve(f)).collect();
        let lookup = match &self.lookup {
            Some(name) => name
                .parse()
                .map_err(|_| bad(format!("lookup {name:?}: expected linear or log")))?,
            None => brdf_io::Lookup::Multilinear,
        };
        let predict = PredictConfig {
            points: p.points.clone(),
            midpoints: p.midpoints.clone(),
            predictor,
            materialize: p.materialize,
            bsdf: p.bsdf,
        };
        // Synthetic materials are known now; other kinds' names once the data are read
        // (`PipelineConfig::check_midpoints`, before the fit).
        if let Some(names) = synth_names.as_ref().or(file_names.as_ref()) {
            check_midpoints(&predict.midpoints, names).map_err(bad)?;
        }
        Ok(PipelineConfig {
            path: path.to_owned(),
            root: root.to_owned(),
            data: DataConfig {
                source,
                grid,
                dtype,
            },
            fit,
            fit_source,
            predict,
            locate,
            lookup,
            params: self,
        })
    }
}

/// Largest dataset store a pipeline config may ask for (64 GB: the MERL grid with 195
/// wavelengths for 51 materials, 58 GB, still fits).
pub const MAX_STORE_BYTES: u64 = 64_000_000_000;

/// Largest |coordinate| of a configured latent point: a quarter of the model files' bound, so
/// that the latent map, which pads the points' bounding box by 15 % and widens it to a square,
/// asks for variances only within that bound (a point at 1e100 passed the predict stage and
/// failed in the render stage).
pub const MAX_POINT_COORDINATE: f64 = gplvm::model::MAX_COORDINATE / 4.0;

/// Largest figure, in pixels (the render crate draws in f64 RGB + alpha, 32 bytes a pixel: 2 GiB
/// while it is drawn).
pub const MAX_FIGURE_PIXELS: usize = 1 << 26;

/// The figures of the render stage as (name, the config keys that size it, width, height), at
/// their layouts (`figures::render_figures`; each sphere cell with its label and padding as
/// `size + 40` pixels square): the sheet is `k` materials by 3 rows, the comparison sheet `k` rows
/// by 7 cells (4 columns and 3 Delta E maps), the paths figure 7 steps by 3 rows per pair (at
/// most 3 pairs), the predictions figure one sphere per point.
pub fn figure_sizes(
    size: usize,
    k: usize,
    pairs: usize,
    points: usize,
) -> Vec<(&'static str, &'static str, usize, usize)> {
    let cell = size.saturating_add(40);
    let mut v = vec![
        (
            "sheet.png",
            "render.size and render.sheet_materials",
            k.saturating_mul(cell),
            3 * cell,
        ),
        (
            "comparison.png",
            "render.size and render.sheet_materials",
            7 * cell,
            k.saturating_mul(cell),
        ),
    ];
    if pairs > 0 {
        v.push((
            "paths.png",
            "render.size and the number of predict.midpoints (up to 3 are drawn)",
            7 * cell,
            pairs.min(3) * 3 * cell,
        ));
    }
    if points > 0 {
        v.push((
            "predictions.png",
            "render.size and the number of predict.points and predict.midpoints",
            points.saturating_mul(cell),
            cell,
        ));
    }
    v
}

/// An error naming the figure and the keys when one would be larger than
/// [`MAX_FIGURE_PIXELS`] (a size of 2048 with 51 sheet materials asked for a 10 GB image and
/// aborted the process after the fit, leaving its staging directory behind).
fn check_figure_sizes(
    size: usize,
    k: usize,
    pairs: usize,
    points: usize,
) -> std::result::Result<(), String> {
    for (name, keys, w, h) in figure_sizes(size, k, pairs, points) {
        let pixels = w.saturating_mul(h);
        if pixels > MAX_FIGURE_PIXELS {
            return Err(format!(
                "{keys} ask for a {name} of about {w} x {h} pixels ({:.1} GB while it is drawn), \
                 over the {} million pixels a figure may have; lower render.size (now {size}) \
                 or draw fewer spheres, or set render.enabled = false",
                pixels as f64 * 32.0 / 1e9,
                MAX_FIGURE_PIXELS / 1_000_000
            ));
        }
    }
    Ok(())
}

/// A `data.only` list: at least 3 names, no name twice (as the data stage looks them up: a
/// network's name is matched without spaces at its ends).
fn check_only(only: &[String]) -> std::result::Result<(), String> {
    if let Some((i, name)) = only
        .iter()
        .enumerate()
        .find(|(i, n)| only[..*i].iter().any(|m| m.trim() == n.trim()))
    {
        return Err(format!("data.only lists {name:?} twice (entry {})", i + 1));
    }
    if only.len() < 3 {
        return Err(format!(
            "data.only needs at least 3 materials (a GPLVM and its leave-one-out evaluation), got {}",
            only.len()
        ));
    }
    Ok(())
}

/// "no material named N", with a near name of `names` when there is one ("did you mean").
pub fn no_material_named<S: AsRef<str>>(n: &str, names: &[S]) -> String {
    let names: Vec<&str> = names.iter().map(AsRef::as_ref).collect();
    match brdf_io::error::closest_name(n, &names) {
        Some(c) => format!("no material named {n:?}; did you mean {c:?}?"),
        None => format!("no material named {n:?}"),
    }
}

/// Every midpoint names two different materials of `names`.
fn check_midpoints(midpoints: &[[String; 2]], names: &[String]) -> std::result::Result<(), String> {
    for [a, b] in midpoints {
        for n in [a, b] {
            if !names.contains(n) {
                return Err(format!(
                    "predict.midpoints: {} in the data",
                    no_material_named(n, names)
                ));
            }
        }
        if a == b {
            return Err(format!(
                "predict.midpoints: [{a:?}, {b:?}] names one material twice"
            ));
        }
    }
    Ok(())
}

impl PipelineConfig {
    /// Checks the midpoints against the materials of the data (`names`, the store's): an error
    /// naming the config before anything is fitted.
    pub fn check_midpoints(&self, names: &[String]) -> Result<()> {
        check_midpoints(&self.predict.midpoints, names).map_err(|reason| Error::Config {
            path: self.path.clone(),
            reason,
        })
    }
}
