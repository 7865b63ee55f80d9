//! The pipelines: one function per user question, joining the analysis crates, reading the
//! input files and returning typed results (no rendering, no output written). The CLI parses
//! arguments, calls one pipeline and writes its outputs through `report`; tests call the same
//! functions. `tests/layering.rs` enforces the split.

use std::path::Path;

use bonnetlab_surface::Surface;

pub mod bonnets;
pub mod calibrate;
pub mod compare;
pub mod demo;
pub mod dwell;
pub mod error;
pub mod msf_prediction;
pub mod psd;
pub mod recipe_samples;
pub mod run_spec;
pub mod samples;
pub mod simulate;
pub mod spots;
pub mod stats;
pub mod vibration;

pub use error::Error;

/// Progress of a long pipeline, reported to whoever shows it (the CLI draws a bar on a
/// terminal; tests pass [`NoProgress`]).
pub trait Progress {
    /// A message about the current step (no step done).
    fn message(&self, msg: &str);
    /// One more step (or item) done.
    fn inc(&self);
    /// A step is done; `next` names the one that starts.
    fn step(&self, next: &str) {
        self.message(next);
        self.inc();
    }
}

/// Progress that nobody watches.
pub struct NoProgress;

impl Progress for NoProgress {
    fn message(&self, _msg: &str) {}
    fn inc(&self) {}
}

/// Reads a map through `bonnetlab_io`, keeping the reader's exit code and one-line message.
pub fn read_map(file: &Path) -> Result<Surface, Error> {
    bonnetlab_io::read_surface(file).map_err(|e| {
        let msg = e.to_string();
        let shown = file.display().to_string();
        let message = if msg.contains(&shown) {
            msg
        } else {
            format!("{shown}: {msg}")
        };
        Error {
            code: e.exit_code(),
            message: message.replace(['\n', '\r'], " "),
        }
    })
}
