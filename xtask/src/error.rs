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
    /// A stage error from any displayable cause. A cause that starts by naming the stage's
    /// file (`PATH: No space left on device`) loses that prefix: the message names it already.
    pub fn stage(
        stage: &'static str,
        path: impl Into<PathBuf>,
        cause: impl std::fmt::Display,
    ) -> Self {
        let path = path.into();
        let reason = brdf_io::error::without_path_prefix(cause.to_string(), &path);
        Self::Stage {
            stage,
            path,
            reason,
        }
    }

    /// The error with `staging` (the staging directory a run wrote into, gone once the run
    /// fails) replaced by `out` (where the run publishes) in its path and message: a failed
    /// stage then names the output the user asked for, not a deleted hidden directory.
    pub fn published(self, staging: &std::path::Path, out: &std::path::Path) -> Self {
        let path = |p: PathBuf| match p.strip_prefix(staging) {
            Ok(rest) => out.join(rest),
            Err(_) => p,
        };
        match self {
            Self::Stage {
                stage,
                path: p,
                reason,
            } => Self::Stage {
                stage,
                path: path(p),
                reason: reason.replace(&staging.display().to_string(), &out.display().to_string()),
            },
            Self::Io { path: p, error } => Self::Io {
                path: path(p),
                error,
            },
            other @ Self::Config { .. } => other,
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// Paths and messages inside the staging directory name the published output instead;
    /// others stay as they were.
    #[test]
    fn published_errors_name_the_output_not_the_staging_directory() {
        let (staging, out) = (Path::new("/runs/.out.x1Y2.tmp"), Path::new("/runs/out"));
        let e = Error::stage(
            "fit",
            staging.join("model.toml"),
            "/runs/.out.x1Y2.tmp/data.sbrdf: two materials are identical",
        )
        .published(staging, out);
        assert_eq!(
            e.to_string(),
            "fit stage (/runs/out/model.toml): /runs/out/data.sbrdf: two materials are identical"
        );
        let e = Error::io(
            staging.join("sheet.png"),
            std::io::Error::other("disk full"),
        )
        .published(staging, out);
        assert_eq!(e.to_string(), "/runs/out/sheet.png: disk full");
        // A cause naming the stage's own file does not name it twice.
        let e = Error::stage("predict", "/o/p.bsdf", "/o/p.bsdf: No space left on device");
        assert_eq!(
            e.to_string(),
            "predict stage (/o/p.bsdf): No space left on device"
        );
        let e = Error::stage("data", "/data/w.npy", "not an .npy file").published(staging, out);
        assert_eq!(e.to_string(), "data stage (/data/w.npy): not an .npy file");
    }
}
