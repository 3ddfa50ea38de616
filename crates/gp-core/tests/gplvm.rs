//! Integration tests for gp-core: gradients against finite differences, invariances, the
//! Gram-vs-dense likelihood, predictors against dense formulas, and numerical stress.

use faer::linalg::solvers::DenseSolveCore;
use gp_core::{
    CholeskyFactor, FlatGplvm, GpError, GpRegression, GplvmObjective, KernelParams, Learn,
    LengthScale, Mat, MatRef, Par, Predictor, centre_gram, column_mean, gram_from_data,
    log_likelihood_from_data, posterior_mean,
};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn rand_mat(rng: &mut ChaCha8Rng, n: usize, m: usize, lo: f64, hi: f64) -> Mat<f64> {
    Mat::from_fn(n, m, |_, _| rng.random_range(lo..hi))
}

/// Column-centred copy of `y`.
fn centre_rows(y: MatRef<'_, f64>) -> Mat<f64> {
    let m = column_mean(y);
    Mat::from_fn(y.nrows(), y.ncols(), |i, j| y[(i, j)] - m[j])
}

fn objective_from_data(y: MatRef<'_, f64>) -> GplvmObjective {
    let g = gram_from_data(y, Par::Seq).unwrap();
    GplvmObjective::from_uncentred_gram(g.as_ref(), y.ncols()).unwrap()
}

fn params(rng: &mut ChaCha8Rng, q: usize, ard: bool, log_mu: f64) -> KernelParams {
    let s2 = rng.random_range(-1.0f64..1.0).exp();
    let ls = if ard {
        LengthScale::Ard(
            (0..q)
                .map(|_| rng.random_range(-0.7f64..1.0).exp())
                .collect(),
        )
    } else {
        LengthScale::Isotropic(rng.random_range(-0.7f64..1.0).exp())
    };
    KernelParams::new(s2, ls, log_mu.exp()).unwrap()
}

/// Central difference of `f` at `theta` along coordinate `k`.
fn central_diff(f: &dyn Fn(&[f64]) -> f64, theta: &[f64], k: usize) -> f64 {
    let h = 1e-5 * theta[k].abs().max(1.0);
    let mut tp = theta.to_vec();
    let mut tm = theta.to_vec();
    tp[k] += h;
    tm[k] -= h;
    (f(&tp) - f(&tm)) / (2.0 * h)
}

