//! `bonnetlab calibrate RECIPE [--json OUT] [--out DIR]` (contract: shared/spec/interfaces.md).
//!
//! Reads the recipe's before/after maps, measured spot (or TIF model) and commanded path log,
//! runs `bonnetlab_calibrate::run::calibrate` and writes the JSON (to OUT, or to stdout when
//! neither flag is given) and, with `--out`, `DIR/calibration.json` and `DIR/report.html`
//! (measured removal, residual maps and PSDs before/after, effects with uncertainties, the
//! error before and after each effect, the hold-out diagnosis trail).

use std::path::{Path, PathBuf};

use bonnetlab_calibrate::model::Problem;
use bonnetlab_calibrate::run::{calibrate, Calibration, Options};
use bonnetlab_surface::Surface;
use ndarray::Array2;

use super::CliError;
use crate::report::format::fixed;
use crate::report::html::{escape, Page, Table};
use crate::report::maps::false_colour_png;
use crate::report::plot::{LinePlot, Series};

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

/// Loads the run and returns the prepared problem (the library's pipeline).
pub fn load(recipe_path: &Path) -> Result<Problem, CliError> {
    bonnetlab_calibrate::pipeline::load_recipe(recipe_path).map_err(|e| match e.exit_code {
        1 => CliError::processing(&e.file, e.message),
        _ if e.message.starts_with(&*e.file.to_string_lossy()) => CliError {
            code: e.exit_code,
            message: e.message,
        },
        _ => CliError::input(&e.file, e.message),
    })
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let bar = spinner();
    bar.set_message(format!("reading the run of {}", args.recipe.display()));
    let problem = load(&args.recipe)?;
    bar.set_message("calibrating (baseline fit, candidate effects, hold-out tests)");
    let cal = calibrate(&problem, &Options::default())
        .map_err(|e| CliError::processing(&args.recipe, e))?;
    bar.finish_and_clear();
    let text = serde_json::to_string_pretty(&cal)
        .map_err(|e| CliError::processing(&args.recipe, e))?
        + "\n";
    if let Some(dir) = &args.out {
        // calibration.json and report.html are published together or not at all.
        let werr = |e: crate::report::write::WriteError| CliError::input(&e.file, e.what);
        let mut set = crate::report::write::Set::begin(dir).map_err(werr)?;
        set.bytes("calibration.json", text.as_bytes())
            .map_err(werr)?;
        let html = report_html(&cal, &args.recipe).map_err(|e| CliError::processing(dir, e))?;
        set.bytes("report.html", html.as_bytes()).map_err(werr)?;
        set.commit().map_err(werr)?;
    }
    if let Some(out) = &args.json {
        super::emit(out, text.as_bytes())?;
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
        super::println_stdout(&summary(&cal, args))?;
    }
    Ok(())
}

/// A spinner on stderr while the run loads and calibrates (a terminal only).
fn spinner() -> indicatif::ProgressBar {
    use std::io::IsTerminal;
    let target = if std::io::stderr().is_terminal() {
        indicatif::ProgressDrawTarget::stderr()
    } else {
        indicatif::ProgressDrawTarget::hidden()
    };
    let bar = indicatif::ProgressBar::with_draw_target(None, target);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} calibrate {elapsed} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// The one line `calibrate` prints when the JSON does not go to stdout.
pub fn summary(cal: &Calibration, args: &Args) -> String {
    let mut wrote = Vec::new();
    if let Some(dir) = &args.out {
        wrote.push(dir.join("report.html").display().to_string());
    }
    if let Some(j) = &args.json {
        wrote.push(j.display().to_string());
    }
    let effects: Vec<&str> = cal.effects.iter().map(|e| e.kind.as_str()).collect();
    format!(
        "calibrate: wrote {}: residual RMS {} -> {} nm (noise floor {} nm), effects: {}",
        wrote.join(", "),
        fixed(cal.baseline.residual_rms_nm, 4),
        fixed(cal.final_.residual_rms_nm, 4),
        fixed(cal.noise_floor_rms_nm, 4),
        if effects.is_empty() {
            "none".to_string()
        } else {
            effects.join(", ")
        }
    )
}

fn fmt_param(v: &serde_json::Value, u: Option<&serde_json::Value>) -> String {
    match (v, u) {
        (serde_json::Value::Number(n), Some(serde_json::Value::Number(s))) => {
            format!(
                "{} ± {:.2e}",
                fixed(n.as_f64().unwrap_or(f64::NAN), 5),
                s.as_f64().unwrap_or(f64::NAN)
            )
        }
        (serde_json::Value::Number(n), _) => fixed(n.as_f64().unwrap_or(f64::NAN), 5),
        (serde_json::Value::String(s), _) => s.clone(),
        (other, _) => other.to_string(),
    }
}

fn surface_of(m: &(Array2<f64>, Array2<bool>), dx: f64, dy: f64) -> Option<Surface> {
    Surface::with_mask(m.0.clone(), m.1.clone(), Some(dx), Some(dy)).ok()
}

