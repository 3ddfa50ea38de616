//! Errors of the GP and of the baselines (DESIGN.md section 5).
//!
//! Every predictor here is linear in the stored rows of the transformed data, `y* = sum_j c_j
//! y_j`, so its squared error against a material `h` in the transformed ("model") space follows
//! from the uncentred Gram matrix alone: `G_hh - 2 c^T G_h + c^T G c` = `d^T G d` with
//! `d = c - e_h` ([`sq_error`]). The leave-one-out protocol ([`leave_one_out`]) therefore needs
//! no pass over the data: refit without `h` from the subset Gram matrix, place `h` at the
//! latent point minimising that error, and compare with baselines chosen the same way (with
//! knowledge of `h`: these are oracles).
//! Errors in BRDF space (after the inverse transform) of every method for every material come
//! from one streaming pass ([`brdf_space_rmse`]: the coefficient matrix times each data block).
//!
//! Both spaces report the paper's Eq. 22 normalisation, `sqrt(sum_d (y_d - y*_d)^2 / (n_th n_td
//! n_pd))`: the sum runs over all D values (cells x channels), divided by the angular count.

use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use brdf_io::store::Store;
use faer::{Mat, MatMut, MatRef, Par, Side};
use gp_core::{GpRegression, all_but, centre_gram, subset_gram};
use gp_core::{GplvmObjective, KernelParams};
use gplvm::optim::{LbfgsSettings, lbfgs};
use gplvm::{FitConfig, OptimizerKind, Transform, fit_gram};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::predictor::{Predictor, PredictorKind, weights_to_coefficients};

/// The prediction methods compared by the evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// GP posterior mean (smooth predictor) at the best latent point of the refit.
    Gp,
    /// The single stored material closest to the held-out one.
    Nearest,
    /// `a y1 + (1 - a) y2` (best a in [0, 1]) between the two materials nearest to the GP's
    /// latent point in the refit's latent space.
    LerpLatent,
    /// `a y1 + (1 - a) y2` for the best pair of materials and best a in [0, 1] (an oracle).
    LerpBest,
    /// Projection onto the leading q principal components of the other materials.
    Pca,
}

impl Method {
    /// All methods, in report order.
    pub const ALL: [Method; 5] = [
        Method::Gp,
        Method::Nearest,
        Method::LerpLatent,
        Method::LerpBest,
        Method::Pca,
    ];

    /// Name used in tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Self::Gp => "gp",
            Self::Nearest => "nearest",
            Self::LerpLatent => "lerp-latent",
            Self::LerpBest => "lerp-best",
            Self::Pca => "pca",
        }
    }
}

/// Squared error of the linear predictor `sum_j c_j y_j` against row `h`, from the uncentred
/// Gram matrix `g` (N x N, `c` of length N): `d^T G d` with `d = c - e_h` (equal to `G_hh -
/// 2 c^T G_h + c^T G c`), clamped at 0.
///
/// Forming `d` first keeps a small error small: the expanded form subtracts terms of the size
/// of `G_hh`, so its rounding (~1e-16 `G_hh`) swamped the error of a near-exact reconstruction
/// (`c` close to `e_h`) on raw data with large values; `d^T G d` rounds relative to `|d|^2 G`.
///
/// # Panics
/// If `g` has fewer columns than rows or `c` is shorter than N (shapes are the caller's
/// contract, as in faer's products). An `h` outside `0..N` is not checked: the result is then
/// `c^T G c`, the error against a zero row.
pub fn sq_error(g: MatRef<'_, f64>, h: usize, c: &[f64]) -> f64 {
    let n = g.nrows();
    let d: Vec<f64> = (0..n)
        .map(|i| if i == h { c[i] - 1.0 } else { c[i] })
        .collect();
    let mut e = 0.0;
    for (i, &di) in d.iter().enumerate() {
        if di == 0.0 {
            continue;
        }
        let gi: f64 = d.iter().enumerate().map(|(j, &dj)| g[(i, j)] * dj).sum();
        e += di * gi;
    }
    e.max(0.0)
}

/// One method's result for one held-out material.
#[derive(Debug, Clone, Serialize)]
pub struct MethodResult {
    /// The method.
    pub method: Method,
    /// Coefficients over all N materials (0 at the held-out one).
    pub coefficients: Vec<f64>,
    /// Squared error in the transformed space (from the Gram matrix).
    pub sq_error: f64,
    /// What was chosen (materials, a, latent point).
    pub detail: String,
}

/// Leave-one-out result for one material.
#[derive(Debug, Clone, Serialize)]
pub struct LooMaterial {
    /// Index of the held-out material.
    pub held_out: usize,
    /// The GP's best latent point in the refit's latent space.
    pub gp_point: Vec<f64>,
    /// Log-likelihood of the refit.
    pub refit_log_likelihood: f64,
    /// Results in [`Method::ALL`] order.
    pub methods: Vec<MethodResult>,
}

/// Best `a` in [0, 1] for `a y_i + (1 - a) y_j` against `y_h` and its squared error.
fn best_lerp(g: MatRef<'_, f64>, h: usize, i: usize, j: usize) -> (f64, f64) {
    let ru = g[(h, i)] - g[(h, j)] - g[(i, j)] + g[(j, j)];
    let uu = g[(i, i)] - 2.0 * g[(i, j)] + g[(j, j)];
    let rr = g[(h, h)] - 2.0 * g[(h, j)] + g[(j, j)];
    let a = if uu > 0.0 {
        (ru / uu).clamp(0.0, 1.0)
    } else {
        0.5
    };
    (a, (rr - 2.0 * a * ru + a * a * uu).max(0.0))
}

fn embed(n: usize, idx: &[usize], c: &[f64]) -> Vec<f64> {
    let mut full = vec![0.0; n];
    for (k, &i) in idx.iter().enumerate() {
        full[i] = c[k];
    }
    full
}

/// Squared error of the linear predictor `sum_j c_j y_j` against a material `y_h` that is not
/// one of the rows, from Gram quantities: `G_hh - 2 c^T g_h + c^T G c` with `g = G` (N x N) of
/// the rows, `g_h[j] = y_j . y_h` and `g_hh = |y_h|^2` (clamped at 0; its rounding is ~1e-16
/// `g_hh`, see [`sq_error`]).
///
/// # Panics
/// If `g` has fewer columns than rows or `g_h` or `c` is shorter than N = `g.nrows()` (extra
/// columns of `g` are not read).
pub fn sq_error_external(g: MatRef<'_, f64>, g_h: &[f64], g_hh: f64, c: &[f64]) -> f64 {
    sq_error_expanded(g, g_h, g_hh, c).max(0.0)
}

/// [`sq_error_external`] before the clamp (the latent search minimises this).
fn sq_error_expanded(g: MatRef<'_, f64>, g_h: &[f64], g_hh: f64, c: &[f64]) -> f64 {
    let gc = gram_times(g, c);
    let mut e = g_hh;
    for i in 0..g.nrows() {
        e += c[i] * (gc[i] - 2.0 * g_h[i]);
    }
    e
}

/// `G c` (length N), accumulated a column of `G` at a time (`gc += c_j G[:, j]`, j ascending):
/// each entry is the same products summed in the same order as the row-by-row dot product
/// `sum_j G_ij c_j` it replaces (no fused multiply-adds either way), so the same bits, but the
/// reads are contiguous (faer stores columns) and the N running sums independent, so the loop
/// vectorises instead of waiting on one chain of N^2 dependent additions: the latent search
/// evaluates this hundreds of times per target.
fn gram_times(g: MatRef<'_, f64>, c: &[f64]) -> Vec<f64> {
    let n = g.nrows();
    let mut gc = vec![0.0; n];
    for (j, &cj) in c.iter().enumerate().take(n) {
        let col = g.col(j);
        match col.try_as_col_major() {
            Some(col) => {
                for (s, &a) in gc.iter_mut().zip(col.as_slice()) {
                    *s += a * cj;
                }
            }
            None => {
                for (i, s) in gc.iter_mut().enumerate() {
                    *s += col[i] * cj;
                }
            }
        }
    }
    gc
}

