//! The error type of `gplvm`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong while fitting or loading a GPLVM.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A configuration value that cannot be used.
    #[error("invalid configuration: {reason}")]
    InvalidConfig {
        /// What is wrong.
        reason: String,
    },
    /// A configuration or model file that cannot be read or parsed.
    #[error("{path}: {reason}")]
    File {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        reason: String,
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