fn assert_close(fd: f64, an: f64, fscale: f64, what: &str) {
    let tol = 1e-6 * (1.0 + fscale) + 1e-5 * an.abs();
    assert!(
        (fd - an).abs() <= tol,
        "{what}: finite difference {fd} vs analytic {an} (tol {tol})"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// dL/dX, dL/dlog(theta) and dL/dtheta against central differences; iso/ARD, prior on/off.
    #[test]
    fn gradients_match_finite_differences(
        seed in any::<u64>(),
        n in 2usize..7,
        q in 1usize..4,
        d in 1usize..8,
        ard in any::<bool>(),
        prior in any::<bool>(),
        log_mu in -4.0f64..0.0,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let y = rand_mat(&mut rng, n, d, -2.0, 2.0);
        let x = rand_mat(&mut rng, n, q, -1.5, 1.5);
        let p = params(&mut rng, q, ard, log_mu);
        let obj = objective_from_data(y.as_ref()).with_prior(prior);
        let e = obj.evaluate(x.as_ref(), &p, Par::Seq).unwrap();
        // Value from evaluate equals the value-only path.
        let (v, info) = obj.log_likelihood(x.as_ref(), &p, Par::Seq).unwrap();
        prop_assert!((v - e.value).abs() <= 1e-10 * (1.0 + v.abs()));
        prop_assert_eq!(info.jitter, 0.0);

        // Flat vector with every hyperparameter learnt: X row-major, then log hypers.
        let flat = obj.flat(q, p.clone(), Learn::ALL).unwrap();
        let theta = flat.pack(x.as_ref(), &p).unwrap();
        prop_assert_eq!(theta.len(), n * q + p.n_hyper());
        let f = |t: &[f64]| -flat.neg_log_likelihood(t, Par::Seq).unwrap();
        let fscale = e.value.abs();
        for i in 0..n {
            for j in 0..q {
                let fd = central_diff(&f, &theta, i * q + j);
                assert_close(fd, e.grad_x[(i, j)], fscale, "dL/dX");
            }
        }
        let glog = e.grad_hyper_log.to_vec();
        for (k, g) in glog.iter().enumerate() {
            let fd = central_diff(&f, &theta, n * q + k);
            assert_close(fd, *g, fscale, "dL/dlog theta");
        }
        // Raw-parameter gradients: chain rule dL/dtheta = dL/dlog theta / theta, checked by FD
        // in raw coordinates.
        let raw_theta: Vec<f64> = p.to_log_vec().iter().map(|v| v.exp()).collect();
        let fr = |t: &[f64]| {
            let lt: Vec<f64> = t.iter().map(|v| v.ln()).collect();
            let pp = KernelParams::from_log_slice(&lt).unwrap();
            let pp = match (p.length_scale(), pp.length_scale()) {
                (LengthScale::Ard(_), LengthScale::Isotropic(l)) => {
                    KernelParams::new(pp.signal_variance(), LengthScale::Ard(vec![*l]), pp.noise()).unwrap()
                }
                _ => pp,
            };
            obj.log_likelihood(x.as_ref(), &pp, Par::Seq).unwrap().0
        };
        let graw = e.grad_hyper.to_vec();
        for (k, g) in graw.iter().enumerate() {
            let h = 1e-6 * raw_theta[k];
            let mut tp = raw_theta.clone();
            let mut tm = raw_theta.clone();
            tp[k] += h;
            tm[k] -= h;
            let fd = (fr(&tp) - fr(&tm)) / (2.0 * h);
            assert_close(fd * raw_theta[k], g * raw_theta[k], fscale, "dL/dtheta (raw)");
        }
        // Flat gradient is the negated analytic gradient, and unpack inverts pack.
        let (nv, ng) = flat.neg_log_likelihood_and_gradient(&theta, Par::Seq).unwrap();
        prop_assert!((nv + e.value).abs() <= 1e-10 * (1.0 + nv.abs()));
        prop_assert_eq!(ng[0], -e.grad_x[(0, 0)]);
        prop_assert_eq!(ng[n * q], -glog[0]);
        let (x2, p2) = flat.unpack(&theta).unwrap();
        prop_assert_eq!(x2, x.clone());
        prop_assert!((p2.signal_variance() - p.signal_variance()).abs() <= 1e-14 * p.signal_variance());
    }

    /// K is exactly symmetric and its eigenvalues are >= mu (up to rounding).
    #[test]
    fn kernel_matrix_is_spd(
        seed in any::<u64>(),
        n in 1usize..25,
        q in 1usize..4,
        ard in any::<bool>(),
        log_mu in -8.0f64..1.0,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x = rand_mat(&mut rng, n, q, -2.0, 2.0);
        let p = params(&mut rng, q, ard, log_mu);
        let k = p.kernel_matrix(x.as_ref()).unwrap();
        for j in 0..n {
            prop_assert_eq!(k[(j, j)], p.signal_variance() + p.noise());
            for i in 0..n {
                prop_assert_eq!(k[(i, j)], k[(j, i)]);
                prop_assert!(k[(i, j)] > 0.0);
            }
        }
        let ev = k.self_adjoint_eigenvalues(faer::Side::Lower).unwrap();
        let tol = 10.0 * n as f64 * f64::EPSILON * (p.signal_variance() * n as f64 + p.noise());
        prop_assert!(ev[0] >= p.noise() - tol, "min eigenvalue {} < mu {}", ev[0], p.noise());
        let f = CholeskyFactor::new(k.as_ref(), Par::Seq).unwrap();
        prop_assert_eq!(f.jitter(), 0.0);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// The exact predictor reproduces every training output to 1e-10 relative (to the largest
    /// |y| of the column), for mu down to 1e-4 (condition numbers up to ~1e6).
    #[test]
    fn exact_predictor_reproduces_training_outputs(
        seed in any::<u64>(),
        n in 2usize..30,
        q in 1usize..4,
        ard in any::<bool>(),
        log_mu in -9.2f64..0.0,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x = rand_mat(&mut rng, n, q, -2.0, 2.0);
        let y = rand_mat(&mut rng, n, 4, -1e3, 1e3);
        let p = params(&mut rng, q, ard, log_mu);
        let gp = GpRegression::new(x.as_ref(), p, Par::Seq).unwrap();
        let cond = gp.factor().condition_estimate();
        let tol = 1e-10;
        let mean = column_mean(y.as_ref());
        let xs = Mat::from_fn(n, q, |i, j| x[(i, j)]);
        let w = gp.weights_batch(xs.as_ref(), Predictor::Exact, Par::Seq).unwrap();
        for i in 0..n {
            let wi: Vec<f64> = (0..n).map(|k| w[(k, i)]).collect();
            let yp = posterior_mean(&wi, y.as_ref(), &mean).unwrap();
            for j in 0..4 {
                let scale = (0..n).map(|k| y[(k, j)].abs()).fold(0.0, f64::max);
                prop_assert!(
                    (yp[j] - y[(i, j)]).abs() <= tol * scale,
                    "point {} dim {}: {} vs {} (cond {:e})", i, j, yp[j], y[(i, j)], cond
                );
            }
        }
    }
}

/// Random rotation in R^q (QR-free: product of Givens rotations).
fn rotation(rng: &mut ChaCha8Rng, q: usize) -> Mat<f64> {
    let mut r = Mat::<f64>::identity(q, q);
    for a in 0..q {
        for b in (a + 1)..q {
            let t: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let g = Mat::from_fn(q, q, |i, j| match (i, j) {
                _ if i == a && j == a || i == b && j == b => t.cos(),
                _ if i == a && j == b => -t.sin(),
                _ if i == b && j == a => t.sin(),
                _ if i == j => 1.0,
                _ => 0.0,
            });
            r = &r * &g;
        }
    }
    r
}

#[test]
fn likelihood_translation_and_rotation_invariance() {
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for q in [2usize, 3] {
        let (n, d) = (12, 9);
        let y = rand_mat(&mut rng, n, d, -1.0, 1.0);
        let x = rand_mat(&mut rng, n, q, -1.0, 1.0);
        let p = KernelParams::isotropic(1.3, 0.8, 1e-3).unwrap();
        let t: Vec<f64> = (0..q).map(|_| rng.random_range(-3.0..3.0)).collect();
        let r = rotation(&mut rng, q);
        let xt = Mat::from_fn(n, q, |i, j| x[(i, j)] + t[j]);
        let xr = &x * r.transpose();
        let sq = |m: &Mat<f64>| -> f64 {
            (0..n)
                .map(|i| (0..q).map(|j| m[(i, j)] * m[(i, j)]).sum::<f64>())
                .sum()
        };
        for prior in [false, true] {
            let obj = objective_from_data(y.as_ref()).with_prior(prior);
            let v0 = obj.log_likelihood(x.as_ref(), &p, Par::Seq).unwrap().0;
            let vt = obj.log_likelihood(xt.as_ref(), &p, Par::Seq).unwrap().0;
            let vr = obj.log_likelihood(xr.as_ref(), &p, Par::Seq).unwrap().0;
            let tol = 1e-11 * v0.abs();
            // Rotations preserve |x| so the value is invariant with or without the prior.
            assert!((vr - v0).abs() <= tol, "rotation: {vr} vs {v0}");
            if prior {
                // Translation changes exactly the prior term -1/2 sum |x_n|^2.
                let expected = -0.5 * (sq(&xt) - sq(&x));
                assert!(expected.abs() > 1.0);
                assert!(
                    ((vt - v0) - expected).abs() <= tol,
                    "{} vs {expected}",
                    vt - v0
                );
            } else {
                assert!((vt - v0).abs() <= tol, "translation: {vt} vs {v0}");
            }
        }
    }
}

#[test]
fn gram_likelihood_equals_dense_likelihood() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for (n, d, q, ard) in [(5, 3, 1, false), (10, 40, 2, true), (30, 7, 3, false)] {
        let y = rand_mat(&mut rng, n, d, -5.0, 20.0);
        let x = rand_mat(&mut rng, n, q, -2.0, 2.0);
        let p = params(&mut rng, q, ard, -3.0);
        let yc = centre_rows(y.as_ref());
        for prior in [false, true] {
            let obj = objective_from_data(y.as_ref()).with_prior(prior);
            let vg = obj.log_likelihood(x.as_ref(), &p, Par::Seq).unwrap().0;
            let ve = obj.evaluate(x.as_ref(), &p, Par::rayon(2)).unwrap().value;
            let vd =
                log_likelihood_from_data(yc.as_ref(), x.as_ref(), &p, prior, Par::Seq).unwrap();
            assert!((vg - vd).abs() <= 1e-10 * vd.abs(), "{vg} vs {vd}");
            assert!((ve - vd).abs() <= 1e-10 * vd.abs(), "{ve} vs {vd}");
        }
        // Centred Gram from G equals the Gram of centred data (S = C G C).
        let s = centre_gram(gram_from_data(y.as_ref(), Par::Seq).unwrap().as_ref()).unwrap();
        let s2 = gram_from_data(yc.as_ref(), Par::Seq).unwrap();
        let scale = (0..n).map(|i| s2[(i, i)]).fold(0.0, f64::max);
        for j in 0..n {
            for i in 0..n {
                assert!((s[(i, j)] - s2[(i, j)]).abs() <= 1e-12 * scale);
            }
        }
    }
}

#[test]
fn predictors_against_dense_formulas() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (n, d, q, m) = (20, 6, 2, 300);
    let x = rand_mat(&mut rng, n, q, -2.0, 2.0);
    let y = rand_mat(&mut rng, n, d, -1.0, 3.0);
    let p = KernelParams::isotropic(1.0, 1.0, 1e-4).unwrap();
    let gp = GpRegression::new(x.as_ref(), p.clone(), Par::Seq).unwrap();
    assert_eq!(gp.factor().jitter(), 0.0);
    let mean = column_mean(y.as_ref());
    // Exact predictor reproduces training outputs; the smooth one does not.
    for i in 0..n {
        let xi: Vec<f64> = (0..q).map(|j| x[(i, j)]).collect();
        let w = gp.weights(&xi, Predictor::Exact).unwrap();
        for (k, wk) in w.iter().enumerate() {
            let e = if k == i { 1.0 } else { 0.0 };
            assert!((wk - e).abs() <= 1e-10, "w[{k}] = {wk}");
        }
        let yp = posterior_mean(&w, y.as_ref(), &mean).unwrap();
        for j in 0..d {
            assert!((yp[j] - y[(i, j)]).abs() <= 1e-10 * y[(i, j)].abs().max(1.0));
        }
        let ws = gp.weights(&xi, Predictor::Smooth).unwrap();
        assert!((ws[i] - 1.0).abs() > 1e-6);
        assert!(gp.variance(&xi).unwrap() < 1e-3);
    }
    // Dense reference: explicit inverse through LU (independent of the Cholesky path).
    let k = p.kernel_matrix(x.as_ref()).unwrap();
    let kinv = k.partial_piv_lu().inverse();
    let xs = rand_mat(&mut rng, m, q, -3.0, 3.0);
    // Include two training points among the test points.
    let xs = Mat::from_fn(m, q, |r, j| if r < 2 { x[(5 * r, j)] } else { xs[(r, j)] });
    for predictor in [Predictor::Exact, Predictor::Smooth] {
        let wb = gp
            .weights_batch(xs.as_ref(), predictor, Par::rayon(2))
            .unwrap();
        let wseq = gp.weights_batch(xs.as_ref(), predictor, Par::Seq).unwrap();
        let var = gp.variance_batch(xs.as_ref(), Par::rayon(2)).unwrap();
        for r in 0..m {
            let xr: Vec<f64> = (0..q).map(|j| xs[(r, j)]).collect();
            let mut ks: Vec<f64> = (0..n)
                .map(|i| {
                    let d2: f64 = (0..q).map(|j| (x[(i, j)] - xr[j]).powi(2)).sum();
                    (-0.5 * d2).exp()
                })
                .collect();
            if predictor == Predictor::Exact && r < 2 {
                ks[5 * r] += 1e-4;
            }
            let wd: Vec<f64> = (0..n)
                .map(|i| (0..n).map(|k2| kinv[(i, k2)] * ks[k2]).sum())
                .collect();
            let w1 = gp.weights(&xr, predictor).unwrap();
            for i in 0..n {
                assert!((wb[(i, r)] - wd[i]).abs() <= 1e-8 * (1.0 + wd[i].abs()));
                assert_eq!(wb[(i, r)], wseq[(i, r)]);
                assert!((w1[i] - wb[(i, r)]).abs() <= 1e-12 * (1.0 + w1[i].abs()));
            }
            // Smooth-k* variance against the dense formula.
            let ksm: Vec<f64> = (0..n)
                .map(|i| {
                    let d2: f64 = (0..q).map(|j| (x[(i, j)] - xr[j]).powi(2)).sum();
                    (-0.5 * d2).exp()
                })
                .collect();
            let quad: f64 = (0..n)
                .map(|i| {
                    (0..n)
                        .map(|k2| ksm[i] * kinv[(i, k2)] * ksm[k2])
                        .sum::<f64>()
                })
                .sum();
            let vd = (1.0 + 1e-4 - quad).max(0.0);
            assert!((var[r] - vd).abs() <= 1e-8, "var {} vs {vd}", var[r]);
            // The single-point path agrees with the batch (it had no check of its own).
            let v1 = gp.variance(&xr).unwrap();
            assert!(
                (v1 - var[r]).abs() <= 1e-12,
                "variance {v1} vs batch {}",
                var[r]
            );
            // Mean against the dense formula m + Y_c^T K^-1 k*.
            let yp = posterior_mean(&w1, y.as_ref(), &mean).unwrap();
            for j in 0..d {
                let md: f64 = mean[j] + (0..n).map(|i| wd[i] * (y[(i, j)] - mean[j])).sum::<f64>();
                assert!((yp[j] - md).abs() <= 1e-8 * (1.0 + md.abs()));
            }
        }
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let p = KernelParams::paper();
    let mut x = Mat::from_fn(4, 2, |i, j| (i * 2 + j) as f64);
    x[(2, 1)] = f64::NAN;
    let s = Mat::<f64>::identity(4, 4);
    let obj = GplvmObjective::new(s.clone(), 10).unwrap();
    assert!(matches!(
        obj.evaluate(x.as_ref(), &p, Par::Seq),
        Err(GpError::NonFinite { row: 2, col: 1, .. })
    ));
    assert!(GpRegression::new(x.as_ref(), p.clone(), Par::Seq).is_err());
    let mut bad_s = s.clone();
    bad_s[(1, 1)] = f64::INFINITY;
    assert!(matches!(
        GplvmObjective::new(bad_s, 10),
        Err(GpError::NonFinite { .. })
    ));
    assert!(GplvmObjective::new(s.clone(), 0).is_err());
    // Not a Gram matrix: a negative diagonal, or an off-diagonal entry larger than the
    // geometric mean of its diagonal entries (|cos| > 1 between two materials).
    assert!(matches!(
        GplvmObjective::new(-s.clone(), 10),
        Err(GpError::NotPositiveSemidefinite { row: 0, col: 0, .. })
    ));
    let mut too_close = s.clone();
    too_close[(3, 1)] = 1.01;
    too_close[(1, 3)] = 1.01;
    let err = GplvmObjective::new(too_close, 10).unwrap_err();
    assert!(
        matches!(err, GpError::NotPositiveSemidefinite { row: 3, col: 1, .. }),
        "{err}"
    );
    // A rank-one Gram matrix (two opposite materials) sits exactly on the boundary: accepted.
    GplvmObjective::new(
        Mat::from_fn(2, 2, |i, j| if i == j { 4.0 } else { -4.0 }),
        3,
    )
    .unwrap();
    // Latent points at +-1e308: the kernel is exactly diagonal, dL/dX finite, but the
    // length-scale gradient's (x_n - x_m)^2 overflows (it came back as NaN inside Ok).
    let two = GplvmObjective::new(
        Mat::from_fn(2, 2, |i, j| if i == j { 1.0 } else { -1.0 }),
        1,
    )
    .unwrap();
    let far = Mat::from_fn(2, 1, |i, _| if i == 0 { 1e308 } else { -1e308 });
    assert!(matches!(
        two.evaluate(far.as_ref(), &p, Par::Seq),
        Err(GpError::NonFiniteResult { .. })
    ));
    let x3 = Mat::<f64>::zeros(3, 2);
    assert!(matches!(
        obj.log_likelihood(x3.as_ref(), &p, Par::Seq),
        Err(GpError::DimensionMismatch { .. })
    ));
    for (s2, l, mu) in [(0.0, 1.0, 1e-4), (1.0, -1.0, 1e-4), (1.0, 1.0, f64::NAN)] {
        assert!(matches!(
            KernelParams::isotropic(s2, l, mu),
            Err(GpError::InvalidHyperparameter { .. })
        ));
    }
    assert!(KernelParams::new(1.0, LengthScale::Ard(vec![]), 1.0).is_err());
    let ard = KernelParams::new(1.0, LengthScale::Ard(vec![1.0, 2.0, 3.0]), 1.0).unwrap();
    let x_ok = Mat::from_fn(4, 2, |i, j| (i * 2 + j) as f64);
    assert!(ard.kernel_matrix(x_ok.as_ref()).is_err());
    // Flat: overflowing log-hyperparameters are errors, not panics.
    let flat: FlatGplvm<'_> = obj.flat(2, p.clone(), Learn::ALL).unwrap();
    let mut theta = flat.pack(x_ok.as_ref(), &p).unwrap();
    let last = theta.len() - 1;
    theta[last] = 1e6;
    assert!(flat.neg_log_likelihood(&theta, Par::Seq).is_err());
    theta[last] = -1e6;
    assert!(flat.neg_log_likelihood(&theta, Par::Seq).is_err());
    assert!(flat.unpack(&theta[..3]).is_err());
    // Its size: 4 points x 2 axes, then log s^2, log l, log mu; never empty.
    assert_eq!(
        (flat.len(), flat.n_hyper(), flat.is_empty()),
        (11, 3, false)
    );
    // Latent points of the wrong shape, either way, are refused with both sizes.
    for (rows, cols) in [(4, 3), (5, 2), (4, 1)] {
        let wrong = Mat::<f64>::zeros(rows, cols);
        assert_eq!(
            flat.pack(wrong.as_ref(), &p),
            Err(GpError::DimensionMismatch {
                what: "latent points X shape (rows * q) vs flat layout",
                expected: 8,
                got: rows * cols
            }),
            "{rows} x {cols}"
        );
    }
    // The objective's sizes and prior as built.
    assert_eq!((obj.n(), obj.d(), obj.has_prior()), (4, 10, false));
    let with_prior = GplvmObjective::new(s.clone(), 7).unwrap().with_prior(true);
    assert_eq!((with_prior.d(), with_prior.has_prior()), (7, true));
    // Data without rows or without columns.
    for (rows, cols) in [(0, 3), (3, 0)] {
        let empty = Mat::<f64>::zeros(rows, cols);
        assert_eq!(
            log_likelihood_from_data(empty.as_ref(), x_ok.as_ref(), &p, false, Par::Seq),
            Err(GpError::Empty { what: "data Y" }),
            "{rows} x {cols}"
        );
    }
    let gp = GpRegression::new(x_ok.as_ref(), p, Par::Seq).unwrap();
    assert!(gp.weights(&[0.0, f64::NAN], Predictor::Exact).is_err());
    assert!(gp.weights(&[0.0], Predictor::Exact).is_err());
}

#[test]
fn stress_duplicates_tiny_noise_and_dynamic_range() {
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let (n, q, d) = (40, 2, 5);
    // Y spanning 1e-6 .. 1e6 (log-uniform magnitudes, random signs).
    let y = Mat::from_fn(n, d, |_, _| {
        let m = 10f64.powf(rng.random_range(-6.0..6.0));
        if rng.random_bool(0.5) { m } else { -m }
    });
    let obj = objective_from_data(y.as_ref()).with_prior(true);
    // Half the latent points duplicated exactly.
    let base = rand_mat(&mut rng, n / 2, q, -1.0, 1.0);
    let x = Mat::from_fn(n, q, |i, j| base[(i % (n / 2), j)]);

    // s^2 = 1, mu = 1e-10: K is singular up to mu but its Cholesky succeeds without jitter;
    // the condition estimate exposes the problem.
    let p = KernelParams::isotropic(1.0, 1.0, 1e-10).unwrap();
    let e = obj.evaluate(x.as_ref(), &p, Par::Seq).unwrap();
    assert!(e.value.is_finite());
    assert!(e.grad_x.as_ref().norm_l2().is_finite());
    assert_eq!(e.factor.jitter, 0.0);
    assert!(
        e.factor.condition_estimate > 1e9,
        "{}",
        e.factor.condition_estimate
    );

    // Exact predictor at a duplicated training point: finite, and the two copies share the
    // prediction (their weights sum to ~1).
    let gp = GpRegression::new(x.as_ref(), p.clone(), Par::Seq).unwrap();
    let x0 = [x[(0, 0)], x[(0, 1)]];
    let w = gp.weights(&x0, Predictor::Exact).unwrap();
    assert!(w.iter().all(|v| v.is_finite()));
    assert!(
        (w[0] + w[n / 2] - 1.0).abs() < 1e-3,
        "{} {}",
        w[0],
        w[n / 2]
    );

    // Numerically rank-deficient K: s^2 = 1e8, l = 100 over latent points in [-1, 1], so K_rbf has
    // ~36 eigenvalues far below rounding (1e-8) while mu = 1e-10: jitter is needed and reported.
    let xs = rand_mat(&mut rng, n, q, -1.0, 1.0);
    let p = KernelParams::isotropic(1e8, 100.0, 1e-10).unwrap();
    let e = obj.evaluate(xs.as_ref(), &p, Par::Seq).unwrap();
    assert!(e.value.is_finite());
    assert!(e.grad_x.as_ref().norm_l2().is_finite());
    assert!(
        e.factor.jitter > 0.0 && e.factor.attempts >= 2,
        "{:?}",
        e.factor
    );
    assert!(e.factor.jitter <= 1e-2 * (1e8 + 1e-10));
    let x = xs;
    let gp = GpRegression::new(x.as_ref(), p.clone(), Par::Seq).unwrap();
    assert_eq!(gp.factor().jitter(), e.factor.jitter);
    let w = gp.weights(&[0.1, 0.2], Predictor::Smooth).unwrap();
    assert!(w.iter().all(|v| v.is_finite()));
    // The jitter is noise of the factored model: far from the data (k_s ~ 0) the variance is
    // its prior s^2 + mu + j, in both the single-point and the batch path.
    let far = [1e4, -1e4];
    let prior = 1e8 + 1e-10 + e.factor.jitter;
    let v = gp.variance(&far).unwrap();
    assert!((v - prior).abs() <= 1e-15 * prior, "{v} vs {prior}");
    let vb = gp
        .variance_batch(faer::Mat::from_fn(1, 2, |_, j| far[j]).as_ref(), Par::Seq)
        .unwrap();
    assert_eq!(vb[0], v);

    // No jitter allowed and a numerically singular K: a clear error, not a panic.
    let strict = objective_from_data(y.as_ref()).with_jitter_policy(gp_core::JitterPolicy::none());
    match strict.log_likelihood(x.as_ref(), &p, Par::Seq) {
        Err(GpError::NotPositiveDefinite { what, attempts, .. }) => {
            assert_eq!(what, "kernel matrix K");
            assert_eq!(attempts, 1);
        }
        other => panic!("expected NotPositiveDefinite, got {other:?}"),
    }
}

/// Where two training points coincide, the exact predictor's `k*` carries the delta (noise)
/// term of both copies, so it is no column of `K` and the weights come from a solve: they
/// equal a dense solve with `k*_i = s^2 exp(-r_i^2 / 2 l^2) + mu [r_i = 0]`, in the
/// single-point and the batch path (a noise of 0.1 makes the delta term visible: with `-mu`
/// the weights move by ~0.1). Batch inputs of the wrong width or with a NaN are errors.
#[test]
fn exact_weights_at_a_duplicated_point_include_both_copies_noise() {
    let (s2, l, mu) = (1.3, 0.8, 0.1);
    let base = [[0.0, 0.0], [0.5, -0.3], [-0.4, 0.6], [0.9, 0.8]];
    // Points 0 and 4 coincide.
    let x = Mat::from_fn(5, 2, |i, j| base[i % 4][j]);
    let gp = GpRegression::new(
        x.as_ref(),
        KernelParams::isotropic(s2, l, mu).unwrap(),
        Par::Seq,
    )
    .unwrap();
    let rbf = |a: [f64; 2], b: [f64; 2]| {
        let r2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
        (s2 * (-0.5 * r2 / (l * l)).exp(), r2)
    };
    // K's noise sits on its diagonal; k*'s wherever x* is a training point's location.
    let k = |a, b| {
        let (v, r2) = rbf(a, b);
        if r2 == 0.0 { v + mu } else { v }
    };
    let row = |i: usize| [x[(i, 0)], x[(i, 1)]];
    let kk = Mat::from_fn(5, 5, |i, j| {
        rbf(row(i), row(j)).0 + if i == j { mu } else { 0.0 }
    });
    let kinv = kk.partial_piv_lu().inverse();
    let points = [base[0], base[1], [0.2, 0.1]];
    let batch = gp
        .weights_batch(
            Mat::from_fn(3, 2, |m, j| points[m][j]).as_ref(),
            Predictor::Exact,
            Par::Seq,
        )
        .unwrap();
    for (m, &p) in points.iter().enumerate() {
        let kstar: Vec<f64> = (0..5).map(|i| k(row(i), p)).collect();
        let want: Vec<f64> = (0..5)
            .map(|i| (0..5).map(|j| kinv[(i, j)] * kstar[j]).sum())
            .collect();
        let w = gp.weights(&p, Predictor::Exact).unwrap();
        for i in 0..5 {
            assert!(
                (w[i] - want[i]).abs() < 1e-12,
                "point {m}, weight {i}: {w:?} vs {want:?}"
            );
            assert!(
                (batch[(i, m)] - w[i]).abs() < 1e-12,
                "point {m}, weight {i}"
            );
        }
    }
    // At the single training point 1 the weights are e_1 exactly.
    assert_eq!(batch[(1, 1)], 1.0);
    // The duplicates share the prediction; their weights sum to more than a half each would
    // give without the delta term.
    let w = gp.weights(&base[0], Predictor::Exact).unwrap();
    assert!((w[0] - w[4]).abs() < 1e-12 && w[0] + w[4] > 0.9, "{w:?}");
    for bad in [
        Mat::from_fn(2, 3, |_, _| 0.0),
        Mat::from_fn(2, 1, |_, _| 0.0),
        Mat::from_fn(2, 2, |i, j| if (i, j) == (1, 0) { f64::NAN } else { 0.0 }),
    ] {
        assert!(
            gp.weights_batch(bad.as_ref(), Predictor::Exact, Par::Seq)
                .is_err()
        );
        assert!(gp.variance_batch(bad.as_ref(), Par::Seq).is_err());
    }
}

/// At a training point the exact predictor's `k*` is a column of `K`, so its weights are `e_i`
/// and its variance 0 *exactly*, however ill-conditioned `K` is; a solve with `K` returns
/// `e_i` only to ~cond(K) eps (here visibly off).
#[test]
fn exact_predictor_returns_training_points_exactly_when_k_is_ill_conditioned() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let (n, q) = (12, 2);
    let mut x = rand_mat(&mut rng, n, q, -1.0, 1.0);
    // Material 1 a hair away from material 0, and a tiny noise: cond(K) ~ 1e13.
    x[(1, 0)] = x[(0, 0)] + 1e-7;
    x[(1, 1)] = x[(0, 1)];
    let p = KernelParams::isotropic(1.0, 1.0, 1e-13).unwrap();
    let gp = GpRegression::new(x.as_ref(), p, Par::Seq).unwrap();
    assert!(
        gp.factor().condition_lower_bound() > 1e11,
        "{}",
        gp.factor().condition_lower_bound()
    );
    for i in 0..n {
        let xi: Vec<f64> = (0..q).map(|j| x[(i, j)]).collect();
        let mut e = vec![0.0; n];
        e[i] = 1.0;
        assert_eq!(
            gp.weights(&xi, Predictor::Exact).unwrap(),
            e,
            "material {i}"
        );
        assert_eq!(gp.variance_of(&xi, Predictor::Exact).unwrap(), 0.0);
        let xs = Mat::from_fn(3, q, |r, j| if r == 1 { xi[j] } else { 0.3 * r as f64 });
        for par in [Par::Seq, Par::rayon(2)] {
            let wb = gp
                .weights_batch(xs.as_ref(), Predictor::Exact, par)
                .unwrap();
            assert!((0..n).all(|k| wb[(k, 1)] == e[k]), "batch, material {i}");
        }
    }
    // The solve the shortcut replaces: K^-1 k* with k* = K e_0 is off by far more than eps.
    let x0 = [x[(0, 0)], x[(0, 1)]];
    let k = gp.cross_covariance(&x0, Predictor::Exact).unwrap();
    let solved = gp.factor().solve_vec(&k).unwrap();
    let off = (0..n)
        .map(|k| (solved[k] - if k == 0 { 1.0 } else { 0.0 }).abs())
        .fold(0.0, f64::max);
    assert!(off > 1e-6, "the solve returns e_0 to {off}");
}

