//! The error type of `brdf-io`: every variant names the file (when there is one) and the problem.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong while reading, writing or resampling BRDF data.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An operating-system I/O error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A grid or channel specification that cannot be used.
    #[error("invalid grid: {reason}")]
    InvalidGrid {
        /// What is wrong with it.
        reason: String,
    },
    /// A BRDF file (tensor file, MERL, npy, names list, CSV) whose content breaks its format.
    #[error("{path}: {reason}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, and where in the file.
        reason: String,
    },
    /// A well-formed BRDF file that uses a feature this crate does not support yet.
    #[error("{path}: not supported yet: {feature}")]
    Unsupported {
        /// The file concerned.
        path: PathBuf,
        /// The unsupported feature.
        feature: String,
    },
    /// A requested wavelength outside the range stored in a spectral file.
    #[error(
        "{path}: wavelength {wavelength_nm} nm is outside the stored range {min_nm}..={max_nm} nm"
    )]
    WavelengthOutOfRange {
        /// The file concerned.
        path: PathBuf,
        /// The wavelength asked for, in nm.
        wavelength_nm: f64,
        /// Smallest stored wavelength, in nm.
        min_nm: f64,
        /// Largest stored wavelength, in nm.
        max_nm: f64,
    },
    /// An argument that does not fit the data (buffer length, channel kind, material index).
    #[error("invalid argument: {reason}")]
    InvalidArgument {
        /// What does not fit.
        reason: String,
    },
}

impl Error {
    /// Wraps an I/O error with the path it concerns.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}
