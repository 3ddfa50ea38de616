//! GPLVM latent-space fitting for specgp (DESIGN.md section 3).
//!
//! One streaming pass over a dataset store gives the uncentred Gram matrix of the transformed
//! data ([`fit::gram_pass`]); everything after it costs O(N^3) whatever the data size: the PCA
//! start ([`pca`]), the likelihood and its analytic gradient (gp-core), and the optimisers
//! ([`optim`]: the paper's Hooke-Jeeves and L-BFGS). The result is a [`Model`] file (TOML).

pub mod config;
pub mod error;
pub mod fit;
pub mod model;
pub mod optim;
pub mod pca;
pub mod transform;

pub use config::{DataScaling, FitConfig, FitParams, InitScaling, OptimizerKind};
pub use error::{Error, Result};
pub use fit::{Fit, GramPass, fit_gram, fit_store, gram_pass};
pub use model::Model;
pub use transform::Transform;