/// The HTML section of a calibration (self-contained page).
pub fn report_html(cal: &Calibration, recipe: &Path) -> Result<String, String> {
    let mut page = Page::new("Calibration: predicted vs measured removal");
    page.paragraph(&format!(
        "Recipe: {}",
        escape(&recipe.display().to_string())
    ));
    page.section("Error before and after");
    let mut t = Table::new(["stage", "residual RMS (nm)", "residual PV (nm)"]);
    t.row([
        "measured removal (piston, tilt removed)".to_string(),
        fixed(cal.baseline.measured_removal_rms_nm, 4),
        String::new(),
    ]);
    t.row([
        "baseline (process model, global rate fit)".to_string(),
        fixed(cal.baseline.residual_rms_nm, 4),
        fixed(cal.baseline.residual_pv_nm, 4),
    ]);
    for e in &cal.effects {
        t.row([
            format!("+ {}", e.kind),
            fixed(e.residual_rms_after_nm, 4),
            String::new(),
        ]);
    }
    t.row([
        "final (joint refit)".to_string(),
        fixed(cal.final_.residual_rms_nm, 4),
        fixed(cal.final_.residual_pv_nm, 4),
    ]);
    t.row([
        "noise floor (from the maps)".to_string(),
        fixed(cal.noise_floor_rms_nm, 4),
        String::new(),
    ]);
    page.table(&t);
    page.note("Residual RMS over the common valid aperture after fitting piston and tilt (the measurement's set-up terms).");

    page.section("Effects accepted (hold-out significant, in the order added)");
    if cal.effects.is_empty() {
        page.paragraph("No effect is significant on held-out data: the baseline model explains the run to the noise.");
    } else {
        let mut t = Table::new([
            "kind",
            "parameters (± 1 sigma)",
            "RMS before (nm)",
            "RMS after (nm)",
            "hold-out z",
            "hold-out reduction",
        ]);
        for e in &cal.effects {
            let params: Vec<String> = e
                .params
                .iter()
                .map(|(k, v)| format!("{k} = {}", fmt_param(v, e.uncertainties.get(k))))
                .collect();
            t.row([
                e.kind.clone(),
                params.join("; "),
                fixed(e.residual_rms_before_nm, 4),
                fixed(e.residual_rms_after_nm, 4),
                fixed(e.significance, 1),
                format!("{} %", fixed(100.0 * e.heldout_reduction_fraction, 2)),
            ]);
        }
        page.table(&t);
    }
    page.section("Unexplained structure");
    if cal.unexplained.is_empty() {
        page.paragraph("None above the noise floor.");
    } else {
        let mut t = Table::new(["description", "band (1/mm)", "RMS (nm)"]);
        for u in &cal.unexplained {
            t.row([
                u.description.clone(),
                format!(
                    "{} - {}",
                    fixed(u.band_per_mm[0], 4),
                    fixed(u.band_per_mm[1], 4)
                ),
                fixed(u.rms_nm, 4),
            ]);
        }
        page.table(&t);
    }
    page.section("Maps");
    let (dx, dy) = (cal.maps.dx_mm, cal.maps.dy_mm);
    for (m, title) in [
        (
            &cal.maps.measured_removal_nm,
            "Measured removal (before - after)",
        ),
        (&cal.maps.baseline_residual_nm, "Residual, baseline"),
        (&cal.maps.final_residual_nm, "Residual, final"),
    ] {
        if let Some(s) = m.as_ref().and_then(|m| surface_of(m, dx, dy)) {
            let png = false_colour_png(&s, title, "nm").map_err(|e| e.what)?;
            page.png(&png, title, title);
        }
    }
    page.section("Residual PSDs (one-sided, nm^2 mm, Hann)");
    for (along_x, name) in [(true, "X (scan)"), (false, "Y (feed)")] {
        let mut plot = LinePlot::new(
            format!("Residual PSD along {name}"),
            "frequency (1/mm)",
            "PSD (nm^2 mm)",
        )
        .log_log();
        for (m, label) in [
            (&cal.maps.baseline_residual_nm, "baseline"),
            (&cal.maps.final_residual_nm, "final"),
        ] {
            if let Some(m) = m {
                let Ok(surf) = bonnetlab_surface::Surface::with_mask(
                    m.0.clone(),
                    m.1.clone(),
                    Some(dx),
                    Some(dy),
                ) else {
                    continue;
                };
                let opts = bonnetlab_spectrum::PsdOptions::default();
                let psd = if along_x {
                    bonnetlab_spectrum::psd_x(&surf, &opts)
                } else {
                    bonnetlab_spectrum::psd_y(&surf, &opts)
                };
                let Ok(p) = psd else { continue };
                let (f, s): (Vec<f64>, Vec<f64>) = p
                    .freq_per_mm
                    .iter()
                    .zip(&p.psd_nm2_mm)
                    .skip(1)
                    .filter(|(_, v)| **v > 0.0)
                    .map(|(a, b)| (*a, *b))
                    .unzip();
                plot = plot.series(Series::new(label, f, s));
            }
        }
        let svg = plot.to_svg().map_err(|e| e.what)?;
        page.svg(
            &svg,
            &format!("Residual PSD along {name}, baseline vs final"),
        );
    }
    page.section("Diagnosis trail (hold-out z of the three best candidates per round)");
    let mut t = Table::new(["round", "accepted", "best candidates"]);
    for (i, r) in cal.rounds.iter().enumerate() {
        let mut c = r.candidates.clone();
        c.sort_by(|a, b| b.z.total_cmp(&a.z));
        let best: Vec<String> = c
            .iter()
            .take(3)
            .map(|c| format!("{} (z {})", c.key, fixed(c.z, 1)))
            .collect();
        t.row([
            format!("{}", i + 1),
            r.accepted.clone().unwrap_or_else(|| "none".into()),
            best.join(", "),
        ]);
    }
    page.table(&t);
    Ok(page.render())
}
