//! Grids, BRDF file formats and the dataset store of specgp.
//!
//! - [`grid`]: the Rusinkiewicz angular grid with MERL's index mapping, the channel axis and the
//!   conversions between (theta_h, theta_d, phi_d) and (wi, wo).
//! - [`store`]: the chunked dataset store (`.sbrdf`): streaming writer, memory-mapped reader.
//! - [`tensor`]: the RGL `tensor_file` container (reader and writer); [`rgl`]: isotropic RGL
//!   `.bsdf` evaluation matching Mitsuba 3's `measured` plugin (f in 1/sr) and grid resampling;
//!   [`merl`]: MERL `.binary` files; [`nbrdf`]: Neural-BRDF networks; [`npy`]: `.npy` I/O.
//! - [`output`]: atomic output files ([`output::write_file_atomic`], [`output::AtomicOutput`]).
//! - [`source`]: the [`BrdfSource`] trait (f(wi, wo) for any source) and the [`ImportReport`].

pub mod error;
pub mod grid;
pub mod merl;
pub mod nbrdf;
pub mod npy;
pub mod output;
pub mod rgl;
pub mod source;
pub mod store;
pub mod tensor;

pub use error::{Error, Result};
pub use grid::{AngularGrid, ChannelSelection, Channels, HalfDiff, Vec3};
pub use source::{Blend, BrdfSource, ImportReport};
pub use store::{Store, StoreInfo, StoreOptions, StoreWriter};
