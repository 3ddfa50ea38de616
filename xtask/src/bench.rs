//! `cargo xtask bench`: run time against error. Every sweep varies one setting of a base point
//! (angular resolution, wavelength sampling, storage precision, latent dimension, transform,
//! optimiser, predictor); each point is synthesised, fitted, predicted (lazy and full) and
//! evaluated (reconstruction, leave-one-out, Delta E), then tabulated and plotted with its
//! Pareto front.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use brdf_io::store::Dtype;
use brdf_io::{AngularGrid, Channels};
use gplvm::{FitParams, OptimizerKind};
use predict::{Predictor, PredictorKind};
use serde::{Deserialize, Serialize};

use crate::config::{DataConfig, DataSource};
use crate::error::{Error, Result};
use crate::pipeline::write_atomic;

/// The settings of one bench point.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    /// Angular grid `TH,TD,PD`.
    pub grid: String,
    /// Wavelengths `START:END:STEP`.
    pub wavelengths: String,
    /// `f32` or `f16`.
    pub dtype: String,
    /// Latent dimension q.
    pub latent_dim: usize,
    /// `raw` or `log`.
    pub transform: String,
    /// `lbfgs` or `hooke-jeeves`.
    pub optimizer: String,
    /// `exact` or `smooth` (the reconstruction error; leave-one-out always uses the smooth mean).
    pub predictor: String,
}

/// Values to sweep, one list per setting (each sweep varies one setting of the base point).
#[derive(Debug, Clone, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Sweeps {
    /// Angular grids.
    #[serde(default)]
    pub grid: Vec<String>,
    /// Wavelength samplings.
    #[serde(default)]
    pub wavelengths: Vec<String>,
    /// Storage precisions.
    #[serde(default)]
    pub dtype: Vec<String>,
    /// Latent dimensions.
    #[serde(default)]
    pub latent_dim: Vec<usize>,
    /// Transforms.
    #[serde(default)]
    pub transform: Vec<String>,
    /// Optimisers.
    #[serde(default)]
    pub optimizer: Vec<String>,
    /// Predictors.
    #[serde(default)]
    pub predictor: Vec<String>,
}

/// `configs/bench.toml`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    /// The point every sweep starts from.
    pub base: Settings,
    /// L-BFGS iteration cap of the fits.
    pub max_iterations: u64,
    /// Hooke-Jeeves evaluation cap of the fits.
    pub max_evaluations: usize,
    /// Spheres (measured against the smooth reconstruction) for Delta E; 0 disables it.
    pub delta_e_materials: usize,
    /// Sphere size for Delta E.
    pub sphere_size: usize,
    /// The sweeps.
    pub sweep: Sweeps,
}

