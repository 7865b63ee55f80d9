//! The bonnets section of the compare report (issue 16) for runs given by their recipes:
//! measured vs predicted σ1 and MSF band RMS per bonnet, each run's accepted calibrated effects
//! with uncertainties, the vibration forcing the measurements imply (with its interval, or why
//! it cannot be constrained), the difference table with shares and the unexplained part, and
//! each conclusion in words with how sure it is and what measurement would change it. Also the
//! JSON fields of `compare` for such runs (shared/spec/interfaces.md).

use serde::Serialize;
use serde_json::Value;

use super::compare_report::ReportError;
use super::html::{Page, Table};
use crate::pipeline::bonnets::{BonnetsComparison, RunAnalysis};
use bonnetlab_vibration::infer::{Difference, VibrationForcing};

/// The paper's measured end-of-robot vibration amplitude near resonance, mm (order of
/// magnitude, DOMAIN.md).
pub const PAPER_END_AMPLITUDE_MM: f64 = 1e-2;

/// Coupling mechanisms (as opposed to calibrated effect kinds) among the causes.
pub const VIBRATION_CAUSES: [&str; 5] = [
    "normal_offset",
    "lateral_jitter",
    "envelope",
    "dwell_execution",
    "interaction",
];

/// `doc` (the comparison's JSON) with, for every run given by its recipe, `predicted`,
/// `calibration` and `vibration_forcing` added to its `runs` entry (matched by name), and the
/// top-level `difference` array and `shared_forcing` object.
pub fn extended_json<T: Serialize>(doc: &T, b: &BonnetsComparison) -> Result<Value, ReportError> {
    let err = |e: serde_json::Error| ReportError(format!("report.json: {e}"));
    let mut v = serde_json::to_value(doc).map_err(err)?;
    if let Some(runs) = v.get_mut("runs").and_then(Value::as_array_mut) {
        for r in runs.iter_mut() {
            let Some(name) = r.get("name").and_then(Value::as_str).map(str::to_string) else {
                continue;
            };
            let Some(a) = b.runs.iter().find(|a| a.name == name) else {
                continue;
            };
            if let Some(o) = r.as_object_mut() {
                o.insert("bonnet".into(), Value::String(a.bonnet.name().into()));
                o.insert(
                    "predicted".into(),
                    serde_json::to_value(&a.predicted).map_err(err)?,
                );
                o.insert(
                    "calibration".into(),
                    serde_json::to_value(&a.calibration).map_err(err)?,
                );
                o.insert(
                    "vibration_forcing".into(),
                    serde_json::to_value(&a.vibration_forcing).map_err(err)?,
                );
                o.insert(
                    "measured_ripple_msf".into(),
                    serde_json::to_value(&a.measured).map_err(err)?,
                );
            }
        }
    }
    if let Some(o) = v.as_object_mut() {
        if b.runs.len() >= 2 {
            o.insert(
                "difference".into(),
                serde_json::to_value(&b.difference).map_err(err)?,
            );
        }
        if let Some(s) = &b.shared_forcing {
            o.insert(
                "shared_forcing".into(),
                serde_json::to_value(s).map_err(err)?,
            );
        }
    }
    Ok(v)
}

fn opt(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "-".into(),
    }
}

fn pct(v: f64) -> String {
    format!("{:.1} %", 100.0 * v)
}

/// The forcing in words: the value with its interval, an upper bound, or why not.
pub fn forcing_words(f: &VibrationForcing) -> String {
    let amp = |a: Option<f64>| {
        match a {
        Some(a) => format!(
            "; end-of-robot amplitude {a:.3e} mm ({:.2} x the paper's ~{PAPER_END_AMPLITUDE_MM:.0e} mm)",
            a / PAPER_END_AMPLITUDE_MM
        ),
        None => String::new(),
    }
    };
    match (f.constrained, f.fn_n, f.interval_n, f.upper_bound_n) {
        (true, Some(v), Some([lo, hi]), _) => format!(
            "spindle-harmonic force amplitude {v:.3} N (95 % interval {lo:.3} to {hi:.3} N){}",
            amp(f.end_amplitude_mm)
        ),
        (_, _, _, Some(u)) => format!(
            "cannot be constrained: {}; 95 % upper bound {u:.3} N{}",
            f.reason,
            amp(f.end_amplitude_mm).replace("amplitude", "amplitude at the bound")
        ),
        _ => format!("cannot be constrained: {}", f.reason),
    }
}

/// What measurement would change a conclusion about `cause`.
pub fn what_would_change(cause: &str) -> &'static str {
    match cause {
        c if VIBRATION_CAUSES.contains(&c) => {
            "a vibrometer reading at the end of the robot during each run, or runs at another \
             spindle speed (the imprint moves with the spindle frequency)"
        }
        "tif_scale" => "a spot measurement (a spot sweep) with each bonnet on the same part",
        "removal_rate" => {
            "a spot measurement with each bonnet, or the absolute removal depth (a masked \
             reference area): with piston removed a wider spot and a lower rate leave the same \
             ripple"
        }
        "registration" => "re-measuring the after map with fiducials or a fixed mount",
        "direction_lag" | "periodic_path_error" | "path_offset" => {
            "the robot's executed-path log (encoder positions) for each run"
        }
        _ => "repeat runs of each bonnet (the run-to-run spread)",
    }
}

