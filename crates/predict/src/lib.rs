//! The specgp prediction service (DESIGN.md sections 4-5).
//!
//! A predicted material is a coefficient vector over the N measured materials: its value at
//! one (angle, channel) index is `inverse(sum_i c_i forward(y_i[d]))`, N multiply-adds over
//! the N stored values at that index. So prediction is lazy by default:
//!
//! - [`Predictor`]: a model bound to its dataset store (validated: path, checksum, grid,
//!   channels, materials); GP weights ([`PredictorKind::Exact`] or [`PredictorKind::Smooth`]),
//!   coefficients, predictive variance; [`Predictor::predict`], [`Predictor::lerp`] (the
//!   paper's linear interpolation), [`Predictor::from_coefficients`] (any linear predictor).
//! - [`PredictedMaterial`]: lookups at a flat index, an angular cell, half/difference angles
//!   (multilinear interpolation) or (wi, wo) ([`brdf_io::BrdfSource`]), for all channels or a
//!   wavelength subset; [`PredictedMaterial::materialize`] streams it to `.sbrdf`, `.npy` or
//!   MERL `.binary`.
//! - [`evaluate`]: the paper's Eq. 22 reconstruction error, leave-one-out with refits from the
//!   Gram matrix, and baselines (nearest material, linear interpolation, PCA), with BRDF-space
//!   errors of every method from one streaming pass.
//! - [`locate`]: where a material outside the training set sits in the latent space (the
//!   inverse of prediction), from one pass for its cross products with the training rows.
//!
//! ```
//! # use brdf_io::{AngularGrid, StoreOptions};
//! # let dir = tempfile::tempdir()?;
//! # let data = dir.path().join("data.sbrdf");
//! # let materials: Vec<_> = brdf_synth::preset(0).into_iter().step_by(4).take(12).collect();
//! # let grid = AngularGrid::new(8, 8, 16)?;
//! # let channels = Channels::parse_wavelengths("400:700:50")?;
//! # let options = StoreOptions::default();
//! # brdf_synth::write_store(&data, &materials, grid, &channels, options, 0, |_| {})?;
//! # let config = gplvm::FitParams { latent_dim: 2, ..Default::default() }.check()?;
//! # let model_path = dir.path().join("model.toml");
//! # gplvm::fit_store(&data, &config)?.save(&model_path)?;
//! use brdf_io::{BrdfSource, Channels, Store};
//! use predict::{Predictor, PredictorKind};
//!
//! // A model file (`specgp fit`, here 12 materials, 2-D) bound to its dataset store, whose
//! // grid (8 x 8 x 16) and channels (400:700:50 nm) it checks.
//! let pred = Predictor::open(&model_path)?;
//! let (a, b) = (&pred.model().materials[0], &pred.model().materials[1]);
//!
//! // A new material halfway between two measured ones: 12 coefficients, nothing materialised.
//! let x: Vec<f64> = a.coords.iter().zip(&b.coords).map(|(p, q)| (p + q) / 2.0).collect();
//! let new = pred.predict(&x, PredictorKind::Exact)?;
//! assert_eq!(new.coefficients().len(), 12);
//! // Its predictive variance lies between a material's (0) and the prior's, far from all.
//! let v = pred.variance(&x)?;
//! assert!(pred.variance_of(&a.coords, PredictorKind::Exact)? == 0.0 && v > 0.0);
//! assert!(v < pred.prior_variance());
//!
//! // Lookups, N multiply-adds per value: f(wi, wo) in 1/sr for every channel, or only the
//! // wavelengths a renderer needs (interpolated between the stored ones).
//! let (wi, wo) = ([0.0, 0.6, 0.8], [0.3, -0.4, 0.75f64.sqrt()]);
//! let mut f = [0.0; 7];
//! new.eval(wi, wo, &mut f)?;
//! let mut f555 = [0.0];
//! new.with_wavelengths(&Channels::parse_wavelengths("555")?)?.eval(wi, wo, &mut f555)?;
//! assert!(f555[0] >= f[3].min(f[4]) && f555[0] <= f[3].max(f[4])); // 550 and 600 nm
//!
//! // The exact predictor at a material's latent point gives that material back.
//! let store = Store::open(&data)?;
//! let d = store.grid().index(2, 3, 5) * 7 + 3; // one cell's 550 nm value
//! let mut stored = [0.0f32; 12];
//! store.values_at(d, &mut stored)?;
//! let back = pred.predict(&a.coords, PredictorKind::Exact)?.value_at(d)?;
//! assert!((back - f64::from(stored[0])).abs() < 1e-9 * f64::from(stored[0]));
//!
//! // Materialised only when asked (`.sbrdf`, `.npy` or MERL `.binary`).
//! let report = new.materialize(&dir.path().join("new.npy"), |_, _| {})?;
//! assert_eq!(report.values, 8 * 8 * 16 * 7);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod error;
pub mod evaluate;
pub mod locate;
pub mod materialize;
pub mod predictor;

pub use error::{Error, Result};
pub use materialize::{MaterializeReport, NegativeCount, OutputFormat};
pub use predictor::{
    ChannelSelection, PointSupport, PredictedMaterial, Predictor, PredictorKind, kernel_params,
    transformed_store_path, weights_to_coefficients,
};
