//! GPLVM log-likelihood from a Gram matrix, its analytic gradient, and a flat-vector interface
//! for optimisers.
//!
//! With `S = Y Y^T` (`N x N`, `Y` transformed and centred, `D` columns), `K = K_rbf(X) + mu I`
//! (DESIGN.md section 3):
//!
//! ```text
//! L(X, theta) = -N D/2 log 2pi - D/2 log|K| - 1/2 tr(K^-1 S)  [ - 1/2 sum_n |x_n|^2 ]
//! dL/dK       = 1/2 (K^-1 S K^-1 - D K^-1)
//! dL/dX       = (dL/dK)(dK/dX)  [ - X ],   dL/dtheta = (dL/dK)(dK/dtheta)
//! ```
//!
//! The bracketed term is the optional standard-normal prior on `X` (its normalising constant
//! `-N q/2 log 2pi` is omitted). Cost `O(N^3 + N^2 q)`, independent of `D`. If the Cholesky
//! factorisation of `K` needed jitter `j`, value and gradient are those of `K + j I` (reported in
//! [`FactorInfo`]).

use crate::cholesky::{CholeskyFactor, JitterPolicy};
use crate::error::{GpError, Result, check_finite, check_psd_minors, check_symmetric};
use crate::gram::{centre_gram, symmetrise};
use crate::kernel::{HyperGradient, KernelParams, LengthScale};
use faer::linalg::matmul::triangular::BlockStructure;
use faer::{Accum, Mat, MatRef, Par};

mod moves;

pub use moves::{MAX_UPDATE_MOVE, MAX_UPDATES, MoveCounts, MoveEvaluator, PointMoves};

const LN_2PI: f64 = 1.837_877_066_409_345_3;

/// Matrices of [`GplvmObjective`]'s evaluations, kept per thread between calls (five N x N
/// matrices of the largest N the thread has evaluated: 0.1 MB at N = 51, 40 MB at N = 1000).
struct Work {
    k: Mat<f64>,
    l: Mat<f64>,
    kinv: Mat<f64>,
    b: Mat<f64>,
    dk: Mat<f64>,
    factor: crate::cholesky::FactorWork,
}

impl Work {
    fn new() -> Self {
        Work {
            k: Mat::new(),
            l: Mat::new(),
            kinv: Mat::new(),
            b: Mat::new(),
            dk: Mat::new(),
            factor: crate::cholesky::FactorWork::new(),
        }
    }
}

thread_local! {
    static WORK: std::cell::RefCell<Work> = std::cell::RefCell::new(Work::new());
}

/// Runs `f` with this thread's [`Work`], or with fresh buffers when they are in use: an
/// evaluation with `Par::Rayon` waits inside faer's parallel products, and rayon may run
/// another evaluation on the waiting thread meanwhile.
fn with_work<R>(f: impl FnOnce(&mut Work) -> R) -> R {
    WORK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut w) => f(&mut w),
        Err(_) => f(&mut Work::new()),
    })
}

/// `b = K^-1 S` and the lower triangle of `a = scale K^-1 S K^-1 = scale b K^-1` (symmetric:
/// half the flops; the strict upper triangle is left as it was), both resized to `N x N`.
fn kinv_s_kinv_lower(
    kinv: MatRef<'_, f64>,
    s: MatRef<'_, f64>,
    scale: f64,
    b: &mut Mat<f64>,
    a: &mut Mat<f64>,
    par: Par,
) {
    let n = kinv.nrows();
    b.resize_with(n, n, |_, _| 0.0);
    faer::linalg::matmul::matmul(b.as_mut(), Accum::Replace, kinv, s, 1.0, par);
    a.resize_with(n, n, |_, _| 0.0);
    faer::linalg::matmul::triangular::matmul(
        a.as_mut(),
        BlockStructure::TriangularLower,
        Accum::Replace,
        b.as_ref(),
        BlockStructure::Rectangular,
        kinv,
        BlockStructure::Rectangular,
        scale,
        par,
    );
}

