//! Property tests of the prediction service over small random datasets: tiny grids, a few
//! materials with values spanning several decades (and duplicates or near-duplicates), models
//! fitted through `gplvm`, and invariants checked against independent computations.
#![allow(clippy::needless_range_loop)]

mod common;

use common::dense_solve;
use std::path::{Path, PathBuf};

use brdf_io::store::Store;
use brdf_io::{AngularGrid, Channels, StoreInfo, StoreOptions, StoreWriter};
use gplvm::{FitParams, Transform};
use predict::{Predictor, PredictorKind};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};

/// A random dataset and its fitted model in a temporary directory.
struct Case {
    dir: tempfile::TempDir,
    model: PathBuf,
    /// Every stored value, material-major (`values[m][d]`).
    values: Vec<Vec<f32>>,
}

#[derive(Debug, Clone, Copy)]
enum Duplicate {
    None,
    /// The last material is a copy of the first (another name).
    Exact,
    /// The last material is the first times 1 + 1e-6 u, u in [-1, 1].
    Near,
}

#[derive(Debug, Clone)]
struct Spec {
    seed: u64,
    n: usize,
    q: usize,
    log: bool,
    rgb: bool,
    duplicate: Duplicate,
}

fn spec() -> impl Strategy<Value = Spec> {
    (
        any::<u64>(),
        3usize..=5,
        1usize..=2,
        any::<bool>(),
        any::<bool>(),
        prop_oneof![
            2 => Just(Duplicate::None),
            1 => Just(Duplicate::Exact),
            1 => Just(Duplicate::Near)
        ],
    )
        .prop_map(|(seed, n, q, log, rgb, duplicate)| Spec {
            seed,
            n,
            q,
            log,
            rgb,
            duplicate,
        })
}

fn grid() -> AngularGrid {
    AngularGrid::new(4, 4, 8).unwrap()
}

/// Writes `values` (material-major) to a store at `path`.
fn write_values(path: &Path, channels: &Channels, values: &[Vec<f32>]) {
    let info = StoreInfo {
        grid: grid(),
        channels: channels.clone(),
    };
    let mut w = StoreWriter::create(path, info, StoreOptions::default()).unwrap();
    for (m, v) in values.iter().enumerate() {
        w.add_material(&format!("m{m}"), "random", v).unwrap();
    }
    w.finish().unwrap();
}

/// Random positive values over ~1e-2..1e4: a per-material level and contrast on a shared
/// per-index shape, with per-value noise; 0 below the horizon (as the store keeps them).
fn random_values(spec: &Spec, d: usize, nc: usize) -> Vec<Vec<f32>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(spec.seed);
    let mask = grid().validity_mask();
    let shape: Vec<f64> = (0..d).map(|_| rng.random_range(0.0..1.0)).collect();
    let mut values: Vec<Vec<f32>> = (0..spec.n)
        .map(|_| {
            let a = rng.random_range(-2.0..1.0);
            let b = rng.random_range(0.0..3.0);
            (0..d)
                .map(|i| {
                    if !mask[i / nc] {
                        return 0.0;
                    }
                    let e: f64 = a + b * shape[i] + rng.random_range(-0.2..0.2);
                    10f64.powf(e) as f32
                })
                .collect()
        })
        .collect();
    let last = spec.n - 1;
    match spec.duplicate {
        Duplicate::None => {}
        Duplicate::Exact => values[last] = values[0].clone(),
        Duplicate::Near => {
            values[last] = values[0]
                .iter()
                .map(|v| v * (1.0 + 1e-6 * rng.random_range(-1.0f32..1.0)))
                .collect();
        }
    }
    values
}

fn channels_of(spec: &Spec) -> Channels {
    if spec.rgb {
        Channels::Rgb
    } else if spec.seed.is_multiple_of(2) {
        Channels::parse_wavelengths("400:600:100").unwrap()
    } else {
        Channels::parse_wavelengths("450:650:50").unwrap()
    }
}

fn make_case(spec: &Spec) -> Case {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("data.sbrdf");
    let channels = channels_of(spec);
    let nc = channels.len();
    let d = grid().len() * nc;
    let values = random_values(spec, d, nc);
    write_values(&store, &channels, &values);
    let params = FitParams {
        latent_dim: spec.q,
        transform: if spec.log { "log" } else { "raw" }.into(),
        max_iterations: 60,
        ..FitParams::default()
    };
    let model = gplvm::fit_store(&store, &params.check().unwrap()).unwrap();
    let model_path = dir.path().join("model.toml");
    model.save(&model_path).unwrap();
    Case {
        dir,
        model: model_path,
        values,
    }
}

/// The model's latent points.
fn points(pred: &Predictor) -> Vec<Vec<f64>> {
    pred.model()
        .materials
        .iter()
        .map(|m| m.coords.clone())
        .collect()
}

/// The length-scale of axis `j`.
fn length_scale(pred: &Predictor, j: usize) -> f64 {
    let l = &pred.model().hyperparameters.length_scale;
    *l.get(j).unwrap_or(&l[0])
}

