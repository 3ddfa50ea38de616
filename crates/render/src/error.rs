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
    /// A BRDF source returned a NaN or infinite value for a channel the colour needs (such a
    /// value rendered as black, or as NaN pixels that the 8-bit encoding turned black, without
    /// a word).
    #[error(
        "the BRDF source returned {value} for channel {channel} at {at}: BRDF values must be \
         finite"
    )]
    NonFiniteValue {
        /// The value.
        value: f64,
        /// The channel (`600 nm`, or `R`, `G`, `B`).
        channel: String,
        /// Where it was looked up (the directions, or the grid cell and its angles).
        at: String,
    },
    /// Finite values whose rendering overflowed to NaN (a source's values near the largest
    /// f64, or a huge exposure of them).
    #[error("rendering overflowed: {reason}")]
    Overflow {
        /// What overflowed.
        reason: String,
    },
    /// A thumbnail of a latent map failed (the source made for its point, or its render).
    #[error("the thumbnail at latent point ({}, {}): {cause}", point[0], point[1])]
    Thumbnail {
        /// Its latent point (the map's first two axes).
        point: [f64; 2],
        /// What failed (in the message, not the error chain: `{:#}` printed it twice).
        cause: Box<Error>,
    },
    /// A picture could not be written.
    #[error("writing {path}: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why (without the path again).
        reason: String,
    },
    /// A picture could not be read.
    #[error("reading {path}: {reason}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// Result alias of the render crate.
pub type Result<T> = std::result::Result<T, Error>;