/// What the Cholesky factorisation of `K` needed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FactorInfo {
    /// Jitter added to the diagonal of `K` (0 if none).
    pub jitter: f64,
    /// Factorisation attempts (1 = no jitter).
    pub attempts: usize,
    /// Hager 1-norm condition estimate of `K + jitter I` ([`CholeskyFactor::condition_estimate`]).
    pub condition_estimate: f64,
}

impl FactorInfo {
    /// With `condition`, the Hager/Higham estimate (a few triangular solves); without it (the
    /// optimisers' inner loop, where nobody reads it) `condition_estimate` is NaN.
    pub(crate) fn of(f: &CholeskyFactor, condition: bool) -> Self {
        FactorInfo {
            jitter: f.jitter(),
            attempts: f.attempts(),
            condition_estimate: if condition {
                f.condition_estimate()
            } else {
                f64::NAN
            },
        }
    }
}

/// Value and analytic gradient of the GPLVM log-likelihood.
#[derive(Debug, Clone)]
pub struct GplvmEval {
    /// `L(X, theta)`.
    pub value: f64,
    /// `dL/dX`, `N x q`.
    pub grad_x: Mat<f64>,
    /// `dL/d(s^2, l, mu)`.
    pub grad_hyper: HyperGradient,
    /// `dL/d(log s^2, log l, log mu)`.
    pub grad_hyper_log: HyperGradient,
    /// Factorisation diagnostics.
    pub factor: FactorInfo,
}

/// GPLVM objective defined by a centred Gram matrix `S` and the data dimension `D`.
#[derive(Debug, Clone)]
pub struct GplvmObjective {
    s: Mat<f64>,
    d: usize,
    prior: bool,
    constant: bool,
    policy: JitterPolicy,
}

impl GplvmObjective {
    /// From an already centred Gram `S = Y Y^T` (`N x N`, symmetric, finite) and `D >= 1`.
    /// Prior off, constant term on, default jitter policy. `S` must look like a Gram matrix:
    /// a negative diagonal entry or a 2 x 2 principal minor below zero (beyond rounding) is
    /// [`GpError::NotPositiveSemidefinite`] (`S = -I` used to give a finite likelihood).
    pub fn new(s: Mat<f64>, d: usize) -> Result<Self> {
        if s.nrows() == 0 {
            return Err(GpError::Empty {
                what: "Gram matrix S",
            });
        }
        if d == 0 {
            return Err(GpError::Empty {
                what: "data dimension D",
            });
        }
        check_finite(s.as_ref(), "Gram matrix S")?;
        check_symmetric(s.as_ref(), "Gram matrix S")?;
        let mut s = s;
        symmetrise(&mut s);
        check_psd_minors(s.as_ref(), "Gram matrix S")?;
        Ok(GplvmObjective {
            s,
            d,
            prior: false,
            constant: true,
            policy: JitterPolicy::default(),
        })
    }

    /// From an uncentred Gram `G = Y_raw Y_raw^T`: `S = C G C` (see [`centre_gram`]).
    pub fn from_uncentred_gram(g: MatRef<'_, f64>, d: usize) -> Result<Self> {
        Self::new(centre_gram(g)?, d)
    }

    /// Enables/disables the standard-normal prior `-1/2 sum |x_n|^2`.
    pub fn with_prior(mut self, prior: bool) -> Self {
        self.prior = prior;
        self
    }

    /// Includes (default) or drops the constant `-N D/2 log 2pi` (dropping it helps optimisers
    /// when `N D` is huge; gradients are unaffected).
    pub fn with_constant(mut self, constant: bool) -> Self {
        self.constant = constant;
        self
    }

    /// Jitter policy for the factorisation of `K`.
    pub fn with_jitter_policy(mut self, policy: JitterPolicy) -> Self {
        self.policy = policy;
        self
    }

    /// Number of points `N`.
    pub fn n(&self) -> usize {
        self.s.nrows()
    }

    /// Data dimension `D`.
    pub fn d(&self) -> usize {
        self.d
    }

    /// Whether the prior on `X` is on.
    pub fn has_prior(&self) -> bool {
        self.prior
    }