/// The dense GP weights `K^-1 k*` computed here from the hyperparameters (the jitter, if the
/// factorisation needed one, counted as noise as `gp_core` does), and `K` itself.
fn dense_weights(pred: &Predictor, x: &[f64], kind: PredictorKind) -> Vec<f64> {
    let h = &pred.model().hyperparameters;
    let s2 = h.signal_variance;
    let mu = pred.gp().effective_noise();
    let pts = points(pred);
    let k = |a: &[f64], b: &[f64]| {
        let r2: f64 = (0..a.len())
            .map(|j| ((a[j] - b[j]) / length_scale(pred, j)).powi(2))
            .sum();
        s2 * (-0.5 * r2).exp()
    };
    let n = pts.len();
    let kk: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            (0..n)
                .map(|j| k(&pts[i], &pts[j]) + if i == j { mu } else { 0.0 })
                .collect()
        })
        .collect();
    let kstar: Vec<f64> = pts
        .iter()
        .map(|p| {
            k(p, x)
                + if kind == PredictorKind::Exact && p == x {
                    mu
                } else {
                    0.0
                }
        })
        .collect();
    dense_solve(|i, j| kk[i][j], &kstar)
}

/// Random latent points: convex combinations of the training points (inside their hull),
/// a little beyond it, and the training points themselves.
fn latent_points(pred: &Predictor, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let pts = points(pred);
    let (n, q) = (pts.len(), pts[0].len());
    let mut out = Vec::new();
    for _ in 0..3 {
        let w: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
        let s: f64 = w.iter().sum();
        out.push(
            (0..q)
                .map(|j| (0..n).map(|i| w[i] / s * pts[i][j]).sum())
                .collect(),
        );
    }
    let l = length_scale(pred, 0);
    out.push(pts[0].iter().map(|v| v + 0.7 * l).collect());
    out.push(pts[n - 1].clone());
    out
}

/// All D values of `pred`'s smooth prediction at `x`.
fn smooth_values(pred: &Predictor, x: &[f64]) -> Vec<f64> {
    let m = pred.predict(x, PredictorKind::Smooth).unwrap();
    (0..pred.store().d())
        .map(|di| m.value_at(di).unwrap())
        .collect()
}

/// A `locate` target of `values` (named `p`).
fn target_of(values: Vec<f32>) -> predict::locate::Target {
    predict::locate::Target {
        name: "p".into(),
        source: "test".into(),
        values,
    }
}

/// `|a - b|` within `tol` of the larger magnitude (plus `abs`).
fn close(a: f64, b: f64, tol: f64, abs: f64) -> bool {
    (a - b).abs() <= tol * a.abs().max(b.abs()) + abs
}

fn kinds() -> [PredictorKind; 2] {
    [PredictorKind::Exact, PredictorKind::Smooth]
}

/// Eq. 22 RMSE in the model's transformed space of the linear predictor `c` (over the stored
/// `values`, material-major) against `target`, computed directly over the valid cells: the
/// transform of the target's values against `sum_i c_i T(values_i)`.
fn transformed_rmse(pred: &Predictor, values: &[Vec<f32>], c: &[f64], target: &[f32]) -> f64 {
    let t = pred.transform();
    let nc = pred.store().channels().len();
    let mask = pred.grid().validity_mask();
    let mut sum = 0.0;
    for (di, &f) in target.iter().enumerate() {
        if !mask[di / nc] {
            continue;
        }
        let y: f64 = (0..c.len())
            .map(|i| c[i] * t.forward(f64::from(values[i][di])))
            .sum();
        sum += (t.forward(f64::from(f)) - y).powi(2);
    }
    (sum / pred.grid().len() as f64).sqrt()
}

