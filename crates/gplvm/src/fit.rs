//! Fitting: the Gram pass over a store, the PCA start, optimisation with restarts, and the model.

use std::path::Path;
use std::time::Instant;

use brdf_io::store::Store;
use faer::{Mat, MatRef, Par};
use gp_core::{FlatGplvm, GplvmObjective, KernelParams, Learn, centre_gram};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};

use crate::config::{DataScaling, FitConfig, FitParams, InitScaling, OptimizerKind};
use crate::error::{Error, Result};
use crate::model::{
    DatasetRef, FitReport, Hyperparameters, LatentMaterial, MODEL_FORMAT, MODEL_VERSION, Model,
};
use crate::optim::{HookeJeevesSettings, LbfgsSettings, Minimum, hooke_jeeves, lbfgs};
use crate::pca::Pca;
use crate::transform::Transform;

/// The result of one streaming pass over a store.
#[derive(Debug, Clone)]
pub struct GramPass {
    /// Uncentred Gram matrix of the transformed values, N x N.
    pub gram: Mat<f64>,
    /// Values per material that carry data (valid cells x channels).
    pub d_effective: usize,
    /// Seconds the pass took.
    pub seconds: f64,
}

/// Above this 2-norm condition of K a fit warns that its likelihood is numerically unreliable
/// (rounding moves log|K| by up to ~cond eps: an audit measured 3e-3 relative at 6.6e15).
const NEAR_SINGULAR: f64 = 1e12;

/// Largest N for which [`condition_number`] is exact (an eigen-decomposition, a few times one
/// likelihood evaluation, once per fit).
const EXACT_CONDITION_MAX_N: usize = 2000;

/// The 2-norm condition number `lambda_max / lambda_min` of `K + jitter I` at the latent points
/// `x`, from its eigenvalues (infinite when `lambda_min <= 0`); `None` above
/// [`EXACT_CONDITION_MAX_N`] points or when the decomposition fails (the caller then reports
/// the Cholesky factor's 1-norm estimate, which an audit found up to 19x low).
fn condition_number(x: &Mat<f64>, params: &KernelParams, jitter: f64) -> Option<f64> {
    if x.nrows() > EXACT_CONDITION_MAX_N {
        return None;
    }
    let mut k = params.kernel_matrix(x.as_ref()).ok()?;
    for i in 0..k.nrows() {
        k[(i, i)] += jitter;
    }
    let ev = k.self_adjoint_eigenvalues(faer::Side::Lower).ok()?;
    let (lo, hi) = ev.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &v| {
        (lo.min(v), hi.max(v))
    });
    Some(if lo > 0.0 { hi / lo } else { f64::INFINITY })
}

/// The random numbers of restart `restart` (>= 1) of a fit with `seed`: one ChaCha stream
/// per restart under the seed's key, so restarts of neighbouring seeds never share a
/// perturbation (`seed + restart` did: seed 1's restart 2 was seed 2's restart 1, an audit
/// found).
fn restart_rng(seed: u64, restart: usize) -> rand_chacha::ChaCha8Rng {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(restart as u64);
    rng
}

/// The start of restart `restart` (0: `theta0` itself): the first `n_latent` values (the
/// latent coordinates) perturbed by N(0, (0.1 l)^2) each, in units of the length-scale `l`, the
/// kernel's unit of latent distance (the same perturbation of `K` whatever `l`); drawn as
/// `0.1 l z` with `z` standard normal from [`restart_rng`].
fn restart_start(
    theta0: &[f64],
    n_latent: usize,
    lengthscale: f64,
    seed: u64,
    restart: usize,
) -> Vec<f64> {
    const RESTART_STD: f64 = 0.1;
    let mut theta = theta0.to_vec();
    if restart > 0 {
        let mut rng = restart_rng(seed, restart);
        for v in theta.iter_mut().take(n_latent) {
            let z: f64 = StandardNormal.sample(&mut rng);
            *v += RESTART_STD * lengthscale * z;
        }
    }
    theta
}