/// The latent point where the smooth posterior mean of `gp` best reconstructs a material `y_h`
/// it was not trained on, and that point's squared error in the transformed space, from Gram
/// quantities only (`g`, `g_h`, `g_hh` as in [`sq_error_external`]; `points` are `gp`'s
/// training points, in `g`'s order).
///
/// Multi-start: of each kind, the `starts` candidates with the smallest error: training
/// points, midpoints of pairs of training points, points half a length-scale off a training
/// point along one axis, and quasi-random points of the region the training points span; each
/// refined by L-BFGS on the error and its analytic gradient ([`GpRegression::weights_vjp`]: two
/// solves a step). Until session 23 Hooke-Jeeves direct search refined the first three kinds
/// (one point off a training point); L-BFGS reaches the same minima (on the default model's
/// leave-one-out, all 51 errors equal or lower, by at most 9e-9 relative) in a fraction of the
/// time, and the added starts removed the rare misses that random cases found
/// (BENCHMARKS.md "predict").
pub fn best_latent_point(
    gp: &GpRegression,
    points: &[Vec<f64>],
    g: MatRef<'_, f64>,
    g_h: &[f64],
    g_hh: f64,
    starts: usize,
) -> Result<(Vec<f64>, f64)> {
    let n = points.len();
    if n == 0 || g.nrows() != n || g.ncols() != n || g_h.len() != n {
        return Err(Error::InvalidArgument {
            reason: format!(
                "best_latent_point: {n} points, a {}x{} Gram matrix and {} cross products",
                g.nrows(),
                g.ncols(),
                g_h.len()
            ),
        });
    }
    let q = gp.q();
    if let Some(k) = points.iter().position(|p| p.len() != q) {
        // (Each start's objective was infinite: "the objective is not finite at the starting
        // point", which did not say why.)
        return Err(Error::InvalidArgument {
            reason: format!(
                "best_latent_point: point {k} has {} coordinates; the GP's latent space has {q}",
                points[k].len()
            ),
        });
    }
    let objective = |x: &[f64]| -> f64 {
        gp.weights(x, gp_core::Predictor::Smooth)
            .map(|w| sq_error_expanded(g, g_h, g_hh, &weights_to_coefficients(&w)))
            .unwrap_or(f64::INFINITY)
    };
    let mut scored: Vec<(f64, usize)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| (objective(p), i))
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Also from the best midpoints of pairs of training points: the objective is multimodal
    // (one basin per stretch between materials), and a minimum between two materials that are
    // not among the best-scoring ones was missed. An audit located a smooth prediction made
    // between two materials (q = 1, N = 5) at another material's basin with 2.4 % error
    // instead of its own point; the training-point starts are kept, so no result gets worse.
    // Scored in one batch: N (N - 1) / 2 of them, 1225 per refit at N = 50, whose scoring one
    // by one took ~10 % of the CPU time of `evaluate --loo` on the default model (perf; ~1 %
    // batched).
    let mids: Vec<Vec<f64>> = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .map(|(i, j)| {
            points[i]
                .iter()
                .zip(&points[j])
                .map(|(a, b)| 0.5 * (a + b))
                .collect()
        })
        .collect();
    let starts = starts.max(1);
    let best_of = |candidates: &[Vec<f64>]| -> Vec<Vec<f64>> {
        let mut scored: Vec<(f64, usize)> =
            batch_objective(gp, g, g_h, g_hh, candidates, &objective)
                .into_iter()
                .enumerate()
                .map(|(i, v)| (v, i))
                .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0));
        scored
            .iter()
            .take(starts)
            .map(|&(_, i)| candidates[i].clone())
            .collect()
    };
    let mids = best_of(&mids);
    // And from the best points half a length-scale off a training point along one axis (of
    // 2 q N, scored in one batch). A training point can sit on the ridge between two basins,
    // one on each side of it, and a local search from it goes to one side (Hooke-Jeeves, which
    // refined the starts until session 23, to whichever its first trial step, +step before
    // -step, improved): a property test (its spec's seed
    // 10770280116901798891, N = 5, q = 1, log, RGB) had the prediction's own point (error 0) in
    // the basin on one side of the best-scoring material (2.6 there, in squared error) and the
    // search in the basin on the other side (0.65: RMSE 0.8 % of the target's size) with 1, 3
    // and 5 starts; the best midpoints' searches jumped the ridge the same way. Half a
    // length-scale off is inside the basin on each side. One such start until session 23,
    // `starts` since: in every miss of this kind seen (4 of 8 collected from random cases), the
    // best-scoring side was the one needed, and with one or with `starts` of them the same
    // 10,000 random cases had no miss (3 before). A start replaces the best only when strictly
    // better, so no result is worse than from the other starts alone.
    let sides: Vec<Vec<f64>> = points
        .iter()
        .flat_map(|p| {
            (0..q).flat_map(move |k| {
                let l = gp.params().length_scale().axis(k);
                [-0.5 * l, 0.5 * l].map(|dx| {
                    let mut x = p.clone();
                    x[k] += dx;
                    x
                })
            })
        })
        .collect();
    let sides = best_of(&sides);
    // And from the best quasi-random points of the region the materials span: a target's basin
    // can lie between all the starts above (seen in q = 2 with raw values, and beside a cluster
    // of near-duplicate materials in q = 1), and L-BFGS from a start does not leave its basin.
    // 32 q Halton points over the points' bounding box widened by half a length-scale, scored
    // in one batch: with them (and `starts` side points), 120,000 random cases of the property
    // test had no miss, against 3 in 100,000 from the session-22 starts (one side point, no
    // Halton points; BENCHMARKS.md "predict", session 23).
    let scatter = best_of(&halton_points(points, gp, 32 * q));
    let mut best = (scored[0].0, points[scored[0].1].clone());
    let from_points = scored.iter().take(starts).map(|&(_, i)| &points[i]);
    for x0 in from_points.chain(&mids).chain(&sides).chain(&scatter) {
        if let Some((v, x)) = refine_by_lbfgs(gp, g, g_h, g_hh, x0)
            && v < best.0
        {
            best = (v, x);
        }
    }
    Ok((best.1, best.0.max(0.0)))
}

/// `count` points of the Halton sequence (bases the first q primes) over the bounding box of
/// `points`, widened on each axis by half of `gp`'s length-scale along it.
fn halton_points(points: &[Vec<f64>], gp: &GpRegression, count: usize) -> Vec<Vec<f64>> {
    let q = gp.q();
    let mut primes: Vec<usize> = Vec::with_capacity(q);
    let mut p = 2;
    while primes.len() < q {
        if primes.iter().all(|d| p % d != 0) {
            primes.push(p);
        }
        p += 1;
    }
    let boxes: Vec<(f64, f64)> = (0..q)
        .map(|k| {
            let pad = 0.5 * gp.params().length_scale().axis(k);
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p[k]), hi.max(p[k]))
                });
            (lo - pad, hi + pad)
        })
        .collect();
    // The radical inverse of `i` in `base`: its digits mirrored behind the point.
    let radical_inverse = |mut i: usize, base: usize| {
        let (mut scale, mut r) = (1.0, 0.0);
        while i > 0 {
            scale /= base as f64;
            r += scale * (i % base) as f64;
            i /= base;
        }
        r
    };
    (1..=count)
        .map(|i| {
            boxes
                .iter()
                .zip(&primes)
                .map(|(&(lo, hi), &b)| lo + (hi - lo) * radical_inverse(i, b))
                .collect()
        })
        .collect()
}

/// The objective of [`best_latent_point`] and its gradient in the latent point: with
/// `c = weights_to_coefficients(w(x))` and `r = 2 (G c - g_h)`, `de/dw = r - mean(r)` (the
/// coefficients' shift), and `de/dx = (de/dw)^T dw/dx` by one adjoint solve
/// ([`GpRegression::weights_vjp`]).
fn objective_and_gradient(
    gp: &GpRegression,
    g: MatRef<'_, f64>,
    g_h: &[f64],
    g_hh: f64,
    x: &[f64],
) -> Result<(f64, Vec<f64>)> {
    let n = g.nrows();
    let c = weights_to_coefficients(&gp.weights(x, gp_core::Predictor::Smooth)?);
    let gc = gram_times(g, &c);
    // The same sum as `sq_error_expanded`, in the same order: the same bits.
    let mut e = g_hh;
    let mut r: Vec<f64> = Vec::with_capacity(n);
    for i in 0..n {
        e += c[i] * (gc[i] - 2.0 * g_h[i]);
        r.push(2.0 * (gc[i] - g_h[i]));
    }
    let mean = r.iter().sum::<f64>() / n as f64;
    r.iter_mut().for_each(|v| *v -= mean);
    let grad = gp.weights_vjp(x, &r)?;
    Ok((e, grad))
}

