//! The error type of `brdf-io`: every variant names the file (when there is one) and the problem.

use std::path::PathBuf;

/// Result alias of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong while reading, writing or resampling BRDF data.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// An operating-system I/O error on a file. The OS error is part of the message (not a
    /// `source()`), so error chains print it once.
    #[error("{path}: {error}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        error: std::io::Error,
    },
    /// An output that its file system cannot hold (checked before writing it).
    #[error(
        "{path}: {what} needs about {needed} bytes ({}), but its file system has {available} \
         bytes ({}) free",
        readable_bytes(*needed),
        readable_bytes(*available)
    )]
    NoSpace {
        /// The output.
        path: PathBuf,
        /// What is being written.
        what: String,
        /// Bytes it needs (an estimate).
        needed: u64,
        /// Bytes free for this user.
        available: u64,
    },
    /// Working memory that could not be allocated (a store of very many materials).
    #[error(
        "{path}: not enough memory for {what}: it needs {needed} bytes ({})",
        readable_bytes(*needed)
    )]
    OutOfMemory {
        /// The store being processed.
        path: PathBuf,
        /// What the memory is for.
        what: String,
        /// Bytes asked for.
        needed: u64,
    },
    /// A grid or channel specification that cannot be used.
    #[error("invalid grid or channels: {reason}")]
    InvalidGrid {
        /// What is wrong with it.
        reason: String,
    },
    /// A file that is not a dataset store (wrong magic bytes).
    #[error("{path}: not a specgp dataset store (.sbrdf): {reason}")]
    NotAStore {
        /// The file concerned.
        path: PathBuf,
        /// What was found instead.
        reason: String,
    },
    /// A dataset store written by a format version this build cannot read.
    #[error(
        "{path}: unsupported .sbrdf format version {found} (this build reads version {supported})"
    )]
    StoreVersion {
        /// The file concerned.
        path: PathBuf,
        /// Version found in the file.
        found: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// A truncated or corrupt dataset store (header, offset table or chunk).
    #[error("{path}: corrupt dataset store: {reason}")]
    StoreCorrupt {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The payload checksum of a dataset store does not match its header.
    #[error("{path}: checksum mismatch: header says {expected}, payload hashes to {actual}")]
    StoreChecksum {
        /// The file concerned.
        path: PathBuf,
        /// Checksum recorded in the header.
        expected: String,
        /// Checksum of the payload as read.
        actual: String,
    },
    /// A NaN or infinite value handed to the store writer.
    #[error("{path}: material {material:?} has a non-finite value {value} at index {index}")]
    NonFiniteValue {
        /// The store being written.
        path: PathBuf,
        /// Name of the material.
        material: String,
        /// Flat dimension index (angular_index * n_channels + channel).
        index: usize,
        /// The offending value.
        value: f32,
    },
    /// A NaN or infinite value read from a store (lookups do not re-hash the payload).
    #[error(
        "{path}: material {material:?} holds a non-finite value {value} at index {index} (a \
         damaged store? `specgp info` verifies its checksum)"
    )]
    DamagedValue {
        /// The store read.
        path: PathBuf,
        /// Name of the material.
        material: String,
        /// Flat dimension index (angular_index * n_channels + channel).
        index: usize,
        /// The value read.
        value: f32,
    },
    /// A store writer or reader used inconsistently (wrong lengths, ranges, order, names).
    #[error("{path}: {reason}")]
    StoreUsage {
        /// The store concerned.
        path: PathBuf,
        /// What is inconsistent.
        reason: String,
    },
    /// A material name that the dataset store does not hold.
    #[error(
        "{path}: no material named {name:?}{} (the store holds: {available})",
        did_you_mean(.closest)
    )]
    UnknownMaterial {
        /// The store concerned.
        path: PathBuf,
        /// The name asked for.
        name: String,
        /// The held name most like it ([`closest_name`]), if any is close.
        closest: Option<String>,
        /// The names it holds, comma-separated.
        available: String,
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
    /// An output that must be seekable (a dataset store) aimed at a pipe, terminal or socket,
    /// or at standard output that is not a regular file at its start.
    #[error(
        "{path}: cannot write {what} there: it is written at offsets, so it needs a seekable \
         file (not a pipe, terminal or socket; standard output only when redirected to a file \
         with `>`, at its start); write it to a regular file"
    )]
    NotSeekable {
        /// The output path.
        path: PathBuf,
        /// What was being written.
        what: String,
    },
    /// A resampled source produced NaN or infinite values, or values beyond the f32 range of a
    /// store (a damaged file or network).
    #[error(
        "{source_name}: {count} of {values} resampled values are NaN or infinite, or finite but \
         beyond the f32 range of a store (|f| > 3.4e38; a damaged file or network?); refusing to \
         store them as zeros"
    )]
    NonFiniteValues {
        /// The source (file, or network name).
        source_name: String,
        /// How many values were not finite.
        count: usize,
        /// Values resampled.
        values: usize,
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
            error: source,
        }
    }
}