impl BenchConfig {
    /// Reads and validates `path` (every swept point is checked before anything runs).
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let c: Self = toml::from_str(&text).map_err(|e| Error::Config {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let bad = |reason: String| Error::Config {
            path: path.to_owned(),
            reason,
        };
        for (sweep, value, s) in c.points() {
            s.check(c.max_iterations, c.max_evaluations)
                .map_err(|reason| bad(format!("{sweep} = {value}: {reason}")))?;
        }
        if c.delta_e_materials > 0 && !(16..=1024).contains(&c.sphere_size) {
            return Err(bad(format!(
                "sphere_size must be in 16..=1024 when delta_e_materials > 0, got {}",
                c.sphere_size
            )));
        }
        Ok(c)
    }

    /// (sweep, value, settings) of every point; the base point once, as sweep `base`.
    pub fn points(&self) -> Vec<(String, String, Settings)> {
        let mut out = vec![("base".to_string(), "-".to_string(), self.base.clone())];
        let mut add = |axis: &str, value: String, s: Settings| {
            if s != self.base {
                out.push((axis.to_string(), value, s));
            }
        };
        let b = &self.base;
        let sw = &self.sweep;
        for v in &sw.grid {
            add(
                "grid",
                v.clone(),
                Settings {
                    grid: v.clone(),
                    ..b.clone()
                },
            );
        }
        for v in &sw.wavelengths {
            add(
                "wavelengths",
                v.clone(),
                Settings {
                    wavelengths: v.clone(),
                    ..b.clone()
                },
            );
        }
        for v in &sw.dtype {
            add(
                "dtype",
                v.clone(),
                Settings {
                    dtype: v.clone(),
                    ..b.clone()
                },
            );
        }
        for v in &sw.latent_dim {
            add(
                "latent_dim",
                v.to_string(),
                Settings {
                    latent_dim: *v,
                    ..b.clone()
                },
            );
        }
        for v in &sw.transform {
            add(
                "transform",
                v.clone(),
                Settings {
                    transform: v.clone(),
                    ..b.clone()
                },
            );
        }
        for v in &sw.optimizer {
            add(
                "optimizer",
                v.clone(),
                Settings {
                    optimizer: v.clone(),
                    ..b.clone()
                },
            );
        }
        for v in &sw.predictor {
            add(
                "predictor",
                v.clone(),
                Settings {
                    predictor: v.clone(),
                    ..b.clone()
                },
            );
        }
        out
    }
}

impl Settings {
    fn parsed(&self) -> std::result::Result<(AngularGrid, Channels, Dtype), String> {
        let grid: AngularGrid = self
            .grid
            .parse()
            .map_err(|e| format!("grid {:?}: {e}", self.grid))?;
        let channels = Channels::parse_wavelengths(&self.wavelengths)
            .map_err(|e| format!("wavelengths {:?}: {e}", self.wavelengths))?;
        let dtype: Dtype = self
            .dtype
            .parse()
            .map_err(|e| format!("dtype {:?}: {e}", self.dtype))?;
        Ok((grid, channels, dtype))
    }

    fn fit_params(&self, max_iterations: u64, max_evaluations: usize) -> FitParams {
        FitParams {
            latent_dim: self.latent_dim,
            optimizer: self.optimizer.parse().unwrap_or(OptimizerKind::Lbfgs),
            transform: self.transform.clone(),
            max_iterations,
            max_evaluations,
            ..FitParams::default()
        }
    }

    fn kind(&self) -> PredictorKind {
        if self.predictor == "smooth" {
            PredictorKind::Smooth
        } else {
            PredictorKind::Exact
        }
    }

