//! Command-line interface: one file per subcommand. The contract (names, flags, JSON fields)
//! is `shared/spec/interfaces.md`; each file owns its `Args` and `run`.

use std::io::Write;
use std::path::Path;

use clap::{Parser, Subcommand};

pub mod batch;
pub mod calibrate;
pub mod compare;
pub mod demo;
pub mod dwell;
pub mod error;
pub mod progress;
pub mod psd;
pub mod simulate;
pub mod spots;
pub mod stats;
pub mod vibration;

pub use error::CliError;

/// bonnetlab: surface metrology, polishing simulation and vibration analysis for robot
/// bonnet polishing.
#[derive(Debug, Parser)]
#[command(name = "bonnetlab", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Height parameters of one map (PV, RMS, Sa, Ssk, Sku, ...) after form removal.
    Stats(stats::Args),
    /// 1-D PSD along X and Y, and the ripple check at the grating spacing.
    Psd(psd::Args),
    /// Compare bonnet runs (before/after maps): convergence, ripple, HTML + JSON report.
    Compare(compare::Args),
    /// Stats and ripple of many maps as JSON lines, in parallel.
    Batch(batch::Args),
    /// Run the bundled two-bonnet example (samples/) and write reports/demo.
    #[command(long_about = demo::ABOUT)]
    Demo(demo::Args),
    /// Solve dwell time for a case file (surface, TIF, clear aperture).
    Dwell(dwell::Args),
    /// Predict the after-surface of a polishing run from its recipe.
    Simulate(simulate::Args),
    /// Two-degree-of-freedom forced vibration response for a bonnet.
    Vibration(vibration::Args),
    /// Close the loop: predicted vs measured removal, diagnose and add missing effects.
    Calibrate(calibrate::Args),
    /// Fixed-point spot sweeps: TIF metrics per spot and trends per bonnet.
    Spots(spots::Args),
}

/// Runs a parsed command line; returns the process exit code and prints any error as one line.
pub fn run(cli: Cli) -> i32 {
    // No output of a command may replace one of its inputs.
    bonnetlab_io::input::enable_input_guard();
    let result = match &cli.command {
        Command::Stats(a) => stats::run(a),
        Command::Psd(a) => psd::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Batch(a) => batch::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Dwell(a) => dwell::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Vibration(a) => vibration::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Spots(a) => spots::run(a),
    };
    match result {
        Ok(()) => 0,
        Err(e) if e.is_closed_pipe() => 0,
        Err(e) => {
            eprintln!("bonnetlab: {}", plain_message(&e.message));
            e.code
        }
    }
}

/// An error message as the user reads it: one line (the libraries' messages carry no tag of
/// their own; the exit code says bad input).
pub fn plain_message(message: &str) -> String {
    message.replace(['\n', '\r'], " ")
}

/// Writes bytes to stdout and flushes, checking every write: a failed write (`> /dev/full`) is
/// [`CliError::stdout`] (exit 1, one line); a closed pipe (`| head -c1`) is
/// [`CliError::closed_pipe`] (the command ends quietly, exit 0). Never panics, unlike `print!`.
pub fn write_stdout(bytes: &[u8]) -> Result<(), CliError> {
    let mut out = std::io::stdout().lock();
    out.write_all(bytes)
        .and_then(|()| out.flush())
        .map_err(|e| stdout_error(&e))
}

/// [`write_stdout`] of a text followed by a newline (the checked `println!`).
pub fn println_stdout(text: &str) -> Result<(), CliError> {
    let mut s = String::with_capacity(text.len() + 1);
    s.push_str(text);
    s.push('\n');
    write_stdout(s.as_bytes())
}

/// The CLI error for a failed write to stdout.
pub fn stdout_error(e: &std::io::Error) -> CliError {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        CliError::closed_pipe()
    } else {
        CliError::stdout(e)
    }
}

