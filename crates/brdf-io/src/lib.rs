//! Grids, BRDF file formats and the dataset store of specgp.
//!
//! - [`grid`]: the Rusinkiewicz angular grid with MERL's index mapping, the channel axis and the
//!   conversions between (theta_h, theta_d, phi_d) and (wi, wo).

pub mod error;
pub mod grid;
pub mod rgl;
pub mod source;
pub mod tensor;

pub use error::{Error, Result};
pub use grid::{AngularGrid, Channels, HalfDiff, Vec3};
pub use source::{BrdfSource, ImportReport};