    /// Checks every value, with the fits' caps.
    pub fn check(
        &self,
        max_iterations: u64,
        max_evaluations: usize,
    ) -> std::result::Result<(), String> {
        let (grid, channels, dtype) = self.parsed()?;
        // As a pipeline config's store (`config::MAX_STORE_BYTES`): a swept grid of 512,512,512
        // started writing a 192 GB store after the earlier points had run.
        let bytes = (grid.len() as u128)
            * (channels.len() as u128)
            * (brdf_synth::N_MATERIALS as u128)
            * (dtype.size() as u128);
        if bytes > u128::from(crate::config::MAX_STORE_BYTES) {
            return Err(format!(
                "the store would take {:.1} GB ({} materials x {} cells x {} channels x {} \
                 bytes), over the {} GB a bench point may write",
                bytes as f64 / 1e9,
                brdf_synth::N_MATERIALS,
                grid.len(),
                channels.len(),
                dtype.size(),
                crate::config::MAX_STORE_BYTES / 1_000_000_000
            ));
        }
        brdf_synth::dataset::wavelengths_of(&channels)
            .map_err(|e| format!("wavelengths {:?}: {e}", self.wavelengths))?;
        self.optimizer
            .parse::<OptimizerKind>()
            .map_err(|e| e.to_string())?;
        if !matches!(self.predictor.as_str(), "exact" | "smooth") {
            return Err(format!(
                "predictor {:?}: expected exact or smooth",
                self.predictor
            ));
        }
        self.fit_params(max_iterations, max_evaluations)
            .check()
            .map(|_| ())
            .map_err(|e| e.to_string())
    }
}

/// The measurements of one bench point.
#[derive(Debug, Clone, Serialize)]
pub struct BenchRow {
    /// Which sweep (`base`, `grid`, ...).
    pub sweep: String,
    /// The swept value.
    pub value: String,
    /// All settings.
    pub settings: Settings,
    /// Values per material D.
    pub d: usize,
    /// Channels.
    pub n_channels: usize,
    /// Store size in bytes.
    pub store_bytes: u64,
    /// Seconds to synthesise the store.
    pub data_seconds: f64,
    /// Seconds to fit (Gram pass + optimisation).
    pub fit_seconds: f64,
    /// Final log-likelihood.
    pub log_likelihood: f64,
    /// Microseconds for one lazy prediction (the N coefficients).
    pub predict_lazy_us: f64,
    /// Microseconds per lazy lookup of one cell (all channels).
    pub lookup_us: f64,
    /// Seconds to materialise one prediction (all D values, `.npy`).
    pub predict_full_seconds: f64,
    /// Mean Eq. 22 reconstruction RMSE (BRDF space) of the chosen predictor.
    pub reconstruction_rmse: f64,
    /// Mean Eq. 22 leave-one-out RMSE of the GP (BRDF space).
    pub loo_rmse: f64,
    /// `loo_rmse / sqrt(n_channels)`: comparable across wavelength samplings.
    pub loo_rmse_per_channel: f64,
    /// Median Eq. 22 leave-one-out RMSE of the GP (BRDF space).
    pub loo_rmse_median: f64,
    /// Mean Delta E 2000 of the smooth reconstruction's spheres (NaN when disabled).
    pub delta_e: f64,
    /// Seconds of the evaluation (refits + streaming pass).
    pub evaluate_seconds: f64,
    /// On the Pareto front of (fit seconds, per-channel leave-one-out error).
    pub pareto: bool,
}

/// Runs every point of `config`, writes `bench.md`, `bench.json` and `bench.png` into `out`.
pub fn run(config: &BenchConfig, config_path: &Path, out: &Path) -> Result<Vec<BenchRow>> {
    // The three outputs are written into a staging directory and published together: a failed
    // or interrupted run leaves `out` as it was (or absent).
    crate::pipeline::run_staged(out, is_bench_output, |staged| {
        run_in(config, config_path, staged)
    })
}

/// The files a bench run publishes (an earlier run's are replaced as a set).
fn is_bench_output(name: &str) -> bool {
    matches!(name, "bench.json" | "bench.md" | "bench.png")
}

/// [`run`], writing into the staging directory `out`.
fn run_in(config: &BenchConfig, config_path: &Path, out: &Path) -> Result<Vec<BenchRow>> {
    // Stores and models of the points live in a hidden scratch directory, deleted when the
    // points are done, whether they succeed or fail (or are interrupted).
    let scratch_dir =
        brdf_io::output::StagingDir::create(out).map_err(|e| Error::stage("bench", out, e))?;
    let scratch = scratch_dir.path().to_owned();
    let mut stores: BTreeMap<(String, String, String), (PathBuf, f64)> = BTreeMap::new();
    let points = config.points();
    let mut rows = Vec::new();
    for (k, (sweep, value, s)) in points.iter().enumerate() {
        eprintln!("bench {}/{}: {sweep} = {value}", k + 1, points.len());
        let (grid, channels, dtype) = s.parsed().map_err(|reason| Error::Config {
            path: config_path.to_owned(),
            reason,
        })?;
        let key = (s.grid.clone(), s.wavelengths.clone(), s.dtype.clone());
        let (store_path, data_seconds) = match stores.get(&key) {
            Some(v) => v.clone(),
            None => {
                let path = scratch.join(format!("data-{}.sbrdf", stores.len()));
                let dc = DataConfig {
                    source: DataSource::Synth {
                        channels: channels.clone(),
                        seed: 0,
                        only: None,
                    },
                    grid,
                    dtype,
                };
                let (_, secs) = crate::data::build_store(&dc, &path)?;
                stores.insert(key, (path.clone(), secs));
                (path, secs)
            }
        };
        let fit_config = s
            .fit_params(config.max_iterations, config.max_evaluations)
            .check()
            .map_err(|e| Error::Config {
                path: config_path.to_owned(),
                reason: e.to_string(),
            })?;
        let t = Instant::now();
        let model = gplvm::fit_store(&store_path, &fit_config)
            .map_err(|e| Error::stage("fit", &store_path, e))?;
        let fit_seconds = t.elapsed().as_secs_f64();
        let model_path = scratch.join(format!("model-{k}.toml"));
        model
            .save(&model_path)
            .map_err(|e| Error::stage("fit", &model_path, e))?;
        let store_bytes = std::fs::metadata(&store_path)
            .map_err(|e| Error::io(&store_path, e))?
            .len();
        let pred =
            Predictor::open(&model_path).map_err(|e| Error::stage("predict", &model_path, e))?;
        let perr = |e: predict::Error| Error::stage("predict", &model_path, e);

        // Lazy and full prediction at the midpoint of the first two materials.
        let x: Vec<f64> = model.materials[0]
            .coords
            .iter()
            .zip(&model.materials[1].coords)
            .map(|(a, b)| 0.5 * (a + b))
            .collect();
        let reps = 200;
        let t = Instant::now();
        let mut m = pred.predict(&x, s.kind()).map_err(perr)?;
        for _ in 1..reps {
            m = pred.predict(&x, s.kind()).map_err(perr)?;
        }
        let predict_lazy_us = t.elapsed().as_secs_f64() * 1e6 / reps as f64;
        let (lookup_us, _) = crate::stages::time_lookups(&m, 4096)?;
        let full = m
            .materialize(&scratch.join("prediction.npy"), |_, _| {})
            .map_err(perr)?;

        // Errors.
        let t = Instant::now();
        let eval = crate::stages::run_evaluate(&pred, true)?;
        let evaluate_seconds = t.elapsed().as_secs_f64();
        let summary = |name: &str| eval.summary.iter().find(|r| r.method == name);
        let recon_name = if s.kind() == PredictorKind::Smooth {
            "reconstruction-smooth"
        } else {
            "reconstruction-exact"
        };
        let reconstruction_rmse = summary(recon_name).map_or(f64::NAN, |r| r.brdf_mean);
        let (loo_rmse, loo_rmse_median) =
            summary("loo-gp").map_or((f64::NAN, f64::NAN), |r| (r.brdf_mean, r.brdf_median));
        let delta_e = if config.delta_e_materials > 0 {
            delta_e_of(&pred, config.delta_e_materials, config.sphere_size)?
        } else {
            f64::NAN
        };
        rows.push(BenchRow {
            sweep: sweep.clone(),
            value: value.clone(),
            settings: s.clone(),
            d: pred.store().d(),
            n_channels: channels.len(),
            store_bytes,
            data_seconds,
            fit_seconds,
            log_likelihood: model.fit.log_likelihood,
            predict_lazy_us,
            lookup_us,
            predict_full_seconds: full.seconds,
            reconstruction_rmse,
            loo_rmse,
            loo_rmse_per_channel: loo_rmse / (channels.len() as f64).sqrt(),
            loo_rmse_median,
            delta_e,
            evaluate_seconds,
            pareto: false,
        });
    }
    mark_pareto(&mut rows);
    drop(scratch_dir);

    let json = serde_json::to_string_pretty(&rows)
        .map_err(|e| Error::stage("bench", out.join("bench.json"), e))?;
    write_atomic(&out.join("bench.json"), json.as_bytes())?;
    write_atomic(
        &out.join("bench.md"),
        markdown(&rows, config_path).as_bytes(),
    )?;
    crate::plot::pareto_plot(&rows, &out.join("bench.png"))?;
    Ok(rows)
}

/// Mean Delta E 2000 of `k` materials' spheres: measured against the smooth reconstruction.
fn delta_e_of(pred: &Predictor, k: usize, size: usize) -> Result<f64> {
    let opts = render::SphereOptions {
        size,
        ..render::SphereOptions::default()
    };
    let model = pred.model();
    let n = model.materials.len();
    let k = k.min(n).max(1);
    let path = pred.model().dataset.path.clone();
    let mut sum = 0.0;
    for j in 0..k {
        let i = j * n / k;
        let measured = brdf_io::store::StoreMaterial::by_index(pred.store().clone(), i)
            .map_err(|e| Error::stage("render", &path, e))?;
        let a = render::render_sphere(&measured, &opts)
            .map_err(|e| Error::stage("render", &path, e))?;
        let rec = pred
            .predict(&model.materials[i].coords, PredictorKind::Smooth)
            .map_err(|e| Error::stage("render", &path, e))?;
        let b = render::render_sphere(&rec, &opts).map_err(|e| Error::stage("render", &path, e))?;
        sum +=
            crate::figures::mean_delta_e(&a, &b).map_err(|e| Error::stage("render", &path, e))?;
    }
    Ok(sum / k as f64)
}

/// Marks the rows not dominated in (fit seconds, per-channel leave-one-out error).
pub fn mark_pareto(rows: &mut [BenchRow]) {
    let pts: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.fit_seconds, r.loo_rmse_per_channel))
        .collect();
    for (i, r) in rows.iter_mut().enumerate() {
        let (t, e) = pts[i];
        r.pareto = t.is_finite()
            && e.is_finite()
            && !pts
                .iter()
                .enumerate()
                .any(|(j, &(t2, e2))| j != i && t2 <= t && e2 <= e && (t2 < t || e2 < e));
    }
}