fn is_coinciding(pred: &Predictor, i: usize) -> bool {
    let pts = points(pred);
    pts.iter().enumerate().any(|(j, p)| j != i && *p == pts[i])
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20, max_shrink_iters: 32, ..ProptestConfig::default() })]

    /// Lazy lookups, the dense posterior mean, training reproduction and materialised files.
    #[test]
    fn predictions_agree_with_the_dense_posterior_and_their_files(spec in spec()) {
        let case = make_case(&spec);
        let pred = Predictor::open(&case.model).unwrap();
        let t = pred.transform();
        let nc = pred.channels().len();
        let d = pred.store().d();
        let n = pred.n_materials();
        let mask = pred.grid().validity_mask();
        let offset = match t {
            Transform::Raw => 0.0,
            Transform::Log { offset } => offset,
        };
        // Independent transforms (the standard library's).
        let fwd = |f: f64| match t {
            Transform::Raw => f,
            Transform::Log { offset } => (f.max(0.0) / offset).ln_1p(),
        };
        let inv = |y: f64| match t {
            Transform::Raw => y,
            Transform::Log { offset } => offset * y.exp_m1(),
        };
        let ty: Vec<Vec<f64>> = case
            .values
            .iter()
            .map(|row| row.iter().map(|v| fwd(f64::from(*v))).collect())
            .collect();
        let mut cell = vec![0.0; nc];
        for (k, x) in latent_points(&pred, spec.seed).iter().enumerate() {
            for kind in kinds() {
                let m = pred.predict(x, kind).unwrap();
                // Dense posterior mean in the transformed space, then the inverse.
                let w = dense_weights(&pred, x, kind);
                let got_w = pred.gp_weights(x, kind).unwrap();
                let cond = pred.gp().factor().condition_estimate();
                let wscale: f64 = w.iter().map(|v| v.abs()).sum::<f64>().max(1.0);
                for i in 0..n {
                    prop_assert!(
                        close(got_w[i], w[i], 0.0, 1e-12 * cond * wscale),
                        "w[{i}] {} vs dense {} (cond {cond:e})", got_w[i], w[i]
                    );
                }
                for a in 0..pred.grid().len() {
                    m.eval_cell(a, &mut cell).unwrap();
                    for c in 0..nc {
                        let di = a * nc + c;
                        // Bit-identical: value_at and eval_cell run the one arithmetic.
                        prop_assert_eq!(cell[c].to_bits(), m.value_at(di).unwrap().to_bits());
                        let mean = (0..n).map(|i| ty[i][di]).sum::<f64>() / n as f64;
                        let ystar = mean
                            + (0..n).map(|i| got_w[i] * (ty[i][di] - mean)).sum::<f64>();
                        let scale: f64 = (0..n)
                            .map(|i| (got_w[i].abs() + 1.0 / n as f64) * ty[i][di].abs())
                            .sum();
                        let want = inv(ystar);
                        // Rounding of the sums (~n eps of the terms) through the inverse,
                        // whose derivative is f + offset.
                        let allowed = 64.0 * f64::EPSILON * scale
                            * if spec.log { want.abs() + offset } else { 1.0 };
                        prop_assert!(
                            (cell[c] - want).abs() <= allowed + 1e-300,
                            "point {k} {kind} index {di}: {} vs {want} (allowed {allowed:e})",
                            cell[c]
                        );
                        if !mask[a] {
                            prop_assert_eq!(cell[c], 0.0);
                        }
                    }
                }
            }
        }
        // The exact predictor returns each training material at its own point (unless another
        // material shares the point bit for bit: the delta term is then shared).
        for i in 0..n {
            if is_coinciding(&pred, i) {
                continue;
            }
            let m = pred.predict(&points(&pred)[i], PredictorKind::Exact).unwrap();
            prop_assert!(m.coefficients().iter().enumerate().all(|(j, c)| *c == f64::from(u8::from(i == j))));
            for di in 0..d {
                let (got, stored) = (m.value_at(di).unwrap(), f64::from(case.values[i][di]));
                if spec.log {
                    // ln_1p then exp_m1: a few ulps.
                    prop_assert!(close(got, stored, 1e-13, 0.0), "{got} vs {stored}");
                } else {
                    prop_assert_eq!(got, stored);
                }
            }
        }

        // Materialised files equal the lazy values rounded to f32, bit for bit.
        let x = &latent_points(&pred, spec.seed)[0];
        for kind in kinds() {
            let m = pred.predict(x, kind).unwrap();
            let lazy: Vec<f32> = (0..d).map(|di| m.value_at(di).unwrap() as f32).collect();
            let npy = case.dir.path().join("p.npy");
            let report = m.materialize(&npy, |_, _| {}).unwrap();
            let arr = brdf_io::npy::read(&npy).unwrap().to_f32();
            prop_assert_eq!(arr.len(), d);
            for di in 0..d {
                prop_assert_eq!(arr[di].to_bits(), lazy[di].to_bits(), "npy index {}", di);
            }
            prop_assert_eq!(report.negatives, lazy.iter().filter(|v| **v < 0.0).count());
            let sbrdf = case.dir.path().join("p.sbrdf");
            m.materialize(&sbrdf, |_, _| {}).unwrap();
            let written = Store::open(&sbrdf).unwrap();
            prop_assert_eq!(written.n_materials(), 1);
            prop_assert_eq!(written.channels(), pred.channels());
            let mut row = vec![0f32; d];
            written.material_row(0, 0..d, &mut row).unwrap();
            for di in 0..d {
                prop_assert_eq!(row[di].to_bits(), lazy[di].to_bits(), "sbrdf index {}", di);
            }
            if spec.rgb && kind == PredictorKind::Smooth {
                check_merl(&case, &m)?;
            }
        }
    }
}

/// The MERL file of an RGB prediction holds, at each MERL bin centre, the lazy prediction
/// interpolated there (negative values as 0), to f32 rounding.
fn check_merl(case: &Case, m: &predict::PredictedMaterial) -> Result<(), TestCaseError> {
    let path = case.dir.path().join("p.binary");
    m.materialize(&path, |_, _| {}).unwrap();
    let merl = brdf_io::merl::read_merl(&path).unwrap();
    let g = AngularGrid::MERL;
    prop_assert_eq!(*merl.grid(), g);
    let (mut rgb, mut cell) = ([0.0; 3], [0.0; 3]);
    for flat in (0..g.len()).step_by(997) {
        let hd = g.bin_centre_flat(flat);
        for c in 0..3 {
            let v = merl.value(c, flat);
            if !hd.is_above_horizon() {
                prop_assert_eq!(v, 0.0);
                continue;
            }
            m.eval_half_diff(&hd, &mut rgb).unwrap();
            let want = rgb[c].max(0.0);
            // The file interpolates the f32-rounded cell values and rounds the sum to f32:
            // a few f32 ulps of sum_a w_a |v_a| (the sum can cancel when values are negative).
            let mut size = 0.0;
            for (a, w) in m.predictor().grid().interpolation_stencil(&hd) {
                m.eval_cell(a, &mut cell).unwrap();
                size += w.abs() * cell[c].abs();
            }
            prop_assert!(
                (v - want).abs() <= 4.0 * f64::from(f32::EPSILON) * size + 1e-30,
                "MERL cell {flat} channel {c}: {v} vs {want} (size {size})"
            );
        }
    }
    Ok(())
}

