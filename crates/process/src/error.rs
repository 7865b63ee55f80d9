//! Errors of the process crate. Every variant that concerns a file names it (and the line or
//! key), so the CLI can print it as one line without adding context.

use std::path::PathBuf;

use bonnetlab_surface::SurfaceError;
use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum ProcessError {
    /// An argument outside its domain (negative pitch, empty grid, ...).
    #[error("{0}")]
    InvalidArgument(String),
    /// A file that cannot be read at all.
    #[error("{}: {}", file.display(), one_line(what))]
    Io { file: PathBuf, what: String },
    /// A tool-path log with a bad line (`line` is 1-based, the header is line 1).
    #[error("{}: line {line}: {}", file.display(), one_line(what))]
    PathLog {
        file: PathBuf,
        line: usize,
        what: String,
    },
    /// A recipe or case TOML with a missing or bad key (`key` as `[table] name`).
    #[error("{}: {}: {}", file.display(), one_line(key), one_line(what))]
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

/// Error text echoes file content (a field, a TOML snippet); control characters such as a
/// newline inside a quoted CSV field would break the one-line error contract, so they are
/// shown escaped.
fn one_line(s: &str) -> String {
    s.split(['\n', '\r'])
        .map(str::trim_end)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" | ")
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn echoed_content_never_breaks_the_line() {
        let e = ProcessError::PathLog {
            file: PathBuf::from("p.csv"),
            line: 3,
            what: "x_mm is not a number: '1\n2\r\n3'".into(),
        };
        let text = e.to_string();
        assert!(!text.contains('\n') && !text.contains('\r'), "{text}");
        assert_eq!(text, "p.csv: line 3: x_mm is not a number: '1 | 2 | 3'");
        let r = ProcessError::Recipe {
            file: "r.toml".into(),
            key: "[tif]".into(),
            what: "bad\n  ^".into(),
        };
        assert_eq!(r.to_string(), "r.toml: [tif]: bad |   ^");
    }
}