    /// The centred Gram matrix `S`.
    pub fn gram(&self) -> MatRef<'_, f64> {
        self.s.as_ref()
    }

    fn check_x(&self, x: MatRef<'_, f64>) -> Result<()> {
        if x.nrows() != self.n() {
            return Err(GpError::DimensionMismatch {
                what: "latent points X rows vs Gram size N",
                expected: self.n(),
                got: x.nrows(),
            });
        }
        Ok(())
    }

    fn factor_matrix(&self, k: MatRef<'_, f64>, par: Par) -> Result<CholeskyFactor> {
        CholeskyFactor::with_policy(k, self.policy, par).map_err(|e| match e {
            GpError::NotPositiveDefinite {
                n,
                attempts,
                last_jitter,
                mean_diagonal,
                ..
            } => GpError::NotPositiveDefinite {
                what: "kernel matrix K",
                n,
                attempts,
                last_jitter,
                mean_diagonal,
            },
            e => e,
        })
    }

    fn assemble(&self, log_det: f64, trace: f64, x: MatRef<'_, f64>) -> Result<f64> {
        let sq = if self.prior {
            Self::sum_of_squares(x)
        } else {
            0.0
        };
        self.assemble_terms(log_det, trace, sq)
    }

    /// `sum |x_n|^2`, in the order the prior's term sums it.
    fn sum_of_squares(x: MatRef<'_, f64>) -> f64 {
        let mut sq = 0.0;
        for j in 0..x.ncols() {
            for i in 0..x.nrows() {
                sq += x[(i, j)] * x[(i, j)];
            }
        }
        sq
    }

    /// `tr(K^-1 S)` from `K^-1`, in the order the value-only path sums it.
    fn trace_with(&self, kinv: MatRef<'_, f64>) -> f64 {
        let n = self.n();
        let mut trace = 0.0;
        for j in 0..n {
            for i in 0..n {
                trace += kinv[(i, j)] * self.s[(i, j)];
            }
        }
        trace
    }

    /// The log-likelihood from `log|K|`, `tr(K^-1 S)` and `sum |x_n|^2` (ignored without the
    /// prior).
    fn assemble_terms(&self, log_det: f64, trace: f64, sq: f64) -> Result<f64> {
        let n = self.n() as f64;
        let d = self.d as f64;
        let mut v = -0.5 * d * log_det - 0.5 * trace;
        if self.constant {
            v -= 0.5 * n * d * LN_2PI;
        }
        if self.prior {
            v -= 0.5 * sq;
        }
        if !v.is_finite() {
            return Err(GpError::NonFiniteResult {
                what: "GPLVM log-likelihood",
                value: v,
            });
        }
        Ok(v)
    }

    /// Log-likelihood value only (`O(N^3)`: one Cholesky and one inverse).
    pub fn log_likelihood(
        &self,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
    ) -> Result<(f64, FactorInfo)> {
        self.log_likelihood_impl(x, params, par, true)
    }

    fn log_likelihood_impl(
        &self,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
        condition: bool,
    ) -> Result<(f64, FactorInfo)> {
        self.check_x(x)?;
        with_work(|w| {
            let (log_det, factor) = self.factor_into(w, x, params, par, condition)?;
            let trace = self.trace_with(w.kinv.as_ref());
            let v = self.assemble(log_det, trace, x)?;
            Ok((v, factor))
        })
    }

    /// K into `w.k`, its inverse into `w.kinv`, and `log|K|`. The optimisers' path (no
    /// condition estimate) factors the K it has just built without re-checking it and without
    /// jitter; a K that needs jitter, and every full evaluation, go through the checked,
    /// jittered factorisation. Same values either way.
    fn factor_into(
        &self,
        w: &mut Work,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
        condition: bool,
    ) -> Result<(f64, FactorInfo)> {
        if condition {
            params.kernel_matrix_into(x, &mut w.k)?;
        } else if let Some(log_det) = self.factor_plain(w, x, params, par)? {
            let info = FactorInfo {
                jitter: 0.0,
                attempts: 1,
                condition_estimate: f64::NAN,
            };
            return Ok((log_det, info));
        }
        let f = self.factor_matrix(w.k.as_ref(), par)?;
        w.kinv = f.inverse();
        Ok((f.log_det(), FactorInfo::of(&f, condition)))
    }

    /// The optimisers' plain path: `K` into `w.k`, factored as it is (no check, no jitter)
    /// into `w.l`, its inverse into `w.kinv`, and `log|K|`; `None` (with `w.k` filled) when
    /// a pivot is not positive and finite.
    fn factor_plain(
        &self,
        w: &mut Work,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
    ) -> Result<Option<f64>> {
        let n = self.n();
        params.kernel_matrix_into(x, &mut w.k)?;
        w.l.resize_with(n, n, |_, _| 0.0);
        w.l.copy_from(&w.k);
        if !w.factor.factor_in_place(w.l.as_mut(), par) {
            return Ok(None);
        }
        w.factor.inverse_into(w.l.as_ref(), &mut w.kinv, par);
        Ok(Some(2.0 * (0..n).map(|i| w.l[(i, i)].ln()).sum::<f64>()))
    }

    /// Value and analytic gradient with respect to `X` and the hyperparameters.
    pub fn evaluate(
        &self,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
    ) -> Result<GplvmEval> {
        self.evaluate_impl(x, params, par, true, true)
    }

    /// [`evaluate`](Self::evaluate) with or without the condition estimate and the
    /// length-scale gradient (0 when left out; the optimisers' inner loop needs neither
    /// unless it learns the length-scale).
    fn evaluate_impl(
        &self,
        x: MatRef<'_, f64>,
        params: &KernelParams,
        par: Par,
        condition: bool,
        length_scale: bool,
    ) -> Result<GplvmEval> {
        self.check_x(x)?;
        let n = self.n();
        // Thread-local matrices reused from call to call (at N ~ 50 allocating and zeroing them
        // cost as much as the arithmetic).
        with_work(|w| {
            let (log_det, factor) = self.factor_into(w, x, params, par, condition)?;
            // B = K^-1 S, and the lower triangle of A / 2 = K^-1 S K^-1 / 2 (mirrored below).
            kinv_s_kinv_lower(
                w.kinv.as_ref(),
                self.s.as_ref(),
                0.5,
                &mut w.b,
                &mut w.dk,
                par,
            );
            let trace: f64 = (0..n).map(|i| w.b[(i, i)]).sum();
            let half_d = 0.5 * self.d as f64;
            // dL/dK's lower triangle column by column (contiguous), then mirrored row by row.
            for j in 0..n {
                let kinv_j = &w.kinv.col_as_slice(j)[j..];
                for (v, k) in w.dk.col_as_slice_mut(j)[j..].iter_mut().zip(kinv_j) {
                    *v -= half_d * k;
                }
            }
            crate::gram::mirror_lower(&mut w.dk);
            let value = self.assemble(log_det, trace, x)?;
            // K's off-diagonal is K_rbf's (the noise sits on the diagonal only).
            let g = params.backprop_with_rbf(x, w.dk.as_ref(), w.k.as_ref(), length_scale)?;
            let mut grad_x = g.x;
            if self.prior {
                for j in 0..x.ncols() {
                    for i in 0..n {
                        grad_x[(i, j)] -= x[(i, j)];
                    }
                }
            }
            check_finite(grad_x.as_ref(), "GPLVM gradient dL/dX")?;
            // The hyperparameter gradients can overflow where dL/dX does not (latent points
            // near 1e308: (x_n - x_m)^2 is infinite while its weight is 0).
            let h = &g.hyper_log;
            let mut hyper = std::iter::once(h.signal_variance)
                .chain(h.length_scale.iter().copied())
                .chain(std::iter::once(h.noise));
            if let Some(v) = hyper.find(|v| !v.is_finite()) {
                return Err(GpError::NonFiniteResult {
                    what: "GPLVM hyperparameter gradient",
                    value: v,
                });
            }
            Ok(GplvmEval {
                value,
                grad_x,
                grad_hyper: g.hyper,
                grad_hyper_log: g.hyper_log,
                factor,
            })
        })
    }

    /// Flat-vector view for optimisers: see [`FlatGplvm`].
    pub fn flat(&self, q: usize, template: KernelParams, learn: Learn) -> Result<FlatGplvm<'_>> {
        FlatGplvm::new(self, q, template, learn)
    }
}