/// Computes the uncentred Gram matrix of the transformed data in one parallel streaming pass.
pub fn gram_pass(store: &Store, transform: Transform) -> Result<GramPass> {
    let start = Instant::now();
    let n = store.n_materials();
    let g = store.gram_with(&transform)?;
    // A non-finite value of material i makes its diagonal entry non-finite.
    if let Some(i) = (0..n).find(|&i| !g[i * n + i].is_finite()) {
        return Err(non_finite_material(store, transform, i));
    }
    let gram = Mat::from_fn(n, n, |i, j| g[i * n + j]);
    let valid = store.validity_mask().iter().filter(|v| **v).count();
    Ok(GramPass {
        gram,
        d_effective: valid * store.channels().len(),
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Why material `i`'s Gram entry is not finite: a stored value that is not
/// ([`Error::NonFiniteData`]: a damaged store), or a finite one that the transform takes out of
/// range ([`Error::TransformOverflow`]: e.g. `log` with an offset below ~1e-270, where
/// `f / offset` overflows). Read again on this error path only.
fn non_finite_material(store: &Store, transform: Transform, i: usize) -> Error {
    let (n, name) = (store.n_materials(), store.names()[i].to_owned());
    let mut culprit = None;
    let mut out = Vec::new();
    let scan = store.for_each_chunk(|_, block| {
        if culprit.is_some() {
            return;
        }
        let values: Vec<f32> = block.iter().skip(i).step_by(n).copied().collect();
        if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            culprit = Some(Err(*v));
            return;
        }
        out.resize(values.len(), 0.0);
        transform.forward_batch(&values, &mut out);
        if let Some(k) = out.iter().position(|y| !y.is_finite()) {
            culprit = Some(Ok(values[k]));
        }
    });
    match (scan, culprit) {
        (Err(e), _) => e.into(),
        (Ok(()), Some(Ok(value))) => Error::TransformOverflow {
            path: store.path().to_owned(),
            index: i,
            name,
            transform: transform.to_string(),
            value: f64::from(value),
        },
        _ => Error::NonFiniteData {
            path: store.path().to_owned(),
            index: i,
            name,
        },
    }
}

/// The centred Gram matrix divided by the data scale, and that scale.
pub fn scaled_centred_gram(
    g: MatRef<'_, f64>,
    d: usize,
    scaling: DataScaling,
) -> Result<(Mat<f64>, f64)> {
    let n = g.nrows();
    if n < 2 {
        return Err(Error::TooFewMaterials { n });
    }
    let s = centre_gram(g)?;
    let trace: f64 = (0..n).map(|i| s[(i, i)]).sum();
    // Centring subtracts numbers of the size of the uncentred trace: for identical materials
    // what is left is rounding, up to ~n eps tr(G) (an audit's 20 copies of one file left a
    // small positive trace and fitted nonsense, 7 copies a negative one).
    let uncentred: f64 = (0..n).map(|i| g[(i, i)].abs()).sum();
    if !(trace > 4.0 * n as f64 * f64::EPSILON * uncentred && trace.is_finite()) {
        return Err(Error::IdenticalMaterials {
            n,
            total_variance: trace,
            uncentred_total: uncentred,
        });
    }
    let scale = match scaling {
        DataScaling::None => 1.0,
        DataScaling::UnitVariance => trace / (n as f64 * d as f64),
    };
    Ok((Mat::from_fn(n, n, |i, j| s[(i, j)] / scale), scale))
}

/// A fitted latent space, before it is wrapped into a [`Model`].
#[derive(Debug, Clone)]
pub struct Fit {
    /// Latent points, N x q.
    pub x: Mat<f64>,
    /// Kernel hyperparameters.
    pub params: KernelParams,
    /// Variance divisor applied to the centred data.
    pub data_scale: f64,
    /// Diagnostics as written to the model file (`gram_seconds` is 0 here: [`fit_store`] fills
    /// it in, since the Gram pass happens outside [`fit_gram`]).
    pub report: FitReport,
}

/// What `learn_hyperparameters` learns with the latent points: the amplitude and the noise.
/// Not the length-scale: `K` depends on `X` only through `X / l`, so the scale of the free
/// latent points already plays its part, and with the prior on `X` the joint objective has no
/// maximum at all (`L(a X, a l) = L(X, l) + (1 - a^2) |X|^2 / 2` rises as `a -> 0`; an audit
/// found learnt fits drifting to l ~ 1e-3..1e-5 with `X` shrinking alike, stopping at the
/// iteration cap). The length-scale stays at its configured value, which only sets the units
/// of the latent space.
pub const LEARNT: Learn = Learn {
    signal_variance: true,
    length_scale: false,
    noise: true,
};

/// The flat objective the optimisers see: latent points, plus the amplitude and the noise
/// when `params.learn_hyperparameters` ([`LEARNT`]; the noise then kept above
/// `params.min_noise`).
pub fn flat_objective<'a>(
    objective: &'a GplvmObjective,
    q: usize,
    template: KernelParams,
    params: &FitParams,
) -> Result<FlatGplvm<'a>> {
    let (learn, floor) = if params.learn_hyperparameters {
        (LEARNT, params.min_noise)
    } else {
        (Learn::NONE, 0.0)
    };
    Ok(objective
        .flat(q, template, learn)?
        .with_noise_floor(floor)?)
}

