//! Errors of the surface model and its analyses.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum SurfaceError {
    /// The map holds no valid pixel (valid-but-unusable data: exit code 1 at the CLI).
    #[error("no valid pixel in the map")]
    NoValidPixel,
    /// Too few valid pixels for the requested fit or statistic.
    #[error("{needed} valid pixels needed for {what}, only {have} available")]
    TooFewPixels {
        what: String,
        needed: usize,
        have: usize,
    },
    /// Two maps that must share a grid do not.
    #[error("grid mismatch: {0}")]
    GridMismatch(String),
    /// An argument outside its domain (unknown term name, negative pixel size, ...).
    #[error("{0}")]
    InvalidArgument(String),
    /// A least-squares system that is singular on the valid pixels.
    #[error("singular fit: {0}")]
    Singular(String),
}
