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

/// Gives a map whose file has no pixel size the one from `--pixel-mm` (`given`, (dx, dy) mm).
/// A file's own pixel size is kept: a batch of mixed files takes `--pixel-mm` for the ones
/// without. Where the file's differs from the one given (by more than 1e-6 relative), the
/// returned note says so, naming the file and both sizes, so the flag is never ignored without
/// a word.
pub fn fill_pixel_size(s: &mut Surface, given: Option<(f64, f64)>, file: &Path) -> Option<String> {
    let (px, py) = given?;
    let differs = |own: Option<f64>, g: f64| own.is_some_and(|v| (v - g).abs() > 1e-6 * g.abs());
    let note = (differs(s.dx_mm, px) || differs(s.dy_mm, py)).then(|| {
        let show = |v: Option<f64>| v.map_or("unknown".to_string(), |v| format!("{v:.7}"));
        format!(
            "{}: the file gives its pixel size ({} x {} mm), which is used; --pixel-mm {} x {} \
             mm applies only to maps without one",
            file.display(),
            show(s.dx_mm),
            show(s.dy_mm),
            px,
            py
        )
    });
    s.dx_mm = Some(s.dx_mm.unwrap_or(px));
    s.dy_mm = Some(s.dy_mm.unwrap_or(py));
    note
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