fn markdown(rows: &[BenchRow], config_path: &Path) -> String {
    use crate::report::{bytes, num};
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# specgp bench: run time against error\n\nConfig `{}`; regenerate with `cargo xtask \
         bench --config {}`. The 51 synthetic materials; each sweep varies one setting of the \
         base point. Errors are the paper's Eq. 22 RMSE in BRDF space (1/sr), means over the \
         materials; `LOO/ch` divides the leave-one-out error by sqrt(channels) so wavelength \
         samplings compare. Delta E: smooth reconstruction against the measured sphere. \
         Pareto (*): no other point is both faster to fit and better in LOO/ch.\n",
        config_path.display(),
        config_path.display()
    );
    let _ = writeln!(
        s,
        "| sweep | value | D | store | fit s | lazy predict us | lookup us | full predict s | reconstruction | LOO | LOO median | LOO/ch | Delta E | Pareto |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|:-:|"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.2} | {:.1} | {:.2} | {:.3} | {} | {} | {} | {} | {} | {} |",
            r.sweep,
            r.value,
            r.d,
            bytes(r.store_bytes),
            r.fit_seconds,
            r.predict_lazy_us,
            r.lookup_us,
            r.predict_full_seconds,
            num(r.reconstruction_rmse),
            num(r.loo_rmse),
            num(r.loo_rmse_median),
            num(r.loo_rmse_per_channel),
            if r.delta_e.is_finite() {
                format!("{:.3}", r.delta_e)
            } else {
                "-".into()
            },
            if r.pareto { "*" } else { "" }
        );
    }
    let _ = writeln!(s, "\n![run time against error](bench.png)");
    s
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A row of fit time `t` and leave-one-out error `e` (per channel too), off the front.
    pub(crate) fn row(t: f64, e: f64) -> BenchRow {
        BenchRow {
            sweep: "s".into(),
            value: "v".into(),
            settings: Settings {
                grid: "4,4,8".into(),
                wavelengths: "400:700:100".into(),
                dtype: "f32".into(),
                latent_dim: 2,
                transform: "log".into(),
                optimizer: "lbfgs".into(),
                predictor: "exact".into(),
            },
            d: 1,
            n_channels: 1,
            store_bytes: 0,
            data_seconds: 0.0,
            fit_seconds: t,
            log_likelihood: 0.0,
            predict_lazy_us: 0.0,
            lookup_us: 0.0,
            predict_full_seconds: 0.0,
            reconstruction_rmse: 0.0,
            loo_rmse: e,
            loo_rmse_per_channel: e,
            loo_rmse_median: e,
            delta_e: f64::NAN,
            evaluate_seconds: 0.0,
            pareto: false,
        }
    }

    #[test]
    fn pareto_front_keeps_exactly_the_undominated_points() {
        let mut rows = vec![
            row(1.0, 5.0),      // front: fastest
            row(2.0, 3.0),      // front
            row(3.0, 4.0),      // dominated by (2, 3)
            row(4.0, 1.0),      // front: most accurate
            row(4.0, 1.0),      // a tie is not dominated
            row(5.0, f64::NAN), // no error: never on the front
            row(1.0, 6.0),      // as fast as (1, 5), worse: dominated
            row(2.5, 3.0),      // as accurate as (2, 3), slower: dominated
        ];
        mark_pareto(&mut rows);
        let front: Vec<bool> = rows.iter().map(|r| r.pareto).collect();
        assert_eq!(front, [true, true, false, true, true, false, false, false]);
    }

    /// Every swept value other than the base's is a point that differs from the base in its
    /// own setting only, set to that value, in the sweeps' order: the repository's sweep has
    /// 12 points (the base and 11 others).
    #[test]
    fn each_sweep_point_changes_only_its_own_setting() {
        let c = BenchConfig::load(&crate::project_root().join("configs/bench.toml")).unwrap();
        let pts = c.points();
        let b = &c.base;
        let field = |s: &Settings, axis: &str| match axis {
            "grid" => s.grid.clone(),
            "wavelengths" => s.wavelengths.clone(),
            "dtype" => s.dtype.clone(),
            "latent_dim" => s.latent_dim.to_string(),
            "transform" => s.transform.clone(),
            "optimizer" => s.optimizer.clone(),
            "predictor" => s.predictor.clone(),
            other => panic!("unknown sweep {other}"),
        };
        let axes = [
            "grid",
            "wavelengths",
            "dtype",
            "latent_dim",
            "transform",
            "optimizer",
            "predictor",
        ];
        for (axis, value, s) in &pts[1..] {
            assert_eq!(&field(s, axis), value, "{axis}");
            assert_ne!(field(b, axis), *value, "{axis}");
            for other in axes.iter().filter(|a| *a != axis) {
                assert_eq!(
                    field(s, other),
                    field(b, other),
                    "{axis} = {value}: {other}"
                );
            }
        }
        let want: Vec<(&str, &str)> = vec![
            ("base", "-"),
            ("grid", "4,4,8"),
            ("grid", "16,16,32"),
            ("wavelengths", "400:700:100"),
            ("wavelengths", "380:780:20"),
            ("dtype", "f16"),
            ("latent_dim", "1"),
            ("latent_dim", "3"),
            ("latent_dim", "5"),
            ("transform", "raw"),
            ("optimizer", "hooke-jeeves"),
            ("predictor", "smooth"),
        ];
        let got: Vec<(&str, &str)> = pts
            .iter()
            .map(|(a, v, _)| (a.as_str(), v.as_str()))
            .collect();
        assert_eq!(got, want);
    }

    /// A point's fit runs with its own latent dimension, optimiser and transform and the
    /// bench's caps (every point of the repository's sweep; Hooke-Jeeves and raw values are
    /// swept, not the base).
    #[test]
    fn fit_params_carry_each_points_settings() {
        let c = BenchConfig::load(&crate::project_root().join("configs/bench.toml")).unwrap();
        let mut seen = (false, false);
        for (axis, value, s) in c.points() {
            let p = s.fit_params(7, 11);
            assert_eq!(p.latent_dim, s.latent_dim, "{axis} = {value}");
            assert_eq!(p.optimizer.to_string(), s.optimizer, "{axis} = {value}");
            assert_eq!(p.transform, s.transform, "{axis} = {value}");
            assert_eq!((p.max_iterations, p.max_evaluations), (7, 11));
            seen.0 |= p.optimizer == OptimizerKind::HookeJeeves;
            seen.1 |= p.transform == "raw";
        }
        assert_eq!(seen, (true, true));
    }

    /// `delta_e_of` averages, over `k` materials spread through the set (`j N / k`), the Delta
    /// E between each stored sphere and its smooth reconstruction at the requested size
    /// (checked against the spheres rendered here), and clamps `k` to 1..=N.
    #[test]
    fn delta_e_averages_the_chosen_materials_spheres() {
        let dir = tempfile::tempdir().unwrap();
        let store_path = dir.path().join("data.sbrdf");
        let dc = DataConfig {
            source: DataSource::Synth {
                channels: Channels::parse_wavelengths("400:700:100").unwrap(),
                seed: 0,
                only: None,
            },
            grid: "4,4,8".parse().unwrap(),
            dtype: Dtype::F32,
        };
        crate::data::build_store(&dc, &store_path).unwrap();
        let fit = FitParams {
            latent_dim: 2,
            max_iterations: 30,
            ..FitParams::default()
        }
        .check()
        .unwrap();
        let model_path = dir.path().join("model.toml");
        gplvm::fit_store(&store_path, &fit)
            .unwrap()
            .save(&model_path)
            .unwrap();
        let pred = Predictor::open(&model_path).unwrap();
        let n = pred.model().materials.len();
        let opts = render::SphereOptions {
            size: 20,
            ..render::SphereOptions::default()
        };
        let sphere_delta_e = |i: usize| {
            let stored = brdf_io::store::StoreMaterial::by_index(pred.store().clone(), i).unwrap();
            let rec = pred
                .predict(&pred.model().materials[i].coords, PredictorKind::Smooth)
                .unwrap();
            crate::figures::mean_delta_e(
                &render::render_sphere(&stored, &opts).unwrap(),
                &render::render_sphere(&rec, &opts).unwrap(),
            )
            .unwrap()
        };
        let want3 = (sphere_delta_e(0) + sphere_delta_e(n / 3) + sphere_delta_e(2 * n / 3)) / 3.0;
        let got3 = delta_e_of(&pred, 3, 20).unwrap();
        assert!(
            (got3 - want3).abs() <= 1e-12 * want3,
            "{got3} against {want3}"
        );
        assert!(got3 > 0.0);
        assert_eq!(delta_e_of(&pred, 0, 20).unwrap(), sphere_delta_e(0));
        let all: f64 = (0..n).map(sphere_delta_e).sum::<f64>() / n as f64;
        let got_all = delta_e_of(&pred, n + 5, 20).unwrap();
        assert!(
            (got_all - all).abs() <= 1e-12 * all,
            "{got_all} against {all}"
        );
    }

    /// The sphere size is only checked when Delta E spheres are asked for: with
    /// `delta_e_materials = 0` a size of 0 loads.
    #[test]
    fn sphere_size_is_free_without_delta_e_spheres() {
        let path = crate::project_root().join("configs/bench.toml");
        let text = std::fs::read_to_string(&path)
            .unwrap()
            .replace("delta_e_materials = 3", "delta_e_materials = 0")
            .replace("sphere_size = 48", "sphere_size = 0");
        let dir = tempfile::tempdir().unwrap();
        let off = dir.path().join("bench.toml");
        std::fs::write(&off, text).unwrap();
        let c = BenchConfig::load(&off).unwrap();
        assert_eq!((c.delta_e_materials, c.sphere_size), (0, 0));
    }

    #[test]
    fn bench_config_in_the_repository_validates_and_dedupes_the_base() {
        let path = crate::project_root().join("configs/bench.toml");
        let c = BenchConfig::load(&path).unwrap();
        let pts = c.points();
        assert_eq!(pts[0].0, "base");
        // No swept point repeats the base point.
        assert!(pts[1..].iter().all(|(_, _, s)| *s != c.base));
        // A bad value is named with the file.
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("bench.toml");
        let text = std::fs::read_to_string(&path)
            .unwrap()
            .replace("latent_dim = [1,", "latent_dim = [0,");
        std::fs::write(&bad, text).unwrap();
        let e = BenchConfig::load(&bad).unwrap_err().to_string();
        assert!(e.contains("bench.toml") && e.contains("latent_dim"), "{e}");
        // Checked at load, before any point runs (they used to fail after earlier points had
        // built their stores): the fits' caps, swept wavelengths outside 360-1000 nm, the
        // sphere size of the Delta E spheres.
        let original = std::fs::read_to_string(&path).unwrap();
        for (from, to, needle) in [
            (
                "max_iterations = 2000",
                "max_iterations = 0",
                "max_iterations",
            ),
            (
                "\"380:780:20\"]",
                "\"200:300:50\"]",
                "wavelengths = 200:300:50",
            ),
            ("sphere_size = 48", "sphere_size = 1", "sphere_size"),
            (
                "\"16,16,32\"]",
                "\"512,512,512\"]",
                "grid = 512,512,512: the store would take 191.7 GB (51 materials x 134217728 \
                 cells x 7 channels x 4 bytes), over the 64 GB a bench point may write",
            ),
        ] {
            assert!(original.contains(from), "{from}");
            std::fs::write(&bad, original.replace(from, to)).unwrap();
            let e = BenchConfig::load(&bad).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
        }
    }
}
