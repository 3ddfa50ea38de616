//! The error type of `predict`.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong while predicting or evaluating.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The model's dataset store is not where the model says (moved or deleted), or not where
    /// the caller said.
    #[error(
        "model {model}: {}",
        if *given {
            format!("the dataset {} given for it is not a file", dataset.display())
        } else {
            format!(
                "its dataset {} is not a file (moved or deleted?); pass the store's new path \
                 explicitly (`--dataset` on the command line)",
                dataset.display()
            )
        }
    )]
    DatasetMissing {
        /// The model file.
        model: PathBuf,
        /// The dataset path: recorded in the model, or given.
        dataset: PathBuf,
        /// Whether the path was given by the caller (not read from the model).
        given: bool,
    },
    /// The store does not match what the model was fitted on.
    #[error("model {model} does not match dataset {dataset}: {what}")]
    DatasetMismatch {
        /// The model file.
        model: PathBuf,
        /// The store.
        dataset: PathBuf,
        /// What differs (checksum, grid, channels, materials, D).
        what: String,
    },
    /// A NaN or infinite value where a finite one is needed and no stored value explains it
    /// (a damaged stored value is [`brdf_io::Error::DamagedValue`], naming its file): an
    /// overflowing prediction, or a target's own values.
    #[error("{what} is {value}: {cause}")]
    NonFiniteValue {
        /// Which value (material or prediction, index).
        what: String,
        /// The value.
        value: f64,
        /// Why it is not finite, as far as known.
        cause: String,
    },
    /// A latent point that cannot be used (NaN, wrong dimension).
    #[error("invalid latent point {point:?}: {reason}")]
    InvalidPoint {
        /// The point as given.
        point: Vec<f64>,
        /// What is wrong.
        reason: String,
    },
    /// An argument that does not fit (buffer length, coefficient count, material name, format).
    #[error("invalid argument: {reason}")]
    InvalidArgument {
        /// What does not fit.
        reason: String,
    },
    /// A leave-one-out step (refit without the material, latent search, baselines) failed.
    #[error("leave-one-out without material {index} ({name:?}): {cause}")]
    LeaveOneOut {
        /// Index of the held-out material.
        index: usize,
        /// Its name.
        name: String,
        /// What failed (part of the message, so not a `source`: error chains, as the CLI
        /// prints them, would show it twice).
        cause: Box<Error>,
    },
    /// An angular cell index beyond the grid (lookups by cell).
    #[error("angular cell {cell} is beyond the grid's {cells} cells")]
    CellOutOfRange {
        /// The cell index given.
        cell: usize,
        /// Cells of the grid (valid indices are below this).
        cells: usize,
    },
    /// An output file that cannot be written in the requested format.
    #[error("{path}: {reason}")]
    Output {
        /// The output file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// An error from the dataset store or a file format.
    #[error(transparent)]
    Store(#[from] brdf_io::Error),
    /// An error from the model (loading, refitting).
    #[error(transparent)]
    Model(#[from] gplvm::Error),
    /// An error from the GP maths.
    #[error(transparent)]
    Gp(#[from] gp_core::GpError),
}
