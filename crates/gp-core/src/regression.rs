//! GP regression on latent points: posterior weights, mean and variance (DESIGN.md section 4).
//!
//! With training latent points `X` (`N x q`), `K = K_rbf(X) + mu I` (plus the factorisation
//! jitter `j`, if any) and a test point `x*`:
//!
//! ```text
//! w(x*)   = K^-1 k*                                  (posterior weights, N values)
//! y*      = m + sum_i w_i (y_i - m)                  (posterior mean, any output dimension)
//! var(x*) = s^2 + mu + j - k_s^T K^-1 k_s            (predictive variance, one scalar)
//! ```
//!
//! Two predictors differ only in `k*` ([`Predictor`]):
//! - [`Predictor::Exact`] (the paper's): `k*_i = k_rbf(x_i, x*) + (mu + j) [x* == x_i]`. At a
//!   training point `k* = K e_i`, so `w = e_i` and the training output is reproduced exactly
//!   (returned as `e_i`, not solved for, so even an ill-conditioned `K` reproduces it).
//! - [`Predictor::Smooth`]: `k*_i = k_rbf(x_i, x*)` (no delta term), the usual noise-free
//!   posterior mean, continuous in `x*` but shrunk towards `m` at training points.
//!
//! [`GpRegression::variance`] uses the smooth `k_s` (the predictive variance of a noisy
//! observation at `x*`); [`GpRegression::variance_of`] the `k*` of a given predictor (the
//! exact one's is 0 at a training point). Both are clamped at 0 against rounding. The jitter counts as noise everywhere (the
//! factor is of `K + j I`): in the exact predictor's delta term and in the variance's prior
//! `s^2 + mu + j`, so a jittered model's variance is that of the model it factors.

use crate::cholesky::{CholeskyFactor, JitterPolicy};
use crate::error::{GpError, Result, check_finite, check_finite_result, check_finite_slice};
use crate::kernel::KernelParams;
use faer::{Mat, MatMut, MatRef, Par};
use rayon::prelude::*;

/// Which cross-covariance `k*` the predictor uses (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Predictor {
    /// Includes the delta term at coinciding training points: reproduces training outputs
    /// exactly (the paper's predictor).
    #[default]
    Exact,
    /// No delta term: smooth posterior mean.
    Smooth,
}

/// A GP conditioned on training latent points: holds `X`, the hyperparameters and the Cholesky
/// factor of `K`.
#[derive(Debug, Clone)]
pub struct GpRegression {
    /// Scaled training coordinates `x_ij / l_j`, one vector per latent axis.
    z: Vec<Vec<f64>>,
    params: KernelParams,
    chol: CholeskyFactor,
}

impl GpRegression {
    /// Factors `K = K_rbf(X) + mu I` (default jitter policy). `X` is `N x q`.
    pub fn new(x: MatRef<'_, f64>, params: KernelParams, par: Par) -> Result<Self> {
        Self::with_policy(x, params, JitterPolicy::default(), par)
    }

    /// As [`new`](Self::new) with an explicit jitter policy.
    pub fn with_policy(
        x: MatRef<'_, f64>,
        params: KernelParams,
        policy: JitterPolicy,
        par: Par,
    ) -> Result<Self> {
        let z = params.scaled_axes(x, "training latent points X")?;
        let k = params.kernel_matrix(x)?;
        let chol = CholeskyFactor::with_policy(k.as_ref(), policy, par)?;
        Ok(GpRegression { z, params, chol })
    }

    /// Number of training points `N`.
    pub fn n(&self) -> usize {
        self.z[0].len()
    }

    /// Latent dimension `q`.
    pub fn q(&self) -> usize {
        self.z.len()
    }

    /// Hyperparameters.
    pub fn params(&self) -> &KernelParams {
        &self.params
    }

    /// Cholesky factor of `K` (jitter, attempts, condition estimate).
    pub fn factor(&self) -> &CholeskyFactor {
        &self.chol
    }

    /// `mu + jitter`: the delta term of the exact predictor.
    pub fn effective_noise(&self) -> f64 {
        self.params.noise() + self.chol.jitter()
    }

