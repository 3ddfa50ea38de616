//! Optimisers of the GPLVM objective: Hooke-Jeeves direct search (the paper's method, Hooke &
//! Jeeves 1961) and L-BFGS with a strong-Wolfe line search on the analytic gradient.
//!
//! Both minimise a function of a flat parameter vector and count objective evaluations, so
//! they can be compared at equal cost.

use std::cell::Cell;

use crate::error::{Error, Result};

/// Settings of the Hooke-Jeeves pattern search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HookeJeevesSettings {
    /// Initial step along every coordinate.
    pub initial_step: f64,
    /// Factor applied to the step when no exploratory move improves (0 < factor < 1).
    pub step_reduction: f64,
    /// Stop when the step falls below this.
    pub min_step: f64,
    /// Stop after this many objective evaluations.
    pub max_evaluations: usize,
}

impl Default for HookeJeevesSettings {
    fn default() -> Self {
        Self {
            initial_step: 0.1,
            step_reduction: 0.5,
            min_step: 1e-6,
            max_evaluations: 200_000,
        }
    }
}

/// Settings of L-BFGS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LbfgsSettings {
    /// Number of correction pairs kept. On the default synthetic store (q = 5, N q = 255) a
    /// memory of 100 needed 300 evaluations on raw values where 50 needed 377 and 30 needed
    /// 492, and 1744 on log values where 50 and 30 needed 2071 and 2091 (`fit_bench` example,
    /// BENCHMARKS.md "gplvm", session 3; raw at 100: 310 since session 9); the two-loop
    /// recursion then streams 2 x 100 x 255 values per step, ~20 us more than a memory of 30
    /// or 50 against ~63 us for the objective.
    pub memory: usize,
    /// Maximum number of iterations.
    pub max_iterations: u64,
    /// Stop when the gradient norm falls below this.
    pub gradient_tolerance: f64,
    /// Stop when one step changes the objective by less than this (absolute).
    pub cost_tolerance: f64,
    /// A gradient norm above this when the value-change test or the line search stops the
    /// method is a stall, not convergence: the correction pairs are dropped and the search
    /// goes on from steepest descent; a second stall in a row stops it with
    /// [`Minimum::stalled`] set.
    pub stall_gradient: f64,
}

impl Default for LbfgsSettings {
    fn default() -> Self {
        Self {
            memory: 100,
            max_iterations: 2_000,
            gradient_tolerance: 1e-6,
            cost_tolerance: 1e-12,
            stall_gradient: 1e-2,
        }
    }
}

/// Outcome of a minimisation.
#[derive(Debug, Clone, PartialEq)]
pub struct Minimum {
    /// Best parameters found.
    pub x: Vec<f64>,
    /// Objective value at `x`.
    pub value: f64,
    /// Iterations of the method: exploratory sweeps about a base point (Hooke-Jeeves; the
    /// pattern moves that follow a successful sweep are not counted) or L-BFGS steps.
    pub iterations: u64,
    /// Objective evaluations (value-and-gradient evaluations for L-BFGS).
    pub evaluations: u64,
    /// Why the method stopped.
    pub stop_reason: String,
    /// Whether it stopped at its iteration or evaluation cap (not converged by its own test).
    pub at_limit: bool,
    /// Whether it stopped because it could not make progress while the gradient was still
    /// large (L-BFGS, [`LbfgsSettings::stall_gradient`]): not converged either.
    pub stalled: bool,
}

/// Minimises `f` by Hooke-Jeeves direct search from `x0`.
///
/// Exploratory moves try +step and -step along each coordinate in turn, keeping any
/// improvement; a successful exploration is followed by a pattern move `x + (x - x_previous)`
/// that is kept when its own exploration improves on the base point. When no move improves,
/// the step is reduced. Non-finite objective values count as no improvement.
///
/// # Errors
/// [`Error::InvalidConfig`] when the settings cannot converge (see
/// [`HookeJeevesSettings`]), and [`Error::Objective`] when the objective is not finite at `x0`.
pub fn hooke_jeeves(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: &[f64],
    settings: &HookeJeevesSettings,
) -> Result<Minimum> {
    let s = *settings;
    // A step that never falls below `min_step` (an infinite initial step, a min_step of 0 or
    // NaN) never stops the search by its own test: it ran to the evaluation cap, and with no
    // parameters (no evaluations) forever.
    if !(s.initial_step.is_finite()
        && s.initial_step > 0.0
        && s.step_reduction > 0.0
        && s.step_reduction < 1.0
        && s.min_step.is_finite()
        && s.min_step > 0.0)
    {
        return Err(Error::InvalidConfig {
            field: "initial_step, step_reduction, min_step",
            value: format!("{}, {}, {}", s.initial_step, s.step_reduction, s.min_step),
            expected: "initial_step and min_step finite and > 0, step_reduction in (0, 1) \
                       (Hooke-Jeeves)"
                .into(),
        });
    }
    let evaluations = Cell::new(0u64);
    // The cap holds inside a sweep too: past it a trial counts as no improvement without
    // evaluating (a sweep of 2 x parameters trials used to run past the cap: 200,102
    // evaluations for a cap of 200,000).
    let cap = s.max_evaluations.max(1) as u64;
    let mut eval = |x: &[f64]| {
        if evaluations.get() >= cap {
            return f64::INFINITY;
        }
        evaluations.set(evaluations.get() + 1);
        let v = f(x);
        if v.is_finite() { v } else { f64::INFINITY }
    };
    let mut base = x0.to_vec();
    let mut base_value = eval(&base);
    if !base_value.is_finite() {
        return Err(Error::Objective {
            reason: "the objective is not finite at the starting point".into(),
        });
    }
    let mut step = s.initial_step;
    let mut iterations = 0u64;

    // One sweep of exploratory moves around `point`; returns the improved point and value.
    fn explore(
        eval: &mut impl FnMut(&[f64]) -> f64,
        point: &[f64],
        value: f64,
        step: f64,
    ) -> (Vec<f64>, f64) {
        let mut x = point.to_vec();
        let mut best = value;
        for i in 0..x.len() {
            let orig = x[i];
            x[i] = orig + step;
            let up = eval(&x);
            if up < best {
                best = up;
                continue;
            }
            x[i] = orig - step;
            let down = eval(&x);
            if down < best {
                best = down;
                continue;
            }
            x[i] = orig;
        }
        (x, best)
    }

    let mut at_limit = false;
    let stop_reason = loop {
        // The cap first: a sweep it cut short shrank the step without a real failure, so a
        // step below min_step then is not convergence.
        if evaluations.get() as usize >= s.max_evaluations {
            at_limit = true;
            break format!("reached {} evaluations", s.max_evaluations);
        }
        if step < s.min_step {
            break format!("step {step:.3e} below {:.1e}", s.min_step);
        }
        iterations += 1;
        let (mut x, mut value) = explore(&mut eval, &base, base_value, step);
        if value < base_value {
            // Pattern moves while they keep improving. An improvement found when the cap cut
            // the exploration about the pattern point short is kept: the best point evaluated
            // is returned (it used to be dropped for the previous base point, e.g. 32 instead
            // of 2 on a quadratic with a cap of 10).
            loop {
                let pattern: Vec<f64> = x.iter().zip(&base).map(|(a, b)| 2.0 * a - b).collect();
                let pattern_value = eval(&pattern);
                let (px, pv) = explore(&mut eval, &pattern, pattern_value, step);
                base = x;
                base_value = value;
                if pv < base_value {
                    x = px;
                    value = pv;
                } else {
                    break;
                }
                if evaluations.get() as usize >= s.max_evaluations {
                    base = x;
                    base_value = value;
                    break;
                }
            }
        } else {
            step *= s.step_reduction;
        }
    };
    Ok(Minimum {
        x: base,
        value: base_value,
        iterations,
        evaluations: evaluations.get(),
        stop_reason,
        at_limit,
        stalled: false,
    })
}