/// The same log-likelihood computed directly from dense data `Y` (`N x D`, used as given: centre
/// it first if the Gram path is centred): `tr(K^-1 Y Y^T) = ||L^-1 Y||_F^2`. `O(N^2 D)`; meant
/// for tests and small problems.
pub fn log_likelihood_from_data(
    y: MatRef<'_, f64>,
    x: MatRef<'_, f64>,
    params: &KernelParams,
    prior: bool,
    par: Par,
) -> Result<f64> {
    let n = y.nrows();
    if n == 0 || y.ncols() == 0 {
        return Err(GpError::Empty { what: "data Y" });
    }
    check_finite(y, "data Y")?;
    if x.nrows() != n {
        return Err(GpError::DimensionMismatch {
            what: "latent points X rows vs data rows",
            expected: n,
            got: x.nrows(),
        });
    }
    let k = params.kernel_matrix(x)?;
    let f = CholeskyFactor::new(k.as_ref(), par)?;
    let mut z = y.to_owned();
    f.solve_lower_in_place(z.as_mut());
    let mut tr = 0.0;
    for j in 0..z.ncols() {
        for i in 0..n {
            tr += z[(i, j)] * z[(i, j)];
        }
    }
    let d = y.ncols() as f64;
    let mut v = -0.5 * n as f64 * d * LN_2PI - 0.5 * d * f.log_det() - 0.5 * tr;
    if prior {
        for j in 0..x.ncols() {
            for i in 0..n {
                v -= 0.5 * x[(i, j)] * x[(i, j)];
            }
        }
    }
    if !v.is_finite() {
        return Err(GpError::NonFiniteResult {
            what: "GPLVM log-likelihood from data",
            value: v,
        });
    }
    Ok(v)
}

