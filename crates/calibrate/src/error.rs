//! Errors of the calibration library.

use bonnetlab_surface::SurfaceError;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum CalibrateError {
    /// Input that cannot be used as given (shape, units, too few samples, ...).
    #[error("{0}")]
    InvalidInput(String),
    /// Valid input on which the calibration cannot proceed (no common aperture, singular fit).
    #[error("{0}")]
    Processing(String),
    #[error(transparent)]
    Surface(#[from] SurfaceError),
    #[error(transparent)]
    Process(#[from] bonnetlab_process::ProcessError),
}
