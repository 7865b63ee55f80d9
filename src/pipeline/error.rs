//! The error of every pipeline and of the CLI that calls them: a one-line message that names
//! the file (and field) and the exit code (2 bad input, 1 valid but unusable).

use std::fmt;
use std::path::Path;

/// Exit code for bad input or usage.
pub const EXIT_BAD_INPUT: i32 = 2;
/// Exit code for a processing error on valid input (for example no valid pixel, no convergence).
pub const EXIT_PROCESSING: i32 = 1;

#[derive(Debug, Clone, PartialEq)]
pub struct Error {
    pub code: i32,
    pub message: String,
}

impl Error {
    /// Bad input: exit code 2. `file` is named at the start of the message.
    pub fn input(file: impl AsRef<Path>, what: impl fmt::Display) -> Self {
        Error {
            code: EXIT_BAD_INPUT,
            message: named(file.as_ref(), what),
        }
    }

    /// Usage error that concerns no file: exit code 2.
    pub fn usage(what: impl fmt::Display) -> Self {
        Error {
            code: EXIT_BAD_INPUT,
            message: what.to_string(),
        }
    }

    /// Processing error on valid input: exit code 1.
    pub fn processing(file: impl AsRef<Path>, what: impl fmt::Display) -> Self {
        Error {
            code: EXIT_PROCESSING,
            message: named(file.as_ref(), what),
        }
    }

    /// An output file that cannot be written (a missing directory, no permission, a special
    /// file, an input of the command, a full disk): exit code 2, the file named once.
    pub fn output(file: impl AsRef<Path>, e: &std::io::Error) -> Self {
        Error {
            code: EXIT_BAD_INPUT,
            message: format!("{}: cannot write: {}", file.as_ref().display(), io_what(e)),
        }
    }

    /// Standard output cannot be written (for example `> /dev/full`): exit code 1.
    pub fn stdout(e: &std::io::Error) -> Self {
        Error {
            code: EXIT_PROCESSING,
            message: format!("stdout: cannot write: {}", io_what(e)),
        }
    }

    /// The reader of standard output went away (`| head`): the command ends quietly, exit 0,
    /// as Unix filters do.
    pub fn closed_pipe() -> Self {
        Error {
            code: 0,
            message: String::new(),
        }
    }

    /// Whether this is the quiet end of [`Error::closed_pipe`].
    pub fn is_closed_pipe(&self) -> bool {
        self.code == 0 && self.message.is_empty()
    }
}

/// A vibration-parameter error of a recipe, labelled with the table the value came from: the
/// coupling reads `spindle_rpm`, `offset_mm` and `inner_pressure_mpa` from `[vibration]` when
/// that table sets them and from `[process]` otherwise, so a bad `[process]` value is reported
/// as `[process] KEY`, not as `[vibration] KEY`. Parameter errors are bad input (exit 2).
pub fn vibration_error(
    file: &Path,
    vibration_table: Option<&toml::Table>,
    e: bonnetlab_vibration::VibrationError,
) -> Error {
    use bonnetlab_vibration::VibrationError as E;
    const FROM_PROCESS: [&str; 3] = ["spindle_rpm", "offset_mm", "inner_pressure_mpa"];
    match e {
        E::InvalidParam { key, what }
            if FROM_PROCESS.contains(&key.as_str())
                && !vibration_table.is_some_and(|t| t.contains_key(&key)) =>
        {
            Error::input(file, format!("[process] {key}: {what}"))
        }
        E::InvalidParam { .. } | E::Table(_) | E::Conflict(..) => Error::input(file, e),
        _ => Error::processing(file, e),
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
        // "WHAT: FILE: ..." from a lower layer: keep one naming, at the start.
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

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Error {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_file_is_named_once() {
        let e = Error::input("case.toml", "[tif] model: case.toml: bad key");
        assert_eq!(e.message, "case.toml: [tif] model: bad key");
        let e = Error::processing("a.dat", "a.dat: no valid pixel");
        assert_eq!(e.message, "a.dat: no valid pixel");
        let e = Error::input("a.dat", "bad");
        assert_eq!(e.message, "a.dat: bad");
    }

    #[test]
    fn io_errors_are_one_line_without_os_codes() {
        let e = std::io::Error::from_raw_os_error(28);
        assert_eq!(
            Error::stdout(&e).message,
            "stdout: cannot write: No space left on device"
        );
        assert_eq!(Error::stdout(&e).code, 1);
        assert_eq!(Error::output("x.json", &e).code, 2);
    }
}