/// Locate inverts predict: a smooth prediction inside the hull, written as a target, is
/// located at least as well as the point it was made at, to the precision of the latent search
/// (L-BFGS since session 23, to rounding; Hooke-Jeeves before, down to steps of 1e-5 of the
/// points' spread: typically 1e-6..1e-5 of the target's size, up to ~1e-3 in a flat valley,
/// seen with N = 3, q = 1, raw); not necessarily at that point, since the prediction can be
/// reached elsewhere (e.g. near the mean far from the materials). Before the search also
/// started from midpoints, a point between two materials was missed for another material's
/// basin (2.4 % error, N = 5, q = 1).
///
/// "At least as well as the point": the target is the prediction only where the transform can
/// represent it. Under `log` a smooth prediction can be slightly negative (it is not clamped),
/// and the transform maps a negative target value to 0 (`ln(1 + f / c)` of f clamped at 0), so
/// there the target differs from the prediction by the prediction's transformed value and the
/// error at the point is not ~0 (1.8 % of the target's size in CI: see
/// `locate_finds_the_minimum_when_the_log_transform_clamps_the_target`); the search then finds
/// a lower error elsewhere, and the bound is that error plus the search's precision.
fn check_locate_inverts_predict(
    case: &Case,
    pred: &Predictor,
    spec: &Spec,
) -> Result<(), TestCaseError> {
    let x = &latent_points(pred, spec.seed)[0];
    let values: Vec<f32> = smooth_values(pred, x).iter().map(|&v| v as f32).collect();
    let c = pred.coefficients(x, PredictorKind::Smooth).unwrap();
    let at_x = transformed_rmse(pred, &case.values, &c, &values);
    let clamped = spec.log && values.iter().any(|v| *v < 0.0);
    let target = target_of(values);
    let targets = std::slice::from_ref(&target);
    let loc = &predict::locate::locate(pred, targets, 3, &|_, _| {}).unwrap()[0];
    let (_, norms) = predict::locate::cross_products(pred, targets, &|_, _| {}).unwrap();
    let typical = (norms[0] / pred.grid().len() as f64).sqrt();
    prop_assert!(
        loc.model_rmse <= at_x + 5e-3 * typical && loc.model_rmse <= loc.nearest_model_rmse,
        "{loc:?} (error at the point {at_x:e}, typical {typical:e})"
    );
    if !clamped {
        // Every value represented: the point itself reconstructs the target to the rounding
        // of its values to f32, and the bound is the search's precision alone.
        prop_assert!(
            at_x <= 1e-6 * typical,
            "error at the point {at_x:e}, typical {typical:e}"
        );
    }
    Ok(())
}

proptest! {
    // Fixed cases. The locate check below failed in CI on one random dataset (spec seed
    // 14001124295530264192): not a search failure but a target the transform cannot represent
    // (see `locate_finds_the_minimum_when_the_log_transform_clamps_the_target`), which the
    // check now allows for. Random cases also found rare misses of the latent search itself
    // (a multi-start local search over a multimodal error): 3 in 10,000 before the side starts
    // (ridges: `locate_does_not_take_the_wrong_side_of_a_ridge`), then 8 in ~75,000 with
    // Hooke-Jeeves refining the starts (where latent points cluster, near-duplicate materials,
    // raw values, or between the starts in q = 2), 3 in ~97,000 with L-BFGS instead (session
    // 23), and 0 in 120,000 with L-BFGS and the quasi-random starts (and `starts` side
    // starts): `locate_finds_the_misses_of_earlier_searches` keeps the 11 missed cases. The
    // cases stay fixed all the same, so that CI runs the same test every time.
    #![proptest_config(ProptestConfig {
        cases: 24,
        max_shrink_iters: 32,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed_1959),
        ..ProptestConfig::default()
    })]

    /// Variance: non-negative, between mu and 2 mu at a training point (a new noisy
    /// observation there), the prior far away (finite at 1e6 length-scales), 0 for the exact
    /// predictor at a training point; locate inverts predict inside the hull.
    #[test]
    fn variance_and_locate_behave(spec in spec()) {
        let case = make_case(&spec);
        let pred = Predictor::open(&case.model).unwrap();
        let n = pred.n_materials();
        let h = &pred.model().hyperparameters;
        let mu = pred.gp().effective_noise();
        let prior = pred.prior_variance();
        prop_assert_eq!(prior, h.signal_variance + mu);
        let pts = points(&pred);
        for i in 0..n {
            let v = pred.variance(&pts[i]).unwrap();
            prop_assert!(v >= mu * (1.0 - 1e-9) && v <= 2.0 * mu * (1.0 + 1e-6) + 1e-12 * prior,
                "variance at training point {i}: {v:e} (mu {mu:e})");
            if !is_coinciding(&pred, i) {
                prop_assert_eq!(pred.variance_of(&pts[i], PredictorKind::Exact).unwrap(), 0.0);
            }
        }
        for x in latent_points(&pred, spec.seed) {
            for kind in kinds() {
                let v = pred.variance_of(&x, kind).unwrap();
                prop_assert!((0.0..=prior).contains(&v), "{v} (prior {prior})");
            }
        }
        for scale in [1e3, 1e6] {
            // Beyond every material along every axis.
            let far: Vec<f64> = (0..pred.latent_dim())
                .map(|j| pts.iter().map(|p| p[j]).fold(f64::MIN, f64::max) + scale * length_scale(&pred, j))
                .collect();
            for kind in kinds() {
                prop_assert_eq!(pred.variance_of(&far, kind).unwrap(), prior);
                // Far from every material the prediction is the data mean.
                let c = pred.coefficients(&far, kind).unwrap();
                prop_assert!(c.iter().all(|v| *v == 1.0 / n as f64), "{:?}", c);
            }
            let s = pred.support(&far).unwrap();
            prop_assert!(s.is_far() && s.distance.is_finite() && s.distance >= scale * 0.999, "{s:?} scale {scale} l {:?}", h.length_scale);
        }

        check_locate_inverts_predict(&case, &pred, &spec)?;
    }
}

