//! `bonnetlab compare` (contract: shared/spec/interfaces.md): before / after maps of one or
//! more bonnet runs -> DIR/report.html, DIR/report.json and PSD CSVs.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::CliError;
use crate::pipeline::bonnets::{self, RunInput};
use crate::pipeline::compare::{compare, CompareError, Comparison, RunSpec, Settings};
use crate::pipeline::run_spec::parse_recipe_run;
use crate::report::compare_report::write_report_full;
use crate::report::format::fixed;
use bonnetlab_process::recipe::Recipe;
use bonnetlab_spectrum::Window;
use bonnetlab_surface::Term;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A run: NAME=BEFORE,AFTER; repeat measurements as NAME=B1+B2,A1+A2; or NAME=RECIPE.toml
    /// (measured, predicted, calibrated and its vibration forcing inferred). The first run is
    /// the reference for the improvement of the others.
    #[arg(long = "run", value_name = "NAME=BEFORE,AFTER", required = true)]
    pub runs: Vec<String>,
    /// Grating (raster) spacing in mm: enables the ripple check and the f0 markers.
    #[arg(long, allow_negative_numbers = true, value_parser = super::num::positive)]
    pub pitch_mm: Option<f64>,
    /// Form terms removed from every map before PV / RMS / PSD (comma list).
    #[arg(long, default_value = "piston,tilt")]
    pub remove: String,
    /// PSD window: hann, none, tukey, blackman, welch.
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
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
}

/// `--pixel-mm [--pixel-mm-y]` as (dx, dy) in mm; both must be positive.
pub fn pixel_size(x: Option<f64>, y: Option<f64>) -> Result<Option<(f64, f64)>, CliError> {
    let Some(x) = x else { return Ok(None) };
    let y = y.unwrap_or(x);
    for (name, v) in [("--pixel-mm", x), ("--pixel-mm-y", y)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CliError::usage(format!(
                "{name} must be a positive number of mm, got {v}"
            )));
        }
    }
    Ok(Some((x, y)))
}

/// Points the user at `--pixel-mm` when a map's pixel size is unknown.
pub fn hint_pixel_mm(message: String) -> String {
    if message.contains("pixel size is unknown") && !message.contains("--pixel-mm") {
        format!("{message} (use --pixel-mm MM)")
    } else {
        message
    }
}

/// Turns the command-line words into run specs and settings.
pub fn parse(args: &Args) -> Result<(Vec<RunSpec>, Settings), CliError> {
    let mut recipe_pitch = None;
    let runs = args
        .runs
        .iter()
        .map(|r| match parse_recipe_run(r) {
            Some((name, file)) => {
                let recipe = Recipe::load(&file).map_err(|e| CliError {
                    code: 2,
                    message: e.to_string(),
                })?;
                // A recipe run's ripple is measured at its own raster pitch everywhere in the
                // report (the bonnets' section reads the recipe): a different --pitch-mm would
                // put two pitches in one report.
                if let (Some(given), Some(own)) = (args.pitch_mm, recipe.pitch_mm) {
                    if (given - own).abs() > 1e-9 * own.abs() {
                        return Err(CliError::usage(format!(
                            "{}: [path] pitch_mm = {own} mm, but --pitch-mm {given} was given: a \
                             recipe run's ripple is measured at its own pitch; leave --pitch-mm \
                             out",
                            file.display()
                        )));
                    }
                }
                recipe_pitch = recipe_pitch.or(recipe.pitch_mm);
                Ok(RunSpec {
                    name,
                    before: vec![recipe.before],
                    after: recipe.after.into_iter().collect(),
                })
            }
            None => RunSpec::parse(r).map_err(|e| CliError::usage(format!("--run: {e}"))),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let remove =
        Term::parse_list(&args.remove).map_err(|e| CliError::usage(format!("--remove: {e}")))?;
    let window =
        Window::parse(&args.window, 0.5).map_err(|e| CliError::usage(format!("--window: {e}")))?;
    Ok((
        runs,
        Settings {
            remove,
            window,
            pitch_mm: args.pitch_mm.or(recipe_pitch),
            pixel_mm: pixel_size(args.pixel_mm, args.pixel_mm_y)?,
            ..Settings::default()
        },
    ))
}

pub fn to_cli(e: CompareError) -> CliError {
    CliError {
        code: if e.bad_input { 2 } else { 1 },
        message: hint_pixel_mm(e.to_string()),
    }
}

/// Runs the comparison with a progress bar on stderr (hidden when stderr is not a terminal,
/// in which case `announce` lines are printed instead when `verbose`).
pub fn compare_with_progress(
    runs: &[RunSpec],
    settings: &Settings,
    verbose: bool,
) -> Result<Comparison, CliError> {
    let n: usize = runs.iter().map(|r| r.before.len() + r.after.len()).sum();
    let bar = ProgressBar::with_draw_target(Some(n as u64), ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("{spinner} analysing maps [{bar:30}] {pos}/{len} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let hidden = bar.is_hidden();
    let step = |p: &Path| {
        bar.inc(1);
        bar.set_message(p.display().to_string());
        if hidden && verbose {
            eprintln!("bonnetlab: analysed {}", p.display());
        }
    };
    let r = compare(runs, settings, &step).map_err(to_cli);
    bar.finish_and_clear();
    if let Ok(c) = &r {
        for n in &c.notes {
            eprintln!("note: {n}");
        }
    }
    r
}

/// The runs given by their recipes, read (errors name the file, exit code 2 for bad input).
pub fn recipe_runs(args: &Args) -> Result<Vec<RunInput>, CliError> {
    args.runs
        .iter()
        .filter_map(|r| parse_recipe_run(r))
        .map(|(name, file)| {
            RunInput::load(&name, &file).map_err(|e| CliError {
                code: e.exit_code,
                message: e.message,
            })
        })
        .collect()
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let (runs, settings) = parse(args)?;
    let recipes = recipe_runs(args)?;
    let c = compare_with_progress(&runs, &settings, false)?;
    let bonnets = if recipes.is_empty() {
        None
    } else {
        let opts = bonnets::Options {
            remove: settings.remove.clone(),
            ..Default::default()
        };
        Some(
            bonnets::compare_runs(&recipes, &opts).map_err(|e| CliError {
                code: e.exit_code,
                message: e.message,
            })?,
        )
    };
    // An unwritable output is bad input (exit 2); the message already names the file.
    write_report_full(&args.out, &c, None, bonnets.as_ref()).map_err(|e| CliError {
        code: 2,
        message: e.to_string(),
    })?;
    super::println_stdout(&summary(&args.out, &c))
}

/// The one line `compare` prints on success.
pub fn summary(out: &Path, c: &Comparison) -> String {
    let runs: Vec<String> = c
        .runs
        .iter()
        .map(|r| {
            format!(
                "{} RMS {} -> {} nm (CR {} %)",
                r.name,
                fixed(r.rms_before_nm, 3),
                fixed(r.rms_after_nm, 3),
                fixed(100.0 * r.cr_rms, 1)
            )
        })
        .collect();
    format!(
        "compare: wrote {}: {}",
        out.join("report.html").display(),
        runs.join("; ")
    )
}