#[test]
fn stress_large_n_and_spread_inputs() {
    let mut rng = ChaCha8Rng::seed_from_u64(2000);
    let (n, q, d) = (2000, 2, 3);
    // Latent coordinates with magnitudes from 1e-6 to 1e3.
    let x = Mat::from_fn(n, q, |_, _| {
        let m = 10f64.powf(rng.random_range(-6.0..3.0));
        if rng.random_bool(0.5) { m } else { -m }
    });
    let y = Mat::from_fn(n, d, |_, _| 10f64.powf(rng.random_range(-6.0..6.0)));
    let obj = objective_from_data(y.as_ref());
    let p = KernelParams::paper();
    let (v, info) = obj.log_likelihood(x.as_ref(), &p, Par::rayon(2)).unwrap();
    assert!(v.is_finite());
    // Hundreds of near-coincident points at the origin: K is ill conditioned (~N/mu) but
    // factors without jitter at mu = 1e-4.
    assert_eq!(info.jitter, 0.0);
    assert!(info.condition_estimate > 1e5 && info.condition_estimate.is_finite());
    let gp = GpRegression::new(x.as_ref(), p, Par::rayon(2)).unwrap();
    let xs = rand_mat(&mut rng, 50, q, -2.0, 2.0);
    let w = gp
        .weights_batch(xs.as_ref(), Predictor::Exact, Par::rayon(2))
        .unwrap();
    assert!(w.as_ref().norm_l2().is_finite());
    let var = gp.variance_batch(xs.as_ref(), Par::rayon(2)).unwrap();
    assert!(
        var.iter()
            .all(|v| v.is_finite() && *v >= 0.0 && *v <= 1.0 + 1e-4)
    );
}