/// The case that failed `variance_and_locate_behave` in CI (its spec's seed
/// 14001124295530264192: N = 5, q = 1, log, spectral): the smooth prediction at x = -0.13509
/// was located at -0.12369 with a transformed RMSE of 0.111 (1.8 % of the target's 6.2).
/// Not a search failure: 5 of the prediction's 300 valid values are negative (down to -6.4e-3
/// 1/sr, transformed -1.03), the log transform maps them to 0, and that alone makes the error
/// at x 0.1126 (`sqrt(sum y^2 / 128)` over those 5 cells; the rounding to f32 adds 3e-8). The
/// error's minimum over the latent line really is at -0.12369, 0.1109: a scan agrees with the
/// located point and error.
#[test]
fn locate_finds_the_minimum_when_the_log_transform_clamps_the_target() {
    let spec = Spec {
        seed: 14001124295530264192,
        n: 5,
        q: 1,
        log: true,
        rgb: false,
        duplicate: Duplicate::None,
    };
    let case = make_case(&spec);
    let pred = Predictor::open(&case.model).unwrap();
    let x = &latent_points(&pred, spec.seed)[0];
    let exact = smooth_values(&pred, x);
    let d = exact.len();
    let values: Vec<f32> = exact.iter().map(|&v| v as f32).collect();
    // The premise: the prediction has values the log transform cannot represent.
    let negative: Vec<usize> = (0..d).filter(|&di| exact[di] < 0.0).collect();
    assert!(
        !negative.is_empty(),
        "no negative value at {x:?}: not the CI case any more"
    );
    let n_angles = pred.grid().len() as f64;
    let t = pred.transform();
    let c = pred.coefficients(x, PredictorKind::Smooth).unwrap();
    let y = |di: usize| -> f64 {
        (0..c.len())
            .map(|i| c[i] * t.forward(f64::from(case.values[i][di])))
            .sum()
    };
    // The error at x is the clamped values' transformed values (the target is 0 there).
    let clamp_residual = (negative.iter().map(|&di| y(di).powi(2)).sum::<f64>() / n_angles).sqrt();
    let at_x = transformed_rmse(&pred, &case.values, &c, &values);
    assert!(
        close(at_x, clamp_residual, 1e-5, 0.0),
        "error at x {at_x:e}, clamp residual {clamp_residual:e}"
    );

    let target = target_of(values);
    let targets = std::slice::from_ref(&target);
    let loc = &predict::locate::locate(&pred, targets, 3, &|_, _| {}).unwrap()[0];
    let (cross, norms) = predict::locate::cross_products(&pred, targets, &|_, _| {}).unwrap();
    let typical = (norms[0] / n_angles).sqrt();
    // The search's objective along the latent line (the smooth predictor's Gram error).
    let objective = |xx: f64| {
        let c = pred.coefficients(&[xx], PredictorKind::Smooth).unwrap();
        (predict::locate::gram_sq_error(&pred, &cross, norms[0], &c) / n_angles).sqrt()
    };
    assert!(close(objective(x[0]), at_x, 1e-6, 1e-9 * typical));
    // A scan over every material's stretch and beyond, then a fine one around its minimum.
    let argmin = |lo: f64, hi: f64, k: usize| {
        (0..=k)
            .map(|i| lo + (hi - lo) * i as f64 / k as f64)
            .map(|xx| (objective(xx), xx))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap()
    };
    let (_, coarse) = argmin(-4.0, 4.0, 8000);
    let (e_min, x_min) = argmin(coarse - 2e-3, coarse + 2e-3, 4000);
    assert!(
        (loc.point[0] - x_min).abs() <= 1e-5,
        "located at {:?}, the scan's minimum at {x_min}",
        loc.point
    );
    assert!(
        close(loc.model_rmse, e_min, 1e-6, 0.0) && loc.model_rmse < at_x,
        "located error {:e}, the scan's minimum {e_min:e}, at x {at_x:e}",
        loc.model_rmse
    );
    // The search is not at fault: it is within the search's precision of the minimum (which
    // is well away from x and far from 0).
    assert!((x_min - x[0]).abs() > 1e-3 && e_min > 1e-2 * typical);
}

