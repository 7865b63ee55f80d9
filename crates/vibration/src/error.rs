//! Errors of the vibration model and its coupling into removal.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum VibrationError {
    /// A `[vibration]` key whose value is out of its domain or of the wrong type.
    #[error("[vibration] {key}: {what}")]
    InvalidParam { key: String, what: String },
    /// A `[vibration]` table that does not read: an unknown key (with the nearest valid name)
    /// or a wrong type; the message names the key (bonnetlab_process::config).
    #[error("{0}")]
    Table(String),
    /// Two keys that cannot be given together.
    #[error("[vibration] '{0}' and '{1}' cannot both be given")]
    Conflict(String, String),
    /// A bad argument to a library function (empty path, zero sampling rate, ...).
    #[error("{0}")]
    InvalidArgument(String),
    /// A failure inside the process simulator the coupling builds on.
    #[error("process: {0}")]
    Process(String),
}

impl VibrationError {
    pub(crate) fn param(key: &str, what: impl Into<String>) -> Self {
        VibrationError::InvalidParam {
            key: key.to_string(),
            what: what.into(),
        }
    }
}