    fn check_point(&self, x_star: &[f64]) -> Result<()> {
        if x_star.len() != self.q() {
            return Err(GpError::DimensionMismatch {
                what: "test point x* vs latent dimension q",
                expected: self.q(),
                got: x_star.len(),
            });
        }
        check_finite_slice(x_star, "test latent point x*")
    }

    fn check_points(&self, x_star: MatRef<'_, f64>) -> Result<()> {
        if x_star.ncols() != self.q() {
            return Err(GpError::DimensionMismatch {
                what: "test points X* columns vs latent dimension q",
                expected: self.q(),
                got: x_star.ncols(),
            });
        }
        check_finite(x_star, "test latent points X*")
    }

    /// Fills `out` (length N) with `k*` for the given predictor. For [`Predictor::Exact`],
    /// returns the training point `x*` coincides with when exactly one does: there
    /// `k* = (K + j I) e_i`, so the weights are `e_i` and the variance 0 exactly, which callers
    /// return as such (a solve gives `e_i` only to ~cond(K) eps: an audit measured 6e-3 off a
    /// training material at cond 5e13). Several training points at one location (bitwise equal
    /// coordinates) share the delta term, and `k*` is then no column of `K`.
    fn fill_kstar(&self, x_star: &[f64], predictor: Predictor, out: &mut [f64]) -> Option<usize> {
        let mu = self.effective_noise();
        let s2 = self.params.signal_variance();
        self.params.fill_sq_dist(&self.z, x_star, out);
        let (mut at, mut coinciding) = (None, 0usize);
        for (i, o) in out.iter_mut().enumerate() {
            let r2 = *o;
            *o = s2 * (-0.5 * r2).exp();
            if predictor == Predictor::Exact && r2 == 0.0 {
                *o += mu;
                at = Some(i);
                coinciding += 1;
            }
        }
        at.filter(|_| coinciding == 1)
    }

    /// `k*` for one test point (length N).
    pub fn cross_covariance(&self, x_star: &[f64], predictor: Predictor) -> Result<Vec<f64>> {
        self.check_point(x_star)?;
        let mut k = vec![0.0; self.n()];
        self.fill_kstar(x_star, predictor, &mut k);
        Ok(k)
    }

    /// Posterior weights `w = K^-1 k*` for one test point (length N); for the exact predictor
    /// at a training point `i`, exactly `e_i`.
    pub fn weights(&self, x_star: &[f64], predictor: Predictor) -> Result<Vec<f64>> {
        self.check_point(x_star)?;
        let mut k = vec![0.0; self.n()];
        if let Some(i) = self.fill_kstar(x_star, predictor, &mut k) {
            return Ok(unit_vector(k.len(), i));
        }
        let mut m = Mat::from_fn(k.len(), 1, |i, _| k[i]);
        self.solve_seq(m.as_mut(), true);
        Ok((0..k.len()).map(|i| m[(i, 0)]).collect())
    }

    /// Jacobian of the posterior weights with respect to the test point,
    /// `dw/dx*_j = K^-1 dk*/dx*_j` (`N x q`, column `j`), with
    /// `dk*_i/dx*_j = k_rbf(x_i, x*) (x_ij - x*_j) / l_j^2`. The delta term of the exact predictor
    /// is piecewise constant, so both predictors share this Jacobian away from training points.
    /// Useful to place a held-out material in the latent space by gradient descent. A training
    /// point whose `k_rbf` is 0 contributes 0 (its distance may overflow: `0 * inf` was NaN).
    pub fn weights_jacobian(&self, x_star: &[f64]) -> Result<Mat<f64>> {
        self.check_point(x_star)?;
        let (n, q) = (self.n(), self.q());
        let mut k = vec![0.0; n];
        self.fill_kstar(x_star, Predictor::Smooth, &mut k);
        let mut jac = Mat::from_fn(n, q, |i, j| {
            let l = self.params.length_scale().axis(j);
            if k[i] == 0.0 {
                0.0
            } else {
                k[i] * (self.z[j][i] - x_star[j] / l) / l
            }
        });
        self.solve_seq(jac.as_mut(), true);
        check_finite_result(jac.as_ref(), "weights Jacobian")?;
        Ok(jac)
    }