/// The random cases in which earlier latent searches missed the target's basin (session 23,
/// ~170,000 cases of `variance_and_locate_behave` over three searches: 8 missed by Hooke-Jeeves
/// refining the starts, 3 by L-BFGS refining them; one of them missed by both): located as
/// well as the point they were predicted at, as `variance_and_locate_behave` checks them.
#[test]
fn locate_finds_the_misses_of_earlier_searches() {
    let missed: [(u64, usize, usize, bool, bool, Duplicate); 11] = [
        (12872555450422222705, 4, 1, true, true, Duplicate::None),
        (10702303389566849176, 5, 2, false, true, Duplicate::Near),
        (4945475653316591113, 3, 1, false, false, Duplicate::None),
        (2420630373883128067, 4, 1, false, true, Duplicate::Near),
        (2018141832678557609, 5, 1, false, false, Duplicate::None),
        (2970846393982980690, 5, 1, false, true, Duplicate::Exact),
        (15649383327711538552, 4, 1, true, false, Duplicate::None),
        (3343143751182000112, 5, 1, false, true, Duplicate::Exact),
        (11972113025270855347, 5, 1, false, false, Duplicate::Near),
        (4658529915704848071, 5, 2, false, true, Duplicate::None),
        (13650506399361138009, 5, 2, false, false, Duplicate::None),
    ];
    for (seed, n, q, log, rgb, duplicate) in missed {
        let spec = Spec {
            seed,
            n,
            q,
            log,
            rgb,
            duplicate,
        };
        let case = make_case(&spec);
        let pred = Predictor::open(&case.model).unwrap();
        if let Err(e) = check_locate_inverts_predict(&case, &pred, &spec) {
            panic!("spec seed {seed}: {e}");
        }
    }
}

/// A material on a ridge of the error between two basins (found by 3,000 random cases of
/// `variance_and_locate_behave`, spec seed 10770280116901798891: N = 5, q = 1, log, RGB): the
/// prediction at x = -0.3807 lies in the basin on one side of the best-scoring material (at
/// 0.026, RMSE 0.141 there), and Hooke-Jeeves from it, and from the best midpoints, went to
/// the basin on the other side (0.3949, RMSE 0.0711: 0.8 % of the target's size) with 1, 3
/// and 5 starts. The starts half a length-scale off the training points find it.
#[test]
fn locate_does_not_take_the_wrong_side_of_a_ridge() {
    let spec = Spec {
        seed: 10770280116901798891,
        n: 5,
        q: 1,
        log: true,
        rgb: true,
        duplicate: Duplicate::None,
    };
    let case = make_case(&spec);
    let pred = Predictor::open(&case.model).unwrap();
    let x = &latent_points(&pred, spec.seed)[0];
    let values: Vec<f32> = smooth_values(&pred, x).iter().map(|&v| v as f32).collect();
    assert!(
        values.iter().all(|v| *v >= 0.0),
        "a clamped target: not the case any more"
    );
    let target = target_of(values);
    let targets = std::slice::from_ref(&target);
    let (_, norms) = predict::locate::cross_products(&pred, targets, &|_, _| {}).unwrap();
    let typical = (norms[0] / pred.grid().len() as f64).sqrt();
    for starts in [1, 3, 5] {
        let loc = &predict::locate::locate(&pred, targets, starts, &|_, _| {}).unwrap()[0];
        assert!(
            loc.model_rmse <= 1e-5 * typical && (loc.point[0] - x[0]).abs() <= 1e-3,
            "{starts} starts: {loc:?} (x {x:?}, typical {typical:e})"
        );
    }
}