/// `weights_vjp` is `v^T J` of the Jacobian (one solve instead of q), for random `v`, ARD
/// length-scales and test points near and far from the data; a wrong length is an error.
#[test]
fn weights_vjp_is_v_times_the_jacobian() {
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let (n, q) = (12, 3);
    let x = rand_mat(&mut rng, n, q, -1.0, 1.0);
    let p = KernelParams::new(0.8, LengthScale::Ard(vec![0.5, 1.3, 0.9]), 1e-3).unwrap();
    let gp = GpRegression::new(x.as_ref(), p, Par::Seq).unwrap();
    for xs in [[0.1, 0.4, -0.3], [0.9, -0.8, 0.2], [4.0, 3.0, -5.0]] {
        let jac = gp.weights_jacobian(&xs).unwrap();
        let v: Vec<f64> = (0..n).map(|_| rng.random_range(-2.0..2.0)).collect();
        let g = gp.weights_vjp(&xs, &v).unwrap();
        for j in 0..q {
            let want: f64 = (0..n).map(|i| v[i] * jac[(i, j)]).sum();
            let size: f64 = (0..n).map(|i| (v[i] * jac[(i, j)]).abs()).sum();
            assert!(
                (g[j] - want).abs() <= 1e-12 * (size + 1e-300),
                "{xs:?} axis {j}: {} vs {want}",
                g[j]
            );
        }
    }
    assert!(gp.weights_vjp(&[0.0; 3], &[1.0; 5]).is_err());
}