/// The local minimum of [`objective_and_gradient`] that L-BFGS reaches from `x0`, or `None`
/// when the error or its gradient is not finite there or cannot be computed (Hooke-Jeeves,
/// which refined the starts before, skipped such a start the same way). It stops when a step
/// changes the error by less than 1e-13 of the target's squared norm `g_hh` (the scale of the
/// error), after 200 steps, or when the line search finds no better point: the error is
/// smooth, so that is its minimum to rounding.
fn refine_by_lbfgs(
    gp: &GpRegression,
    g: MatRef<'_, f64>,
    g_h: &[f64],
    g_hh: f64,
    x0: &[f64],
) -> Option<(f64, Vec<f64>)> {
    let settings = LbfgsSettings {
        memory: 10,
        max_iterations: 200,
        gradient_tolerance: 0.0,
        cost_tolerance: 1e-13 * g_hh.abs().max(f64::MIN_POSITIVE),
        stall_gradient: f64::INFINITY,
    };
    let f = |x: &[f64]| {
        objective_and_gradient(gp, g, g_h, g_hh, x).map_err(|e| gplvm::Error::Objective {
            reason: e.to_string(),
        })
    };
    // `lbfgs` fails only at the start (an error there, or a value or gradient that is not
    // finite); past it, a failing step is one the line search backs off from.
    lbfgs(f, x0, &settings).ok().map(|m| (m.value, m.x))
}

/// The objective of [`best_latent_point`] (the smooth posterior mean's squared error against
/// `y_h`, [`sq_error_expanded`]) at every point of `candidates`, in one batch: the weights of
/// all of them from one triangular solve with many right-hand sides
/// ([`GpRegression::weights_batch`]), their coefficients `C` (N x M), `G C` by one matrix
/// product, then per column `g_hh + c . (G c - 2 g_h)`. The same formula as the one-point
/// objective (summed in another order: the scores agree to rounding, ~1e-16 of `g_hh`); they
/// only rank the starts, which the search then evaluates with `one`. Should the batch fail (a
/// point that is not finite), each candidate is scored with `one` instead, which maps failures
/// to infinity.
fn batch_objective(
    gp: &GpRegression,
    g: MatRef<'_, f64>,
    g_h: &[f64],
    g_hh: f64,
    candidates: &[Vec<f64>],
    one: &dyn Fn(&[f64]) -> f64,
) -> Vec<f64> {
    let (n, m, q) = (g.nrows(), candidates.len(), gp.q());
    if m == 0 {
        return Vec::new();
    }
    let xs = Mat::from_fn(m, q, |j, k| candidates[j][k]);
    let Ok(mut c) = gp.weights_batch(xs.as_ref(), gp_core::Predictor::Smooth, Par::Seq) else {
        return candidates.iter().map(|x| one(x)).collect();
    };
    // Weights on centred rows as coefficients on raw rows (`weights_to_coefficients`).
    for j in 0..m {
        let shift = (1.0 - (0..n).map(|i| c[(i, j)]).sum::<f64>()) / n as f64;
        for i in 0..n {
            c[(i, j)] += shift;
        }
    }
    let mut gc = Mat::<f64>::zeros(n, m);
    faer::linalg::matmul::matmul(
        gc.as_mut(),
        faer::Accum::Replace,
        g,
        c.as_ref(),
        1.0,
        Par::Seq,
    );
    (0..m)
        .map(|j| {
            let mut e = g_hh;
            for i in 0..n {
                e += c[(i, j)] * (gc[(i, j)] - 2.0 * g_h[i]);
            }
            e
        })
        .collect()
}

/// Leave-one-out for material `h` from the uncentred Gram matrix `g` (N x N) of data with
/// `d_eff` informative values per material, refitting with `config` (q = its latent dim).
///
/// The GP's latent point minimises the transformed-space error of the smooth posterior mean:
/// multi-start from the training points of the refit, midpoints of pairs of them, points half
/// a length-scale off them and quasi-random points of the region they span (`starts` of each,
/// those with the smallest error), each refined by L-BFGS ([`best_latent_point`]).
///
/// `warm`: the full model's latent points (N x q) and hyperparameters; the refit then starts
/// from them (minus row `h`) instead of the PCA start of [`gplvm::fit_gram`].
pub fn leave_one_out(
    g: MatRef<'_, f64>,
    d_eff: usize,
    config: &FitConfig,
    h: usize,
    starts: usize,
    warm: Option<(MatRef<'_, f64>, &KernelParams)>,
) -> Result<LooMaterial> {
    let n = g.nrows();
    if n < 3 || h >= n {
        return Err(Error::InvalidArgument {
            reason: format!(
                "leave-one-out needs at least 3 materials (the refit without one keeps >= 2) and a \
                 held-out index h < N; got N = {n}, h = {h}"
            ),
        });
    }
    let others = all_but(n, h);
    let n1 = others.len();
    let g_oo = subset_gram(g, &others)?;
    let fit = match warm {
        Some((x_full, params)) => {
            let x0 = Mat::from_fn(n1, x_full.ncols(), |i, k| x_full[(others[i], k)]);
            refit_warm(g_oo.as_ref(), d_eff, config, x0.as_ref(), params)?
        }
        None => {
            let f = fit_gram(g_oo.as_ref(), d_eff, config)?;
            Refit {
                x: f.x,
                params: f.params,
                log_likelihood: f.report.log_likelihood,
            }
        }
    };
    let gp = GpRegression::new(fit.x.as_ref(), fit.params.clone(), Par::Seq)?;
    let q = fit.x.ncols();
    let g_h: Vec<f64> = others.iter().map(|&j| g[(h, j)]).collect();
    let points: Vec<Vec<f64>> = (0..n1)
        .map(|i| (0..q).map(|k| fit.x[(i, k)]).collect())
        .collect();
    let (gp_point, _) = best_latent_point(&gp, &points, g_oo.as_ref(), &g_h, g[(h, h)], starts)?;
    let c_gp = weights_to_coefficients(&gp.weights(&gp_point, gp_core::Predictor::Smooth)?);
    let c_gp = embed(n, &others, &c_gp);

    // Nearest single material.
    let nearest = others
        .iter()
        .copied()
        .min_by(|&a, &b| {
            let ea = g[(a, a)] - 2.0 * g[(h, a)];
            let eb = g[(b, b)] - 2.0 * g[(h, b)];
            ea.total_cmp(&eb)
        })
        .ok_or_else(|| Error::InvalidArgument {
            reason: "no other material".into(),
        })?;
    let mut c_near = vec![0.0; n];
    c_near[nearest] = 1.0;

    // Linear interpolation between the two materials nearest to the GP's point.
    let mut by_dist: Vec<(f64, usize)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let d: f64 = p.iter().zip(&gp_point).map(|(a, b)| (a - b).powi(2)).sum();
            (d, others[i])
        })
        .collect();
    by_dist.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (i1, i2) = (by_dist[0].1, by_dist[1].1);
    let (a_lat, _) = best_lerp(g, h, i1, i2);
    let mut c_lat = vec![0.0; n];
    c_lat[i1] += a_lat;
    c_lat[i2] += 1.0 - a_lat;

    // Best pair overall.
    let mut bp = (f64::INFINITY, 0, 0, 0.0);
    for (x, &i) in others.iter().enumerate() {
        for &j in &others[x + 1..] {
            let (a, e) = best_lerp(g, h, i, j);
            if e < bp.0 {
                bp = (e, i, j, a);
            }
        }
    }
    let mut c_best = vec![0.0; n];
    c_best[bp.1] += bp.3;
    c_best[bp.2] += 1.0 - bp.3;

    // PCA with q components of the others, projecting y_h - m.
    let c_pca = embed(n, &others, &pca_projection(g, &others, h, q)?);

    let names = |i: usize| i.to_string();
    let methods = vec![
        (Method::Gp, c_gp, format!("x = {gp_point:?}")),
        (
            Method::Nearest,
            c_near,
            format!("material {}", names(nearest)),
        ),
        (
            Method::LerpLatent,
            c_lat,
            format!("materials {} and {}, a = {a_lat:.4}", names(i1), names(i2)),
        ),
        (
            Method::LerpBest,
            c_best,
            format!(
                "materials {} and {}, a = {:.4}",
                names(bp.1),
                names(bp.2),
                bp.3
            ),
        ),
        (Method::Pca, c_pca, format!("{q} components")),
    ]
    .into_iter()
    .map(|(method, coefficients, detail)| MethodResult {
        method,
        sq_error: sq_error(g, h, &coefficients),
        coefficients,
        detail,
    })
    .collect();
    Ok(LooMaterial {
        held_out: h,
        gp_point,
        refit_log_likelihood: fit.log_likelihood,
        methods,
    })
}