/// Leave-one-out from the Gram matrix equals brute force on raw data: refitting on a store
/// without the held-out material (cold, as `warm_start: false` refits) gives the same latent
/// space, the GP's prediction at the reported point from that refit equals the reported
/// coefficients' combination of the stored rows, and every method's errors equal the errors
/// computed directly from the values.
#[test]
fn leave_one_out_equals_brute_force_refits_on_raw_data() {
    for seed in [3u64, 11] {
        let spec = Spec {
            seed,
            n: 4,
            q: 1,
            log: false,
            rgb: seed % 2 == 1,
            duplicate: Duplicate::None,
        };
        let case = make_case(&spec);
        let pred = Predictor::open(&case.model).unwrap();
        let options = predict::evaluate::EvalOptions {
            loo: true,
            starts: 3,
            warm_start: false,
            refit_iterations: None,
        };
        let ev = predict::evaluate::evaluate(&pred, &options, &|_, _, _| {}).unwrap();
        let (n, d) = (pred.n_materials(), pred.store().d());
        let n_angles = pred.grid().len() as f64;
        let channels = pred.channels().clone();
        let y = |i: usize, di: usize| f64::from(case.values[i][di]);
        for (h, row) in ev.loo.as_ref().unwrap().iter().enumerate() {
            // Errors of every method, directly from the values.
            for entry in &row.methods {
                assert!(
                    close(
                        entry.brdf_rmse,
                        entry.model_rmse,
                        1e-6,
                        1e-9 * entry.brdf_rmse.max(1.0)
                    ),
                    "{h} {:?}: {} vs {}",
                    entry.method,
                    entry.brdf_rmse,
                    entry.model_rmse
                );
            }
            let c = &row.gp_coefficients;
            assert_eq!(c[h], 0.0);
            let sq: f64 = (0..d)
                .map(|di| (y(h, di) - (0..n).map(|i| c[i] * y(i, di)).sum::<f64>()).powi(2))
                .sum();
            let gp = &row.methods[0];
            assert!(
                close(gp.brdf_rmse, (sq / n_angles).sqrt(), 1e-9, 1e-12),
                "{h}"
            );

            // Brute force: the store without h, fitted from scratch with the same settings.
            let others: Vec<usize> = (0..n).filter(|&i| i != h).collect();
            let values: Vec<Vec<f32>> = others.iter().map(|&i| case.values[i].clone()).collect();
            let dir = case.dir.path().join(format!("without{h}"));
            std::fs::create_dir(&dir).unwrap();
            let store = dir.join("data.sbrdf");
            write_values(&store, &channels, &values);
            let config = pred.model().fit_config(&case.model).unwrap();
            let model = gplvm::fit_store(&store, &config).unwrap();
            let model_path = dir.join("model.toml");
            model.save(&model_path).unwrap();
            let refit = Predictor::open(&model_path).unwrap();
            let m = refit.predict(&row.gp_point, PredictorKind::Smooth).unwrap();
            for di in 0..d {
                let via_c: f64 = (0..n).map(|i| c[i] * y(i, di)).sum();
                let brute = m.value_at(di).unwrap();
                assert!(
                    close(brute, via_c, 1e-6, 1e-9),
                    "held out {h}, index {di}: refit {brute} vs leave-one-out {via_c}"
                );
            }
        }
    }
}

/// Evaluation (with leave-one-out), locate and materialised files are bit-identical in rayon
/// pools of 1, 2 and 3 threads.
#[test]
fn results_do_not_depend_on_the_thread_count() {
    let spec = Spec {
        seed: 5,
        n: 5,
        q: 2,
        log: true,
        rgb: false,
        duplicate: Duplicate::Near,
    };
    let case = make_case(&spec);
    let pred = Predictor::open(&case.model).unwrap();
    let x = latent_points(&pred, spec.seed)[1].clone();
    let target_values: Vec<f32> = smooth_values(&pred, &x)
        .iter()
        .map(|&v| 1.1 * v as f32)
        .collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let options = predict::evaluate::EvalOptions {
                loo: true,
                refit_iterations: Some(30),
                ..Default::default()
            };
            let mut ev = predict::evaluate::evaluate(&pred, &options, &|_, _, _| {}).unwrap();
            (ev.loo_seconds, ev.pass_seconds) = (0.0, 0.0);
            let target = predict::locate::Target {
                name: "t".into(),
                source: "test".into(),
                values: target_values.clone(),
            };
            let loc = predict::locate::locate(&pred, &[target], 3, &|_, _| {}).unwrap();
            let out = case.dir.path().join(format!("p{threads}.npy"));
            pred.predict(&x, PredictorKind::Exact)
                .unwrap()
                .materialize(&out, |_, _| {})
                .unwrap();
            (
                format!("{ev:?}"),
                format!("{:?} {:?}", loc, loc[0].coefficients),
                std::fs::read(&out).unwrap(),
            )
        })
    };
    let one = run(1);
    for threads in [2, 3] {
        let other = run(threads);
        assert_eq!(one.0, other.0, "evaluation, {threads} threads");
        assert_eq!(one.1, other.1, "locate, {threads} threads");
        assert!(one.2 == other.2, "materialised file, {threads} threads");
    }
}

/// A materialisation that fails part-way (a blend that overflows) leaves an existing output
/// file as it was, in every format, and leaves no temporary file beside it.
#[test]
fn a_failed_materialisation_leaves_the_existing_file_untouched() {
    let spec = Spec {
        seed: 9,
        n: 3,
        q: 1,
        log: true,
        rgb: true,
        duplicate: Duplicate::None,
    };
    let case = make_case(&spec);
    let pred = Predictor::open(&case.model).unwrap();
    let good = pred.predict(&[0.0], PredictorKind::Smooth).unwrap();
    let bad = pred.lerp("m0", "m1", 1e6).unwrap();
    let out = case.dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    for name in ["p.npy", "p.sbrdf", "p.binary"] {
        let path = out.join(name);
        good.materialize(&path, |_, _| {}).unwrap();
        let before = std::fs::read(&path).unwrap();
        let e = bad.materialize(&path, |_, _| {}).unwrap_err().to_string();
        assert!(e.contains("overflowed"), "{name}: {e}");
        assert!(std::fs::read(&path).unwrap() == before, "{name} changed");
        let files: Vec<_> = std::fs::read_dir(&out).unwrap().collect();
        assert_eq!(files.len(), 1, "{name}: {files:?}");
        std::fs::remove_file(&path).unwrap();
    }
}