/// `n` and the noun (given in the singular) as a message says them: "1 material", "51
/// materials", "0 materials".
pub fn quantity(n: usize, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

/// `"; did you mean \"NAME\"?"` for a close name, else nothing.
pub fn did_you_mean(closest: &Option<String>) -> String {
    closest
        .as_ref()
        .map_or_else(String::new, |c| format!("; did you mean {c:?}?"))
}

/// `bytes` in the largest decimal unit that keeps a leading digit (`598 kB`, `1.2 GB`): a
/// small size read "0.0 GB".
pub fn readable_bytes(bytes: u64) -> String {
    let b = bytes as f64;
    match [(1e12, "TB"), (1e9, "GB"), (1e6, "MB"), (1e3, "kB")]
        .into_iter()
        .find(|&(unit, _)| b >= unit)
    {
        Some((unit, name)) if b / unit < 10.0 => format!("{:.1} {name}", b / unit),
        Some((unit, name)) => format!("{:.0} {name}", b / unit),
        None => format!("{bytes} B"),
    }
}

/// The candidate most like `name`, for "did you mean" hints: one equal to it but for case,
/// else the only one containing it (or contained in it; none when several do), else the most
/// similar by Jaro-Winkler similarity if that is at least 0.8. `None` when nothing is close.
pub fn closest_name<'a>(name: &str, candidates: &[&'a str]) -> Option<&'a str> {
    let lower = name.to_lowercase();
    if let Some(c) = candidates.iter().find(|c| c.to_lowercase() == lower) {
        return Some(c);
    }
    let containing: Vec<&&str> = candidates
        .iter()
        .filter(|c| {
            let c = c.to_lowercase();
            !lower.is_empty() && (c.contains(&lower) || lower.contains(&c))
        })
        .collect();
    match containing.as_slice() {
        [one] => return Some(one),
        [] => {}
        // A part of several names ("metal") is ambiguous: no guess.
        _ => return None,
    }
    candidates
        .iter()
        .map(|c| (c, strsim::jaro_winkler(&lower, &c.to_lowercase())))
        .filter(|(_, s)| *s >= 0.8)
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(c, _)| *c)
}

/// `message` without a leading `"PATH: "` for `path`, the form this crate's file errors take
/// (`"{path}: {problem}"`): for wrappers whose own message names the file already, so it is
/// said once ("writing P: No space left", not "writing P: P: No space left").
pub fn without_path_prefix(message: String, path: &std::path::Path) -> String {
    match message.strip_prefix(&format!("{}: ", path.display())) {
        Some(rest) => rest.to_owned(),
        None => message,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_leading_path_is_dropped_only_when_it_is_the_given_file() {
        let p = std::path::Path::new("/o/a b.png");
        assert_eq!(without_path_prefix("/o/a b.png: full".into(), p), "full");
        assert_eq!(
            without_path_prefix("/o/c.png: full".into(), p),
            "/o/c.png: full"
        );
        assert_eq!(
            without_path_prefix("/o/a b.pngx: full".into(), p),
            "/o/a b.pngx: full"
        );
    }

    /// "1 material", never "1 materials".
    #[test]
    fn quantities_are_singular_for_one() {
        assert_eq!(quantity(1, "material"), "1 material");
        assert_eq!(quantity(51, "material"), "51 materials");
        assert_eq!(quantity(0, "channel"), "0 channels");
    }

    #[test]
    fn byte_counts_read_in_a_unit_that_keeps_a_digit() {
        assert_eq!(readable_bytes(512), "512 B");
        assert_eq!(readable_bytes(598_000), "598 kB");
        assert_eq!(readable_bytes(1_226_941_477), "1.2 GB");
        assert_eq!(readable_bytes(23_000_000_000), "23 GB");
        // A leading digit and a decimal below 10 units, whole units from 10 on.
        assert_eq!(readable_bytes(9_900_000_000), "9.9 GB");
        assert_eq!(readable_bytes(10_000_000_000), "10 GB");
        assert_eq!(readable_bytes(1_000), "1.0 kB");
        assert_eq!(readable_bytes(999), "999 B");
        let e = Error::NoSpace {
            path: "a.sbrdf".into(),
            what: "the store".into(),
            needed: 700_000,
            available: 600_000,
        };
        assert!(
            e.to_string().contains("700000 bytes (700 kB)")
                && e.to_string().contains("(600 kB) free"),
            "{e}"
        );
    }

    #[test]
    fn closest_names_catch_typos_case_and_parts_but_not_strangers() {
        let names = [
            "metal_gold",
            "metal_copper",
            "metal_chromium",
            "paper_white",
            "acrylic_felt_white",
        ];
        assert_eq!(closest_name("metal_gol", &names), Some("metal_gold"));
        assert_eq!(closest_name("Metal_Gold", &names), Some("metal_gold"));
        assert_eq!(closest_name("gold", &names), Some("metal_gold"));
        assert_eq!(closest_name("metal_coper", &names), Some("metal_copper"));
        assert_eq!(closest_name("papr_white", &names), Some("paper_white"));
        // "white" is in two names and "metal" in three: no unique part, and no close whole.
        assert_eq!(closest_name("white", &names), None);
        assert_eq!(closest_name("metal", &names), None);
        assert_eq!(closest_name("xyz", &names), None);
        assert_eq!(closest_name("", &names), None);
        assert_eq!(closest_name("gold", &[]), None);
        let e = Error::UnknownMaterial {
            path: "d.sbrdf".into(),
            name: "metal_gol".into(),
            closest: Some("metal_gold".into()),
            available: names.join(", "),
        };
        assert!(
            e.to_string()
                .starts_with("d.sbrdf: no material named \"metal_gol\"; did you mean \"metal_gold\"? (the store holds: metal_gold,"),
            "{e}"
        );
    }
}