/// Which hyperparameters a [`FlatGplvm`] optimises (the others stay at the template's values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Learn {
    /// Optimise `log s^2`.
    pub signal_variance: bool,
    /// Optimise `log l` (1 value, or `q` for ARD).
    pub length_scale: bool,
    /// Optimise `log mu`.
    pub noise: bool,
}

impl Learn {
    /// Only `X` is optimised (the paper's setting).
    pub const NONE: Learn = Learn {
        signal_variance: false,
        length_scale: false,
        noise: false,
    };
    /// `X` and every hyperparameter.
    pub const ALL: Learn = Learn {
        signal_variance: true,
        length_scale: true,
        noise: true,
    };
}

/// Flat parameter vector `theta = [vec_row(X), free log-hyperparameters]` for an optimiser
/// minimising the *negative* log-likelihood.
///
/// Layout: `X` row-major (`x_00, x_01, .., x_0(q-1), x_10, ..`, `N q` values), then in order
/// `log s^2` (if learnt), `log l` (1, or `q` for ARD, if learnt), `log(mu - floor)` (if learnt;
/// the floor is 0 unless set with [`with_noise_floor`](FlatGplvm::with_noise_floor), and then
/// the entry is `log mu`).
#[derive(Debug, Clone)]
pub struct FlatGplvm<'a> {
    obj: &'a GplvmObjective,
    q: usize,
    template: KernelParams,
    learn: Learn,
    /// A learnt noise stays above this: `mu = floor + exp(theta_mu)`.
    noise_floor: f64,
}

impl<'a> FlatGplvm<'a> {
    /// Flat view of `obj` with latent dimension `q`; `template` supplies fixed hyperparameters
    /// and the iso/ARD choice.
    pub fn new(
        obj: &'a GplvmObjective,
        q: usize,
        template: KernelParams,
        learn: Learn,
    ) -> Result<Self> {
        template.check_dim(q)?;
        Ok(FlatGplvm {
            obj,
            q,
            template,
            learn,
            noise_floor: 0.0,
        })
    }

    /// Keeps a learnt noise variance above `floor` (finite, >= 0): the free parameter becomes
    /// `log(mu - floor)`. Without a floor, data that a noise-free GP interpolates drive `mu`
    /// towards 0 and `K` towards singular (measured on raw synthetic data: mu = 1e-16, cond(K)
    /// ~ 1e12, the fit stuck at its iteration cap). No effect when the noise is fixed.
    pub fn with_noise_floor(mut self, floor: f64) -> Result<Self> {
        if !(floor.is_finite() && floor >= 0.0) {
            return Err(GpError::InvalidHyperparameter {
                name: "noise floor".into(),
                value: floor,
            });
        }
        self.noise_floor = floor;
        Ok(self)
    }

