//! The error type of the render crate.

use std::path::PathBuf;

/// Errors of rendering and picture writing.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An argument is out of range or inconsistent.
    #[error("invalid argument: {reason}")]
    InvalidArgument {
        /// What is wrong.
        reason: String,
    },
    /// A BRDF source failed to evaluate (its own message: it names the file and the problem).
    #[error(transparent)]
    Source(#[from] brdf_io::Error),
    /// A picture could not be written.
    #[error("writing {path}: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// Result alias of the render crate.
pub type Result<T> = std::result::Result<T, Error>;
