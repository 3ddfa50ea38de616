//! The xtask's one error type: every variant names the file (or stage) and the problem.

use std::path::PathBuf;

/// Result alias of the xtask library.
pub type Result<T> = std::result::Result<T, Error>;

/// What went wrong, and where.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A config file has an unknown key, a missing key or a bad value.
    #[error("{}: {reason}", path.display())]
    Config {
        /// The config file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// Reading or writing a file failed.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error (part of the message, so not a `source`: error chains would print it
        /// twice).
        error: std::io::Error,
    },
    /// A pipeline stage failed.
    #[error("{stage} stage ({}): {reason}", path.display())]
    Stage {
        /// The stage (`data`, `fit`, `predict`, ...).
        stage: &'static str,
        /// The file the stage was working on.
        path: PathBuf,
        /// Why it failed.
        reason: String,
    },
}

impl Error {
    /// A stage error from any displayable cause.
    pub fn stage(
        stage: &'static str,
        path: impl Into<PathBuf>,
        cause: impl std::fmt::Display,
    ) -> Self {
        Self::Stage {
            stage,
            path: path.into(),
            reason: cause.to_string(),
        }
    }

    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            error: source,
        }
    }
}
