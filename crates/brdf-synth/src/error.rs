//! The error type of `brdf-synth`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong while generating a synthetic dataset.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The grid or channel axis cannot be used for synthesis.
    #[error("invalid synthesis request: {reason}")]
    InvalidRequest {
        /// What is wrong with it.
        reason: String,
    },
    /// The dataset store failed while writing `path`.
    #[error("{path}: writing the synthetic dataset failed")]
    Store {
        /// The output file.
        path: PathBuf,
        /// The store's error (the cause in the error chain).
        #[source]
        source: brdf_io::Error,
    },
    /// The dataset would not fit in memory.
    #[error("a dataset of {n_materials} materials x {dims} values is too large to hold in memory")]
    TooLarge {
        /// Number of materials requested.
        n_materials: usize,
        /// Values per material.
        dims: usize,
    },
}
