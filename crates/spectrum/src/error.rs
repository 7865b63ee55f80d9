//! Errors of the spectral analyses.

use bonnetlab_surface::SurfaceError;
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum SpectrumError {
    /// Form removal or another surface-level step failed.
    #[error(transparent)]
    Surface(#[from] SurfaceError),
    /// An argument outside its domain (window parameter, band edges, pitch, ...).
    #[error("{0}")]
    InvalidArgument(String),
    /// No line along the requested axis had a valid segment long enough to analyse.
    #[error("no usable {axis} line: every line has fewer than {min_len} consecutive valid pixels")]
    NoUsableLine { axis: &'static str, min_len: usize },
    /// The quantity cannot be computed from this map (pitch longer than the field, band
    /// outside the measured frequencies, ...); the text says why.
    #[error("not resolvable: {0}")]
    NotResolvable(String),
    /// The map is too small for the requested analysis.
    #[error("map too small: {0}")]
    TooSmall(String),
}