/// A refitted latent space.
#[derive(Debug, Clone)]
pub struct Refit {
    /// Latent points.
    pub x: Mat<f64>,
    /// Hyperparameters.
    pub params: KernelParams,
    /// Log-likelihood at the optimum.
    pub log_likelihood: f64,
}

/// Refits the GPLVM to the uncentred Gram matrix `g` starting from latent points `x0` and
/// hyperparameters `params` (warm start), with the optimiser and settings of `config` (the
/// same objective as [`gplvm::fit_gram`]: data scaled as configured, values per data value),
/// in one run: `config`'s restarts are not made.
pub fn refit_warm(
    g: MatRef<'_, f64>,
    d_eff: usize,
    config: &FitConfig,
    x0: MatRef<'_, f64>,
    params: &KernelParams,
) -> Result<Refit> {
    let p = &config.params;
    let (s, _) = gplvm::fit::scaled_centred_gram(g, d_eff, p.data_scaling)?;
    let n = s.nrows();
    let objective = GplvmObjective::new(s, d_eff)?.with_prior(p.prior);
    let flat = gplvm::fit::flat_objective(&objective, x0.ncols(), params.clone(), p)?;
    let theta0 = flat.pack(x0, params)?;
    let per_value = 1.0 / (n as f64 * d_eff as f64);
    let par = Par::Seq;
    let best = match p.optimizer {
        OptimizerKind::Lbfgs => lbfgs(
            |t| {
                let (v, mut gr) = flat.neg_log_likelihood_and_gradient(t, par)?;
                gr.iter_mut().for_each(|x| *x *= per_value);
                Ok((v * per_value, gr))
            },
            &theta0,
            &LbfgsSettings {
                max_iterations: p.max_iterations,
                gradient_tolerance: p.gradient_tolerance,
                cost_tolerance: p.cost_tolerance,
                ..LbfgsSettings::default()
            },
        )?,
        OptimizerKind::HookeJeeves => {
            gplvm::fit::minimise_by_hooke_jeeves(&flat, &theta0, p, per_value)?
        }
    };
    let (x, params) = flat.unpack(&best.x)?;
    Ok(Refit {
        x,
        params,
        log_likelihood: -best.value / per_value,
    })
}

/// Coefficients over `others` of the projection of `y_h` onto the mean plus the leading `q`
/// principal directions of the `others` rows: `y* = m + Y_c^T U Lambda^-1 U^T Y_c (y_h - m)`.
pub fn pca_projection(
    g: MatRef<'_, f64>,
    others: &[usize],
    h: usize,
    q: usize,
) -> Result<Vec<f64>> {
    let n1 = others.len();
    let g_oo = subset_gram(g, others)?;
    let s = centre_gram(g_oo.as_ref())?;
    let r: Vec<f64> = (0..n1)
        .map(|i| (0..n1).map(|j| g_oo[(i, j)]).sum::<f64>() / n1 as f64)
        .collect();
    let t = r.iter().sum::<f64>() / n1 as f64;
    let mh = others.iter().map(|&j| g[(h, j)]).sum::<f64>() / n1 as f64;
    // s_h[j] = <y_j - m, y_h - m>.
    let s_h: Vec<f64> = (0..n1).map(|j| g[(others[j], h)] - r[j] - mh + t).collect();
    let eig = s
        .self_adjoint_eigen(Side::Lower)
        .map_err(|e| Error::InvalidArgument {
            reason: format!("PCA eigen-decomposition failed: {e:?}"),
        })?;
    let vals = eig.S().column_vector();
    let u = eig.U();
    let top = vals[n1 - 1].max(0.0);
    let mut beta = vec![0.0; n1];
    for k in 0..q.min(n1) {
        let col = n1 - 1 - k;
        let lambda = vals[col];
        if lambda.is_nan() || lambda <= 1e-12 * top {
            continue;
        }
        let proj: f64 = (0..n1).map(|i| u[(i, col)] * s_h[i]).sum::<f64>() / lambda;
        for (i, b) in beta.iter_mut().enumerate() {
            *b += u[(i, col)] * proj;
        }
    }
    Ok(weights_to_coefficients(&beta))
}

/// Eq. 22 RMSE in BRDF space of `M` linear predictors (rows of `coef`, `M x N`) against their
/// target materials `targets` (length M), in one parallel streaming pass over `store`:
/// `sqrt(sum_d (f_target[d] - inverse(sum_j c_j forward(f_j[d])))^2 / n_angles)`.
/// `progress(done, total)` counts chunks.
pub fn brdf_space_rmse(
    store: &Store,
    transform: Transform,
    targets: &[usize],
    coef: MatRef<'_, f64>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<f64>> {
    let n = store.n_materials();
    let m = coef.nrows();
    if coef.ncols() != n || targets.len() != m || targets.iter().any(|&t| t >= n) {
        return Err(Error::InvalidArgument {
            reason: format!(
                "coefficient matrix {}x{} and {} targets for {n} materials",
                m,
                coef.ncols(),
                targets.len()
            ),
        });
    }
    let target_values = |_d: usize, row: &[f32], out: &mut [f32]| {
        for (o, &t) in out.iter_mut().zip(targets) {
            *o = row[t];
        }
    };
    let target_name = |r: usize| format!("material {:?}", store.names()[targets[r]]);
    let sums = rmse_pass(
        store,
        transform,
        coef,
        &target_values,
        &target_name,
        false,
        progress,
    )?;
    let n_angles = store.grid().len() as f64;
    Ok(sums
        .into_iter()
        .map(|(s, _)| (s / n_angles).sqrt())
        .collect())
}

/// The columns of a chunk covering the indices `range` whose cells are above the horizon
/// (`mask` over cells, `nc` channels per cell), relative to the chunk, into `cols`.
pub(crate) fn valid_columns(range: Range<usize>, mask: &[bool], nc: usize, cols: &mut Vec<usize>) {
    cols.clear();
    cols.extend(
        range
            .clone()
            .filter(|d| mask[d / nc])
            .map(|d| d - range.start),
    );
}

/// The valid columns `cols` (ascending, relative to the chunk) of an index-major chunk
/// `block` (`n` values per column), transformed as the Gram pass does (`forward_batch`,
/// vectorised, one run of consecutive columns at a time) into `t` (column-major, `n` x
/// `cols.len()`).
pub(crate) fn forward_columns(
    transform: Transform,
    block: &[f32],
    n: usize,
    cols: &[usize],
    t: &mut Vec<f64>,
) {
    t.clear();
    t.resize(cols.len() * n, 0.0);
    for (k, e) in column_runs(cols) {
        let (a, b) = (cols[k], cols[e - 1] + 1);
        transform.forward_batch(&block[a * n..b * n], &mut t[k * n..e * n]);
    }
}

/// The maximal runs `(start, end)` of consecutive values in the ascending `cols` (positions
/// into `cols`, end exclusive).
pub(crate) fn column_runs(cols: &[usize]) -> impl Iterator<Item = (usize, usize)> + '_ {
    let mut k = 0;
    std::iter::from_fn(move || {
        if k >= cols.len() {
            return None;
        }
        let start = k;
        k += 1;
        while k < cols.len() && cols[k] == cols[k - 1] + 1 {
            k += 1;
        }
        Some((start, k))
    })
}

/// Writes the target values of an error pass's rows at one index: `(d, stored, out)`.
pub(crate) type TargetValues<'a> = dyn Fn(usize, &[f32], &mut [f32]) + Sync + 'a;

/// Columns (valid indices) per product and sums of [`rmse_pass`]: with 7 x 51 rows, 512
/// columns of predictions are 1.4 MB.
const PASS_COLUMNS: usize = 512;