#[test]
fn weights_jacobian_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let (n, q) = (15, 3);
    let x = rand_mat(&mut rng, n, q, -1.0, 1.0);
    let p = KernelParams::new(1.7, LengthScale::Ard(vec![0.6, 1.1, 2.0]), 1e-2).unwrap();
    let gp = GpRegression::new(x.as_ref(), p.clone(), Par::Seq).unwrap();
    let xs = [0.3, -0.2, 0.5];
    let jac = gp.weights_jacobian(&xs).unwrap();
    // Cross-covariance gradient from the kernel module agrees with the K^-1-free part.
    let kg = p.cross_gradient(x.as_ref(), &xs).unwrap();
    let f = gp.factor();
    let kj = f.solve(kg.as_ref()).unwrap();
    for j in 0..q {
        let h = 1e-6;
        let mut xp = xs;
        let mut xm = xs;
        xp[j] += h;
        xm[j] -= h;
        let wp = gp.weights(&xp, Predictor::Smooth).unwrap();
        let wm = gp.weights(&xm, Predictor::Smooth).unwrap();
        for i in 0..n {
            let fd = (wp[i] - wm[i]) / (2.0 * h);
            assert!(
                (fd - jac[(i, j)]).abs() <= 1e-6 * (1.0 + fd.abs()),
                "{fd} vs {}",
                jac[(i, j)]
            );
            assert!((kj[(i, j)] - jac[(i, j)]).abs() <= 1e-10 * (1.0 + fd.abs()));
        }
    }
    // Overflowing scaled coordinates are an error, not NaN weights; a length-scale whose
    // inverse square overflows is refused up front.
    assert!(matches!(
        KernelParams::isotropic(1.0, 1e-300, 1e-4),
        Err(GpError::InvalidHyperparameter { .. })
    ));
    let tiny = KernelParams::isotropic(1.0, 1e-150, 1e-4).unwrap();
    let big = Mat::from_fn(3, 1, |i, _| 1e160 * (i as f64 + 1.0));
    assert!(matches!(
        GpRegression::new(big.as_ref(), tiny, Par::Seq),
        Err(GpError::NonFiniteResult { .. })
    ));
}

/// The optimisers' path (reused buffers, plain factorisation) hands a K that needs jitter to
/// the general path: with the default policy the flat evaluation succeeds and equals the full
/// evaluation; with no jitter allowed it is a clear error, not a wrong value.
#[test]
fn optimiser_path_falls_back_to_jitter() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let y = rand_mat(&mut rng, 6, 40, -1.0, 1.0);
    let obj = objective_from_data(y.as_ref());
    // Duplicate latent points and a noise far below rounding: K is singular in f64.
    let x = Mat::from_fn(6, 2, |i, j| ((i / 2) as f64) * 0.7 + j as f64 * 0.1);
    let p = KernelParams::isotropic(1.0, 1.0, 1e-300).unwrap();
    let flat = obj.flat(2, p.clone(), Learn::NONE).unwrap();
    let theta = flat.pack(x.as_ref(), &p).unwrap();
    let (v, g) = flat
        .neg_log_likelihood_and_gradient(&theta, Par::Seq)
        .unwrap();
    let full = obj.evaluate(x.as_ref(), &p, Par::Seq).unwrap();
    assert!(full.factor.jitter > 0.0, "{:?}", full.factor);
    assert_eq!(v, -full.value);
    assert_eq!(g[0], -full.grad_x[(0, 0)]);
    let strict = objective_from_data(y.as_ref()).with_jitter_policy(gp_core::JitterPolicy::none());
    let flat = strict.flat(2, p.clone(), Learn::NONE).unwrap();
    assert!(matches!(
        flat.neg_log_likelihood_and_gradient(&theta, Par::Seq),
        Err(GpError::NotPositiveDefinite { .. })
    ));
}

/// Every partial hyperparameter mask (and iso/ARD): the flat layout has the learnt entries only,
/// unpack inverts pack and keeps the template's fixed values, and the flat gradient matches
/// central differences of the flat objective.
#[test]
fn partial_learn_masks_pack_and_differentiate() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (n, q, d) = (5, 2, 6);
    let y = rand_mat(&mut rng, n, d, -2.0, 2.0);
    let x = rand_mat(&mut rng, n, q, -1.5, 1.5);
    let obj = objective_from_data(y.as_ref());
    for ard in [false, true] {
        let template = params(&mut rng, q, ard, -2.0);
        let other = params(&mut rng, q, ard, -1.0);
        // Without a floor, and with one below both noises (mu = floor + exp(theta)).
        let floor = 0.5 * template.noise().min(other.noise());
        for (bits, floor) in (0..8u8).flat_map(|b| [(b, 0.0), (b, floor)]) {
            let learn = Learn {
                signal_variance: bits & 1 != 0,
                length_scale: bits & 2 != 0,
                noise: bits & 4 != 0,
            };
            let flat = obj
                .flat(q, template.clone(), learn)
                .unwrap()
                .with_noise_floor(floor)
                .unwrap();
            let k = template.length_scale().len();
            let n_hyper = usize::from(learn.signal_variance)
                + if learn.length_scale { k } else { 0 }
                + usize::from(learn.noise);
            let theta = flat.pack(x.as_ref(), &other).unwrap();
            assert_eq!(theta.len(), n * q + n_hyper, "{learn:?}");
            // Learnt values come from `other`, fixed ones from the template.
            let (x2, p2) = flat.unpack(&theta).unwrap();
            assert_eq!(x2, x);
            let pick = |learnt: bool, o: f64, t: f64| if learnt { o } else { t };
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-14 * b.abs();
            assert!(close(
                p2.signal_variance(),
                pick(
                    learn.signal_variance,
                    other.signal_variance(),
                    template.signal_variance()
                )
            ));
            assert!(close(
                p2.noise(),
                pick(learn.noise, other.noise(), template.noise())
            ));
            for j in 0..k {
                let (o, t) = (
                    other.length_scale().axis(j),
                    template.length_scale().axis(j),
                );
                assert!(close(
                    p2.length_scale().axis(j),
                    pick(learn.length_scale, o, t)
                ));
            }
            // Fixed values are the template's bits (not exp(log v): the paper's mu = 1e-4 came
            // back as 1.0000000000000009e-4).
            let paper = KernelParams::isotropic(1.0, 1.0, 1e-4).unwrap();
            let fixed = obj.flat(q, paper.clone(), Learn::NONE).unwrap();
            let (_, back) = fixed
                .unpack(&fixed.pack(x.as_ref(), &paper).unwrap())
                .unwrap();
            assert_eq!(back.noise(), 1e-4);
            if !learn.noise {
                assert_eq!(p2.noise().to_bits(), template.noise().to_bits());
            }
            if !learn.signal_variance {
                assert_eq!(p2.signal_variance(), template.signal_variance());
            }
            if !learn.length_scale {
                assert_eq!(p2.length_scale(), template.length_scale());
            }
            // Flat gradient against central differences of the flat objective.
            let (v, g) = flat
                .neg_log_likelihood_and_gradient(&theta, Par::Seq)
                .unwrap();
            let f = |t: &[f64]| flat.neg_log_likelihood(t, Par::Seq).unwrap();
            for (i, gi) in g.iter().enumerate() {
                assert_close(central_diff(&f, &theta, i), *gi, v.abs(), "flat gradient");
            }
            // The optimisers' path (no condition estimate; the length-scale gradient only
            // when learnt) has the full evaluation's bits.
            let full = flat.evaluate(&theta, Par::Seq).unwrap();
            let mut want: Vec<f64> = (0..n)
                .flat_map(|i| (0..q).map(move |j| (i, j)))
                .map(|(i, j)| -full.grad_x[(i, j)])
                .collect();
            let h = &full.grad_hyper_log;
            if learn.signal_variance {
                want.push(-h.signal_variance);
            }
            if learn.length_scale {
                want.extend(h.length_scale.iter().map(|v| -v));
            }
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let learnt = if learn.noise { g.len() - 1 } else { g.len() };
            assert_eq!(bits(&g[..learnt]), bits(&want), "{learn:?}");
            assert_eq!(v.to_bits(), (-full.value).to_bits());
            if learn.noise && floor > 0.0 {
                // The floor holds for any theta; a noise that reached it (as unpacked) packs
                // and unpacks to itself (a warm start from a fit that ran into the floor: an
                // audit found leave-one-out refits refusing it); a noise below it cannot be
                // packed.
                let mut t = theta.clone();
                *t.last_mut().unwrap() = -800.0;
                let (_, at_floor) = flat.unpack(&t).unwrap();
                assert_eq!(at_floor.noise(), floor);
                let repacked = flat.pack(x.as_ref(), &at_floor).unwrap();
                assert_eq!(flat.unpack(&repacked).unwrap().1.noise(), floor);
                // ... through a finite theta (ln of the floor's eps / 8, not ln 0), from which
                // an optimiser can move.
                assert_eq!(*repacked.last().unwrap(), (floor * f64::EPSILON / 8.0).ln());
                let low = KernelParams::new(
                    other.signal_variance(),
                    other.length_scale().clone(),
                    floor * (1.0 - 1e-9),
                )
                .unwrap();
                assert!(matches!(
                    flat.pack(x.as_ref(), &low),
                    Err(GpError::NoiseBelowFloor { .. })
                ));
            }
        }
    }
    let flat = obj.flat(q, params(&mut rng, q, false, -2.0), Learn::ALL);
    assert!(flat.unwrap().with_noise_floor(-1.0).is_err());
}