/// Reads a text input (recipe, list, manifest): a regular file of at most
/// `bonnetlab_io::input::TEXT_LIMIT` bytes of UTF-8, registered as an input so no output of the
/// command may replace it. `what` names the expected format in the error.
pub fn read_text_input(path: &Path, what: &str) -> Result<String, CliError> {
    bonnetlab_io::input::read_text(path, bonnetlab_io::input::TEXT_LIMIT, what)
        .map_err(|e| CliError::input(path, format!("cannot read: {}", error::io_what(&e))))
}

/// A write failure of an output set or file, naming the file (exit 2):
/// `FILE: cannot write: WHY`.
pub fn write_error(e: crate::report::write::WriteError) -> CliError {
    CliError::input(&e.file, format!("cannot write: {}", e.what))
}

/// Whether an output path means stdout (`-`).
pub fn is_stdout(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// Writes one output: to stdout when `path` is `-` (every command's `--json -`), otherwise to
/// the file atomically (see `bonnetlab_io::atomic`: never over an input or a special file).
/// An unwritable file is exit 2 naming it once.
pub fn emit(path: &Path, bytes: &[u8]) -> Result<(), CliError> {
    if is_stdout(path) {
        write_stdout(bytes)
    } else {
        bonnetlab_io::atomic::write_atomic(path, bytes).map_err(|e| CliError::output(path, &e))
    }
}

/// Every output of a command, published together: single files are staged whole beside their
/// destinations (`bonnetlab_io::atomic::stage`) and a `--out` directory's files in its staging
/// area (`report::write::Set`), and nothing is published until every one is staged. So an
/// output that cannot be written (a read-only or missing directory, a special file) leaves every
/// other output as it was. What goes to stdout (`-`) is printed after the files.
#[derive(Default)]
pub struct Outputs {
    // Declared (so dropped) before the set: a staged file inside the set's new directory is
    // removed before the set removes that directory.
    files: Vec<(std::path::PathBuf, bonnetlab_io::atomic::Staged)>,
    set: Option<crate::report::write::Set>,
    stdout: Vec<u8>,
}

impl Outputs {
    /// Adds the `--out` directory's set (staged by the caller, published by [`Outputs::publish`]).
    pub fn set(&mut self, set: crate::report::write::Set) {
        self.set = Some(set);
    }

    /// Stages one output: a file (checked and written whole now, published later), or stdout
    /// when `path` is `-`.
    pub fn file(&mut self, path: &Path, bytes: &[u8]) -> Result<(), CliError> {
        if is_stdout(path) {
            self.stdout.extend_from_slice(bytes);
            return Ok(());
        }
        let staged =
            bonnetlab_io::atomic::stage(path, bytes).map_err(|e| CliError::output(path, &e))?;
        self.files.push((path.to_path_buf(), staged));
        Ok(())
    }

    /// Publishes the set, then the files (one rename each), then prints what goes to stdout.
    /// Two outputs that name one file (`--json` onto a file of the `--out` set, `--csv` and
    /// `--plot` alike) are refused before anything is published: one would silently replace
    /// the other.
    pub fn publish(self) -> Result<(), CliError> {
        let mut seen: Vec<std::path::PathBuf> = Vec::new();
        let set_dests = self.set.iter().flat_map(|s| s.destinations());
        let file_dests = self.files.iter().map(|(_, f)| f.destination());
        for (dest, named) in set_dests
            .map(|d| (d, d))
            .chain(file_dests.zip(self.files.iter().map(|(p, _)| p.as_path())))
        {
            let key = same_file_key(dest);
            if seen.contains(&key) {
                return Err(CliError::usage(format!(
                    "{}: two outputs of this command name the same file (one would replace the \
                     other); give them different names",
                    named.display()
                )));
            }
            seen.push(key);
        }
        if let Some(set) = self.set {
            set.commit().map_err(write_error)?;
        }
        for (path, staged) in self.files {
            staged.commit().map_err(|e| CliError::output(&path, &e))?;
        }
        if !self.stdout.is_empty() {
            write_stdout(&self.stdout)?;
        }
        Ok(())
    }
}

/// A file's identity for comparing output destinations: its directory resolved (it exists
/// once something is staged there) and its name.
fn same_file_key(p: &Path) -> std::path::PathBuf {
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    match p.file_name() {
        Some(n) => dir.join(n),
        None => dir,
    }
}

/// Writes a value as pretty JSON with a trailing newline through [`emit`].
pub fn emit_json<T: serde::Serialize + ?Sized>(path: &Path, value: &T) -> Result<(), CliError> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|e| CliError::processing(path, format!("JSON: {e}")))?;
    text.push('\n');
    emit(path, text.as_bytes())
}