use gp_core::fastmath::{axpy_then_dot_wide, dot, dot_wide, norm};

/// `y += a x`.
#[inline(always)]
fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += a * xi;
    }
}

/// Correction pairs (s, y, 1 / s'y), oldest first.
type Pairs = std::collections::VecDeque<(Vec<f64>, Vec<f64>, f64)>;

/// The L-BFGS two-loop recursion: `dir = -H grad` with the initial Hessian scaled by s'y / y'y
/// of the newest pair (1 / |grad| without pairs). Compiled for AVX2 + FMA or AVX-512 when the
/// CPU has them (selected at run time; every build has the same bits). With a memory of 100 and
/// N q = 255 it is 100 k multiply-adds per step in 200 dot products, each waiting on the one
/// before; with [`gp_core::fastmath::dot`]'s four addition chains they made it ~25 % of a
/// default fit's time (BENCHMARKS.md "gplvm", sessions 10 and 43), hence
/// [`gp_core::fastmath::dot_wide`]'s 32.
fn two_loop(pairs: &Pairs, grad: &[f64], gnorm: f64, alpha: &mut [f64], dir: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU supports AVX-512F (checked just above; it implies AVX2 and FMA),
            // the only requirement of a `#[target_feature]` function.
            unsafe { two_loop_avx512(pairs, grad, gnorm, alpha, dir) };
            return;
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above), the only requirement
            // of a `#[target_feature]` function.
            unsafe { two_loop_avx2(pairs, grad, gnorm, alpha, dir) };
            return;
        }
    }
    two_loop_body(pairs, grad, gnorm, alpha, dir);
}

/// [`two_loop`] compiled for AVX-512 (8-lane element-wise updates and partial sums).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn two_loop_avx512(
    pairs: &Pairs,
    grad: &[f64],
    gnorm: f64,
    alpha: &mut [f64],
    dir: &mut [f64],
) {
    two_loop_body(pairs, grad, gnorm, alpha, dir);
}

/// [`two_loop`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn two_loop_avx2(
    pairs: &Pairs,
    grad: &[f64],
    gnorm: f64,
    alpha: &mut [f64],
    dir: &mut [f64],
) {
    two_loop_body(pairs, grad, gnorm, alpha, dir);
}

/// The two-loop recursion, inlined into each build (plain element-wise arithmetic and
/// [`dot_wide`], so the same bits whatever the compiler vectorises). Each update of `dir` is
/// fused with the next pair's dot product ([`axpy_then_dot_wide`], the same bits as the two
/// steps), so `dir` is read and written once per pair.
#[inline(always)]
fn two_loop_body(pairs: &Pairs, grad: &[f64], gnorm: f64, alpha: &mut [f64], dir: &mut [f64]) {
    dir.copy_from_slice(grad);
    let m = pairs.len();
    // Newest pair first: alpha_k = rho_k s_k'dir, dir -= alpha_k y_k.
    if let Some((s, _, _)) = pairs.back() {
        let mut s_dir = dot_wide(s, dir);
        for k in (0..m).rev() {
            let (_, y, rho) = &pairs[k];
            alpha[k] = rho * s_dir;
            match k.checked_sub(1) {
                Some(next) => s_dir = axpy_then_dot_wide(-alpha[k], y, dir, &pairs[next].0),
                None => axpy(-alpha[k], y, dir),
            }
        }
    }
    let gamma = match pairs.back() {
        Some((s, y, _)) => {
            // s'y / y'y; y'y overflows for gradients near 1e154 (and underflows near 1e-154):
            // then (s'y / |y|) / |y| with the safe norm (gamma was 0, the direction degenerate).
            let (sy, yy) = (dot_wide(s, y), dot_wide(y, y));
            if gp_core::fastmath::is_safe_sum_of_squares(yy) {
                sy / yy
            } else {
                let ny = norm(y);
                (sy / ny) / ny
            }
        }
        None => 1.0 / gnorm,
    };
    dir.iter_mut().for_each(|d| *d *= gamma);
    // Oldest pair first: beta_k = rho_k y_k'dir, dir += (alpha_k - beta_k) s_k.
    if let Some((_, y, _)) = pairs.front() {
        let mut y_dir = dot_wide(y, dir);
        for k in 0..m {
            let (s, _, rho) = &pairs[k];
            let step = alpha[k] - rho * y_dir;
            match pairs.get(k + 1) {
                Some((_, y_next, _)) => y_dir = axpy_then_dot_wide(step, s, dir, y_next),
                None => axpy(step, s, dir),
            }
        }
    }
    dir.iter_mut().for_each(|d| *d = -*d);
}

/// A point of the line search: step, value, directional derivative, gradient.
struct Trial {
    step: f64,
    value: f64,
    slope: f64,
    grad: Vec<f64>,
}

/// Minimiser of the cubic through (a, fa, da) and (b, fb, db), safeguarded into the interval
/// between a and b (bisection when the cubic has no usable minimum).
fn cubic_step(a: f64, fa: f64, da: f64, b: f64, fb: f64, db: f64) -> f64 {
    let d1 = da + db - 3.0 * (fa - fb) / (a - b);
    let disc = d1 * d1 - da * db;
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    let mid = 0.5 * (a + b);
    // sqrt(disc); for slopes near 1e154 and above the squares overflow (disc inf or NaN, and
    // the step fell back to bisection): then in units of the largest slope.
    let root = if disc.is_finite() {
        (disc >= 0.0).then(|| disc.sqrt())
    } else {
        let m = d1.abs().max(da.abs()).max(db.abs());
        let (e1, ea, eb) = (d1 / m, da / m, db / m);
        let scaled = e1 * e1 - ea * eb;
        (scaled >= 0.0).then(|| m * scaled.sqrt())
    };
    let Some(root) = root else {
        return mid;
    };
    let d2 = (b - a).signum() * root;
    let t = b - (b - a) * (db + d2 - d1) / (db - da + 2.0 * d2);
    // Keep away from the ends so the interval shrinks.
    let margin = 0.1 * (hi - lo);
    if t.is_finite() && t > lo + margin && t < hi - margin {
        t
    } else {
        mid
    }
}

