//! Errors of the readers and writers.
//!
//! A format parser works on bytes and knows nothing of the file, so it returns a `ParseError`;
//! `read_surface` / `write_surface` wrap it in an `IoError` that names the file. Every message is
//! one line (the CLI prints it as is) and names the field or line that is wrong.

use std::path::Path;

use thiserror::Error;

/// What is wrong with the bytes of a map file, without the file name.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ParseError {
    /// A header field holds a value the format does not allow.
    #[error("header field {field} = {value} {expected}")]
    Field {
        field: &'static str,
        value: String,
        expected: String,
    },
    /// Any other malformation (truncation, bad token, wrong magic...).
    #[error("{0}")]
    Invalid(String),
    /// The file is well formed but holds no valid pixel.
    #[error("no valid pixel in the map")]
    NoValidPixel,
}

impl ParseError {
    /// A header-field error: `header field NAME = VALUE EXPECTED`.
    pub fn field(field: &'static str, value: impl ToString, expected: impl Into<String>) -> Self {
        ParseError::Field {
            field,
            value: one_line(&value.to_string()),
            expected: one_line(&expected.into()),
        }
    }

    /// A free-form malformation message (made one line).
    pub fn invalid(what: impl Into<String>) -> Self {
        ParseError::Invalid(one_line(&what.into()))
    }
}

/// An error reading or writing a map file; its Display names the file.
#[derive(Debug, Error)]
pub enum IoError {
    /// The file could not be opened or read.
    #[error("{file}: cannot read: {}", one_line(&source.to_string()))]
    Read {
        file: String,
        source: std::io::Error,
    },
    /// The file was read but its content is not a valid map.
    #[error("{file}: {source}")]
    Parse { file: String, source: ParseError },
    /// The output could not be written (the destination is left untouched).
    #[error("{file}: cannot write: {}", one_line(&source.to_string()))]
    Write {
        file: String,
        source: std::io::Error,
    },
    /// The requested output format has no writer (a usage error).
    #[error("{file}: {what}")]
    Unsupported { file: String, what: String },
    /// The map cannot be represented in the requested output format.
    #[error("{file}: {what}")]
    Unrepresentable { file: String, what: String },
}

impl IoError {
    /// Process exit code for this error: 1 when the input is valid but unusable (no valid
    /// pixel, a map the output format cannot hold), 2 for bad input or an unwritable path.
    pub fn exit_code(&self) -> i32 {
        match self {
            IoError::Parse {
                source: ParseError::NoValidPixel,
                ..
            }
            | IoError::Unrepresentable { .. } => 1,
            _ => 2,
        }
    }

    pub(crate) fn parse(path: &Path, source: ParseError) -> Self {
        IoError::Parse {
            file: path.display().to_string(),
            source,
        }
    }

    pub(crate) fn read(path: &Path, source: std::io::Error) -> Self {
        IoError::Read {
            file: path.display().to_string(),
            source,
        }
    }

    pub(crate) fn write(path: &Path, source: std::io::Error) -> Self {
        IoError::Write {
            file: path.display().to_string(),
            source,
        }
    }
}

/// Collapses line breaks so a message stays on one line.
pub(crate) fn one_line(s: &str) -> String {
    if s.contains(['\n', '\r']) {
        s.split(['\n', '\r'])
            .map(str::trim)
            .filter(|p| !p.is_empty())
            .collect::<Vec<_>>()
            .join(" ")
    } else {
        s.to_string()
    }
}