    /// Number of free log-hyperparameters.
    pub fn n_hyper(&self) -> usize {
        usize::from(self.learn.signal_variance)
            + if self.learn.length_scale {
                self.template.length_scale().len()
            } else {
                0
            }
            + usize::from(self.learn.noise)
    }

    /// Length of `theta`: `N q + n_hyper`.
    pub fn len(&self) -> usize {
        self.obj.n() * self.q + self.n_hyper()
    }

    /// Always false (`N, q >= 1`).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Packs `X` (`N x q`) and the learnt hyperparameters of `params` into `theta`.
    pub fn pack(&self, x: MatRef<'_, f64>, params: &KernelParams) -> Result<Vec<f64>> {
        let n = self.obj.n();
        if x.nrows() != n || x.ncols() != self.q {
            return Err(GpError::DimensionMismatch {
                what: "latent points X shape (rows * q) vs flat layout",
                expected: n * self.q,
                got: x.nrows() * x.ncols(),
            });
        }
        params.check_dim(self.q)?;
        if params.length_scale().is_ard() != self.template.length_scale().is_ard() {
            return Err(GpError::DimensionMismatch {
                what: "length-scale count (iso vs ARD) vs template",
                expected: self.template.length_scale().len(),
                got: params.length_scale().len(),
            });
        }
        let mut v = Vec::with_capacity(self.len());
        for i in 0..n {
            for j in 0..self.q {
                v.push(x[(i, j)]);
            }
        }
        let lt = params.to_log_vec();
        let k = params.length_scale().len();
        if self.learn.signal_variance {
            v.push(lt[0]);
        }
        if self.learn.length_scale {
            v.extend_from_slice(&lt[1..1 + k]);
        }
        if self.learn.noise {
            let (mu, floor) = (params.noise(), self.noise_floor);
            if mu < floor || mu <= 0.0 {
                return Err(GpError::NoiseBelowFloor { noise: mu, floor });
            }
            // With a floor of 0 this is `ln(mu)`, the same bits as `to_log_vec`'s entry. A
            // noise equal to a positive floor is what `unpack` gives once `exp(theta)` falls
            // below half an ulp of the floor (a fit that drove the noise to its floor): packed
            // as such a `theta` (floor eps / 8), so it unpacks to the same noise.
            let excess = if mu > floor {
                mu - floor
            } else {
                floor * f64::EPSILON / 8.0
            };
            v.push(excess.ln());
        }
        Ok(v)
    }

    /// Inverse of [`pack`](Self::pack). Errors on a wrong length or on hyperparameters that
    /// overflow (`exp` to 0 or infinity).
    pub fn unpack(&self, theta: &[f64]) -> Result<(Mat<f64>, KernelParams)> {
        if theta.len() != self.len() {
            return Err(GpError::DimensionMismatch {
                what: "flat parameter vector length",
                expected: self.len(),
                got: theta.len(),
            });
        }
        let (n, q) = (self.obj.n(), self.q);
        let x = Mat::from_fn(n, q, |i, j| theta[i * q + j]);
        // Fixed hyperparameters are the template's values themselves (not exp(log v), which
        // recorded a fixed mu = 1e-4 as 1.0000000000000009e-4).
        let k = self.template.length_scale().len();
        let mut p = n * q;
        let signal_variance = if self.learn.signal_variance {
            p += 1;
            theta[p - 1].exp()
        } else {
            self.template.signal_variance()
        };
        let length_scale = if self.learn.length_scale {
            let ls: Vec<f64> = theta[p..p + k].iter().map(|v| v.exp()).collect();
            p += k;
            match self.template.length_scale() {
                LengthScale::Isotropic(_) => LengthScale::Isotropic(ls[0]),
                LengthScale::Ard(_) => LengthScale::Ard(ls),
            }
        } else {
            self.template.length_scale().clone()
        };
        // (With a floor of 0 this is exactly the former `exp(log mu)`.)
        let noise = if self.learn.noise {
            self.noise_floor + theta[p].exp()
        } else {
            self.template.noise()
        };
        let params = KernelParams::new(signal_variance, length_scale, noise)?;
        Ok((x, params))
    }