/// Minimises `-L / per_value` of `flat` by Hooke-Jeeves from `theta0` with the step and
/// budget of `params` (the fits' and the leave-one-out refits' direct search). Its exploratory
/// trials move one latent point each and are evaluated in `O(N^2)` from a reference
/// factorisation ([`gp_core::MoveEvaluator`]); a trial whose evaluation fails counts as no
/// improvement.
pub fn minimise_by_hooke_jeeves(
    flat: &FlatGplvm<'_>,
    theta0: &[f64],
    params: &FitParams,
    per_value: f64,
) -> Result<Minimum> {
    let settings = HookeJeevesSettings {
        initial_step: params.initial_step,
        step_reduction: 0.5,
        min_step: params.min_step,
        max_evaluations: params.max_evaluations,
    };
    let mut evaluator = flat.move_evaluator();
    let run = hooke_jeeves(
        |t| {
            evaluator
                .neg_log_likelihood(t, Par::Seq)
                .map_or(f64::INFINITY, |v| v * per_value)
        },
        theta0,
        &settings,
    )?;
    let c = evaluator.counts();
    tracing::debug!(
        evaluations = c.evaluations,
        cheap = c.cheap,
        references = c.references,
        updates = c.updates,
        "Hooke-Jeeves trials by one-point moves"
    );
    Ok(run)
}

fn template_params(config: &FitConfig) -> Result<KernelParams> {
    let p = &config.params;
    Ok(KernelParams::isotropic(
        p.amplitude * p.amplitude,
        p.lengthscale,
        p.noise,
    )?)
}

/// The factor `a` in 10^-3..10^3 maximising the likelihood of the start `a x0` (hyperparameters
/// at the template): a coarse log-spaced scan refined by golden-section search on log a.
fn best_start_scale(
    flat: &gp_core::FlatGplvm<'_>,
    x0: MatRef<'_, f64>,
    template: &KernelParams,
    par: Par,
) -> Result<f64> {
    let value = |log_a: f64| -> f64 {
        let a = log_a.exp();
        let x = Mat::from_fn(x0.nrows(), x0.ncols(), |i, k| x0[(i, k)] * a);
        flat.pack(x.as_ref(), template)
            .and_then(|t| flat.neg_log_likelihood(&t, par))
            .unwrap_or(f64::INFINITY)
    };
    let (lo, hi, steps) = (
        -3.0f64 * std::f64::consts::LN_10,
        3.0 * std::f64::consts::LN_10,
        25,
    );
    let grid: Vec<f64> = (0..=steps)
        .map(|i| lo + (hi - lo) * i as f64 / steps as f64)
        .collect();
    let values: Vec<f64> = grid.iter().map(|&g| value(g)).collect();
    let best = (0..values.len())
        .min_by(|&a, &b| values[a].total_cmp(&values[b]))
        .ok_or_else(|| Error::Objective {
            reason: "empty scale scan".into(),
        })?;
    if !values[best].is_finite() {
        return Err(Error::Objective {
            reason: "the likelihood is not finite at any scale of the PCA start".into(),
        });
    }
    // Golden-section refinement in the bracketing interval.
    let (mut a, mut b) = (grid[best.saturating_sub(1)], grid[(best + 1).min(steps)]);
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    let (mut c, mut d) = (b - phi * (b - a), a + phi * (b - a));
    let (mut fc, mut fd) = (value(c), value(d));
    for _ in 0..40 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - phi * (b - a);
            fc = value(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + phi * (b - a);
            fd = value(d);
        }
    }
    let refined = 0.5 * (a + b);
    Ok(if value(refined) <= values[best] {
        refined.exp()
    } else {
        grid[best].exp()
    })
}

