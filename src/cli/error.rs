//! The CLI's error: a one-line message that names the file (and field) and an exit code.

use std::fmt;
use std::path::Path;

/// Exit code for bad input or usage.
pub const EXIT_BAD_INPUT: i32 = 2;
/// Exit code for a processing error on valid input (for example no valid pixel, no convergence).
pub const EXIT_PROCESSING: i32 = 1;

#[derive(Debug, Clone, PartialEq)]
pub struct CliError {
    pub code: i32,
    pub message: String,
}

impl CliError {
    /// Bad input: exit code 2. `file` is named at the start of the message.
    pub fn input(file: impl AsRef<Path>, what: impl fmt::Display) -> Self {
        CliError {
            code: EXIT_BAD_INPUT,
            message: format!("{}: {}", file.as_ref().display(), what),
        }
    }

    /// Usage error that concerns no file: exit code 2.
    pub fn usage(what: impl fmt::Display) -> Self {
        CliError {
            code: EXIT_BAD_INPUT,
            message: what.to_string(),
        }
    }

    /// Processing error on valid input: exit code 1.
    pub fn processing(file: impl AsRef<Path>, what: impl fmt::Display) -> Self {
        CliError {
            code: EXIT_PROCESSING,
            message: format!("{}: {}", file.as_ref().display(), what),
        }
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for CliError {}
