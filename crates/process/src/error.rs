//! Errors of the process crate. Every variant that concerns a file names it (and the line or
//! key), so the CLI can print it as one line without adding context.

use std::path::PathBuf;

use bonnetlab_surface::SurfaceError;
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum ProcessError {
    /// An argument outside its domain (negative pitch, empty grid, ...).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A file that cannot be read at all.
    #[error("{}: {what}", file.display())]
    Io { file: PathBuf, what: String },
    /// A tool-path log with a bad line (`line` is 1-based, the header is line 1).
    #[error("{}: line {line}: {what}", file.display())]
    PathLog {
        file: PathBuf,
        line: usize,
        what: String,
    },
    /// A recipe or case TOML with a missing or bad key (`key` as `[table] name`).
    #[error("{}: {key}: {what}", file.display())]
    Recipe {
        file: PathBuf,
        key: String,
        what: String,
    },
    /// Valid input that cannot be processed (no valid pixel in the aperture, ...).
    #[error("{0}")]
    Processing(String),
    /// An error of the surface model.
    #[error(transparent)]
    Surface(#[from] SurfaceError),
}

impl ProcessError {
    pub(crate) fn invalid(what: impl Into<String>) -> Self {
        ProcessError::InvalidArgument(what.into())
    }

    /// True when the error is bad input (exit code 2) rather than a processing failure (1).
    pub fn is_bad_input(&self) -> bool {
        !matches!(
            self,
            ProcessError::Processing(_) | ProcessError::Surface(SurfaceError::NoValidPixel)
        )
    }
}