/// Line search for the strong Wolfe conditions (Nocedal & Wright, Algorithms 3.5 and 3.6, with
/// cubic interpolation; c1 = 1e-4, c2 = 0.9, at most 30 evaluations): sufficient decrease
/// `f(a) <= f0 + c1 a f0'` and curvature `|f'(a)| <= c2 |f0'|`. Evaluation errors and
/// non-finite values count as "too far" (an infinite value: the zoom searches below that
/// step), so the search never leaves the region where the objective is defined. Returns the
/// accepted trial; when the evaluation budget runs out or the zoom's interval shrinks to
/// rounding, the lowest trial that satisfies sufficient decrease (the curvature condition
/// unmet), or `None` when no trial does.
fn wolfe_search(
    f: &mut impl FnMut(&[f64]) -> Result<(f64, Vec<f64>)>,
    x: &[f64],
    dir: &[f64],
    f0: f64,
    slope0: f64,
    first_step: f64,
    evaluations: &mut u64,
) -> Option<Trial> {
    const C1: f64 = 1e-4;
    const C2: f64 = 0.9;
    const MAX_EVALS: usize = 30;
    let mut xt = vec![0.0; x.len()];
    let mut eval = |step: f64, evaluations: &mut u64| -> Option<Trial> {
        for ((t, xi), di) in xt.iter_mut().zip(x).zip(dir) {
            *t = xi + step * di;
        }
        *evaluations += 1;
        match f(&xt) {
            Ok((value, grad)) if value.is_finite() && grad.iter().all(|g| g.is_finite()) => {
                let slope = dot(&grad, dir);
                Some(Trial {
                    step,
                    value,
                    slope,
                    grad,
                })
            }
            _ => None,
        }
    };
    let start = Trial {
        step: 0.0,
        value: f0,
        slope: slope0,
        grad: Vec::new(),
    };
    let mut prev = start;
    let mut step = first_step;
    let mut used = 0;
    // Bracketing phase.
    let (mut lo, mut hi) = loop {
        if used >= MAX_EVALS {
            // `prev` (when it is a step) satisfies sufficient decrease and is the lowest point
            // so far, as the zoom phase returns at its budget; it used to be dropped, so a
            // minimum more than ~2^29 first steps away was never approached.
            return if prev.step > 0.0 { Some(prev) } else { None };
        }
        used += 1;
        let Some(t) = eval(step, evaluations) else {
            // Undefined or non-finite: a failed decrease (infinite value), so the step bounds
            // the interval the zoom searches. (Halving it and doubling again from the next
            // finite point re-entered the undefined region and spent the budget there.)
            break (
                prev,
                Trial {
                    step,
                    value: f64::INFINITY,
                    slope: f64::NAN,
                    grad: Vec::new(),
                },
            );
        };
        if t.value > f0 + C1 * t.step * slope0 || (prev.step > 0.0 && t.value >= prev.value) {
            break (prev, t);
        }
        if t.slope.abs() <= -C2 * slope0 {
            return Some(t);
        }
        if t.slope >= 0.0 {
            break (t, prev);
        }
        step = 2.0 * t.step;
        prev = t;
    };
    // Zoom phase: lo satisfies sufficient decrease and has the lowest value so far.
    loop {
        if used >= MAX_EVALS {
            return if lo.step > 0.0 { Some(lo) } else { None };
        }
        used += 1;
        let step = cubic_step(lo.step, lo.value, lo.slope, hi.step, hi.value, hi.slope);
        if (hi.step - lo.step).abs() < 1e-16 * lo.step.abs().max(1.0) {
            return if lo.step > 0.0 { Some(lo) } else { None };
        }
        let Some(t) = eval(step, evaluations) else {
            hi = Trial {
                step,
                value: f64::INFINITY,
                slope: f64::NAN,
                grad: Vec::new(),
            };
            continue;
        };
        if t.value > f0 + C1 * t.step * slope0 || t.value >= lo.value {
            hi = t;
        } else {
            if t.slope.abs() <= -C2 * slope0 {
                return Some(t);
            }
            if t.slope * (hi.step - lo.step) >= 0.0 {
                hi = lo;
            }
            lo = t;
        }
    }
}

/// The slope of `dir` along `grad` (whose norm is `gnorm`), and `false`; when `dir` is not a
/// descent direction (a slope >= 0 or NaN: numerical trouble in the two-loop recursion),
/// `dir` becomes the unit steepest-descent direction `-grad / gnorm`, with slope `-gnorm`, and
/// `true` (L-BFGS then drops its correction pairs).
fn descent_slope(dir: &mut [f64], grad: &[f64], gnorm: f64) -> (f64, bool) {
    let slope = dot(grad, dir);
    if slope < 0.0 {
        return (slope, false);
    }
    dir.iter_mut().zip(grad).for_each(|(d, g)| *d = -g / gnorm);
    (-gnorm, true)
}