    /// Gradient with respect to the test point of `v . w(x*)`, `w` the smooth predictor's
    /// weights: `v^T J` for the Jacobian `J` of [`GpRegression::weights_jacobian`], by one solve
    /// (`a = K^-1 v`, then `sum_i a_i dk*_i/dx*_j`) instead of q. A gradient-based search for
    /// the latent point of a material costs two solves per step this way.
    pub fn weights_vjp(&self, x_star: &[f64], v: &[f64]) -> Result<Vec<f64>> {
        self.check_point(x_star)?;
        let (n, q) = (self.n(), self.q());
        if v.len() != n {
            return Err(GpError::DimensionMismatch {
                what: "weights_vjp: v vs N",
                expected: n,
                got: v.len(),
            });
        }
        let mut k = vec![0.0; n];
        self.fill_kstar(x_star, Predictor::Smooth, &mut k);
        let mut a = Mat::from_fn(n, 1, |i, _| v[i]);
        self.solve_seq(a.as_mut(), true);
        let grad: Vec<f64> = (0..q)
            .map(|j| {
                let l = self.params.length_scale().axis(j);
                let xj = x_star[j] / l;
                (0..n)
                    .filter(|&i| k[i] != 0.0)
                    .map(|i| a[(i, 0)] * k[i] * (self.z[j][i] - xj) / l)
                    .sum()
            })
            .collect();
        check_finite_slice(&grad, "weights vector-Jacobian product")?;
        Ok(grad)
    }

    /// Predictive variance `s^2 + mu + j - k_s^T K^-1 k_s` at one test point (clamped at 0;
    /// `j` = the factorisation jitter, usually 0): that of a new noisy observation at `x*`
    /// (the smooth `k_s`), what [`GpRegression::variance_batch`] shades maps with.
    pub fn variance(&self, x_star: &[f64]) -> Result<f64> {
        self.variance_of(x_star, Predictor::Smooth)
    }

    /// Predictive variance `s^2 + mu + j - k*^T K^-1 k*` with the `k*` of `predictor`: for
    /// [`Predictor::Smooth`] it is [`GpRegression::variance`]; for [`Predictor::Exact`] it is the
    /// same away from the training points and 0 at one (`k* = K e_i`: the exact predictor
    /// returns the training material itself), DESIGN.md section 4 with the paper's `k*`.
    pub fn variance_of(&self, x_star: &[f64], predictor: Predictor) -> Result<f64> {
        self.check_point(x_star)?;
        let mut k = vec![0.0; self.n()];
        if self.fill_kstar(x_star, predictor, &mut k).is_some() {
            return Ok(0.0);
        }
        let mut m = Mat::from_fn(k.len(), 1, |i, _| k[i]);
        self.solve_seq(m.as_mut(), false);
        let q: f64 = (0..k.len()).map(|i| m[(i, 0)] * m[(i, 0)]).sum();
        Ok((self.params.signal_variance() + self.effective_noise() - q).max(0.0))
    }

    fn solve_seq(&self, b: MatMut<'_, f64>, full: bool) {
        let mut b = b;
        faer::linalg::triangular_solve::solve_lower_triangular_in_place(
            self.chol.l(),
            b.as_mut(),
            Par::Seq,
        );
        if full {
            faer::linalg::triangular_solve::solve_upper_triangular_in_place(
                self.chol.l().transpose(),
                b.as_mut(),
                Par::Seq,
            );
        }
    }