/// Command-line number parsers (clap `value_parser`s): a number that is not finite or out of
/// range is a usage error at parse time, naming the option's value.
pub mod num {
    fn f(s: &str) -> Result<f64, String> {
        let v: f64 = s
            .trim()
            .parse()
            .map_err(|_| format!("'{s}' is not a number"))?;
        if !v.is_finite() {
            return Err(format!("'{s}' is not a finite number"));
        }
        Ok(v)
    }

    /// Any finite number.
    pub fn finite(s: &str) -> Result<f64, String> {
        f(s)
    }

    /// A finite number > 0.
    pub fn positive(s: &str) -> Result<f64, String> {
        let v = f(s)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(format!("'{s}' must be > 0"))
        }
    }

    /// A finite number >= 0.
    pub fn non_negative(s: &str) -> Result<f64, String> {
        let v = f(s)?;
        if v >= 0.0 {
            Ok(v)
        } else {
            Err(format!("'{s}' must be >= 0"))
        }
    }

    fn count(s: &str, lo: usize, hi: usize) -> Result<usize, String> {
        let v: u128 = s
            .trim()
            .parse()
            .map_err(|_| format!("'{s}' is not a whole number"))?;
        if v < lo as u128 || v > hi as u128 {
            return Err(format!("'{s}' must be between {lo} and {hi}"));
        }
        Ok(v as usize)
    }

    /// A harmonic count: 0 to 1000.
    pub fn harmonics(s: &str) -> Result<usize, String> {
        count(s, 0, 1000)
    }

    /// A worker thread count: 1 to 1024.
    pub fn jobs(s: &str) -> Result<usize, String> {
        count(s, 1, 1024)
    }

    /// A repeat count: 1 to 10000.
    pub fn repeats(s: &str) -> Result<usize, String> {
        count(s, 1, 10_000)
    }

    /// A gap length in pixels: 0 to 1,000,000.
    pub fn pixels(s: &str) -> Result<usize, String> {
        count(s, 0, 1_000_000)
    }
}

/// Reports a command-line parse error: `--help` and `--version` print in full (exit 0, write
/// errors checked); a usage error is one line on stderr (exit 2), ending with where to look.
pub fn usage_error(e: &clap::Error) -> i32 {
    use clap::error::ErrorKind;
    match e.kind() {
        ErrorKind::DisplayHelp
        | ErrorKind::DisplayVersion
        | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let text = e.render().to_string();
            if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
                eprint!("{text}");
                return 2;
            }
            match write_stdout(text.as_bytes()) {
                Ok(()) => 0,
                Err(err) if err.is_closed_pipe() => 0,
                Err(err) => {
                    eprintln!("bonnetlab: {}", err.message);
                    err.code
                }
            }
        }
        _ => {
            // The message is its first paragraph, on one line: clap lists the missing
            // arguments on the lines below "the following required arguments were not provided:".
            let text = e.render().to_string();
            let para: Vec<&str> = text
                .lines()
                .map(str::trim)
                .skip_while(|l| l.is_empty())
                .take_while(|l| !l.is_empty() && !l.starts_with("Usage:"))
                .collect();
            let first = if para.is_empty() {
                "invalid arguments".to_string()
            } else {
                para.join(" ")
            };
            let first = first.strip_prefix("error: ").unwrap_or(&first);
            eprintln!("bonnetlab: {first} (see bonnetlab --help)");
            2
        }
    }
}
