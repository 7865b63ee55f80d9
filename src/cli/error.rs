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
            message: named(file.as_ref(), what),
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
            message: named(file.as_ref(), what),
        }
    }

    /// An output file that cannot be written (a missing directory, no permission, a special
    /// file, an input of the command, a full disk): exit code 2, the file named once.
    pub fn output(file: impl AsRef<Path>, e: &std::io::Error) -> Self {
        CliError {
            code: EXIT_BAD_INPUT,
            message: format!("{}: cannot write: {}", file.as_ref().display(), io_what(e)),
        }
    }

    /// Standard output cannot be written (for example `> /dev/full`): exit code 1.
    pub fn stdout(e: &std::io::Error) -> Self {
        CliError {
            code: EXIT_PROCESSING,
            message: format!("stdout: cannot write: {}", io_what(e)),
        }
    }

    /// The reader of standard output went away (`| head`): the command ends quietly, exit 0,
    /// as Unix filters do.
    pub fn closed_pipe() -> Self {
        CliError {
            code: 0,
            message: String::new(),
        }
    }

    /// Whether this is the quiet end of [`CliError::closed_pipe`].
    pub fn is_closed_pipe(&self) -> bool {
        self.code == 0 && self.message.is_empty()
    }
}

/// `FILE: WHAT`, naming the file once even when WHAT already starts with it.
fn named(file: &Path, what: impl fmt::Display) -> String {
    let what = what.to_string();
    let f = file.display().to_string();
    let tag = format!("{f}: ");
    if f.is_empty() || what.starts_with(&tag) {
        what
    } else if what.contains(&tag) {
        // "invalid argument: FILE: ..." from a lower layer: keep one naming, at the start.
        format!("{f}: {}", what.replacen(&tag, "", 1))
    } else {
        format!("{f}: {what}")
    }
}

/// An I/O error's text on one line, without Rust's "(os error N)" suffix.
pub fn io_what(e: &std::io::Error) -> String {
    let s = e.to_string().replace(['\n', '\r'], " ");
    match s.find(" (os error ") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for CliError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_is_named_once() {
        let e = CliError::input("case.toml", "invalid argument: case.toml: bad key");
        assert_eq!(e.message, "case.toml: invalid argument: bad key");
        let e = CliError::processing("a.dat", "a.dat: no valid pixel");
        assert_eq!(e.message, "a.dat: no valid pixel");
        let e = CliError::input("a.dat", "bad");
        assert_eq!(e.message, "a.dat: bad");
    }

    #[test]
    fn io_errors_are_one_line_without_os_codes() {
        let e = std::io::Error::from_raw_os_error(28);
        assert_eq!(
            CliError::stdout(&e).message,
            "stdout: cannot write: No space left on device"
        );
        assert_eq!(CliError::stdout(&e).code, 1);
        assert_eq!(CliError::output("x.json", &e).code, 2);
    }
}