/// Fits the latent space to an uncentred Gram matrix `g` of data with `d` informative values
/// per material.
pub fn fit_gram(g: MatRef<'_, f64>, d: usize, config: &FitConfig) -> Result<Fit> {
    let p = &config.params;
    let (s, data_scale) = scaled_centred_gram(g, d, p.data_scaling)?;
    let n = s.nrows();
    let q = p.latent_dim;
    // Centred data span at most min(N - 1, D) dimensions (D = 1 value per material spans one).
    let span = n.saturating_sub(1).min(d);
    if q > span {
        tracing::warn!(
            "latent dimension q = {q} for N = {n} materials of D = {d} values: centred data \
             span at most min(N - 1, D) = {span} dimensions, so the PCA start leaves {} of them \
             at 0 up to rounding (a smaller q fits the same)",
            q - span
        );
    }
    let (s2, mu) = (p.amplitude * p.amplitude, p.noise);
    if mu >= s2 && !p.learn_hyperparameters {
        tracing::warn!(
            "noise {mu:e} is at least the kernel's signal variance s^2 = {s2:e}: K is mostly \
             noise, so where the materials sit hardly changes the likelihood (the fit may stop \
             at once); with data scaled to unit average variance (the default), a noise well \
             below 1 (default 1e-4) makes a latent space"
        );
    }
    if s2 + mu == s2 {
        tracing::warn!(
            "noise {mu:e} is below the rounding of the kernel's diagonal s^2 + mu = {s2:e}: it \
             acts as 0 (any noise under {:.0e} fits the same)",
            s2 * f64::EPSILON / 2.0
        );
    }
    let pca = Pca::from_centred_gram(s.as_ref(), q)?;
    let objective = GplvmObjective::new(s, d)?.with_prior(p.prior);
    let template = template_params(config)?;
    let flat = flat_objective(&objective, q, template.clone(), p)?;
    let par = Par::Seq;
    let mut x0 = pca.latent_start(p.init_scaling);
    if p.init_scaling == InitScaling::Likelihood {
        let factor = best_start_scale(&flat, x0.as_ref(), &template, par)?;
        tracing::info!(
            factor,
            "PCA start scaled by the likelihood-maximising factor"
        );
        x0 = Mat::from_fn(x0.nrows(), x0.ncols(), |i, k| x0[(i, k)] * factor);
    }
    let theta0 = flat.pack(x0.as_ref(), &template)?;
    let initial_log_likelihood = -flat.neg_log_likelihood(&theta0, par)?;
    // The optimisers see the negative log-likelihood per data value, -L / (N D): the same
    // optimum, with values and gradients of order 1 whatever the data size, so step sizes and
    // tolerances mean the same thing for every dataset.
    let per_value = 1.0 / (n as f64 * d as f64);

    let start = Instant::now();
    let mut best: Option<Minimum> = None;
    let (mut iterations, mut evaluations) = (0u64, 0u64);
    for restart in 0..=p.restarts {
        let start_theta = restart_start(&theta0, n * q, p.lengthscale, p.seed, restart);
        let run = match p.optimizer {
            OptimizerKind::HookeJeeves => {
                minimise_by_hooke_jeeves(&flat, &start_theta, p, per_value)?
            }
            OptimizerKind::Lbfgs => {
                let settings = LbfgsSettings {
                    max_iterations: p.max_iterations,
                    gradient_tolerance: p.gradient_tolerance,
                    cost_tolerance: p.cost_tolerance,
                    ..LbfgsSettings::default()
                };
                lbfgs(
                    |t| {
                        let (v, mut g) = flat.neg_log_likelihood_and_gradient(t, par)?;
                        g.iter_mut().for_each(|x| *x *= per_value);
                        Ok((v * per_value, g))
                    },
                    &start_theta,
                    &settings,
                )?
            }
        };
        tracing::info!(
            restart,
            value = -run.value / per_value,
            evaluations = run.evaluations,
            "optimisation run finished"
        );
        iterations += run.iterations;
        evaluations += run.evaluations;
        if best.as_ref().is_none_or(|b| run.value < b.value) {
            best = Some(run);
        }
    }
    let seconds = start.elapsed().as_secs_f64();
    let best = best.ok_or_else(|| Error::Objective {
        reason: "no optimisation run".into(),
    })?;
    let eval = flat.evaluate(&best.x, par)?;
    let (_, grad) = flat.neg_log_likelihood_and_gradient(&best.x, par)?;
    let gradient_norm = gp_core::fastmath::norm(&grad);
    if best.stalled {
        tracing::warn!(
            "the optimiser stalled before converging ({}): log-likelihood {:.6e}, |gradient| \
             {gradient_norm:.2e}; the fit is not at a maximum (try --restarts, fixed \
             hyperparameters, or another latent dimension)",
            best.stop_reason,
            -best.value / per_value,
        );
    }
    if best.at_limit {
        tracing::warn!(
            "the optimiser stopped at its cap ({}) before converging: log-likelihood {:.6e}, \
             |gradient| {gradient_norm:.2e}; raise {} in the fit configuration for a converged fit",
            best.stop_reason,
            -best.value / per_value,
            match p.optimizer {
                OptimizerKind::Lbfgs => "max_iterations",
                OptimizerKind::HookeJeeves => "max_evaluations",
            }
        );
    }
    let (x, params) = flat.unpack(&best.x)?;
    let condition_number =
        condition_number(&x, &params, eval.factor.jitter).unwrap_or(eval.factor.condition_estimate);
    if condition_number > NEAR_SINGULAR {
        tracing::warn!(
            "K is nearly singular at the optimum (2-norm condition {condition_number:.1e}): its \
             log-determinant and the log-likelihood carry a relative error of up to about \
             {:.0e}; a larger noise (or min_noise when it is learnt) keeps K well conditioned",
            condition_number * f64::EPSILON
        );
    }
    let isolated = isolated_materials(x.as_ref(), &params);
    if 2 * isolated > n {
        tracing::warn!(
            "{isolated} of {n} materials correlate less than {ISOLATED_CORRELATION:e} with their \
             nearest neighbour in the latent space (they sit many length-scales apart): between \
             them the GP predicts the data mean, so the space does not interpolate; a larger \
             lengthscale (or a fit from a smaller PCA scale) brings them together"
        );
    }
    Ok(Fit {
        x,
        params,
        data_scale,
        report: FitReport {
            optimizer: p.optimizer.to_string(),
            log_likelihood: eval.value,
            initial_log_likelihood,
            gradient_norm,
            jitter: eval.factor.jitter,
            condition_number,
            iterations,
            evaluations,
            stop_reason: best.stop_reason,
            gram_seconds: 0.0,
            optimize_seconds: seconds,
            pca_explained: pca.explained(q),
        },
    })
}

