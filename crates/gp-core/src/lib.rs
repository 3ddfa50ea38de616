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

pub mod cholesky;
pub mod diagnostics;
pub mod error;
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
    FactorInfo, FlatGplvm, GplvmEval, GplvmObjective, Learn, log_likelihood_from_data,
};
pub use regression::{GpRegression, Predictor, column_mean, posterior_mean};