/// Inputs that panicked or passed silently are errors naming the model: a model built or
/// edited in memory with a material's coordinates too few (an index panic in the latent
/// matrix) or too many (silently cut to q), a Gram matrix of the wrong size (wrong errors
/// without a word) or a length-scale per axis too many; NaN or infinite latent points (the
/// message named no model); non-finite half/difference angles (NaN values returned as a
/// lookup, or a finite value for a NaN theta_h); latent search points of the wrong dimension
/// ("the objective is not finite at the starting point").
#[test]
fn bad_models_points_and_angles_are_errors_naming_the_model() {
    use std::sync::Arc;
    let spec = Spec {
        seed: 2,
        n: 4,
        q: 2,
        log: true,
        rgb: false,
        duplicate: Duplicate::None,
    };
    let case = make_case(&spec);
    let pred = Predictor::open(&case.model).unwrap();
    let store = pred.store().clone();
    let model_name = case.model.display().to_string();
    type Edit = (&'static str, fn(&mut gplvm::Model), &'static str);
    let edits: [Edit; 6] = [
        (
            "short coords",
            |m| {
                m.materials[1].coords.pop();
            },
            "material \"m1\" has 1 latent coordinates; the model's latent_dim is 2",
        ),
        (
            "long coords",
            |m| m.materials[2].coords.push(0.5),
            "material \"m2\" has 3 latent coordinates",
        ),
        (
            "gram rows",
            |m| {
                m.gram.pop();
            },
            "the Gram matrix is not 4 x 4",
        ),
        (
            "gram columns",
            |m| {
                m.gram[3].pop();
            },
            "the Gram matrix is not 4 x 4",
        ),
        (
            "latent_dim 0",
            |m| m.latent_dim = 0,
            "latent_dim = 0: must be in 1..=64",
        ),
        (
            "3 length-scales",
            |m| m.hyperparameters.length_scale = vec![1.0; 3],
            "3 length-scales for latent_dim 2",
        ),
    ];
    for (what, edit, want) in edits {
        let mut model = pred.model().clone();
        edit(&mut model);
        let e = Predictor::with_store(model, &case.model, Arc::clone(&store))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(&format!("{model_name}: ")) && e.contains(want),
            "{what}: {e}"
        );
    }
    let mut model = pred.model().clone();
    model.gram[1][2] = f64::NAN;
    let e = Predictor::with_store(model, &case.model, Arc::clone(&store))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&model_name) && e.contains("NaN or infinite"),
        "{e}"
    );

    for x in [
        [f64::NAN, 0.0],
        [0.0, f64::INFINITY],
        [f64::NEG_INFINITY, 1.0],
    ] {
        let calls: [(&str, predict::Result<()>); 5] = [
            (
                "predict",
                pred.predict(&x, PredictorKind::Smooth).map(|_| ()),
            ),
            (
                "weights",
                pred.gp_weights(&x, PredictorKind::Exact).map(|_| ()),
            ),
            ("variance", pred.variance(&x).map(|_| ())),
            (
                "variance_of",
                pred.variance_of(&x, PredictorKind::Exact).map(|_| ()),
            ),
            ("support", pred.support(&x).map(|_| ())),
        ];
        for (what, r) in calls {
            let e = r.unwrap_err().to_string();
            assert!(
                e.contains(&model_name) && e.contains("finite coordinates"),
                "{what}: {e}"
            );
        }
    }

    let m = pred.predict(&[0.1, 0.2], PredictorKind::Exact).unwrap();
    let mut out = vec![0.0; pred.channels().len()];
    for hd in [
        brdf_io::HalfDiff {
            theta_h: f64::NAN,
            theta_d: 0.3,
            phi_d: 0.2,
        },
        brdf_io::HalfDiff {
            theta_h: 0.2,
            theta_d: 0.3,
            phi_d: f64::INFINITY,
        },
    ] {
        let e = m.eval_half_diff(&hd, &mut out).unwrap_err().to_string();
        assert!(
            e.contains("must be finite") && e.contains("gp-exact@0.1,0.2"),
            "{e}"
        );
    }
    m.eval_half_diff(
        &brdf_io::HalfDiff {
            theta_h: 0.2,
            theta_d: 0.3,
            phi_d: 0.4,
        },
        &mut out,
    )
    .unwrap();
    assert!(out.iter().all(|v| v.is_finite() && *v > 0.0), "{out:?}");

    let g = pred.model().gram_matrix();
    let flat = vec![vec![0.0]; 4];
    let e = predict::evaluate::best_latent_point(pred.gp(), &flat, g.as_ref(), &[0.0; 4], 1.0, 2)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("point 0 has 1 coordinates; the GP's latent space has 2"),
        "{e}"
    );
}
