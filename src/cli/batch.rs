//! `bonnetlab batch (DIR | MANIFEST | MAP) [--pitch-mm P] [--remove TERMS] [--window W] [--jobs N]`:
//! every map's height statistics (the `stats --json` object) and, with `--pitch-mm`, its
//! `ripple` object (as in `psd`; where the map cannot resolve the pitch, `ripple_reason` says why
//! instead), one JSON line per map on stdout.
//!
//! - DIR: every file with a map extension (.dat, .datx, .asc, .xyz, .csv, .exr) directly in it,
//!   sorted by name; MANIFEST: a text file with one map path per line (relative to the
//!   manifest's directory; blank lines and `#` comments ignored); a single map file is a batch
//!   of one, so a cluster scheduler can fan maps out one per task.
//! - Output order is the input order whatever the parallelism; maps run in parallel (rayon,
//!   `--jobs` threads), with a progress bar on stderr when stderr is a terminal.
//! - A map that fails gives a line `{"file": ..., "error": ..., "exit_code": ...}`; the command
//!   exits non-zero at the end if any map failed: with the failures' exit code when they all
//!   share one (2 when every failure is bad input, so a batch of one map exits as `stats` would),
//!   else 1.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;
use serde_json::{json, Value};

use super::CliError;
use crate::pipeline::stats::batch_value;
use bonnetlab_spectrum::Window;
use bonnetlab_surface::Term;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A directory of maps, a manifest (one map path per line), or a single map.
    pub input: PathBuf,
    /// Grating spacing in mm: adds each map's `ripple` object.
    #[arg(long, allow_negative_numbers = true, value_parser = super::num::positive)]
    pub pitch_mm: Option<f64>,
    /// Form terms removed before the statistics and the PSD (comma list).
    #[arg(long, default_value = "piston,tilt")]
    pub remove: String,
    /// PSD window for the ripple check.
    #[arg(long, default_value = "hann")]
    pub window: String,
    /// Pixel size in mm for maps whose file does not carry one (a file's own value wins).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    pub pixel_mm: Option<f64>,
    /// Pixel size along Y (rows) in mm when it differs from --pixel-mm.
    #[arg(
        long,
        allow_negative_numbers = true,
        value_name = "MM",
        requires = "pixel_mm"
    )]
    pub pixel_mm_y: Option<f64>,
    /// Worker threads, 1 to 1024 (default: all cores).
    #[arg(long, allow_negative_numbers = true, value_parser = super::num::jobs)]
    pub jobs: Option<usize>,
}

/// Map file extensions recognised when scanning a directory.
pub const MAP_EXTENSIONS: [&str; 6] = ["dat", "datx", "asc", "xyz", "csv", "exr"];

fn is_map_file(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .map(|e| MAP_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        .unwrap_or(false)
}

/// The maps named by the input, in a stable order.
pub fn list_inputs(input: &Path) -> Result<Vec<PathBuf>, CliError> {
    if input.is_dir() {
        let rd = std::fs::read_dir(input)
            .map_err(|e| CliError::input(input, format!("cannot list: {e}")))?;
        let mut v: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && is_map_file(p))
            .collect();
        v.sort();
        if v.is_empty() {
            return Err(CliError::input(
                input,
                "no map file (.dat, .datx, .asc, .xyz, .csv, .exr) in the directory",
            ));
        }
        return Ok(v);
    }
    if is_map_file(input) {
        return Ok(vec![input.to_path_buf()]);
    }
    let text = super::read_text_input(input, "a list of map paths")?;
    let base = input.parent().unwrap_or(Path::new(""));
    let v: Vec<PathBuf> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| {
            let p = PathBuf::from(l);
            if p.is_absolute() {
                p
            } else {
                base.join(p)
            }
        })
        .collect();
    if v.is_empty() {
        return Err(CliError::input(input, "the manifest lists no map"));
    }
    Ok(v)
}

/// One map's JSON line (an `error` object when it fails) and its note for stderr, if any.
pub fn map_line(
    file: &Path,
    terms: &[Term],
    pitch_mm: Option<f64>,
    window: Window,
    pixel_mm: Option<(f64, f64)>,
) -> (Value, Option<String>) {
    batch_value(file, terms, pitch_mm, window, pixel_mm).unwrap_or_else(|e| {
        let v = json!({
            "file": file.display().to_string(),
            "error": super::compare::hint_pixel_mm(super::plain_message(&e.message)),
            "exit_code": e.code
        });
        (v, None)
    })
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let terms =
        Term::parse_list(&args.remove).map_err(|e| CliError::usage(format!("--remove: {e}")))?;
    let window =
        Window::parse(&args.window, 0.5).map_err(|e| CliError::usage(format!("--window: {e}")))?;
    if let Some(p) = args.pitch_mm {
        if !(p.is_finite() && p > 0.0) {
            return Err(CliError::usage(format!(
                "--pitch-mm must be a positive number of mm, got {p}"
            )));
        }
    }
    let pixel_mm = super::compare::pixel_size(args.pixel_mm, args.pixel_mm_y)?;
    if args.jobs == Some(0) {
        return Err(CliError::usage("--jobs must be at least 1"));
    }
    let files = list_inputs(&args.input)?;
    let bar = ProgressBar::with_draw_target(Some(files.len() as u64), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{bar:30}] {pos}/{len} maps {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let work = || -> Vec<(Value, Option<String>)> {
        files
            .par_iter()
            .map(|f| {
                let v = map_line(f, &terms, args.pitch_mm, window, pixel_mm);
                bar.inc(1);
                v
            })
            .collect()
    };
    let lines = match args.jobs {
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| CliError::usage(format!("--jobs: {e}")))?
            .install(work),
        None => work(),
    };
    bar.finish_and_clear();
    let mut failed = 0;
    let mut codes: Vec<i64> = Vec::new();
    let mut text = String::new();
    for (v, note) in &lines {
        if let Some(n) = note {
            eprintln!("note: {n}");
        }
        if v.get("error").is_some() {
            failed += 1;
            codes.push(v.get("exit_code").and_then(Value::as_i64).unwrap_or(1));
        }
        text.push_str(&format!("{v}\n"));
    }
    super::write_stdout(text.as_bytes())?;
    if failed > 0 {
        codes.sort_unstable();
        codes.dedup();
        let code = match codes[..] {
            [2] => 2,
            _ => 1,
        };
        return Err(CliError {
            code,
            message: format!(
                "{failed} of {} maps failed (their JSON lines carry the error)",
                lines.len()
            ),
        });
    }
    Ok(())
}
