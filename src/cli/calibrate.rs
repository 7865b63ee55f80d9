//! `bonnetlab calibrate RECIPE [--json OUT] [--out DIR]` (contract: shared/spec/interfaces.md).
//!
//! Reads the recipe's before/after maps, measured spot (or TIF model) and commanded path log,
//! runs `bonnetlab_calibrate::run::calibrate` and writes the JSON (to OUT, or to stdout when
//! neither flag is given) and, with `--out`, `DIR/calibration.json` and `DIR/report.html`
//! (measured removal, residual maps and PSDs before/after, effects with uncertainties, the
//! error before and after each effect, the hold-out diagnosis trail).

use std::path::PathBuf;

use bonnetlab_calibrate::run::Options;

use super::CliError;
use crate::pipeline::calibrate::{calibrate, load};
use crate::report::calibration::{report_html, summary};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Run recipe (TOML: [measurement] before/after, [tif], [path] log).
    pub recipe: PathBuf,
    /// Write the calibration JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write calibration.json and report.html into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let bar = super::progress::spinner("calibrate");
    bar.set_message(format!("reading the run of {}", args.recipe.display()));
    let problem = load(&args.recipe)?;
    bar.set_message("calibrating (baseline fit, candidate effects, hold-out tests)");
    let cal = calibrate(&args.recipe, &problem, &Options::default())?;
    bar.finish_and_clear();
    let text = serde_json::to_string_pretty(&cal)
        .map_err(|e| CliError::processing(&args.recipe, e))?
        + "\n";
    // calibration.json, report.html and the --json file are published together or not at all.
    // The set first: it creates the --out directory, where the --json file may be.
    let mut outputs = super::Outputs::default();
    if let Some(dir) = &args.out {
        let werr = super::write_error;
        let html = report_html(&cal, &args.recipe).map_err(|e| CliError::processing(dir, e))?;
        let mut set = crate::report::write::Set::begin(dir, "calibrate").map_err(werr)?;
        set.bytes("calibration.json", text.as_bytes())
            .map_err(werr)?;
        set.bytes("report.html", html.as_bytes()).map_err(werr)?;
        outputs.set(set);
    }
    if let Some(out) = &args.json {
        outputs.file(out, text.as_bytes())?;
    }
    outputs.publish()?;
    // After the outputs are in place: a run that fails prints its one error line alone.
    for w in &cal.warnings {
        eprintln!("warning: {}: {w}", args.recipe.display());
    }
    let json_on_stdout = match &args.json {
        Some(out) => super::is_stdout(out),
        None => args.out.is_none(),
    };
    if json_on_stdout {
        if args.json.is_none() {
            super::write_stdout(text.as_bytes())?;
        }
    } else {
        super::println_stdout(&summary(&cal, &written(args)))?;
    }
    Ok(())
}

/// The files `calibrate` wrote, as its summary names them.
fn written(args: &Args) -> Vec<String> {
    let mut wrote = Vec::new();
    if let Some(dir) = &args.out {
        wrote.push(dir.join("report.html").display().to_string());
    }
    if let Some(j) = &args.json {
        wrote.push(j.display().to_string());
    }
    wrote
}