/// Dropping the constant shifts the likelihood by exactly N D/2 log(2 pi) and leaves the
/// gradients alone.
#[test]
fn the_constant_term_only_shifts_the_value() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let (n, q, d) = (6, 2, 9);
    let y = rand_mat(&mut rng, n, d, -2.0, 2.0);
    let x = rand_mat(&mut rng, n, q, -1.5, 1.5);
    let p = params(&mut rng, q, false, -2.0);
    let with = objective_from_data(y.as_ref());
    let without = objective_from_data(y.as_ref()).with_constant(false);
    let a = with.evaluate(x.as_ref(), &p, Par::Seq).unwrap();
    let b = without.evaluate(x.as_ref(), &p, Par::Seq).unwrap();
    let shift = (n * d) as f64 / 2.0 * (2.0 * std::f64::consts::PI).ln();
    assert!(
        ((b.value - a.value) - shift).abs() <= 1e-12 * a.value.abs().max(shift),
        "{} - {} vs {shift}",
        b.value,
        a.value
    );
    assert_eq!(a.grad_x, b.grad_x);
    assert_eq!(a.grad_hyper_log, b.grad_hyper_log);
}

/// The Gram-matrix check rejects a non-PSD matrix at every magnitude and accepts a genuine one:
/// its 2 x 2 minors were products that overflowed (NaN, not below 0) for entries near 1e200
/// and underflowed to 0 near 1e-200, so `[[c, 2c], [2c, c]]` passed there.
#[test]
fn gram_check_rejects_non_psd_matrices_at_every_magnitude() {
    for c in [1e-300, 1e-200, 1e-100, 1.0, 1e100, 1e200, 1e300] {
        let bad = Mat::from_fn(2, 2, |i, j| if i == j { c } else { 2.0 * c });
        match GplvmObjective::new(bad, 3) {
            Err(GpError::NotPositiveSemidefinite {
                row: 1,
                col: 0,
                value,
                ..
            // (-3e-600 at 1e-300 rounds to -0.)
            }) => assert!(value.is_sign_negative(), "{c:e}: minor {value:e}"),
            other => panic!("{c:e}: {other:?}"),
        }
        // |cos| = 0.5 and a rank-one pair on the boundary are Gram matrices.
        let good = Mat::from_fn(2, 2, |i, j| if i == j { c } else { 0.5 * c });
        GplvmObjective::new(good, 3).unwrap();
        let opposite = Mat::from_fn(2, 2, |i, j| if i == j { c } else { -c });
        GplvmObjective::new(opposite, 3).unwrap();
    }
}

/// The Gram-matrix check's tolerance, `tol = sqrt(eps) max|S|`: rounding-level negatives of a
/// centred Gram matrix pass. A diagonal entry down to `-tol` itself is accepted and one below
/// it refused (naming it); an off-diagonal entry may exceed the diagonal's geometric mean by
/// what `tol` on the diagonal allows; a zero matrix (identical materials) is a Gram matrix.
#[test]
fn gram_check_tolerates_rounding_level_negatives() {
    let tol = f64::EPSILON.sqrt();
    let diagonal = |d: f64| Mat::from_fn(2, 2, |i, j| [[1.0, 0.0], [0.0, d]][i][j]);
    for d in [-tol, -0.9 * tol, 0.0] {
        GplvmObjective::new(diagonal(d), 3).unwrap();
    }
    let below = -tol * (1.0 + f64::EPSILON);
    assert_eq!(
        GplvmObjective::new(diagonal(below), 3).unwrap_err(),
        GpError::NotPositiveSemidefinite {
            what: "Gram matrix S",
            row: 1,
            col: 1,
            value: below
        }
    );
    // With the diagonal raised by tol an off-diagonal entry may reach 1 + tol: 1 + tol / 2
    // passes, 1 + 2 tol does not.
    let pair = |a: f64| Mat::from_fn(2, 2, |i, j| if i == j { 1.0 } else { a });
    GplvmObjective::new(pair(1.0 + 0.5 * tol), 3).unwrap();
    assert!(matches!(
        GplvmObjective::new(pair(1.0 + 2.0 * tol), 3),
        Err(GpError::NotPositiveSemidefinite { row: 1, col: 0, .. })
    ));
    GplvmObjective::new(Mat::<f64>::zeros(3, 3), 3).unwrap();
    // The refused minor is reported: 1 * 1 - 2^2.
    match GplvmObjective::new(pair(2.0), 3) {
        Err(GpError::NotPositiveSemidefinite { value, .. }) => assert_eq!(value, -3.0),
        other => panic!("{other:?}"),
    }
    // Symmetry to the same relative tolerance: at max|S| = 100, a difference of 1e-6 (below
    // 100 sqrt(eps) = 1.5e-6) passes and 2e-6 does not.
    let skewed = |e: f64| Mat::from_fn(2, 2, |i, j| [[100.0, 50.0], [50.0 + e, 100.0]][i][j]);
    GplvmObjective::new(skewed(1e-6), 3).unwrap();
    assert!(matches!(
        GplvmObjective::new(skewed(2e-6), 3),
        Err(GpError::NotSymmetric { row: 1, col: 0, .. })
    ));
}

/// Gram quantities computed from finite inputs that overflow are errors naming them, not
/// infinities or NaN inside an `Ok`: `Y Y^T` of data near 1e200, the centring of entries near
/// `f64::MAX` (row sums overflow), and the likelihood of data whose squares overflow.
#[test]
fn overflowing_gram_quantities_are_errors() {
    let y = Mat::from_fn(2, 3, |i, j| 1e200 * (1.0 + (i + j) as f64));
    assert!(matches!(
        gram_from_data(y.as_ref(), Par::Seq),
        Err(GpError::NonFiniteResult { .. })
    ));
    let g = Mat::from_fn(3, 3, |i, j| if i == j { 1.5e308 } else { 1e308 });
    assert!(matches!(
        centre_gram(g.as_ref()),
        Err(GpError::NonFiniteResult { .. })
    ));
    let x = Mat::from_fn(2, 1, |i, _| i as f64);
    let p = KernelParams::paper();
    assert!(matches!(
        log_likelihood_from_data(y.as_ref(), x.as_ref(), &p, false, Par::Seq),
        Err(GpError::NonFiniteResult { .. })
    ));
    // Large but representable: still values.
    let y = Mat::from_fn(2, 3, |i, j| 1e100 * (1.0 + (i + j) as f64));
    let g = gram_from_data(y.as_ref(), Par::Seq).unwrap();
    assert!((g[(0, 0)] / 14e200 - 1.0).abs() < 1e-15);
    assert!(centre_gram(g.as_ref()).is_ok());
    assert!(log_likelihood_from_data(y.as_ref(), x.as_ref(), &p, false, Par::Seq).is_ok());
}