/// Minimises `f` (returning value and gradient) by L-BFGS from `x0`: the two-loop recursion over
/// the last `memory` correction pairs (initial Hessian scaled by s'y / y'y) and a strong-Wolfe
/// line search with cubic interpolation. Stops when the gradient norm falls below
/// `gradient_tolerance`, when one step changes the value by less than `cost_tolerance`
/// (absolute), after `max_iterations` steps ([`Minimum::at_limit`]), or when the line search
/// finds no acceptable step. The value-change stop and the line-search stop are taken for
/// convergence only when the gradient norm is at most `stall_gradient`; otherwise the
/// correction pairs (a badly scaled Hessian model, e.g. after learnt hyperparameters ran away)
/// are dropped and the method restarts from steepest descent, and a second such stall in a row
/// (or one while there were no pairs to drop) ends it as [`Minimum::stalled`]. (An audit found
/// fits with learnt hyperparameters stopping this way at a gradient of 0.49 per data value,
/// 1.4e5 below what scipy's L-BFGS then reached from the same point.)
///
/// Own implementation rather than argmin's (used before): with N q = 255 parameters and a
/// memory of 100, argmin's generic vector arithmetic cost as much per iteration as the O(N^3)
/// GPLVM objective itself (~0.1 ms); here the recursion is a few plain slice loops.
///
/// # Errors
/// [`Error::Objective`] when the value or the gradient is not finite at `x0`, and the error of
/// `f` at `x0` itself (errors at later trial points only shorten the line search).
pub fn lbfgs(
    mut f: impl FnMut(&[f64]) -> Result<(f64, Vec<f64>)>,
    x0: &[f64],
    settings: &LbfgsSettings,
) -> Result<Minimum> {
    let memory = settings.memory.max(1);
    let mut evaluations = 1u64;
    let (mut value, mut grad) = f(x0)?;
    if !value.is_finite() || grad.iter().any(|g| !g.is_finite()) {
        return Err(Error::Objective {
            reason: "the objective or its gradient is not finite at the starting point".into(),
        });
    }
    let mut x = x0.to_vec();
    let mut pairs = Pairs::with_capacity(memory);
    let mut alpha = vec![0.0; memory];
    let mut dir = vec![0.0; x.len()];
    let mut iterations = 0u64;
    let (mut at_limit, mut stalled) = (false, false);
    // Whether the last step followed a stall (the pairs were dropped for it).
    let mut after_stall = false;
    // A stop that is not convergence while the gradient is large: the first one drops the
    // pairs and goes on, a second in a row stops (`stalled`).
    let stall = |reason: String, gnorm: f64, pairs: &mut Pairs, after: &mut bool| {
        if gnorm <= settings.stall_gradient {
            return Some(reason);
        }
        if *after || pairs.is_empty() {
            let again = if *after {
                ", again after dropping the Hessian model,"
            } else {
                ", from steepest descent,"
            };
            return Some(format!(
                "{reason}{again} with |gradient| {gnorm:.2e} (not converged)"
            ));
        }
        pairs.clear();
        *after = true;
        None
    };
    let stop_reason = loop {
        let gnorm = norm(&grad);
        if gnorm <= settings.gradient_tolerance {
            break format!("gradient norm {gnorm:.2e} below tolerance");
        }
        if iterations >= settings.max_iterations {
            at_limit = true;
            break format!("reached {} iterations", settings.max_iterations);
        }
        two_loop(&pairs, &grad, gnorm, &mut alpha, &mut dir);
        let (slope, restarted) = descent_slope(&mut dir, &grad, gnorm);
        if restarted {
            pairs.clear();
        }
        let Some(t) = wolfe_search(&mut f, &x, &dir, value, slope, 1.0, &mut evaluations) else {
            let reason = "line search found no acceptable step".to_string();
            match stall(reason, gnorm, &mut pairs, &mut after_stall) {
                Some(r) => {
                    stalled = gnorm > settings.stall_gradient;
                    break r;
                }
                None => continue,
            }
        };
        let s: Vec<f64> = dir.iter().map(|d| t.step * d).collect();
        let y: Vec<f64> = t.grad.iter().zip(&grad).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        axpy(1.0, &s, &mut x);
        let change = value - t.value;
        value = t.value;
        grad = t.grad;
        iterations += 1;
        if sy > 1e-12 * norm(&s) * norm(&y) {
            if pairs.len() == memory {
                pairs.pop_front();
            }
            pairs.push_back((s, y, 1.0 / sy));
        }
        if change.abs() < settings.cost_tolerance {
            let reason = format!(
                "value changed by {change:.2e} < {:.1e} in one step",
                settings.cost_tolerance
            );
            let gnorm = norm(&grad);
            match stall(reason, gnorm, &mut pairs, &mut after_stall) {
                Some(r) => {
                    stalled = gnorm > settings.stall_gradient;
                    break r;
                }
                None => continue,
            }
        }
        after_stall = false;
    };
    Ok(Minimum {
        x,
        value,
        iterations,
        evaluations,
        stop_reason,
        at_limit,
        stalled,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Xorshift values uniform in [-0.5, 0.5).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// The two-loop recursion has the same bits in every build the CPU has (fits must not
    /// depend on the vector width).
    #[test]
    fn two_loop_builds_agree_bitwise() {
        let n = 255;
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        let mut pairs = Pairs::new();
        for _ in 0..7 {
            let (sv, yv): (Vec<f64>, Vec<f64>) = (0..n).map(|_| (next(), next())).unzip();
            let rho = 1.0 / dot(&sv, &yv);
            pairs.push_back((sv, yv, rho));
        }
        let grad: Vec<f64> = (0..n).map(|_| next()).collect();
        let run = |f: &dyn Fn(&mut [f64], &mut [f64])| {
            let (mut alpha, mut dir) = (vec![0.0; pairs.len()], vec![0.0; n]);
            f(&mut alpha, &mut dir);
            dir.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        };
        let want = run(&|a, d| two_loop_body(&pairs, &grad, 2.0, a, d));
        assert_eq!(run(&|a, d| two_loop(&pairs, &grad, 2.0, a, d)), want);
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU supports AVX-512F (checked just above).
                let got = run(&|a, d| unsafe { two_loop_avx512(&pairs, &grad, 2.0, a, d) });
                assert_eq!(got, want, "AVX-512");
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                let got = run(&|a, d| unsafe { two_loop_avx2(&pairs, &grad, 2.0, a, d) });
                assert_eq!(got, want, "AVX2");
            }
        }
    }

    /// The fused recursion has the bits of the textbook one (each update, then the next dot
    /// product), with no pairs, one pair and several, and its direction is `-H grad`: with one
    /// pair on a two-dimensional problem, the BFGS update of `gamma I` applied to `grad`.
    #[test]
    fn fused_two_loop_is_the_textbook_recursion() {
        fn textbook(pairs: &Pairs, grad: &[f64], gnorm: f64) -> Vec<f64> {
            let mut dir = grad.to_vec();
            let mut alpha = vec![0.0; pairs.len()];
            for (k, (s, y, rho)) in pairs.iter().enumerate().rev() {
                alpha[k] = rho * dot_wide(s, &dir);
                axpy(-alpha[k], y, &mut dir);
            }
            let gamma = pairs
                .back()
                .map_or(1.0 / gnorm, |(s, y, _)| dot_wide(s, y) / dot_wide(y, y));
            dir.iter_mut().for_each(|d| *d *= gamma);
            for (k, (s, y, rho)) in pairs.iter().enumerate() {
                let beta = rho * dot_wide(y, &dir);
                axpy(alpha[k] - beta, s, &mut dir);
            }
            dir.iter().map(|d| -d).collect()
        }
        let n = 70;
        let mut next = uniform(0x9e37_79b9_7f4a_7c15);
        let grad: Vec<f64> = (0..n).map(|_| next()).collect();
        let mut pairs = Pairs::new();
        for m in 0..8 {
            if m > 0 {
                let (sv, yv): (Vec<f64>, Vec<f64>) = (0..n).map(|_| (next(), next())).unzip();
                let rho = 1.0 / dot(&sv, &yv);
                pairs.push_back((sv, yv, rho));
            }
            let (mut alpha, mut dir) = (vec![0.0; pairs.len()], vec![0.0; n]);
            two_loop(&pairs, &grad, 3.0, &mut alpha, &mut dir);
            let want = textbook(&pairs, &grad, 3.0);
            assert_eq!(
                dir.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
                want.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
                "{m} pairs"
            );
        }
        // One pair in two dimensions: H = (I - rho s y') gamma (I - rho y s') + rho s s'.
        let (s, y, g) = ([1.0, 2.0], [3.0, 1.0], [0.5, -1.5]);
        let rho = 1.0 / (s[0] * y[0] + s[1] * y[1]);
        let gamma = (s[0] * y[0] + s[1] * y[1]) / (y[0] * y[0] + y[1] * y[1]);
        let left = [
            [1.0 - rho * s[0] * y[0], -rho * s[0] * y[1]],
            [-rho * s[1] * y[0], 1.0 - rho * s[1] * y[1]],
        ];
        let h = |i: usize, j: usize| {
            // (left gamma left')_ij + rho s_i s_j: the right factor is left's transpose.
            gamma * (left[i][0] * left[j][0] + left[i][1] * left[j][1]) + rho * s[i] * s[j]
        };
        let one: Pairs = [(s.to_vec(), y.to_vec(), rho)].into_iter().collect();
        let (mut alpha, mut dir) = ([0.0], [0.0; 2]);
        two_loop(&one, &g, 1.0, &mut alpha, &mut dir);
        for (i, d) in dir.iter().enumerate() {
            let want = -(h(i, 0) * g[0] + h(i, 1) * g[1]);
            assert!((d - want).abs() < 1e-14, "{i}: {d} against {want}");
        }
    }

    /// Rosenbrock function and its gradient.
    fn rosenbrock(x: &[f64]) -> (f64, Vec<f64>) {
        let (a, b) = (x[0], x[1]);
        let v = (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2);
        let g = vec![
            -2.0 * (1.0 - a) - 400.0 * a * (b - a * a),
            200.0 * (b - a * a),
        ];
        (v, g)
    }

    #[test]
    fn hooke_jeeves_finds_quadratic_minimum() {
        let f = |x: &[f64]| (x[0] - 1.5).powi(2) + 3.0 * (x[1] + 0.5).powi(2) + x[2].powi(2);
        let m = hooke_jeeves(f, &[0.0, 0.0, 1.0], &HookeJeevesSettings::default()).unwrap();
        assert!(
            (m.x[0] - 1.5).abs() < 1e-5 && (m.x[1] + 0.5).abs() < 1e-5,
            "{m:?}"
        );
        assert!(m.x[2].abs() < 1e-5 && m.value < 1e-9);
    }

    #[test]
    fn hooke_jeeves_on_rosenbrock() {
        let s = HookeJeevesSettings {
            min_step: 1e-9,
            ..Default::default()
        };
        let m = hooke_jeeves(|x| rosenbrock(x).0, &[-1.2, 1.0], &s).unwrap();
        assert!(
            (m.x[0] - 1.0).abs() < 1e-3 && (m.x[1] - 1.0).abs() < 2e-3,
            "{m:?}"
        );
    }

    /// A kink (f = 10 |x - 0.3|: the slope is 10 on either side, so no step satisfies the
    /// curvature condition) stops L-BFGS with a large gradient: reported as stalled, not as
    /// converged; Rosenbrock converges without a stall.
    #[test]
    fn lbfgs_reports_a_stall_with_a_large_gradient() {
        let kink = |x: &[f64]| {
            let d = x[0] - 0.3;
            Ok((10.0 * d.abs(), vec![10.0 * d.signum()]))
        };
        let m = lbfgs(kink, &[0.0], &LbfgsSettings::default()).unwrap();
        assert!(m.stalled && !m.at_limit, "{m:?}");
        assert!(m.stop_reason.contains("not converged"), "{m:?}");
        let r = lbfgs(
            |x| Ok(rosenbrock(x)),
            &[-1.2, 1.0],
            &LbfgsSettings::default(),
        )
        .unwrap();
        assert!(!r.stalled, "{r:?}");
    }

    /// A line search that fails from steepest descent (no pairs to drop: the objective is
    /// undefined everywhere but at the start) stops at once as stalled, after one search's 30
    /// evaluations; a start whose value or gradient is not finite is an error.
    #[test]
    fn lbfgs_stops_when_steepest_descent_finds_no_step() {
        let only_at_one = |x: &[f64]| {
            if x[0] == 1.0 {
                Ok((1.0, vec![2.0]))
            } else {
                Err(Error::Objective {
                    reason: "undefined".into(),
                })
            }
        };
        let m = lbfgs(only_at_one, &[1.0], &LbfgsSettings::default()).unwrap();
        assert!(m.stalled && !m.at_limit, "{m:?}");
        assert_eq!((m.x[0], m.iterations, m.evaluations), (1.0, 0, 31), "{m:?}");
        assert!(m.stop_reason.contains("from steepest descent"), "{m:?}");
        for start in [(f64::NAN, 0.0), (1.0, f64::NAN), (f64::INFINITY, 1.0)] {
            let e = lbfgs(
                |_| Ok((start.0, vec![start.1])),
                &[0.0],
                &LbfgsSettings::default(),
            );
            assert!(matches!(e, Err(Error::Objective { .. })), "{start:?}");
        }
    }

    /// With the gradient test off, L-BFGS stops when one step changes the value by less than
    /// `cost_tolerance`, also far from 0 (a minimum value of 100), as converged: the gradient
    /// is then below `stall_gradient`.
    #[test]
    fn lbfgs_stops_on_a_small_change_of_value() {
        let offset = |x: &[f64]| {
            let (v, g) = rosenbrock(x);
            Ok((v + 100.0, g))
        };
        let settings = LbfgsSettings {
            gradient_tolerance: 0.0,
            cost_tolerance: 1e-9,
            ..LbfgsSettings::default()
        };
        let m = lbfgs(offset, &[-1.2, 1.0], &settings).unwrap();
        assert!(m.stop_reason.starts_with("value changed by"), "{m:?}");
        assert!(!m.stalled && !m.at_limit && m.iterations < 100, "{m:?}");
        assert!((m.value - 100.0).abs() < 1e-8, "{m:?}");
    }

    /// A descent direction is kept with its slope; an ascent, flat or NaN direction becomes
    /// the unit steepest-descent direction, with slope -|gradient|.
    #[test]
    fn non_descent_directions_restart_from_steepest_descent() {
        let grad = [3.0, -4.0];
        let mut dir = vec![-1.0, 1.0];
        assert_eq!(descent_slope(&mut dir, &grad, 5.0), (-7.0, false));
        assert_eq!(dir, [-1.0, 1.0]);
        for bad in [[1.0, 0.0], [4.0, 3.0], [f64::NAN, 1.0]] {
            let mut dir = bad.to_vec();
            assert_eq!(descent_slope(&mut dir, &grad, 5.0), (-5.0, true), "{bad:?}");
            assert_eq!(dir, [-0.6, 0.8], "{bad:?}");
        }
    }

    /// The line search's cubic step is the exact minimiser of a cubic (or quadratic) given
    /// its values and slopes at the two ends, in either order, and with slopes whose squares
    /// overflow; a minimiser within a tenth of the interval of an end, or no minimum at all,
    /// gives the midpoint.
    #[test]
    fn cubic_step_minimises_cubics_and_keeps_off_the_ends() {
        // f = c (t^3 - 3 t): minimum at t = 1; f(0) = 0, f'(0) = -3c, f(2) = 2c, f'(2) = 9c.
        for c in [1.0, 1e-150, 1e200] {
            let (fa, da, fb, db) = (0.0, -3.0 * c, 2.0 * c, 9.0 * c);
            for t in [
                cubic_step(0.0, fa, da, 2.0, fb, db),
                cubic_step(2.0, fb, db, 0.0, fa, da),
            ] {
                assert!((t - 1.0).abs() < 1e-12, "{c:e}: {t}");
            }
        }
        // f = (t - m)^2 on [0, 2]: m itself inside the margins, the midpoint outside them.
        let quadratic = |m: f64| {
            let f = |t: f64| (t - m) * (t - m);
            cubic_step(0.0, f(0.0), -2.0 * m, 2.0, f(2.0), 2.0 * (2.0 - m))
        };
        assert!((quadratic(0.7) - 0.7).abs() < 1e-12);
        assert!((quadratic(1.75) - 1.75).abs() < 1e-12);
        assert_eq!(quadratic(1.9), 1.0);
        assert_eq!(quadratic(0.1), 1.0);
        // f = -t^3 + 3t on [-0.5, 0.5]: its minimum (t = -1) is outside; f = t^3 + t has none.
        assert_eq!(cubic_step(-0.5, -1.375, 2.25, 0.5, 1.375, 2.25), 0.0);
        assert_eq!(cubic_step(0.0, 0.0, 1.0, 1.0, 2.0, 4.0), 0.5);
    }

    /// `wolfe_search` along +x from 0 with f(0) = `f0` and f'(0) = `slope0`: the trial
    /// returned, the evaluations counted and every (step, value) evaluated.
    fn search_1d(
        f: impl Fn(f64) -> (f64, f64),
        f0: f64,
        slope0: f64,
        first: f64,
    ) -> (Option<Trial>, u64, Vec<(f64, f64)>) {
        let (mut evaluations, mut tried) = (0, Vec::new());
        let mut objective = |x: &[f64]| {
            let (value, slope) = f(x[0]);
            tried.push((x[0], value));
            Ok((value, vec![slope]))
        };
        let t = wolfe_search(
            &mut objective,
            &[0.0],
            &[1.0],
            f0,
            slope0,
            first,
            &mut evaluations,
        );
        (t, evaluations, tried)
    }

    /// The line search returns a step that meets the strong Wolfe conditions (sufficient
    /// decrease with c1 = 1e-4, curvature with c2 = 0.9), with the value and slope of that
    /// step, in at most 30 evaluations, and no lower than any other trial that decreased
    /// sufficiently, over 3000 seeded 1-D objectives `a (x - c)^2 + e (x - c)^4 + b sin(w x)`
    /// and first steps from 1e-3 to 1e2 times the distance to the minimum.
    #[test]
    fn wolfe_search_meets_the_strong_wolfe_conditions() {
        let mut s = 0x9e37_79b9_7f4a_7c15_u64;
        let mut uniform = move |lo: f64, hi: f64| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            lo + (hi - lo) * ((s >> 11) as f64 / (1u64 << 53) as f64)
        };
        let mut checked = 0;
        for case in 0..3000 {
            let (a, c, e) = (uniform(0.1, 10.0), uniform(0.5, 5.0), uniform(0.0, 1.0));
            let (b, w) = (uniform(0.0, 0.3) * a, uniform(1.0, 10.0));
            let f = |x: f64| {
                let value = a * (x - c).powi(2) + e * (x - c).powi(4) + b * (w * x).sin();
                let slope = 2.0 * a * (x - c) + 4.0 * e * (x - c).powi(3) + b * w * (w * x).cos();
                (value, slope)
            };
            let (f0, slope0) = f(0.0);
            if slope0 >= 0.0 {
                continue;
            }
            checked += 1;
            let first = c * 10f64.powf(uniform(-3.0, 2.0));
            let (t, evaluations, tried) = search_1d(f, f0, slope0, first);
            let t = t.unwrap_or_else(|| panic!("case {case}: no step"));
            let what = format!("case {case}: step {} of first {first}", t.step);
            assert!(t.step > 0.0 && evaluations <= 30, "{what}: {evaluations}");
            assert_eq!((t.value, t.slope), f(t.step), "{what}");
            let decreases = |step: f64, value: f64| value <= f0 + 1e-4 * step * slope0;
            assert!(decreases(t.step, t.value), "{what}: no sufficient decrease");
            assert!(t.slope.abs() <= 0.9 * slope0.abs(), "{what}: curvature");
            let lowest = tried
                .iter()
                .filter(|&&(step, value)| decreases(step, value))
                .fold(f64::INFINITY, |m, &(_, value)| m.min(value));
            assert_eq!(t.value, lowest, "{what}: {tried:?}");
        }
        assert!(checked > 2000, "{checked}");
    }

    /// f = -t + (1 + 0.75 d) t^2 - (1 + d) t^3 / 4 is flat (f' = 0) at the first step, 2, but
    /// above f(0) by d = 1e-5, less than the sufficient decrease's 1e-4 t |f'(0)|: the search
    /// must not take it, and goes back to the minimum at 2/3.
    #[test]
    fn wolfe_search_refuses_a_flat_step_that_did_not_decrease() {
        let d = 1e-5;
        let f = |x: f64| {
            let value = -x + (1.0 + 0.75 * d) * x * x - (1.0 + d) * x.powi(3) / 4.0;
            let slope = -1.0 + 2.0 * (1.0 + 0.75 * d) * x - 0.75 * (1.0 + d) * x * x;
            (value, slope)
        };
        assert!(f(2.0).1.abs() < 1e-12 && f(2.0).0 > 0.0);
        let t = search_1d(f, 0.0, -1.0, 2.0).0.unwrap();
        assert!(
            t.value < -0.1 && (t.step - 2.0 / 3.0).abs() < 0.2,
            "step {}",
            t.step
        );
    }

    /// Along a direction in which the objective falls without end, the line search stops
    /// after its 30 evaluations (doubling the step each time) with the last, lowest step.
    #[test]
    fn wolfe_search_stops_at_its_budget() {
        let (t, evaluations, tried) = search_1d(|x| (-x, -1.0), 0.0, -1.0, 0.5);
        let t = t.unwrap();
        assert_eq!((evaluations, tried.len()), (30, 30));
        assert_eq!((t.step, t.value), (2f64.powi(28), -(2f64.powi(28))));
    }

    /// At a kink (|t - 1|: slopes -1 and 1, so the curvature condition holds nowhere) the
    /// zoom cannot succeed either: it stops at its budget with the lowest step found.
    #[test]
    fn wolfe_search_zoom_stops_at_its_budget() {
        let (t, evaluations, _) =
            search_1d(|x| ((x - 1.0).abs(), (x - 1.0).signum()), 1.0, -1.0, 3.0);
        let t = t.unwrap();
        assert_eq!(evaluations, 30);
        assert!(t.step < 1.0 && t.value < 1e-3, "step {}", t.step);
    }

    /// The evaluations L-BFGS reports are the objective's calls, line searches included.
    #[test]
    fn lbfgs_counts_every_evaluation() {
        let calls = std::cell::Cell::new(0u64);
        let m = lbfgs(
            |x| {
                calls.set(calls.get() + 1);
                Ok(rosenbrock(x))
            },
            &[-1.2, 1.0],
            &LbfgsSettings::default(),
        )
        .unwrap();
        assert!(m.evaluations > m.iterations && m.iterations > 10, "{m:?}");
        assert_eq!(m.evaluations, calls.get());
    }

    #[test]
    fn lbfgs_on_rosenbrock_uses_few_evaluations() {
        let m = lbfgs(
            |x| Ok(rosenbrock(x)),
            &[-1.2, 1.0],
            &LbfgsSettings::default(),
        )
        .unwrap();
        assert!(
            (m.x[0] - 1.0).abs() < 1e-6 && (m.x[1] - 1.0).abs() < 1e-6,
            "{m:?}"
        );
        assert!(m.evaluations < 200, "{m:?}");
        assert!(!m.at_limit, "{m:?}");
    }

    /// L-BFGS is invariant to scaling the objective (the initial Hessian s'y / y'y and the
    /// cubic step scale with it): with both tolerances off, an ill-conditioned quadratic and
    /// Rosenbrock scaled by 1e200 or 1e-150 take the steps of the unscaled ones. At 1e200, y'y
    /// and the cubic's squared slopes overflowed: the quadratic took 665 evaluations for 25
    /// steps (26 unscaled) and ended 0.99 from its minimum (0.25 unscaled), and Rosenbrock's
    /// line search fell back to bisection.
    #[test]
    fn lbfgs_steps_do_not_depend_on_the_objectives_scale() {
        let a: Vec<f64> = (0..30).map(|i| 1.0 + 0.3 * f64::from(i * i)).collect();
        let quadratic = |c: f64| {
            let a = a.clone();
            move |x: &[f64]| -> Result<(f64, Vec<f64>)> {
                let v = x
                    .iter()
                    .zip(&a)
                    .map(|(x, a)| 0.5 * c * a * (x - 1.0).powi(2));
                let g = x.iter().zip(&a).map(|(x, a)| c * a * (x - 1.0)).collect();
                Ok((v.sum(), g))
            }
        };
        let rosen = |c: f64| {
            move |x: &[f64]| -> Result<(f64, Vec<f64>)> {
                let (v, g) = rosenbrock(x);
                Ok((c * v, g.iter().map(|g| c * g).collect()))
            }
        };
        let settings = |max_iterations| LbfgsSettings {
            max_iterations,
            gradient_tolerance: 0.0,
            cost_tolerance: 0.0,
            ..LbfgsSettings::default()
        };
        let close = |m: &Minimum, base: &Minimum, what: &str| {
            assert_eq!(m.evaluations, base.evaluations, "{what}: {m:?}");
            for (a, b) in m.x.iter().zip(&base.x) {
                assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{what}: {m:?}");
            }
        };
        let (x0, s) = (vec![0.0; 30], settings(25));
        let base = lbfgs(quadratic(1.0), &x0, &s).unwrap();
        let (r0, s) = ([-1.2, 1.0], settings(30));
        let base_r = lbfgs(rosen(1.0), &r0, &s).unwrap();
        for c in [1e200, 1e-150] {
            close(
                &lbfgs(quadratic(c), &x0, &settings(25)).unwrap(),
                &base,
                "quadratic",
            );
            close(&lbfgs(rosen(c), &r0, &s).unwrap(), &base_r, "Rosenbrock");
        }
    }

    /// Both methods say when they stop at their cap rather than by their convergence test.
    #[test]
    fn stopping_at_the_cap_is_reported() {
        let capped = LbfgsSettings {
            max_iterations: 3,
            ..LbfgsSettings::default()
        };
        let m = lbfgs(|x| Ok(rosenbrock(x)), &[-1.2, 1.0], &capped).unwrap();
        assert!(m.at_limit && m.iterations == 3, "{m:?}");
        assert_eq!(m.stop_reason, "reached 3 iterations");
        let s = HookeJeevesSettings {
            max_evaluations: 20,
            ..Default::default()
        };
        let m = hooke_jeeves(|x| rosenbrock(x).0, &[-1.2, 1.0], &s).unwrap();
        assert!(m.at_limit && m.evaluations == 20, "{m:?}");
        // Exactly at the cap with many parameters too (a sweep is 2 x 40 trials).
        let s = HookeJeevesSettings {
            max_evaluations: 101,
            ..Default::default()
        };
        let m = hooke_jeeves(|x| x.iter().map(|v| v * v).sum(), &[1.0; 40], &s).unwrap();
        assert!(m.at_limit && m.evaluations == 101, "{m:?}");
        // A sweep cut short by the cap that shrinks the step below min_step is still a stop
        // at the cap, not convergence.
        let s = HookeJeevesSettings {
            initial_step: 0.1,
            step_reduction: 0.5,
            min_step: 0.06,
            max_evaluations: 3,
        };
        let m = hooke_jeeves(|x| x.iter().map(|v| v * v).sum(), &[0.0, 0.0], &s).unwrap();
        assert!(m.at_limit && m.evaluations == 3, "{m:?}");
        let m = hooke_jeeves(|x| x[0] * x[0], &[0.3], &HookeJeevesSettings::default()).unwrap();
        assert!(!m.at_limit, "{m:?}");
    }

    /// Hooke-Jeeves returns the best point it evaluated, whatever its evaluation cap, and the
    /// value it reports is the objective there. (At the cap inside the exploration about a
    /// pattern point it returned the previous base point: 32 where 2 had been evaluated.)
    #[test]
    fn hooke_jeeves_returns_the_best_point_evaluated_at_any_cap() {
        for (dim, target) in [(2, 10.0), (5, 3.7)] {
            let f = |x: &[f64]| -> f64 { x.iter().map(|a| (a - target) * (a - target)).sum() };
            for cap in 1..400 {
                let best = Cell::new(f64::INFINITY);
                let counted = |x: &[f64]| {
                    let v = f(x);
                    best.set(best.get().min(v));
                    v
                };
                let s = HookeJeevesSettings {
                    initial_step: 1.0,
                    max_evaluations: cap,
                    ..Default::default()
                };
                let m = hooke_jeeves(counted, &vec![0.0; dim], &s).unwrap();
                assert_eq!(m.value, best.get(), "dim {dim}, cap {cap}: {m:?}");
                assert_eq!(f(&m.x), m.value, "dim {dim}, cap {cap}: {m:?}");
                assert!(m.evaluations <= cap as u64, "dim {dim}, cap {cap}: {m:?}");
            }
        }
    }

    #[test]
    fn lbfgs_solves_an_ill_conditioned_quadratic() {
        // 60-D diagonal quadratic with curvatures 1..1e4, from a gradient of norm ~1e4 down to
        // 1e-8. Reference: scipy's L-BFGS-B (maxcor = 100, gtol = 1e-8) takes 377 iterations on
        // this problem (this implementation: 369); steepest descent would need ~1e5.
        let n = 60;
        let h: Vec<f64> = (0..n)
            .map(|i| 10f64.powf(4.0 * i as f64 / (n - 1) as f64))
            .collect();
        let f = |x: &[f64]| {
            let v = x
                .iter()
                .zip(&h)
                .map(|(a, c)| 0.5 * c * (a - 1.0) * (a - 1.0))
                .sum();
            let g = x.iter().zip(&h).map(|(a, c)| c * (a - 1.0)).collect();
            Ok((v, g))
        };
        let settings = LbfgsSettings {
            gradient_tolerance: 1e-8,
            cost_tolerance: 0.0,
            ..LbfgsSettings::default()
        };
        let m = lbfgs(f, &vec![0.0; n], &settings).unwrap();
        assert!(
            m.x.iter().all(|a| (a - 1.0).abs() < 1e-9),
            "{:?}",
            m.stop_reason
        );
        assert!(m.iterations < 450, "{} iterations", m.iterations);
    }

    #[test]
    fn lbfgs_stays_where_the_objective_is_defined() {
        // (x - 2)^2 is only defined for x < 1.5 (errors beyond, like a kernel matrix that stops
        // being positive definite): the line search must back off, never propagate the error,
        // and stop close to the boundary.
        let f = |x: &[f64]| {
            if x[0] >= 1.5 {
                Err(Error::Objective {
                    reason: "outside the domain".into(),
                })
            } else {
                Ok(((x[0] - 2.0).powi(2), vec![2.0 * (x[0] - 2.0)]))
            }
        };
        let m = lbfgs(f, &[0.0], &LbfgsSettings::default()).unwrap();
        assert!(m.x[0] < 1.5 && m.x[0] > 1.4, "{m:?}");
        assert!(m.value < 0.37, "{m:?}");
        // Non-finite values or gradients beyond it are treated alike, and the search gets to
        // within 1e-6 of the boundary: a failed step bounds the interval searched. (It halved
        // such a step, then doubled again from the next finite point back into the undefined
        // region, and stopped at 1.4968.) The gradient there is still -1: not converged.
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for bad_value in [true, false] {
                let f = |x: &[f64]| -> Result<(f64, Vec<f64>)> {
                    let (v, g) = ((x[0] - 2.0).powi(2), 2.0 * (x[0] - 2.0));
                    Ok(match (x[0] >= 1.5, bad_value) {
                        (false, _) => (v, vec![g]),
                        (true, true) => (bad, vec![g]),
                        (true, false) => (v, vec![bad]),
                    })
                };
                let m = lbfgs(f, &[0.0], &LbfgsSettings::default()).unwrap();
                let what = format!("{bad} (value {bad_value}): {m:?}");
                assert!(m.x[0] < 1.5 && m.x[0] > 1.5 - 1e-6, "{what}");
                assert!(
                    m.value == (m.x[0] - 2.0).powi(2) && m.value < 0.25 + 1e-6,
                    "{what}"
                );
                assert!(m.stalled && m.evaluations < 200, "{what}");
            }
        }
        // An error at the start is reported, not hidden.
        let bad = |_: &[f64]| -> Result<(f64, Vec<f64>)> {
            Err(Error::Objective {
                reason: "broken".into(),
            })
        };
        assert!(lbfgs(bad, &[0.0], &LbfgsSettings::default()).is_err());
    }

    /// A minimum ~2^33 first steps away (f = sqrt(1 + (x - c)^2), slope ~-1 until near c):
    /// the bracketing phase runs out of evaluations before the curvature condition holds, and
    /// its last point, which satisfies sufficient decrease, is taken. (It was dropped: L-BFGS
    /// stayed at 0 and reported a stall.)
    #[test]
    fn lbfgs_reaches_a_distant_minimum() {
        for c in [1e3, 1e10] {
            let f = |x: &[f64]| {
                let d = x[0] - c;
                let r = (1.0 + d * d).sqrt();
                Ok((r, vec![d / r]))
            };
            let m = lbfgs(f, &[0.0], &LbfgsSettings::default()).unwrap();
            assert!((m.x[0] - c).abs() < 1e-3, "{c:e}: {m:?}");
            assert!(
                !m.stalled && !m.at_limit && m.value < 1.0 + 1e-9,
                "{c:e}: {m:?}"
            );
        }
    }

    #[test]
    fn bad_settings_and_non_finite_start_are_errors() {
        let s = HookeJeevesSettings {
            step_reduction: 1.5,
            ..Default::default()
        };
        assert!(hooke_jeeves(|x| x[0], &[0.0], &s).is_err());
        // Settings whose step never falls below min_step are refused: with no parameters the
        // search made no evaluation, so neither its own test nor the cap stopped it (a hang),
        // and with parameters it burnt the whole budget at a step of 0 or infinity.
        for (initial_step, min_step) in [
            (0.1, 0.0),
            (0.1, -1.0),
            (0.1, f64::NAN),
            (f64::INFINITY, 1e-6),
            (0.1, f64::INFINITY),
        ] {
            let s = HookeJeevesSettings {
                initial_step,
                min_step,
                ..Default::default()
            };
            let e = hooke_jeeves(|_| 0.0, &[], &s).unwrap_err().to_string();
            assert!(e.contains("min_step"), "{initial_step} {min_step}: {e}");
            assert!(hooke_jeeves(|x| x[0] * x[0], &[1.0], &s).is_err());
        }
        // Sound settings with no parameters stop by the step test.
        let m = hooke_jeeves(|_| 0.0, &[], &HookeJeevesSettings::default()).unwrap();
        assert!(!m.at_limit && m.evaluations == 1, "{m:?}");
        // The bounds themselves: a zero step and a reduction of 0 or 1 never converge.
        for (initial_step, step_reduction) in [(0.0, 0.5), (0.1, 0.0), (0.1, 1.0)] {
            let s = HookeJeevesSettings {
                initial_step,
                step_reduction,
                ..Default::default()
            };
            let e = hooke_jeeves(|x| x[0], &[0.0], &s).unwrap_err().to_string();
            assert!(e.contains("step_reduction in (0, 1)"), "{e}");
        }
        let s = HookeJeevesSettings::default();
        assert!(hooke_jeeves(|_| f64::NAN, &[0.0], &s).is_err());
    }

    /// On a constant objective every sweep fails, so the step halves from 1 until it is below
    /// 1e-3: 10 iterations (steps 2^0..2^-9) of 2 trials per coordinate, plus the start, and
    /// the start is returned.
    #[test]
    fn hooke_jeeves_counts_iterations_and_evaluations() {
        let s = HookeJeevesSettings {
            initial_step: 1.0,
            step_reduction: 0.5,
            min_step: 1e-3,
            max_evaluations: 1000,
        };
        let m = hooke_jeeves(|_| 7.0, &[0.25, -2.0, 3.0], &s).unwrap();
        assert_eq!(m.x, vec![0.25, -2.0, 3.0]);
        assert_eq!(
            (m.value, m.iterations, m.evaluations),
            (7.0, 10, 1 + 10 * 2 * 3)
        );
        assert!(
            !m.at_limit && m.stop_reason.starts_with("step 9.766e-4 below"),
            "{m:?}"
        );
    }

    /// Exploratory moves take strict improvements only: a coordinate the objective does not
    /// depend on stays exactly where it started while the others reach the minimum.
    #[test]
    fn hooke_jeeves_leaves_a_flat_coordinate_alone() {
        let s = HookeJeevesSettings {
            initial_step: 1.0,
            ..Default::default()
        };
        let m = hooke_jeeves(|x| (x[1] - 3.0).powi(2), &[0.5, 0.0], &s).unwrap();
        assert_eq!(m.x[0], 0.5, "{m:?}");
        assert!((m.x[1] - 3.0).abs() < 1e-6 && m.value < 1e-12, "{m:?}");
    }
}
