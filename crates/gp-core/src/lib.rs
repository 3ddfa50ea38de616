//! Gaussian-process maths for specgp: RBF kernels, a jitter-escalating Cholesky, the GPLVM
//! log-likelihood and its analytic gradient from a Gram matrix, and GP regression weights.
//!
//! Conventions: latent points are the rows of an `N x q` matrix `X` ([`faer::Mat<f64>`]);
//! `K = K_rbf(X) + mu I` with `k(x, x') = s^2 exp(-1/2 sum_j (x_j - x'_j)^2 / l_j^2)`. Functions
//! that do `O(N^3)` work take an explicit [`Par`] (faer style). No function panics on bad numeric
//! input: it returns a [`GpError`]. See DESIGN.md sections 3 and 4.
//!
//! - [`kernel`]: [`KernelParams`] (validated from [`KernelParamsUnchecked`]), `K`, cross
//!   covariances, gradients via [`KernelParams::backprop`].
//! - [`cholesky`]: [`CholeskyFactor`] with [`JitterPolicy`], solves, log-det, inverse, condition
//!   estimates.
//! - [`gram`]: `G = Y Y^T`, centring, subsets.
//! - [`objective`]: [`GplvmObjective`] (value + gradient) and [`FlatGplvm`] (flat `&[f64]`
//!   interface for optimisers).
//! - [`regression`]: [`GpRegression`] posterior weights / variance, [`Predictor`] exact vs smooth.
//! - [`diagnostics`]: the length-scale condition ([`length_scale_condition`]).
//!
//! ```
//! use gp_core::{GplvmObjective, GpRegression, KernelParams, Learn, Mat, Par, Predictor};
//!
//! // Uncentred Gram G = Y Y^T of N = 4 materials with D = 3 values each.
//! let y = Mat::from_fn(4, 3, |i, j| ((i * 3 + j) as f64).sin());
//! let g = gp_core::gram_from_data(y.as_ref(), Par::Seq)?;
//! let obj = GplvmObjective::from_uncentred_gram(g.as_ref(), 3)?.with_prior(true);
//!
//! // Flat interface for an optimiser: X (row-major) + learnt log-hyperparameters.
//! let x = Mat::from_fn(4, 2, |i, j| 0.3 * i as f64 - 0.2 * j as f64);
//! let flat = obj.flat(2, KernelParams::paper(), Learn::ALL)?;
//! let theta = flat.pack(x.as_ref(), &KernelParams::paper())?;
//! let (neg_ll, grad) = flat.neg_log_likelihood_and_gradient(&theta, Par::Seq)?;
//! assert!(neg_ll.is_finite() && grad.len() == 4 * 2 + 3);
//!
//! // Prediction: the exact predictor returns the training weights e_i at x_i.
//! let gp = GpRegression::new(x.as_ref(), KernelParams::paper(), Par::Seq)?;
//! let w = gp.weights(&[x[(1, 0)], x[(1, 1)]], Predictor::Exact)?;
//! assert!((w[1] - 1.0).abs() < 1e-10);
//! # Ok::<(), gp_core::GpError>(())
//! ```

pub mod cholesky;
pub mod diagnostics;
pub mod error;
pub mod fastmath;
pub mod gram;
pub mod kernel;
pub mod objective;
pub mod regression;

pub use cholesky::{CholeskyFactor, JitterPolicy};
pub use diagnostics::{LengthScaleDiagnostic, LengthScaleThresholds, length_scale_condition};
pub use error::{GpError, Result};
pub use faer::{Mat, MatRef, Par};
pub use gram::{all_but, centre_gram, gram_from_data, subset_gram};
pub use kernel::{HyperGradient, KernelGradient, KernelParams, KernelParamsUnchecked, LengthScale};
pub use objective::{
    FactorInfo, FlatGplvm, GplvmEval, GplvmObjective, Learn, MAX_UPDATE_MOVE, MAX_UPDATES,
    MoveCounts, MoveEvaluator, PointMoves, log_likelihood_from_data,
};
pub use regression::{GpRegression, Predictor, column_mean, posterior_mean};
