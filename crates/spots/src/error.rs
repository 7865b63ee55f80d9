//! Errors of spot analysis, manifests and model fits. Messages are one line; the CLI prefixes
//! the file name.

use bonnetlab_surface::SurfaceError;
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum SpotsError {
    /// The manifest is malformed: `at` names the line and/or key.
    #[error("{at}: {what}")]
    Manifest { at: String, what: String },
    /// The spot map cannot be analysed (no dip, no border ring, unknown pixel size, ...).
    #[error("{0}")]
    Spot(String),
    /// A model parameter or factor outside its physical domain.
    #[error("invalid model input: {0}")]
    Model(String),
    /// A least-squares fit that could not be carried out.
    #[error("fit failed: {0}")]
    Fit(String),
    #[error(transparent)]
    Surface(#[from] SurfaceError),
}

impl SpotsError {
    /// True when the error is about the user's input (exit code 2) rather than a processing
    /// failure on valid input (exit code 1).
    pub fn is_bad_input(&self) -> bool {
        matches!(self, SpotsError::Manifest { .. })
    }
}
