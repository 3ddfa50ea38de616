//! The error type of `gplvm`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong while fitting or loading a GPLVM.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A configuration value that cannot be used.
    #[error("invalid configuration: {field} = {value}: must be {expected}")]
    InvalidConfig {
        /// The setting (its name in fit configuration files).
        field: &'static str,
        /// The value given.
        value: String,
        /// What it must be (the message reads "must be {expected}").
        expected: String,
    },
    /// A configuration or model file that cannot be read or parsed.
    #[error("{path}: {reason}")]
    File {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A material of the store holds NaN or infinite values (found by the Gram pass).
    #[error(
        "{path} holds non-finite values (NaN or infinity) in material {index} ({name}): a \
         damaged store? (`specgp info` verifies its checksum)"
    )]
    NonFiniteData {
        /// The store.
        path: PathBuf,
        /// Row of the material.
        index: usize,
        /// Its name.
        name: String,
    },
    /// The transform takes a finite stored value out of the f64 range (found by the Gram
    /// pass).
    #[error(
        "{path}: the transform {transform} is not finite for the value {value:e} of material \
         {index} ({name}); use a larger log offset"
    )]
    TransformOverflow {
        /// The store.
        path: PathBuf,
        /// Row of the material.
        index: usize,
        /// Its name.
        name: String,
        /// The transform (`log:OFFSET`).
        transform: String,
        /// The stored value.
        value: f64,
    },
    /// Fewer than two materials: a GPLVM needs at least two.
    #[error("a GPLVM needs at least 2 materials, got {n}")]
    TooFewMaterials {
        /// The number given.
        n: usize,
    },
    /// Every material is the same after the transform: no variance to fit.
    #[error(
        "the {n} materials are identical after the transform, up to rounding (total variance \
         {total_variance:.3e} about their mean against {uncentred_total:.3e} about 0); nothing to fit"
    )]
    IdenticalMaterials {
        /// Number of materials.
        n: usize,
        /// Trace of the centred Gram matrix.
        total_variance: f64,
        /// Trace of the uncentred Gram matrix (the rounding of centring scales with it).
        uncentred_total: f64,
    },
    /// The data cannot support the requested fit.
    #[error("invalid data: {reason}")]
    InvalidData {
        /// What is wrong.
        reason: String,
    },
    /// The objective could not be evaluated or optimised.
    #[error("objective: {reason}")]
    Objective {
        /// What went wrong.
        reason: String,
    },
    /// An error from the dataset store.
    #[error(transparent)]
    Store(#[from] brdf_io::Error),
    /// An error from the GP maths.
    #[error(transparent)]
    Gp(#[from] gp_core::GpError),
}