/// Far from a training point its kernel value is 0 and so is its share of the gradients, even
/// where the scaled distance overflows (`0 * inf` gave NaN inside an `Ok`): the weights
/// Jacobian at 1e301 with a length-scale of 1e-8, and the cross-covariance gradient between
/// +-1e308. Near the points they are unchanged (finite differences elsewhere in this file).
#[test]
fn gradients_far_from_every_point_are_zero_not_nan() {
    let x = Mat::from_fn(3, 1, |i, _| i as f64);
    let p = KernelParams::isotropic(1.0, 1e-8, 1e-4).unwrap();
    let gp = GpRegression::new(x.as_ref(), p, Par::Seq).unwrap();
    for far in [1e301, -1e301, 1e3] {
        let jac = gp.weights_jacobian(&[far]).unwrap();
        assert!((0..3).all(|i| jac[(i, 0)] == 0.0), "{far:e}: {jac:?}");
        assert_eq!(gp.weights(&[far], Predictor::Smooth).unwrap(), [0.0; 3]);
    }
    let x = Mat::from_fn(2, 1, |i, _| if i == 0 { 1e308 } else { 0.0 });
    let g = KernelParams::paper()
        .cross_gradient(x.as_ref(), &[-1e308])
        .unwrap();
    assert_eq!((g[(0, 0)], g[(1, 0)]), (0.0, 0.0));
    // Near a point the gradient is the formula's.
    let g = KernelParams::paper()
        .cross_gradient(x.as_ref(), &[0.5])
        .unwrap();
    assert!((g[(1, 0)] - (-0.125f64).exp() * -0.5).abs() < 1e-16);
}

/// Latent points `x` with row `n` set to `point`.
fn with_point(x: MatRef<'_, f64>, n: usize, point: &[f64]) -> Mat<f64> {
    Mat::from_fn(x.nrows(), x.ncols(), |i, j| {
        if i == n { point[j] } else { x[(i, j)] }
    })
}

/// A move of one latent point evaluated in O(N^2) against the full O(N^3) evaluation: the
/// reference's value has the same bits, and moves agree to rounding. Measured over 300 random
/// problems (N 2-51, mu 7e-5..1, iso/ARD, prior on/off), the worst |move - full| / (eps |L|)
/// was 3e7 for moves of size ~1, 1.6e4 for moves below 0.1 and 1e4 below 0.01 (full
/// evaluations against the Cholesky-solve likelihood of the data: <= 27): W = K^-1 S K^-1
/// amplifies rounding by cond(K), which the full trace does not. Hooke-Jeeves compares trials
/// whose values differ by far more (5e7 eps |L| for a move of 1e-7 in the paper's setting).
#[test]
fn point_moves_match_full_evaluations() {
    let mut cheap = 0;
    for seed in 0..300u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n = rng.random_range(2..52);
        let q = rng.random_range(1..4);
        let d = rng.random_range(1..60);
        let y = rand_mat(&mut rng, n, d, -2.0, 2.0);
        let x = rand_mat(&mut rng, n, q, -1.5, 1.5);
        let log_mu = rng.random_range(-9.5..0.0);
        let p = params(&mut rng, q, seed % 2 == 0, log_mu);
        let obj = objective_from_data(y.as_ref()).with_prior(seed % 3 == 0);
        let mut moves = gp_core::PointMoves::new(&obj, x.as_ref(), &p, Par::Seq)
            .unwrap()
            .expect("these K factor without jitter, with cond(K) <= 1e7");
        let (full0, _) = obj.log_likelihood(x.as_ref(), &p, Par::Seq).unwrap();
        assert_eq!(moves.value(), full0, "seed {seed}: the reference's value");
        for _ in 0..10 {
            let m = rng.random_range(0..n);
            let size = 10f64.powf(-rng.random_range(0.0..8.0));
            let point: Vec<f64> = (0..q)
                .map(|j| x[(m, j)] + size * rng.random_range(-1.0..1.0))
                .collect();
            let moved = with_point(x.as_ref(), m, &point);
            let (full, _) = obj.log_likelihood(moved.as_ref(), &p, Par::Seq).unwrap();
            let Some(v) = moves.value_with_point(m, &point).unwrap() else {
                continue;
            };
            cheap += 1;
            // 10x and 15x the worst measured (a CPU with other kernels rounds otherwise).
            let units = if size < 1e-2 { 1e5 } else { 5e8 };
            let tol = units * f64::EPSILON * full.abs().max(1.0);
            assert!(
                (v - full).abs() <= tol,
                "seed {seed}, point {m} moved by {size:e}: {v} against {full}"
            );
        }
        // The moves leave the reference as it was.
        assert_eq!(moves.value(), full0);
        assert_eq!(moves.x(), x.as_ref());
    }
    assert!(
        cheap > 2900,
        "{cheap} of 3000 moves evaluated by the update"
    );
}

/// A point moved onto another with a tiny noise: the update declines (its determinant ratio
/// is below 1e-6), a reference with the duplicate takes no moves, and the evaluator's full
/// fallback gives the optimisers' value exactly. Bad moves are errors.
#[test]
fn point_moves_decline_near_duplicates_and_refuse_bad_points() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (n, q) = (6, 2);
    let y = rand_mat(&mut rng, n, 5, -1.0, 1.0);
    let x = rand_mat(&mut rng, n, q, -1.0, 1.0);
    let p = KernelParams::isotropic(1.0, 1.0, 1e-10).unwrap();
    let obj = objective_from_data(y.as_ref());
    let mut moves = gp_core::PointMoves::new(&obj, x.as_ref(), &p, Par::Seq)
        .unwrap()
        .unwrap();
    let onto: Vec<f64> = (0..q).map(|j| x[(1, j)]).collect();
    assert_eq!(moves.value_with_point(0, &onto).unwrap(), None);
    // Nor does a reference with the duplicate take moves (cond(K) ~ 1e10 > 1e7).
    let duplicate = with_point(x.as_ref(), 0, &onto);
    assert!(
        gp_core::PointMoves::new(&obj, duplicate.as_ref(), &p, Par::Seq)
            .unwrap()
            .is_none()
    );
    assert!(moves.value_with_point(0, &[0.1, f64::NAN]).is_err());
    assert!(moves.value_with_point(0, &[0.1]).is_err());
    assert!(moves.value_with_point(n, &[0.1, 0.2]).is_err());

    let flat = obj.flat(q, p.clone(), Learn::NONE).unwrap();
    let mut evaluator = flat.move_evaluator();
    let mut theta = flat.pack(x.as_ref(), &p).unwrap();
    let v0 = evaluator.neg_log_likelihood(&theta, Par::Seq).unwrap();
    assert_eq!(v0, flat.neg_log_likelihood(&theta, Par::Seq).unwrap());
    theta[..q].copy_from_slice(&onto);
    let v = evaluator.neg_log_likelihood(&theta, Par::Seq).unwrap();
    assert_eq!(v, flat.neg_log_likelihood(&theta, Par::Seq).unwrap());
    let c = evaluator.counts();
    assert_eq!((c.cheap, c.evaluations, c.references), (0, 2, 1));
    // A failed evaluation drops the reference; the next ones are right again.
    theta[2] = f64::NAN;
    assert!(evaluator.neg_log_likelihood(&theta, Par::Seq).is_err());
    theta[2] = x[(1, 0)] + 0.3;
    let v = evaluator.neg_log_likelihood(&theta, Par::Seq).unwrap();
    assert_eq!(v, flat.neg_log_likelihood(&theta, Par::Seq).unwrap());
}

/// The reference's condition limit is on the 1-norm condition number `|K|_1 |K^-1|_1`, which
/// for two points does not depend on the signal variance: with `s^2 = 100` a reference at
/// 5e6 takes moves and one at 2e7 does not (while `|K|_1 + |K^-1|_1` stays below 1e6 in
/// both). For two points `cond_1 = (1 + m + rho) / (1 + m - rho)`, `m = mu / s^2`.
#[test]
fn point_moves_need_a_reference_condition_of_at_most_1e7() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let y = rand_mat(&mut rng, 2, 4, -1.0, 1.0);
    let obj = objective_from_data(y.as_ref());
    let (s2, mu) = (100.0, 1e-7);
    let p = KernelParams::isotropic(s2, 1.0, mu).unwrap();
    for (condition, takes_moves) in [(5e6, true), (2e7, false)] {
        let m1 = 1.0 + mu / s2;
        let rho: f64 = m1 * (condition - 1.0) / (condition + 1.0);
        let r = (-2.0 * rho.ln()).sqrt();
        let x = Mat::from_fn(2, 1, |i, _| i as f64 * r);
        let k = p.kernel_matrix(x.as_ref()).unwrap();
        let kinv = k.as_ref().llt(faer::Side::Lower).unwrap().inverse();
        let norm1 = |a: MatRef<'_, f64>| {
            (0..2)
                .map(|j| a[(0, j)].abs() + a[(1, j)].abs())
                .fold(0.0, f64::max)
        };
        let (nk, ni) = (norm1(k.as_ref()), norm1(kinv.as_ref()));
        assert!(((nk * ni) / condition - 1.0).abs() < 1e-3, "{}", nk * ni);
        assert!(nk + ni < 1e6, "{nk} + {ni}");
        let moves = gp_core::PointMoves::new(&obj, x.as_ref(), &p, Par::Seq).unwrap();
        assert_eq!(moves.is_some(), takes_moves, "condition {condition:e}");
    }
}