    /// Full evaluation at `theta` (log-likelihood, not negated).
    pub fn evaluate(&self, theta: &[f64], par: Par) -> Result<GplvmEval> {
        let (x, params) = self.unpack(theta)?;
        self.obj.evaluate(x.as_ref(), &params, par)
    }

    /// An evaluator of [`neg_log_likelihood`](Self::neg_log_likelihood) for a direct search:
    /// trials that move one latent point cost `O(N^2)` ([`MoveEvaluator`]).
    pub fn move_evaluator(&self) -> MoveEvaluator<'_, 'a> {
        MoveEvaluator::new(self)
    }

    /// `-L(theta)` only.
    pub fn neg_log_likelihood(&self, theta: &[f64], par: Par) -> Result<f64> {
        let (x, params) = self.unpack(theta)?;
        Ok(-self
            .obj
            .log_likelihood_impl(x.as_ref(), &params, par, false)?
            .0)
    }

    /// `(-L(theta), -dL/dtheta)` in the layout of [`pack`](Self::pack).
    pub fn neg_log_likelihood_and_gradient(
        &self,
        theta: &[f64],
        par: Par,
    ) -> Result<(f64, Vec<f64>)> {
        let (x, params) = self.unpack(theta)?;
        // No condition estimate in the optimisers' inner loop (FlatGplvm::evaluate has it),
        // and the length-scale gradient only when it is learnt.
        let e = self
            .obj
            .evaluate_impl(x.as_ref(), &params, par, false, self.learn.length_scale)?;
        let (n, q) = (self.obj.n(), self.q);
        let mut g = Vec::with_capacity(self.len());
        for i in 0..n {
            for j in 0..q {
                g.push(-e.grad_x[(i, j)]);
            }
        }
        if self.learn.signal_variance {
            g.push(-e.grad_hyper_log.signal_variance);
        }
        if self.learn.length_scale {
            g.extend(e.grad_hyper_log.length_scale.iter().map(|v| -v));
        }
        if self.learn.noise {
            // d/d log(mu - floor) = (mu - floor) / mu * d/d log mu.
            let mu = params.noise();
            g.push(-e.grad_hyper_log.noise * ((mu - self.noise_floor) / mu));
        }
        Ok((-e.value, g))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn nested_evaluations_get_their_own_buffers() {
        // The thread's buffers are in use: a nested call gets fresh ones instead of panicking.
        let sizes = with_work(|outer| {
            outer.k.resize_with(3, 3, |_, _| 1.0);
            let inner = with_work(|inner| inner.k.nrows());
            (outer.k.nrows(), inner)
        });
        assert_eq!(sizes, (3, 0));
        // Parallel evaluations, each with parallel products inside (rayon may run one on a
        // thread that waits in another's product): the same values as sequential ones.
        let n = 40;
        let y = Mat::from_fn(n, 30, |i, j| ((i * 7 + j * 3) % 11) as f64 / 11.0);
        let g = crate::gram_from_data(y.as_ref(), Par::Seq).unwrap();
        let obj = GplvmObjective::from_uncentred_gram(g.as_ref(), 30).unwrap();
        let p = KernelParams::paper();
        let points: Vec<Mat<f64>> = (0..8)
            .map(|s| Mat::from_fn(n, 2, |i, j| ((i * 5 + j + s) % 13) as f64 / 6.0 - 1.0))
            .collect();
        let seq: Vec<f64> = points
            .iter()
            .map(|x| obj.evaluate(x.as_ref(), &p, Par::Seq).unwrap().value)
            .collect();
        let par: Vec<f64> = points
            .par_iter()
            .map(|x| obj.evaluate(x.as_ref(), &p, Par::rayon(2)).unwrap().value)
            .collect();
        for (a, b) in seq.iter().zip(&par) {
            assert!((a - b).abs() <= 1e-9 * a.abs(), "{a} vs {b}");
        }
    }
}