fn effect_params(a: &RunAnalysis) -> Vec<[String; 4]> {
    a.calibration
        .effects
        .iter()
        .map(|e| {
            let params: Vec<String> = e
                .params
                .iter()
                .filter_map(|(k, v)| {
                    let x = v.as_f64()?;
                    Some(match e.uncertainties.get(k).and_then(Value::as_f64) {
                        Some(s) => format!("{k} = {x:.5} ± {s:.2e}"),
                        None => format!("{k} = {x:.5}"),
                    })
                })
                .collect();
            [
                a.name.clone(),
                e.kind.clone(),
                params.join("; "),
                format!("{:.1}", e.significance),
            ]
        })
        .collect()
}

fn difference_words(d: &Difference, b: &BonnetsComparison) -> Vec<String> {
    let [na, nb] = &d.runs;
    let mut out = Vec::new();
    let dir = if d.sigma1_difference_nm < 0.0 {
        "lower"
    } else {
        "higher"
    };
    let beyond = |b: bool| {
        if b {
            "beyond the maps' white noise"
        } else {
            "WITHIN the maps' white noise: no cause can be named for it"
        }
    };
    out.push(format!(
        "{nb} leaves a ripple σ1 {:.3} ± {:.3} nm {dir} than {na} ({}), and its CR(RMS) differs \
         by {:+.2} ± {:.2} percentage points ({}). The ± are 1 standard deviation from the maps' \
         white noise (each run's calibrated noise floor, re-drawn {} times); \
         the process's run-to-run scatter is not in them: only repeat runs measure it.",
        d.sigma1_difference_nm.abs(),
        d.sigma1_difference_sd_nm,
        beyond(d.sigma1_difference_beyond_noise),
        100.0 * d.cr_rms_difference,
        100.0 * d.cr_rms_difference_sd,
        beyond(d.cr_rms_difference_beyond_noise),
        crate::pipeline::bonnets::NOISE_DRAWS,
    ));
    let vib: f64 = d
        .causes
        .iter()
        .filter(|c| VIBRATION_CAUSES.contains(&c.cause.as_str()))
        .map(|c| c.share_of_sigma1_difference)
        .sum();
    match d.causes.iter().find(|c| c.significant_sigma1) {
        Some(c) => out.push(format!(
            "The largest significant cause of the σ1 difference is {} with {} of it ({} of the \
             CR difference); its effect differs between the runs by more than 1.96 standard \
             deviations and by more than the causes leave unexplained (95 % sure, against the \
             model's uncertainty and the maps' noise). What would change this: {}.",
            c.cause,
            pct(c.share_of_sigma1_difference),
            pct(c.share_of_cr_rms_difference),
            what_would_change(&c.cause)
        )),
        None => out.push(format!(
            "No cause of the σ1 difference is significant (95 %): it is not explained with \
             confidence. What would change this: {}.",
            what_would_change("")
        )),
    }
    let cr_only: Vec<&str> = d
        .causes
        .iter()
        .filter(|c| c.significant_cr_rms && !c.significant_sigma1)
        .map(|c| c.cause.as_str())
        .collect();
    if !cr_only.is_empty() {
        out.push(format!(
            "Significant for the CR(RMS) difference only: {} (they change the run's RMS, not \
             its ripple at the pitch).",
            cr_only.join(", ")
        ));
    }
    out.push(format!(
        "The vibration mechanisms together account for {} of the σ1 difference at the forcings \
         fitted to each run; {} is left unexplained (noise, interactions between causes, and \
         whatever no modelled cause describes){}.",
        pct(vib),
        pct(d.unexplained_share_of_sigma1_difference),
        if d.unexplained_share_of_sigma1_difference.abs() > 0.3 {
            "; repeat runs would show whether that remainder is run-to-run scatter"
        } else {
            ""
        }
    ));
    let unconstrained: Vec<&str> = b
        .runs
        .iter()
        .filter(|r| d.runs.contains(&r.name) && !r.vibration_forcing.constrained)
        .map(|r| r.name.as_str())
        .collect();
    if !unconstrained.is_empty() {
        out.push(format!(
            "The forcing of {} cannot be constrained from the maps, so the vibration share is \
             uncertain over its whole allowed range and cannot be called significant; a \
             vibrometer reading, or a run whose spindle imprint the spot passes (a faster feed \
             or the resonance speed), would settle it.",
            unconstrained.join(", ")
        ));
    }
    out
}