/// A reference move of exactly `MAX_UPDATE_MOVE` length-scales along an axis (ARD: each
/// axis its own) is made by an update; a longer one is refused and leaves the reference as
/// it was. The debug form names the sizes and the value.
#[test]
fn reference_moves_up_to_the_longest_update_along_each_axis() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let y = rand_mat(&mut rng, 4, 6, -1.0, 1.0);
    let obj = objective_from_data(y.as_ref());
    let x = Mat::from_fn(4, 2, |i, j| {
        [[0.0, 0.0], [1.0, 0.5], [-1.0, 0.8], [0.5, -1.0]][i][j]
    });
    let p = KernelParams::new(1.5, LengthScale::Ard(vec![2.0, 0.5]), 1e-3).unwrap();
    let longest = [
        gp_core::MAX_UPDATE_MOVE * 2.0,
        gp_core::MAX_UPDATE_MOVE * 0.5,
    ];
    for axis in 0..2 {
        let mut moves = gp_core::PointMoves::new(&obj, x.as_ref(), &p, Par::Seq)
            .unwrap()
            .unwrap();
        let before = moves.value();
        let mut point = [0.0, 0.0];
        point[axis] = longest[axis] * (1.0 + 4.0 * f64::EPSILON);
        assert!(!moves.move_reference(0, &point).unwrap(), "axis {axis}");
        assert_eq!((moves.value(), moves.x()), (before, x.as_ref()));
        point[axis] = longest[axis];
        assert!(moves.move_reference(0, &point).unwrap(), "axis {axis}");
        let moved = with_point(x.as_ref(), 0, &point);
        assert_eq!(moves.x(), moved.as_ref());
        let (full, _) = obj.log_likelihood(moved.as_ref(), &p, Par::Seq).unwrap();
        assert!(
            (moves.value() - full).abs() <= 1e-12 * full.abs(),
            "axis {axis}"
        );
    }
    let moves = gp_core::PointMoves::new(&obj, x.as_ref(), &p, Par::Seq)
        .unwrap()
        .unwrap();
    let text = format!("{moves:?}");
    assert!(
        text.starts_with("PointMoves { n: 4, q: 2, value: ") && text.ends_with(", .. }"),
        "{text}"
    );
    assert!(
        text.contains(&format!("value: {:?}", moves.value())),
        "{text}"
    );
}

/// The evaluator along the trial sequence a direct search makes (one coordinate at a time,
/// accepted moves, pattern moves, changed hyperparameters, the same point again) gives the
/// full evaluation's value to rounding, and evaluates most trials without a factorisation.
#[test]
fn move_evaluator_follows_full_evaluations_along_a_search() {
    for (seed, learn) in [(1u64, Learn::NONE), (2, Learn::ALL), (3, Learn::NONE)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (n, q) = (12, 2);
        let y = rand_mat(&mut rng, n, 30, -2.0, 2.0);
        let x = rand_mat(&mut rng, n, q, -1.5, 1.5);
        let p = params(&mut rng, q, false, -4.0);
        let obj = objective_from_data(y.as_ref()).with_prior(seed == 3);
        let flat = obj.flat(q, p.clone(), learn).unwrap();
        let mut evaluator = flat.move_evaluator();
        let mut base = flat.pack(x.as_ref(), &p).unwrap();
        let mut trials = 0;
        let mut check = |evaluator: &mut gp_core::MoveEvaluator, t: &[f64]| {
            trials += 1;
            let v = evaluator.neg_log_likelihood(t, Par::Seq).unwrap();
            let full = flat.neg_log_likelihood(t, Par::Seq).unwrap();
            assert!(
                (v - full).abs() <= 1e-9 * full.abs().max(1.0),
                "seed {seed}, trial {trials}: {v} against {full}"
            );
            v
        };
        let mut best = check(&mut evaluator, &base);
        for sweep in 0..10 {
            let step = 0.2 / f64::from(1 << sweep);
            let before = base.clone();
            for i in 0..base.len() {
                for sign in [1.0, -1.0] {
                    let mut t = base.clone();
                    t[i] += sign * step;
                    let v = check(&mut evaluator, &t);
                    if v < best {
                        best = v;
                        base = t;
                        break;
                    }
                }
            }
            // A pattern move, then the current point again.
            let pattern: Vec<f64> = base.iter().zip(&before).map(|(a, b)| 2.0 * a - b).collect();
            check(&mut evaluator, &pattern);
            check(&mut evaluator, &base);
        }
        // The current point once more: the reference's own value (the same bits as a full
        // evaluation), without a factorisation.
        let before = evaluator.counts();
        let again = check(&mut evaluator, &base);
        assert_eq!(again, flat.neg_log_likelihood(&base, Par::Seq).unwrap());
        let after = evaluator.counts();
        assert_eq!(
            (after.cheap, after.references),
            (before.cheap + 1, before.references),
            "seed {seed}"
        );
        let c = evaluator.counts();
        assert_eq!(c.evaluations, trials);
        let share = c.cheap as f64 / c.evaluations as f64;
        assert!(
            share > if learn == Learn::NONE { 0.8 } else { 0.5 },
            "seed {seed}: {c:?}"
        );
        // Accepted moves were followed by trials in later points: some references moved by
        // an update.
        assert!(c.updates > 0, "seed {seed}: {c:?}");
    }
}

/// Moving the reference by updates (`K^-1` and `W` rank-2 updated, `O(N^2)`), up to
/// `MAX_UPDATES` times in a row: the reference's value and the next moves still agree with full
/// evaluations at the moved points (worst 1.2e-12 relative over these 60 problems), moves
/// longer than `MAX_UPDATE_MOVE` length-scales are refused (unrestricted, large moves drifted
/// to 2.6e-6), and so is one more update after `MAX_UPDATES` (reset first).
#[test]
fn reference_updates_stay_close_to_full_evaluations() {
    let mut worst = 0.0f64;
    for seed in 0..60u64 {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n = rng.random_range(3..52);
        let q = rng.random_range(1..4);
        let y = rand_mat(&mut rng, n, 40, -2.0, 2.0);
        let mut x = rand_mat(&mut rng, n, q, -1.5, 1.5);
        let log_mu = rng.random_range(-9.5..-2.0);
        let p = params(&mut rng, q, seed % 2 == 0, log_mu);
        let obj = objective_from_data(y.as_ref()).with_prior(seed % 3 == 0);
        let mut moves = gp_core::PointMoves::new(&obj, x.as_ref(), &p, Par::Seq)
            .unwrap()
            .expect("these K factor without jitter, with cond(K) <= 1e7");
        // About 7 moves in 10 are updates (32 took at most 61 here); the bound keeps a broken
        // update (one that declines every later move) from looping for ever.
        let mut done = 0;
        for _ in 0..100 * gp_core::MAX_UPDATES {
            if done == gp_core::MAX_UPDATES {
                break;
            }
            let m = rng.random_range(0..n);
            let size = 10f64.powf(-rng.random_range(0.0..6.0));
            let point: Vec<f64> = (0..q)
                .map(|j| x[(m, j)] + size * rng.random_range(-1.0..1.0))
                .collect();
            let long = (0..q).any(|j| {
                (point[j] - x[(m, j)]).abs() > gp_core::MAX_UPDATE_MOVE * p.length_scale().axis(j)
            });
            let moved = moves.move_reference(m, &point).unwrap();
            assert!(
                !(moved && long),
                "seed {seed}: a move of {size:e} by an update"
            );
            if moved {
                x = with_point(x.as_ref(), m, &point);
                done += 1;
            }
        }
        assert_eq!(done, gp_core::MAX_UPDATES, "seed {seed}: updates made");
        let (full, _) = obj.log_likelihood(x.as_ref(), &p, Par::Seq).unwrap();
        let rel = |v: f64, full: f64| (v - full).abs() / full.abs().max(1.0);
        worst = worst.max(rel(moves.value(), full));
        assert_eq!(moves.x(), x.as_ref());
        for _ in 0..5 {
            let m = rng.random_range(0..n);
            let point: Vec<f64> = (0..q)
                .map(|j| x[(m, j)] + 1e-3 * (j as f64 + 0.5))
                .collect();
            let (full, _) = obj
                .log_likelihood(with_point(x.as_ref(), m, &point).as_ref(), &p, Par::Seq)
                .unwrap();
            if let Some(v) = moves.value_with_point(m, &point).unwrap() {
                worst = worst.max(rel(v, full));
            }
        }
        let point: Vec<f64> = (0..q).map(|j| x[(0, j)] + 1e-3).collect();
        assert!(
            !moves.move_reference(0, &point).unwrap(),
            "update 33 is refused"
        );
    }
    eprintln!(
        "worst relative difference after {} updates: {worst:e}",
        gp_core::MAX_UPDATES
    );
    assert!(worst <= 2e-11, "{worst:e}");
}
