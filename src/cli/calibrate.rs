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
    let problem = load(&args.recipe)?;
    let cal = calibrate(&problem, &Options::default())
        .map_err(|e| CliError::processing(&args.recipe, e))?;
    let text = serde_json::to_string_pretty(&cal)
        .map_err(|e| CliError::processing(&args.recipe, e))?
        + "\n";
    if let Some(out) = &args.json {
        super::emit(out, text.as_bytes())?;
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir)
            .map_err(|e| CliError::input(dir, format!("cannot create directory: {e}")))?;
        let j = dir.join("calibration.json");
        bonnetlab_io::atomic::write_atomic(&j, text.as_bytes())
            .map_err(|e| CliError::input(&j, format!("cannot write: {e}")))?;
        let html = report_html(&cal, &args.recipe).map_err(|e| CliError::processing(dir, e))?;
        let h = dir.join("report.html");
        bonnetlab_io::atomic::write_atomic(&h, html.as_bytes())
            .map_err(|e| CliError::input(&h, format!("cannot write: {e}")))?;
    }
    if args.json.is_none() && args.out.is_none() {
        super::write_stdout(text.as_bytes())?;
    }
    Ok(())
}

fn fmt_param(v: &serde_json::Value, u: Option<&serde_json::Value>) -> String {
    match (v, u) {
        (serde_json::Value::Number(n), Some(serde_json::Value::Number(s))) => {
            format!(
                "{:.5} ± {:.2e}",
                n.as_f64().unwrap_or(f64::NAN),
                s.as_f64().unwrap_or(f64::NAN)
            )
        }
        (serde_json::Value::Number(n), _) => format!("{:.5}", n.as_f64().unwrap_or(f64::NAN)),
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
        format!("{:.4}", cal.baseline.measured_removal_rms_nm),
        String::new(),
    ]);
    t.row([
        "baseline (process model, global rate fit)".to_string(),
        format!("{:.4}", cal.baseline.residual_rms_nm),
        format!("{:.4}", cal.baseline.residual_pv_nm),
    ]);
    for e in &cal.effects {
        t.row([
            format!("+ {}", e.kind),
            format!("{:.4}", e.residual_rms_after_nm),
            String::new(),
        ]);
    }
    t.row([
        "final (joint refit)".to_string(),
        format!("{:.4}", cal.final_.residual_rms_nm),
        format!("{:.4}", cal.final_.residual_pv_nm),
    ]);
    t.row([
        "noise floor (from the maps)".to_string(),
        format!("{:.4}", cal.noise_floor_rms_nm),
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
                format!("{:.4}", e.residual_rms_before_nm),
                format!("{:.4}", e.residual_rms_after_nm),
                format!("{:.1}", e.significance),
                format!("{:.2} %", 100.0 * e.heldout_reduction_fraction),
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
                format!("{:.4} - {:.4}", u.band_per_mm[0], u.band_per_mm[1]),
                format!("{:.4}", u.rms_nm),
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
            .map(|c| format!("{} (z {:.1})", c.key, c.z))
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
