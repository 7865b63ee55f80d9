//! Rendering of a calibration (`pipeline::calibrate`): the one-line summary and the HTML report
//! (measured removal, residual maps and PSDs before/after, effects with uncertainties, the
//! error before and after each effect, the hold-out diagnosis trail).

use std::path::Path;

use bonnetlab_calibrate::run::Calibration;
use bonnetlab_surface::Surface;
use ndarray::Array2;

use super::format::fixed;
use super::html::{escape, Page, Table};
use super::maps::false_colour_png;
use super::plot::{LinePlot, Series};

/// The one line `calibrate` prints when the JSON does not go to stdout.
/// `wrote` lists the files written (the report, the JSON).
pub fn summary(cal: &Calibration, wrote: &[String]) -> String {
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
    page.note(&format!(
        "Residual RMS over the common valid aperture after fitting piston and tilt (the measurement's set-up terms). \
         Noise floor: the white level of the one-sided PSD of the registered before - after along {} at {} - {} 1/mm.",
        cal.noise_floor_axis,
        fixed(cal.noise_floor_band_per_mm[0], 3),
        fixed(cal.noise_floor_band_per_mm[1], 3)
    ));
    for w in &cal.warnings {
        page.note(&format!("Warning: {w}."));
    }
    if let Some(r) = cal.repeatability_nm {
        page.note(&match &cal.repeatability_note {
            Some(why) => format!("Repeatability: {why}."),
            None => format!(
                "Repeatability: {} nm RMS as declared ([measurement] repeatability_nm); it bounds the smooth \
                 difference the instrument alone makes between the two maps (rounds' smooth check).",
                fixed(r, 4)
            ),
        });
    }
    page.section("Final residual per band");
    let mut t = Table::new([
        "band",
        "radial frequency (1/mm)",
        "residual RMS (nm)",
        "noise floor in band (nm)",
        "above floor (nm)",
    ]);
    for b in &cal.final_.bands {
        t.row([
            if b.band == "process" {
                "process (the TIF passes it)".to_string()
            } else {
                "fine (the process cannot make it)".to_string()
            },
            format!(
                "{} - {}",
                fixed(b.band_per_mm[0], 3),
                fixed(b.band_per_mm[1], 3)
            ),
            fixed(b.rms_nm, 4),
            fixed(b.floor_nm, 4),
            fixed((b.rms_nm.powi(2) - b.floor_nm.powi(2)).max(0.0).sqrt(), 4),
        ]);
    }
    page.table(&t);
    page.note(&format!(
        "Process band: radial frequencies where the TIF's |MTF| is at least {} of its value at 0 \
         (cutoff {} 1/mm, periods above {} mm); effects are selected and scored there. \
         Bands from the areal split of the residual map (2-D DCT, brick-wall); they add up to the full-band RMS in power.",
        cal.process_band.mtf_threshold,
        fixed(cal.process_band.cutoff_per_mm, 3),
        fixed(1.0 / cal.process_band.cutoff_per_mm.max(1e-12), 2)
    ));

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