/// Renders the section into the compare report.
pub fn section(page: &mut Page, b: &BonnetsComparison) {
    page.section("Bonnets: measured vs predicted ripple");
    let mut t = Table::new([
        "run",
        "bonnet",
        "σ1 measured (nm)",
        "σ1 predicted (nm)",
        "MSF band RMS measured (nm)",
        "MSF band RMS predicted (nm)",
        "CR(RMS) measured",
    ]);
    for r in &b.runs {
        t.row([
            r.name.clone(),
            r.bonnet.name().to_string(),
            format!("{:.4}", r.measured.sigma1_nm),
            opt(r.predicted.sigma1_nm, 4),
            format!("{:.4}", r.measured.msf_rms_nm),
            format!("{:.4}", r.predicted.msf_rms_nm),
            pct(r.measured.cr_rms),
        ]);
    }
    page.table(&t);
    page.note(
        "σ1: ripple at 1/pitch along Y of the after map (registered with the calibrated \
         registration); MSF band RMS: along Y in the coupling's MSF band (one-sided PSD, Hann); \
         predicted with the forward model and the vibration coupling of each run's bonnet at \
         the recipe's forcing and rate.",
    );
    for r in &b.runs {
        if let Some(p) = r.predicted.sigma1_nm {
            let ratio = r.measured.sigma1_nm / p;
            if !(0.8..=1.25).contains(&ratio) {
                page.paragraph(&format!(
                    "{}: the prediction and the measurement of σ1 disagree by a factor of {:.2} \
                     (measured / predicted). The prediction uses the recipe's forcing and \
                     nominal spot; the calibrated effects and the forcing below are what the \
                     measurement says instead.",
                    r.name, ratio
                ));
            }
        }
    }

    page.subsection("Effects accepted by calibration (± 1 sigma)");
    let rows: Vec<[String; 4]> = b.runs.iter().flat_map(effect_params).collect();
    if rows.is_empty() {
        page.paragraph(
            "No run has an effect significant on held-out data: each is explained by its \
             recipe to the noise.",
        );
    } else {
        let mut t = Table::new(["run", "effect", "parameters (± 1 sigma)", "hold-out z"]);
        for r in rows {
            t.row(r);
        }
        page.table(&t);
    }

    page.subsection("Vibration forcing inferred from the measurements");
    let mut t = Table::new([
        "run",
        "bonnet",
        "spindle-harmonic forcing",
        "broadband force RMS (N)",
    ]);
    for r in &b.runs {
        t.row([
            r.name.clone(),
            r.bonnet.name().to_string(),
            forcing_words(&r.vibration_forcing),
            match r.forcing_fit.noise_interval_n {
                Some([lo, hi]) => format!(
                    "{:.3} (95 % {lo:.3} to {hi:.3})",
                    r.forcing_fit.noise_force_rms_n
                ),
                None => format!("{:.3} (not bounded)", r.forcing_fit.noise_force_rms_n),
            },
        ]);
    }
    page.table(&t);
    page.note(&format!(
        "Fitted to the measured removal's one-sided X and Y PSDs through each bonnet's \
         damping and series compliance; the paper measured end-of-robot amplitudes of order \
         {PAPER_END_AMPLITUDE_MM:.0e} mm near resonance."
    ));
    if let Some(s) = &b.shared_forcing {
        page.paragraph(&format!(
            "One forcing for all runs: {} (p = {:.3}; {}; {}). What would change this: {}.",
            s.reason,
            s.p_value,
            if s.consistent {
                "consistent"
            } else {
                "not consistent"
            },
            if s.plausible {
                "physically plausible"
            } else {
                "not physically plausible"
            },
            what_would_change("normal_offset")
        ));
    }

    for d in &b.difference {
        page.subsection(&format!(
            "Difference {} − {}: what accounts for it",
            d.runs[1], d.runs[0]
        ));
        let yes = |b: bool| if b { "yes" } else { "no" }.to_string();
        let mut t = Table::new([
            "cause",
            "share of σ1 difference",
            "significant for σ1 (95 %)",
            "share of CR(RMS) difference",
            "significant for CR (95 %)",
        ])
        .caption(
            "Share = the cause's effect difference (run B − run A; effect = the measured value \
             less the value with the cause's removal taken back) over the measured difference. \
             Significant: the difference stands beyond the maps' white noise, the cause's \
             effect differs by more than 1.96 standard deviations (model uncertainty and map \
             noise) and by more than the causes leave unexplained, and its share is at least \
             5 %. Run-to-run scatter of the process is not known without repeat runs.",
        );
        for c in &d.causes {
            t.row([
                c.cause.clone(),
                pct(c.share_of_sigma1_difference),
                yes(c.significant_sigma1),
                pct(c.share_of_cr_rms_difference),
                yes(c.significant_cr_rms),
            ]);
        }
        t.row([
            "unexplained".to_string(),
            pct(d.unexplained_share_of_sigma1_difference),
            String::new(),
            pct(d.unexplained_share_of_cr_rms_difference),
            String::new(),
        ]);
        page.table(&t);
        for w in difference_words(d, b) {
            page.paragraph(&w);
        }
    }
}