/// The squared-error sums behind the Eq. 22 RMSEs of the `M` linear predictors in `coef`
/// (`M x N`) over `store`'s valid cells: per row, in BRDF space and (with `model_space`, else
/// 0) in the transformed space. `target(d, row, out)` writes the M rows' target values at
/// index `d` into `out` (`row`: the N stored values there); `target_name(r)` names row `r`'s
/// target in errors.
pub(crate) fn rmse_pass(
    store: &Store,
    transform: Transform,
    coef: MatRef<'_, f64>,
    target: &TargetValues<'_>,
    target_name: &dyn Fn(usize) -> String,
    model_space: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<(f64, f64)>> {
    let n = store.n_materials();
    let m = coef.nrows();
    let nc = store.channels().len();
    let mask = store.validity_mask();
    let done = AtomicUsize::new(0);
    let total = store.n_chunks();
    // Per worker: the sums, then scratch (valid columns, transformed values, predictions,
    // target values and their transforms).
    type Scratch = (Vec<usize>, Vec<f64>, Vec<f64>, Vec<f32>, Vec<f64>);
    let sums = store.par_fold_chunks(
        || (vec![(0.0f64, 0.0f64); m], Scratch::default()),
        |(acc, (cols, t, p, ft, fy)), range, block| {
            // Valid columns only: below-horizon cells are 0 in every material and prediction.
            valid_columns(range.clone(), mask, nc, cols);
            forward_columns(transform, block, n, cols, t);
            // Predictions and targets of up to PASS_COLUMNS columns at a time, column-major
            // (rows x columns): they stay in the cache between the product and the sums, and
            // the scratch stays small (a whole chunk's took fresh pages from the kernel for
            // every rayon split: a fifth of the pass in a profile).
            for (block_cols, tb) in cols
                .chunks(PASS_COLUMNS)
                .zip(t.chunks(PASS_COLUMNS * n.max(1)))
            {
                let len = block_cols.len();
                let tm = MatRef::from_column_major_slice(tb, n, len);
                p.clear();
                p.resize(m * len, 0.0);
                faer::linalg::matmul::matmul(
                    MatMut::from_column_major_slice_mut(p, m, len),
                    faer::Accum::Replace,
                    coef,
                    tm,
                    1.0,
                    Par::Seq,
                );
                ft.clear();
                ft.resize(m * len, 0.0);
                for (&j, out) in block_cols.iter().zip(ft.chunks_exact_mut(m)) {
                    target(range.start + j, &block[j * n..(j + 1) * n], out);
                }
                // Column by column (the rows' sums in the same order as entry by entry, without
                // an integer division per entry to find its row).
                if model_space {
                    fy.clear();
                    fy.resize(ft.len(), 0.0);
                    transform.forward_batch(ft, fy);
                    for (ys, qs) in fy.chunks_exact(m).zip(p.chunks_exact(m)) {
                        for ((a, y), q) in acc.iter_mut().zip(ys).zip(qs) {
                            a.1 += (y - q) * (y - q);
                        }
                    }
                }
                transform.inverse_in_place(p);
                for (fs, qs) in ft.chunks_exact(m).zip(p.chunks_exact(m)) {
                    for ((a, f), q) in acc.iter_mut().zip(fs).zip(qs) {
                        let diff = f64::from(*f) - q;
                        a.0 += diff * diff;
                    }
                }
            }
            let k = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(k, total);
        },
        |(mut a, scratch), (b, _)| {
            a.iter_mut().zip(b).for_each(|(x, y)| {
                x.0 += y.0;
                x.1 += y.1;
            });
            (a, scratch)
        },
    )?;
    if let Some(r) = sums
        .0
        .iter()
        .position(|s| !(s.0.is_finite() && s.1.is_finite()))
    {
        // The error path only: blame a stored value, if one is not finite.
        return Err(match damaged_value(store)? {
            Some(e) => e,
            None => Error::NonFiniteValue {
                what: format!(
                    "the squared BRDF-space error of {} in {}",
                    target_name(r),
                    store.path().display()
                ),
                value: if sums.0[r].0.is_finite() {
                    sums.0[r].1
                } else {
                    sums.0[r].0
                },
                cause: "every stored value is finite (checked), so the error overflowed: a \
                        prediction far outside the training materials, or values too large for \
                        f64 squares"
                    .into(),
            },
        });
    }
    Ok(sums.0)
}

/// The error naming the first NaN or infinite value stored in `store`, if it holds one (an
/// error path: a second pass over the data).
pub(crate) fn damaged_value(store: &Store) -> Result<Option<Error>> {
    let n = store.n_materials();
    let mut first_bad: Option<(usize, usize, f32)> = None;
    store.for_each_chunk(|range, block| {
        if first_bad.is_none()
            && let Some(k) = block.iter().position(|v| !v.is_finite())
        {
            first_bad = Some((range.start + k / n, k % n, block[k]));
        }
    })?;
    Ok(first_bad.map(|(d, material, value)| {
        Error::Store(brdf_io::Error::DamagedValue {
            path: store.path().to_owned(),
            material: store.names()[material].to_owned(),
            index: d,
            value,
        })
    }))
}

/// Options of [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalOptions {
    /// Run leave-one-out over every material (refits) and the baselines.
    pub loo: bool,
    /// Starting points of the GP's latent search per held-out material, of each kind
    /// ([`best_latent_point`]: training points, midpoints, side points, quasi-random points).
    pub starts: usize,
    /// Warm-start the refits from the full model's latent points (otherwise: PCA start, as a
    /// fresh fit).
    pub warm_start: bool,
    /// Cap on the optimiser iterations of each leave-one-out refit (L-BFGS iterations;
    /// Hooke-Jeeves at most `cap * 2 N q` evaluations, N the model's materials), applied only
    /// where the model's fit configuration allows more; `None` uses that configuration.
    pub refit_iterations: Option<u64>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            loo: false,
            starts: 3,
            warm_start: true,
            refit_iterations: Some(200),
        }
    }
}

/// Reconstruction errors of one training material (Eq. 22 normalisation).
#[derive(Debug, Clone, Serialize)]
pub struct ReconstructionRow {
    /// Material name.
    pub name: String,
    /// Exact predictor at its own latent point, BRDF space.
    pub exact_rmse: f64,
    /// Smooth predictor at its own latent point, BRDF space.
    pub smooth_rmse: f64,
    /// Exact predictor, transformed space (from the Gram matrix).
    pub exact_model_rmse: f64,
    /// Smooth predictor, transformed space (from the Gram matrix).
    pub smooth_model_rmse: f64,
}

/// One method's leave-one-out errors for one material.
#[derive(Debug, Clone, Serialize)]
pub struct LooEntry {
    /// The method.
    pub method: Method,
    /// Eq. 22 RMSE in the transformed space (from the Gram matrix).
    pub model_rmse: f64,
    /// Eq. 22 RMSE in BRDF space.
    pub brdf_rmse: f64,
    /// What was chosen.
    pub detail: String,
}

/// Leave-one-out errors of one material.
#[derive(Debug, Clone, Serialize)]
pub struct LooRow {
    /// Material name.
    pub name: String,
    /// The GP's latent point in the refit.
    pub gp_point: Vec<f64>,
    /// Per method, in [`Method::ALL`] order.
    pub methods: Vec<LooEntry>,
    /// The GP's prediction of the held-out material as coefficients over all N materials
    /// (0 at the held-out one; [`crate::Predictor::from_coefficients`] makes it a material).
    /// Not serialised (N x N numbers).
    #[serde(skip)]
    pub gp_coefficients: Vec<f64>,
}

/// Mean and median of one column of errors.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// `reconstruction-exact`, `reconstruction-smooth` or `loo-<method>`.
    pub method: String,
    /// Mean Eq. 22 RMSE in BRDF space.
    pub brdf_mean: f64,
    /// Median Eq. 22 RMSE in BRDF space.
    pub brdf_median: f64,
    /// Mean Eq. 22 RMSE in the transformed space.
    pub model_mean: f64,
    /// Median Eq. 22 RMSE in the transformed space.
    pub model_median: f64,
    /// For leave-one-out baselines: materials where the GP's BRDF-space error is lower.
    pub gp_better: Option<usize>,
}

/// The result of [`evaluate`].
#[derive(Debug, Clone, Serialize)]
pub struct Evaluation {
    /// The dataset store.
    pub dataset: String,
    /// The model's transform.
    pub transform: String,
    /// Latent dimension q.
    pub latent_dim: usize,
    /// Materials N.
    pub n_materials: usize,
    /// Angular cells n_th n_td n_pd (the Eq. 22 divisor).
    pub n_angles: usize,
    /// Per training material.
    pub reconstruction: Vec<ReconstructionRow>,
    /// Leave-one-out per material (with `--loo`).
    pub loo: Option<Vec<LooRow>>,
    /// Mean and median per method.
    pub summary: Vec<Summary>,
    /// Seconds spent refitting and searching (leave-one-out, from the Gram matrix).
    pub loo_seconds: f64,
    /// Seconds of the streaming pass.
    pub pass_seconds: f64,
}

fn mean_median(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let k = s.len();
    let median = if k % 2 == 1 {
        s[k / 2]
    } else {
        0.5 * (s[k / 2 - 1] + s[k / 2])
    };
    (mean, median)
}