/// Fits a GPLVM to the store at `path` and returns the model (not yet saved). The store's
/// payload checksum is verified too: the model records that checksum, so a store damaged after
/// it was written must not be fitted as if it were the data the checksum names (a mismatch is
/// the error, whatever the Gram pass found). The hash runs on a thread of its own during the
/// Gram pass, so that both read the payload from the disk once between them: the hash mostly
/// reads what the pass has just brought into the page cache, or the other way round (the
/// paper's 58 GB grid, larger than this machine's memory, was read twice: 60 of 100 s).
pub fn fit_store(path: &Path, config: &FitConfig) -> Result<Model> {
    let store = Store::open(path)?;
    let (verified, pass) = std::thread::scope(|s| {
        let hash = s.spawn(|| store.verify_checksum());
        let pass = gram_pass(&store, config.transform);
        (hash.join(), pass)
    });
    verified.unwrap_or_else(|panic| std::panic::resume_unwind(panic))?;
    let pass = pass?;
    let fit = fit_gram(pass.gram.as_ref(), pass.d_effective, config)?;
    let header = store.header();
    let n = store.n_materials();
    let abs_path = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_owned());
    Ok(Model {
        format: MODEL_FORMAT.into(),
        version: MODEL_VERSION,
        dataset: DatasetRef {
            path: abs_path,
            checksum: header.checksum.to_string(),
            n_materials: n,
            d: store.d(),
            d_effective: pass.d_effective,
            grid: store.grid().to_string(),
            channels: store.channels().labels(),
        },
        transform: config.transform,
        data_scale: fit.data_scale,
        prior: config.params.prior,
        latent_dim: config.params.latent_dim,
        hyperparameters: Hyperparameters {
            signal_variance: fit.params.signal_variance(),
            length_scale: fit.params.length_scale().values().to_vec(),
            noise: fit.params.noise(),
        },
        fit: FitReport {
            gram_seconds: pass.seconds,
            ..fit.report
        },
        config: config.params.clone(),
        materials: store
            .names()
            .iter()
            .enumerate()
            .map(|(i, name)| LatentMaterial {
                name: (*name).to_owned(),
                coords: (0..fit.x.ncols()).map(|k| fit.x[(i, k)]).collect(),
            })
            .collect(),
        gram: (0..n)
            .map(|i| (0..n).map(|j| pass.gram[(i, j)]).collect())
            .collect(),
    })
}

