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