/// Stages reported to the progress callback of [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Leave-one-out refits (count: materials).
    Refits,
    /// The streaming pass (count: chunks).
    Pass,
}

/// Reconstruction errors of every training material and, with `options.loo`, leave-one-out
/// errors of the GP and the baselines; BRDF-space errors of everything from one pass.
pub fn evaluate(
    pred: &Predictor,
    options: &EvalOptions,
    progress: &(dyn Fn(Stage, usize, usize) + Sync),
) -> Result<Evaluation> {
    let model = pred.model();
    let g = model.gram_matrix();
    let n = pred.n_materials();
    let n_angles = pred.grid().len();
    let to_rmse = |sq: f64| (sq / n_angles as f64).sqrt();

    let mut rows: Vec<Vec<f64>> = Vec::new();
    let mut targets = Vec::new();
    let mut recon_model = Vec::new();
    for i in 0..n {
        let x = &model.materials[i].coords;
        let ce = pred.coefficients(x, PredictorKind::Exact)?;
        let cs = pred.coefficients(x, PredictorKind::Smooth)?;
        recon_model.push((
            to_rmse(sq_error(g.as_ref(), i, &ce)),
            to_rmse(sq_error(g.as_ref(), i, &cs)),
        ));
        rows.push(ce);
        rows.push(cs);
        targets.extend([i, i]);
    }

    let t0 = Instant::now();
    let loo = if options.loo {
        // Named: the configuration is read from the model file.
        let mut config = model.fit_config(pred.model_path())?;
        if let Some(cap) = options.refit_iterations {
            let p = &mut config.params;
            p.max_iterations = p.max_iterations.min(cap);
            // Saturating: a cap beyond any budget means the configuration's own (it wrapped
            // to a handful of evaluations, or panicked in debug builds, for caps >= 2^63).
            let evals = usize::try_from(cap)
                .unwrap_or(usize::MAX)
                .saturating_mul((2 * n).saturating_mul(model.latent_dim));
            p.max_evaluations = p.max_evaluations.min(evals);
        }
        let done = AtomicUsize::new(0);
        let d_eff = model.dataset.d_effective;
        let x_full = model.latent_matrix();
        let params = crate::predictor::kernel_params(model)?;
        let res: Vec<LooMaterial> = (0..n)
            .into_par_iter()
            .map(|h| {
                // A refit's warnings (a fit at its cap) name the material held out; WARN level,
                // so that the span shows whenever its warnings do.
                let name = &model.materials[h].name;
                let _span = tracing::warn_span!("leave-one-out", held_out = %name).entered();
                let warm = options.warm_start.then(|| (x_full.as_ref(), &params));
                // Named: the refit's own message counts the N - 1 materials it was given.
                let r = leave_one_out(g.as_ref(), d_eff, &config, h, options.starts, warm).map_err(
                    |e| Error::LeaveOneOut {
                        index: h,
                        name: model.materials[h].name.clone(),
                        cause: Box::new(e),
                    },
                );
                progress(Stage::Refits, done.fetch_add(1, Ordering::Relaxed) + 1, n);
                r
            })
            .collect::<Result<_>>()?;
        for r in &res {
            for m in &r.methods {
                rows.push(m.coefficients.clone());
                targets.push(r.held_out);
            }
        }
        Some(res)
    } else {
        None
    };
    let loo_seconds = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let coef = Mat::from_fn(rows.len(), n, |r, j| rows[r][j]);
    let brdf = brdf_space_rmse(
        pred.store(),
        pred.transform(),
        &targets,
        coef.as_ref(),
        &|k, t| progress(Stage::Pass, k, t),
    )?;
    let pass_seconds = t1.elapsed().as_secs_f64();

    let reconstruction: Vec<ReconstructionRow> = (0..n)
        .map(|i| ReconstructionRow {
            name: model.materials[i].name.clone(),
            exact_rmse: brdf[2 * i],
            smooth_rmse: brdf[2 * i + 1],
            exact_model_rmse: recon_model[i].0,
            smooth_model_rmse: recon_model[i].1,
        })
        .collect();
    let mut summary = Vec::new();
    let col = |f: &dyn Fn(&ReconstructionRow) -> f64| -> Vec<f64> {
        reconstruction.iter().map(f).collect()
    };
    for (name, b, m) in [
        (
            "reconstruction-exact",
            col(&|r| r.exact_rmse),
            col(&|r| r.exact_model_rmse),
        ),
        (
            "reconstruction-smooth",
            col(&|r| r.smooth_rmse),
            col(&|r| r.smooth_model_rmse),
        ),
    ] {
        let (bm, bmed) = mean_median(&b);
        let (mm, mmed) = mean_median(&m);
        summary.push(Summary {
            method: name.into(),
            brdf_mean: bm,
            brdf_median: bmed,
            model_mean: mm,
            model_median: mmed,
            gp_better: None,
        });
    }
    let loo_rows = loo.map(|res| {
        let k = Method::ALL.len();
        res.iter()
            .enumerate()
            .map(|(r, l)| LooRow {
                name: model.materials[l.held_out].name.clone(),
                gp_point: l.gp_point.clone(),
                methods: l
                    .methods
                    .iter()
                    .enumerate()
                    .map(|(mi, m)| LooEntry {
                        method: m.method,
                        model_rmse: to_rmse(m.sq_error),
                        brdf_rmse: brdf[2 * n + r * k + mi],
                        detail: m.detail.clone(),
                    })
                    .collect(),
                gp_coefficients: l
                    .methods
                    .iter()
                    .find(|m| m.method == Method::Gp)
                    .map(|m| m.coefficients.clone())
                    .unwrap_or_default(),
            })
            .collect::<Vec<_>>()
    });
    if let Some(rows) = &loo_rows {
        for (mi, method) in Method::ALL.iter().enumerate() {
            let b: Vec<f64> = rows.iter().map(|r| r.methods[mi].brdf_rmse).collect();
            let m: Vec<f64> = rows.iter().map(|r| r.methods[mi].model_rmse).collect();
            let (bm, bmed) = mean_median(&b);
            let (mm, mmed) = mean_median(&m);
            let gp_better = (*method != Method::Gp).then(|| {
                rows.iter()
                    .filter(|r| r.methods[0].brdf_rmse < r.methods[mi].brdf_rmse)
                    .count()
            });
            summary.push(Summary {
                method: format!("loo-{}", method.name()),
                brdf_mean: bm,
                brdf_median: bmed,
                model_mean: mm,
                model_median: mmed,
                gp_better,
            });
        }
    }
    Ok(Evaluation {
        dataset: pred.store().path().display().to_string(),
        transform: pred.transform().to_string(),
        latent_dim: pred.latent_dim(),
        n_materials: n,
        n_angles,
        reconstruction,
        loo: loo_rows,
        summary,
        loo_seconds,
        pass_seconds,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The methods' names are the ones reports, JSON and configs use, in report order.
    #[test]
    fn method_names_are_the_reported_ones() {
        assert_eq!(
            Method::ALL.map(Method::name),
            ["gp", "nearest", "lerp-latent", "lerp-best", "pca"]
        );
    }

    /// The row-by-row form `sq_error_expanded` had before it read `G` by columns.
    fn sq_error_by_rows(g: MatRef<'_, f64>, g_h: &[f64], g_hh: f64, c: &[f64]) -> f64 {
        let n = g.nrows();
        let mut e = g_hh;
        for i in 0..n {
            let mut gi = 0.0;
            for j in 0..n {
                gi += g[(i, j)] * c[j];
            }
            e += c[i] * (gi - 2.0 * g_h[i]);
        }
        e
    }

    /// A random Gram matrix of `n` rows of `d` values, a target's cross products and norm.
    fn gram_case(rng: &mut impl Rng, n: usize, d: usize) -> (Mat<f64>, Vec<f64>, f64) {
        let y = Mat::from_fn(n + 1, d, |_, _| rng.random_range(-3.0..3.0f64).exp());
        let g = Mat::from_fn(n, n, |i, j| (0..d).map(|k| y[(i, k)] * y[(j, k)]).sum());
        let g_h = (0..n)
            .map(|i| (0..d).map(|k| y[(i, k)] * y[(n, k)]).sum())
            .collect();
        let g_hh = (0..d).map(|k| y[(n, k)] * y[(n, k)]).sum();
        (g, g_h, g_hh)
    }

    /// A GP on the latent points `x` (rows), signal variance 1, noise 1e-4.
    fn gp_on(x: MatRef<'_, f64>, length_scale: gp_core::LengthScale) -> GpRegression {
        let params = gp_core::KernelParamsUnchecked {
            signal_variance: 1.0,
            length_scale,
            noise: 1e-4,
        }
        .check()
        .unwrap();
        GpRegression::new(x, params, Par::Seq).unwrap()
    }

    /// The one-point objective of `best_latent_point` at `p`: the smooth prediction's squared
    /// error against the target.
    fn point_error(
        gp: &GpRegression,
        g: MatRef<'_, f64>,
        g_h: &[f64],
        g_hh: f64,
        p: &[f64],
    ) -> f64 {
        let w = gp.weights(p, gp_core::Predictor::Smooth).unwrap();
        sq_error_expanded(g, g_h, g_hh, &weights_to_coefficients(&w))
    }

    #[test]
    fn the_column_wise_error_has_the_bits_of_the_row_wise_one() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for n in [1, 2, 3, 7, 16, 50, 101] {
            let (g, g_h, g_hh) = gram_case(&mut rng, n, 40);
            for _ in 0..20 {
                let c: Vec<f64> = (0..n).map(|_| rng.random_range(-1.5..1.5)).collect();
                let a = sq_error_expanded(g.as_ref(), &g_h, g_hh, &c);
                let b = sq_error_by_rows(g.as_ref(), &g_h, g_hh, &c);
                assert_eq!(a.to_bits(), b.to_bits(), "n = {n}: {a:e} vs {b:e}");
            }
            // A strided view (a transposed copy) takes the other branch, to the same bits.
            let gt = g.transpose().to_owned();
            let c: Vec<f64> = (0..n).map(|_| rng.random_range(-1.5..1.5)).collect();
            let a = sq_error_expanded(gt.transpose(), &g_h, g_hh, &c);
            let b = sq_error_by_rows(g.as_ref(), &g_h, g_hh, &c);
            assert_eq!(a.to_bits(), b.to_bits());
        }
    }

    #[test]
    fn batch_scores_agree_with_the_one_point_objective() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (n, q) in [(3, 1), (12, 2), (40, 5)] {
            let (g, g_h, g_hh) = gram_case(&mut rng, n, 30);
            let x = Mat::from_fn(n, q, |_, _| rng.random_range(-2.0..2.0));
            let gp = gp_on(x.as_ref(), gp_core::LengthScale::Isotropic(1.0));
            let one = |p: &[f64]| point_error(&gp, g.as_ref(), &g_h, g_hh, p);
            let candidates: Vec<Vec<f64>> = (0..25)
                .map(|_| (0..q).map(|_| rng.random_range(-3.0..3.0)).collect())
                .collect();
            let batch = batch_objective(&gp, g.as_ref(), &g_h, g_hh, &candidates, &one);
            for (p, b) in candidates.iter().zip(batch) {
                let a = one(p);
                assert!((a - b).abs() <= 1e-12 * g_hh, "{p:?}: {a:e} vs {b:e}");
            }
            assert!(batch_objective(&gp, g.as_ref(), &g_h, g_hh, &[], &one).is_empty());
        }
    }

    /// `objective_and_gradient`: the error is the one-point objective's, to the bit, and the
    /// gradient matches central differences of it (step 1e-5 on each axis) to 1e-5 of its
    /// largest component, isotropic and ARD.
    #[test]
    fn objective_gradient_matches_central_differences() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
        let mut worst = 0.0f64;
        for (n, q) in [(5, 1), (12, 2), (20, 3)] {
            let (g, g_h, g_hh) = gram_case(&mut rng, n, 30);
            let x = Mat::from_fn(n, q, |_, _| rng.random_range(-2.0..2.0));
            let ls = (0..q).map(|k| 0.7 + 0.3 * k as f64).collect();
            for gp in [
                gp_on(x.as_ref(), gp_core::LengthScale::Isotropic(0.9)),
                gp_on(x.as_ref(), gp_core::LengthScale::Ard(ls)),
            ] {
                let value = |p: &[f64]| point_error(&gp, g.as_ref(), &g_h, g_hh, p);
                for _ in 0..5 {
                    let p: Vec<f64> = (0..q).map(|_| rng.random_range(-2.0..2.0)).collect();
                    let (e, grad) =
                        objective_and_gradient(&gp, g.as_ref(), &g_h, g_hh, &p).unwrap();
                    assert_eq!(e.to_bits(), value(&p).to_bits());
                    let size = grad.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    for k in 0..q {
                        let at = |dx: f64| {
                            let mut y = p.clone();
                            y[k] += dx;
                            value(&y)
                        };
                        let fd = (at(1e-5) - at(-1e-5)) / 2e-5;
                        let err = (fd - grad[k]).abs() / size;
                        worst = worst.max(err);
                        assert!(
                            err < 1e-5,
                            "n {n}, q {q}, {p:?}, axis {k}: {fd} vs {}",
                            grad[k]
                        );
                    }
                }
            }
        }
        // Measured: 4.9e-9 at worst.
        assert!(worst > 0.0, "no differences compared");
    }

    /// The summary's mean and median of a column: the mean, and the middle value of the sorted
    /// column, or the mean of the two middle ones for an even count (unsorted input, values
    /// chosen so that every other order statistic or combination differs); NaN for none.
    #[test]
    fn mean_median_takes_the_middle_of_the_sorted_column() {
        assert_eq!(mean_median(&[9.0, 2.0, 7.0, 1.0, 4.0]), (4.6, 4.0));
        assert_eq!(mean_median(&[8.0, 1.0, 20.0, 3.0]), (8.0, 5.5));
        assert_eq!(mean_median(&[2.5]), (2.5, 2.5));
        let (mean, median) = mean_median(&[]);
        assert!(mean.is_nan() && median.is_nan());
    }

    /// `best_lerp` between two identical materials (the same file imported twice: `y_i - y_j`
    /// is 0, so every `a` gives the same blend) takes `a = 0.5` and the error of either one
    /// against the target, exactly; not `0 / 0`, a NaN coefficient with its error clamped to 0.
    #[test]
    fn best_lerp_between_identical_materials_is_their_midpoint() {
        // y0 = y1; the target y3 is |y3 - y0|^2 = 1 + 2.25 away from them (all exact in f64).
        let y = [[1.0, 2.0], [1.0, 2.0], [3.0, -1.0], [2.0, 0.5]];
        let g = Mat::from_fn(4, 4, |i, j| y[i][0] * y[j][0] + y[i][1] * y[j][1]);
        assert_eq!(best_lerp(g.as_ref(), 3, 0, 1), (0.5, 3.25));
    }

    /// `halton_points`: point i (from 1) has coordinate k at `lo_k + (hi_k - lo_k) phi_p(i)`,
    /// `phi_p` the radical inverse in the k-th prime base p (2, 3, 5) and `[lo_k, hi_k]` the
    /// points' range along axis k widened on both sides by half that axis's length-scale (ARD:
    /// three different ones). The radical inverses are written out as fractions.
    #[test]
    fn halton_points_fill_the_widened_box_in_prime_bases() {
        let rows = [
            [0.5, -1.0, 2.0],
            [1.5, 3.0, 2.5],
            [-0.5, 0.0, 4.0],
            [1.0, 1.0, 3.0],
        ];
        let x = Mat::from_fn(4, 3, |i, k| rows[i][k]);
        let gp = gp_on(x.as_ref(), gp_core::LengthScale::Ard(vec![0.8, 2.0, 0.4]));
        let points: Vec<Vec<f64>> = rows.iter().map(|r| r.to_vec()).collect();
        // Ranges [-0.5, 1.5], [-1, 3], [2, 4], widened by 0.4, 1 and 0.2.
        let boxes = [(-0.9, 1.9), (-2.0, 4.0), (1.8, 4.2)];
        // phi_2, phi_3, phi_5 of 1..=7 (e.g. 6 = 110 in base 2: 0/2 + 1/4 + 1/8).
        let phi = [
            [
                1.0 / 2.0,
                1.0 / 4.0,
                3.0 / 4.0,
                1.0 / 8.0,
                5.0 / 8.0,
                3.0 / 8.0,
                7.0 / 8.0,
            ],
            [
                1.0 / 3.0,
                2.0 / 3.0,
                1.0 / 9.0,
                4.0 / 9.0,
                7.0 / 9.0,
                2.0 / 9.0,
                5.0 / 9.0,
            ],
            [
                1.0 / 5.0,
                2.0 / 5.0,
                3.0 / 5.0,
                4.0 / 5.0,
                1.0 / 25.0,
                6.0 / 25.0,
                11.0 / 25.0,
            ],
        ];
        let got = halton_points(&points, &gp, 7);
        assert_eq!(got.len(), 7);
        for (i, p) in got.iter().enumerate() {
            assert_eq!(p.len(), 3);
            for (k, &(lo, hi)) in boxes.iter().enumerate() {
                let want = lo + (hi - lo) * phi[k][i];
                assert!(
                    (p[k] - want).abs() <= 1e-14 * (hi - lo),
                    "point {}, axis {k}: {} vs {want}",
                    i + 1,
                    p[k]
                );
            }
        }
    }

    /// `best_latent_point` refuses each shape mismatch alone (no points, a Gram matrix with a
    /// row or a column more than the points, one cross product fewer), with the shapes in the
    /// message, where the search would index out of bounds, read past the matrix or search
    /// nothing; the same call with matching shapes succeeds.
    #[test]
    fn best_latent_point_refuses_inputs_of_other_shapes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (g, g_h, g_hh) = gram_case(&mut rng, 4, 10);
        let x = Mat::from_fn(4, 1, |i, _| i as f64);
        let gp = gp_on(x.as_ref(), gp_core::LengthScale::Isotropic(1.0));
        let points: Vec<Vec<f64>> = (0..4).map(|i| vec![i as f64]).collect();
        let pad = |r: usize, c: usize| {
            Mat::from_fn(r, c, |i, j| if i < 4 && j < 4 { g[(i, j)] } else { 1.0 })
        };
        let (empty, taller, wider) = (Mat::<f64>::zeros(0, 0), pad(5, 4), pad(4, 5));
        for (pts, gm, gh) in [
            (&points[..0], empty.as_ref(), &g_h[..0]),
            (&points[..], taller.as_ref(), &g_h[..]),
            (&points[..], wider.as_ref(), &g_h[..]),
            (&points[..], g.as_ref(), &g_h[..3]),
        ] {
            let e = best_latent_point(&gp, pts, gm, gh, g_hh, 2)
                .unwrap_err()
                .to_string();
            let want = format!(
                "best_latent_point: {} points, a {}x{} Gram matrix and {} cross products",
                pts.len(),
                gm.nrows(),
                gm.ncols(),
                gh.len()
            );
            assert!(e.contains(&want), "{e}");
        }
        let (x, e) = best_latent_point(&gp, &points, g.as_ref(), &g_h, g_hh, 2).unwrap();
        assert!(x.len() == 1 && e.is_finite(), "{x:?} {e}");
    }

    /// `valid_columns`: the indices of `range` (relative to its start) whose cell `d / nc` is
    /// above the horizon, over a range starting mid-cell and a mask whose first cells differ
    /// from later ones (so that `d % nc` or the absolute index would pick others).
    #[test]
    fn valid_columns_keep_the_indices_of_cells_above_the_horizon() {
        let mask = [true, false, true, true, false, false, true];
        let mut cols = vec![99];
        valid_columns(4..20, &mask, 3, &mut cols);
        // Cells of 4..20 with 3 channels: 1 (4, 5), 2 (6..9), 3 (9..12), 4, 5, 6 (18, 19).
        let want: Vec<usize> = [6, 7, 8, 9, 10, 11, 18, 19].iter().map(|d| d - 4).collect();
        assert_eq!(cols, want);
    }

    /// `column_runs` splits ascending columns into maximal runs of consecutive values
    /// (positions into the columns, end exclusive), written out by hand: a gap of one column
    /// or more ends a run, a run can end at the last column, and no columns give no runs.
    #[test]
    fn column_runs_are_the_maximal_runs_of_consecutive_columns() {
        let runs = |cols: &[usize]| column_runs(cols).collect::<Vec<_>>();
        assert_eq!(runs(&[]), vec![]);
        assert_eq!(runs(&[5]), vec![(0, 1)]);
        assert_eq!(runs(&[3, 4]), vec![(0, 2)]);
        // 0 1 2 | 5 | 7 8 | 10 11 12 13
        assert_eq!(
            runs(&[0, 1, 2, 5, 7, 8, 10, 11, 12, 13]),
            vec![(0, 3), (3, 4), (4, 6), (6, 10)]
        );
        assert_eq!(runs(&[2, 4, 6]), vec![(0, 1), (1, 2), (2, 3)]);
    }

    /// `forward_columns` gathers the valid columns of an index-major block (`n` values per
    /// column) and transforms them into a column-major `n x cols` matrix: every entry equals
    /// the scalar `Transform::forward` of the value at that column and material, for columns
    /// in runs and alone, starting past column 0 and ending before the block does. The batch
    /// transform is a vectorised `ln_1p`, the scalar one another evaluation of it: relative
    /// tolerance 1e-13 (a few ulps of f64).
    #[test]
    fn forward_columns_transform_the_chosen_columns_of_every_material() {
        let n = 3;
        let block: Vec<f32> = (0..10 * n).map(|k| 0.01 + 0.37 * k as f32).collect();
        let cols = [1, 2, 3, 5, 8];
        let transform = Transform::Log { offset: 0.05 };
        let mut t = vec![7.0; 2];
        forward_columns(transform, &block, n, &cols, &mut t);
        assert_eq!(t.len(), cols.len() * n);
        for (k, &c) in cols.iter().enumerate() {
            for i in 0..n {
                let want = transform.forward(f64::from(block[c * n + i]));
                let got = t[k * n + i];
                assert!(
                    (got - want).abs() <= 1e-13 * want.abs(),
                    "column {c}, material {i}: {got} vs {want}"
                );
            }
        }
    }

    /// The latent search with one start of each kind reaches a target placed exactly at a
    /// point of each kind (the smooth prediction at a midpoint of two training points, at a
    /// point half a length-scale off one along one axis, or at one of the 32 q Halton points),
    /// whose error is 0 by construction: the search's error is below 1e-9 of the target's
    /// squared norm in every one of 1,800 random cases (q = 1 and 2, N = 4..8, isotropic
    /// length-scales 0.15..0.8 over points in [0, 4]^q). A start of the wrong kind or place
    /// (a corrupted midpoint, one side only, fewer Halton points) misses some of them.
    #[test]
    fn latent_search_reaches_targets_placed_at_each_kind_of_start() {
        let kinds = ["midpoint", "side", "Halton"];
        let mut misses = Vec::new();
        for q in [1usize, 2] {
            for (kind, name) in kinds.iter().enumerate() {
                for seed in 0..300u64 {
                    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
                        seed * 7 + kind as u64 + 1000 * q as u64,
                    );
                    let n = rng.random_range(4..9);
                    let xs: Vec<Vec<f64>> = (0..n)
                        .map(|_| (0..q).map(|_| rng.random_range(0.0..4.0)).collect())
                        .collect();
                    let l = rng.random_range(0.15..0.8);
                    let (g, _, _) = gram_case(&mut rng, n, 12);
                    let x = Mat::from_fn(n, q, |i, k| xs[i][k]);
                    let gp = gp_on(x.as_ref(), gp_core::LengthScale::Isotropic(l));
                    let a = rng.random_range(0..n);
                    let b = (a + rng.random_range(1..n)) % n;
                    let k = rng.random_range(0..q);
                    let side = [-0.5, 0.5][rng.random_range(0..2)];
                    let at: Vec<f64> = match kind {
                        0 => (0..q).map(|j| 0.5 * (xs[a][j] + xs[b][j])).collect(),
                        1 => {
                            let mut p = xs[a].clone();
                            p[k] += side * l;
                            p
                        }
                        _ => {
                            let h = halton_points(&xs, &gp, 32 * q);
                            h[rng.random_range(0..h.len())].clone()
                        }
                    };
                    // The target y_h = sum_j c_j y_j: g_h = G c and g_hh = c^T G c.
                    let w = gp.weights(&at, gp_core::Predictor::Smooth).unwrap();
                    let c = weights_to_coefficients(&w);
                    let g_h: Vec<f64> = (0..n)
                        .map(|i| (0..n).map(|j| g[(i, j)] * c[j]).sum())
                        .collect();
                    let g_hh: f64 = (0..n).map(|i| c[i] * g_h[i]).sum();
                    let (p, e) = best_latent_point(&gp, &xs, g.as_ref(), &g_h, g_hh, 1).unwrap();
                    if e > 1e-9 * g_hh {
                        misses.push(format!(
                            "q {q}, {name} seed {seed}: error {:e} of |y_h|^2 at {p:?}, target \
                             at {at:?}",
                            e / g_hh
                        ));
                    }
                }
            }
        }
        assert!(misses.is_empty(), "{misses:#?}");
    }
}