/// Below this kernel correlation `k(x_i, x_j) / s^2` with its nearest neighbour a material is
/// isolated: the GP barely links it to any other.
pub const ISOLATED_CORRELATION: f64 = 1e-3;

/// How many latent points correlate less than [`ISOLATED_CORRELATION`] with their nearest
/// neighbour (`exp(-r^2 / 2)`, r the scaled distance). `O(N^2 q)`. When most are, the fit
/// may report convergence on the plateau `K ~ (s^2 + mu) I` (an audit: lengthscale 1e-6), where
/// the space predicts the mean everywhere between materials.
pub fn isolated_materials(x: MatRef<'_, f64>, params: &KernelParams) -> usize {
    let n = x.nrows();
    let rows: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..x.ncols()).map(|k| x[(i, k)]).collect())
        .collect();
    // exp(-r^2 / 2) < c  <=>  r^2 > -2 ln c.
    let r2_max = -2.0 * ISOLATED_CORRELATION.ln();
    (0..n)
        .filter(|&i| {
            n > 1
                && (0..n)
                    .filter(|&j| j != i)
                    .all(|j| params.scaled_sq_dist(&rows[i], &rows[j]) > r2_max)
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngCore;

    /// Points 4 length-scales apart correlate exp(-8) = 3.4e-4 < 1e-3 (isolated); 3 apart
    /// exp(-4.5) = 1.1e-2 (linked).
    #[test]
    fn isolated_materials_counts_points_far_from_every_other() {
        let p = KernelParams::isotropic(1.0, 0.5, 1e-4).unwrap();
        let x = Mat::from_fn(4, 1, |i, _| [0.0, 1.5, 3.5, 5.5][i]);
        // In length-scales: 0, 3, 7, 11: points 0 and 1 linked, 2 and 3 each 4 from the next.
        assert_eq!(isolated_materials(x.as_ref(), &p), 2);
        let wide = KernelParams::isotropic(1.0, 1.0, 1e-4).unwrap();
        assert_eq!(isolated_materials(x.as_ref(), &wide), 0);
        assert_eq!(isolated_materials(x.as_ref().subrows(0, 1), &p), 0);
    }

    /// Restart streams differ between restarts of one seed and between neighbouring seeds
    /// (seed 7's restart 2 and seed 8's restart 1 were the same stream).
    #[test]
    fn restart_streams_of_neighbouring_seeds_differ() {
        let first = |seed, restart| restart_rng(seed, restart).next_u64();
        let draws = [
            first(7, 1),
            first(7, 2),
            first(8, 1),
            first(8, 2),
            first(9, 1),
        ];
        for i in 0..draws.len() {
            for j in 0..i {
                assert_ne!(draws[i], draws[j], "{i} {j}");
            }
        }
        // Deterministic.
        assert_eq!(first(7, 2), first(7, 2));
    }

    /// A restart moves the latent coordinates by the same multiple of the length-scale whatever
    /// it is (a fixed 0.1 was 1e-3 length-scales at l = 100 and 1000 at l = 1e-4), leaves the
    /// hyperparameters after them alone, and restart 0 is the start itself.
    #[test]
    fn restart_perturbations_are_in_length_scales() {
        let theta0 = [0.5, -1.0, 2.0, 0.25, 7.0];
        assert_eq!(restart_start(&theta0, 4, 3.0, 5, 0), theta0);
        let unit = restart_start(&theta0, 4, 1.0, 5, 2);
        let moved = |t: &[f64]| -> Vec<f64> { t.iter().zip(&theta0).map(|(a, b)| a - b).collect() };
        let d1 = moved(&unit);
        assert!(d1[..4].iter().all(|d| *d != 0.0) && d1[4] == 0.0, "{d1:?}");
        // Standard deviation 0.1 length-scales: four draws stay within 6 of them.
        assert!(d1.iter().all(|d| d.abs() < 0.6), "{d1:?}");
        // From a zero start (no rounding of the sum), in length-scales.
        let zero = [0.0, 0.0, 0.0, 0.0, 7.0];
        let z1 = restart_start(&zero, 4, 1.0, 5, 2);
        for l in [1e-4, 0.3, 100.0] {
            let d = restart_start(&zero, 4, l, 5, 2);
            for k in 0..4 {
                let rel = (d[k] / l - z1[k]).abs() / z1[k].abs();
                assert!(
                    rel < 1e-14,
                    "l = {l}, coordinate {k}: {} vs {}",
                    d[k] / l,
                    z1[k]
                );
            }
            assert_eq!(d[4], 7.0);
        }
    }

    /// The condition number is the ratio of the extreme eigenvalues of `K + jitter I`: for two
    /// points, `(k11 + j + k12) / (k11 + j - k12)`; `None` beyond
    /// [`EXACT_CONDITION_MAX_N`] points (the caller falls back to the Cholesky estimate).
    #[test]
    fn condition_number_is_exact_for_two_points_and_skipped_beyond_the_cap() {
        let p = KernelParams::isotropic(1.5, 0.8, 1e-3).unwrap();
        let x = Mat::from_fn(2, 1, |i, _| [0.0, 0.5][i]);
        let k = p.kernel_matrix(x.as_ref()).unwrap();
        let (k11, k12) = (k[(0, 0)], k[(0, 1)]);
        assert!(k12 > 0.5 && k11 > k12);
        for jitter in [0.0, 0.25] {
            let want = (k11 + jitter + k12) / (k11 + jitter - k12);
            let got = condition_number(&x, &p, jitter).unwrap();
            assert!(
                (got - want).abs() <= 1e-12 * want,
                "jitter {jitter}: {got} vs {want}"
            );
        }
        let far = Mat::from_fn(EXACT_CONDITION_MAX_N + 1, 1, |i, _| i as f64);
        assert_eq!(condition_number(&far, &p, 0.0), None);
    }

    /// At exactly [`EXACT_CONDITION_MAX_N`] points the condition number is still exact: with
    /// the points far apart K is `(s^2 + mu) I` up to ~1e-300, so it is 1.
    #[test]
    fn condition_number_is_exact_up_to_the_cap() {
        let p = KernelParams::isotropic(1.0, 1.0, 1e-4).unwrap();
        let x = Mat::from_fn(EXACT_CONDITION_MAX_N, 1, |i, _| 40.0 * i as f64);
        let c = condition_number(&x, &p, 0.0).unwrap();
        assert!((c - 1.0).abs() < 1e-12, "{c}");
    }

    /// The likelihood-maximising scale of the PCA start: the coarse scan and the golden-section
    /// refinement find the minimum of a dense scan of `-L(a x0)` to 1e-3 in `log a`, anywhere
    /// in 10^-3..10^3: dividing `x0` by 300 multiplies the factor by 300, and dividing it by
    /// 1e4 puts the optimum beyond the range, where its upper end is returned.
    #[test]
    fn best_start_scale_finds_the_likelihood_maximum_across_its_range() {
        let (n, d) = (9, 6);
        let y = Mat::from_fn(n, d, |i, j| {
            (0.7 * i as f64 + 1.3 * j as f64).sin() + 0.5 * (0.3 * (i * j) as f64).cos()
        });
        let g = &y * y.transpose();
        let (s, _) = scaled_centred_gram(g.as_ref(), d, DataScaling::UnitVariance).unwrap();
        let params = FitParams {
            latent_dim: 2,
            ..FitParams::default()
        };
        let template = KernelParams::isotropic(1.0, 1.0, 1e-4).unwrap();
        let objective = GplvmObjective::new(s.clone(), d).unwrap().with_prior(true);
        let flat = flat_objective(&objective, 2, template.clone(), &params).unwrap();
        let x0 = Pca::from_centred_gram(s.as_ref(), 2)
            .unwrap()
            .latent_start(InitScaling::Isotropic);
        let value = |x: MatRef<'_, f64>, log_a: f64| {
            let a = log_a.exp();
            let xa = Mat::from_fn(x.nrows(), x.ncols(), |i, k| x[(i, k)] * a);
            let t = flat.pack(xa.as_ref(), &template).unwrap();
            flat.neg_log_likelihood(&t, Par::Seq).unwrap()
        };
        let dense_argmin = |x: MatRef<'_, f64>| {
            let (lo, hi) = (
                -3.0 * std::f64::consts::LN_10,
                3.0 * std::f64::consts::LN_10,
            );
            (0..=60_000)
                .map(|i| lo + (hi - lo) * f64::from(i) / 60_000.0)
                .min_by(|a, b| value(x, *a).total_cmp(&value(x, *b)))
                .unwrap()
        };
        let a1 = best_start_scale(&flat, x0.as_ref(), &template, Par::Seq).unwrap();
        let want = dense_argmin(x0.as_ref());
        assert!((a1.ln() - want).abs() < 1e-3, "{a1} vs {}", want.exp());
        // Inside, away from the ends: a maximum, not a range end.
        assert!(a1 > 1e-2 && a1 < 10.0, "{a1}");
        // The same start 300 times smaller needs a factor 300 times larger (ln 300 = 5.7,
        // near the top of the range).
        let small = Mat::from_fn(n, 2, |i, k| x0[(i, k)] / 300.0);
        let a300 = best_start_scale(&flat, small.as_ref(), &template, Par::Seq).unwrap();
        assert!(
            (a300 / a1 / 300.0 - 1.0).abs() < 1e-3,
            "{a300} vs 300 x {a1}"
        );
        // Beyond the range: its upper end, 10^3.
        let tiny = Mat::from_fn(n, 2, |i, k| x0[(i, k)] / (1e4 * a1));
        let top = best_start_scale(&flat, tiny.as_ref(), &template, Par::Seq).unwrap();
        assert!((top / 1e3 - 1.0).abs() < 1e-9, "{top}");
    }
}
