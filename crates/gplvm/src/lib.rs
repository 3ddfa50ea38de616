//! GPLVM latent-space fitting for specgp (DESIGN.md section 3).
//!
//! One streaming pass over a dataset store gives the uncentred Gram matrix of the transformed
//! data ([`fit::gram_pass`]); everything after it costs O(N^3) whatever the data size: the PCA
//! start ([`pca`]), the likelihood and its analytic gradient (gp-core), and the optimisers
//! ([`optim`]: the paper's Hooke-Jeeves and L-BFGS). The result is a [`Model`] file (TOML).
//!
//! ```
//! use brdf_io::{AngularGrid, Channels, Store, StoreOptions};
//! use gplvm::{FitParams, InitScaling, Model, OptimizerKind};
//!
//! // Twelve of the embedded synthetic materials on a coarse grid (a 0.3 MB store).
//! let dir = tempfile::tempdir()?;
//! let data = dir.path().join("data.sbrdf");
//! let materials: Vec<_> = brdf_synth::preset(0).into_iter().step_by(4).take(12).collect();
//! let grid = AngularGrid::new(8, 8, 16)?;
//! let channels = Channels::parse_wavelengths("400:700:50")?;
//! let options = StoreOptions::default();
//! brdf_synth::write_store(&data, &materials, grid, &channels, options, 0, |_| {})?;
//!
//! // The default fit (log values, L-BFGS on the analytic gradient), here with q = 2.
//! let config = FitParams { latent_dim: 2, ..FitParams::default() }.check()?;
//! let model = gplvm::fit_store(&data, &config)?;
//! assert_eq!(model.materials.len(), 12);
//! assert!(model.fit.log_likelihood > model.fit.initial_log_likelihood); // better than PCA
//! let path = dir.path().join("model.toml");
//! model.save(&path)?;
//! assert_eq!(Model::load(&path)?.materials, model.materials);
//!
//! // `fit_store` verifies the store's checksum, makes one pass over the data for the Gram
//! // matrix, then calls `fit_gram`, which reads no data: other fits of the same transform
//! // start from the same pass, here the paper's
//! // Hooke-Jeeves search (the paper fits raw values, which need a pass of their own).
//! let pass = gplvm::gram_pass(&Store::open(&data)?, config.transform)?;
//! let again = gplvm::fit_gram(pass.gram.as_ref(), pass.d_effective, &config)?;
//! assert_eq!(again.report.log_likelihood, model.fit.log_likelihood);
//! let search = FitParams {
//!     latent_dim: 2,
//!     optimizer: OptimizerKind::HookeJeeves,
//!     init_scaling: InitScaling::Isotropic,
//!     ..FitParams::default()
//! }
//! .check()?;
//! let hooke_jeeves = gplvm::fit_gram(pass.gram.as_ref(), pass.d_effective, &search)?;
//! assert!(hooke_jeeves.report.log_likelihood > hooke_jeeves.report.initial_log_likelihood);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

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