    /// Runs `f(first_column, chunk)` over column chunks of `out`, in parallel for `Par::Rayon`.
    fn for_chunks(
        &self,
        out: &mut Mat<f64>,
        par: Par,
        f: impl Fn(usize, MatMut<'_, f64>) + Sync + Send,
    ) {
        let m = out.ncols();
        if m == 0 {
            return;
        }
        match par {
            Par::Seq => f(0, out.as_mut()),
            Par::Rayon(nt) => {
                let nt = nt.get().max(1);
                // Enough chunks to balance the load, each large enough for blocked solves.
                let chunk = m.div_ceil(4 * nt).clamp(64, 4096);
                out.as_mut()
                    .par_col_chunks_mut(chunk)
                    .enumerate()
                    .for_each(|(c, block)| f(c * chunk, block));
            }
        }
    }

    /// Posterior weights for `M` test points (rows of `X*`, `M x q`): returns `W = K^-1 K*`
    /// (`N x M`, column `m` = weights of test point `m`). One triangular solve pair with many
    /// right-hand sides, over column chunks in parallel when `par` is [`Par::Rayon`].
    pub fn weights_batch(
        &self,
        x_star: MatRef<'_, f64>,
        predictor: Predictor,
        par: Par,
    ) -> Result<Mat<f64>> {
        self.check_points(x_star)?;
        let q = self.q();
        let mut out = Mat::<f64>::zeros(self.n(), x_star.nrows());
        self.for_chunks(&mut out, par, |c0, mut block| {
            let mut xs = vec![0.0; q];
            // Columns at a training point: exactly e_i (see `fill_kstar`).
            let mut at_training = Vec::new();
            for (c, col) in block.as_mut().col_iter_mut().enumerate() {
                for (j, v) in xs.iter_mut().enumerate() {
                    *v = x_star[(c0 + c, j)];
                }
                if let Some(col) = col.try_as_col_major_mut()
                    && let Some(i) = self.fill_kstar(&xs, predictor, col.as_slice_mut())
                {
                    at_training.push((c, i));
                }
            }
            self.solve_seq(block.as_mut(), true);
            for (c, i) in at_training {
                let mut col = block.as_mut().col_mut(c);
                col.fill(0.0);
                col[i] = 1.0;
            }
        });
        Ok(out)
    }

    /// Predictive variances for `M` test points (rows of `X*`), clamped at 0.
    pub fn variance_batch(&self, x_star: MatRef<'_, f64>, par: Par) -> Result<Vec<f64>> {
        self.check_points(x_star)?;
        let q = self.q();
        let mut v = Mat::<f64>::zeros(self.n(), x_star.nrows());
        self.for_chunks(&mut v, par, |c0, mut block| {
            let mut xs = vec![0.0; q];
            for (c, col) in block.as_mut().col_iter_mut().enumerate() {
                for (j, v) in xs.iter_mut().enumerate() {
                    *v = x_star[(c0 + c, j)];
                }
                if let Some(col) = col.try_as_col_major_mut() {
                    self.fill_kstar(&xs, Predictor::Smooth, col.as_slice_mut());
                }
            }
            self.solve_seq(block, false);
        });
        let prior = self.params.signal_variance() + self.effective_noise();
        let n = self.n();
        Ok((0..v.ncols())
            .into_par_iter()
            .map(|c| {
                let s: f64 = (0..n).map(|i| v[(i, c)] * v[(i, c)]).sum();
                (prior - s).max(0.0)
            })
            .collect())
    }
}

/// The unit vector `e_i` of length `n`.
fn unit_vector(n: usize, i: usize) -> Vec<f64> {
    let mut e = vec![0.0; n];
    e[i] = 1.0;
    e
}

/// Posterior mean `y* = m + sum_i w_i (y_i - m)` for weights `w` (length N), training outputs
/// `Y` (`N x D`, rows are materials) and the mean `m` (length D; e.g. [`column_mean`]).
pub fn posterior_mean(w: &[f64], y: MatRef<'_, f64>, mean: &[f64]) -> Result<Vec<f64>> {
    let (n, d) = (y.nrows(), y.ncols());
    if w.len() != n {
        return Err(GpError::DimensionMismatch {
            what: "weights vs training outputs rows",
            expected: n,
            got: w.len(),
        });
    }
    if mean.len() != d {
        return Err(GpError::DimensionMismatch {
            what: "mean vs training outputs columns",
            expected: d,
            got: mean.len(),
        });
    }
    check_finite_slice(w, "weights")?;
    check_finite_slice(mean, "mean")?;
    check_finite(y, "training outputs Y")?;
    Ok((0..d)
        .map(|j| mean[j] + (0..n).map(|i| w[i] * (y[(i, j)] - mean[j])).sum::<f64>())
        .collect())
}

/// Mean row `m_j = 1/N sum_i Y_ij` of `Y` (`N x D`).
pub fn column_mean(y: MatRef<'_, f64>) -> Vec<f64> {
    let n = y.nrows().max(1) as f64;
    (0..y.ncols())
        .map(|j| (0..y.nrows()).map(|i| y[(i, j)]).sum::<f64>() / n)
        .collect()
}
