//! Renders a [`Comparison`] into the files of `bonnetlab compare --out DIR`:
//! `report.html` (self-contained: summary table like the paper's, maps, PSD overlays with the
//! grating frequency marked, band and ripple tables, settings, tool version), `report.json`
//! (the `runs` contract of shared/spec/interfaces.md) and one CSV per plotted curve set
//! (`psd_x_<run>.csv`, `psd_y_<run>.csv`: frequency and before / after PSDs).
//!
//! Percentages are for people only: the JSON keeps fractions.

use crate::report::format::fixed;
use std::path::{Path, PathBuf};

use super::comparison::{fmt_sig, BandCr, Comparison, RunResult};
use super::html::{Page, Table};
use super::maps::{false_colour_png_with, valid_range, MapOptions};
use super::msf_prediction::PredictedMsf;
use super::plot::{LinePlot, Series, PALETTE};
use super::write;
use crate::pipeline::bonnets::BonnetsComparison;
use bonnetlab_spectrum::Psd1d;

/// A failure writing the report: the file and what went wrong.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ReportError(pub String);

impl From<write::WriteError> for ReportError {
    fn from(e: write::WriteError) -> Self {
        ReportError(e.to_string())
    }
}

impl From<super::plot::PlotError> for ReportError {
    fn from(e: super::plot::PlotError) -> Self {
        ReportError(e.to_string())
    }
}

fn pct(v: f64) -> String {
    format!("{} %", fixed(100.0 * v, 2))
}

fn pct_pm(v: f64, sd: Option<f64>) -> String {
    match sd {
        Some(s) => format!("{} \u{b1} {} %", fixed(100.0 * v, 2), fixed(100.0 * s, 2)),
        None => pct(v),
    }
}

fn nm(v: f64) -> String {
    fixed(v, 3)
}

/// A file-name-safe form of a run name.
pub fn file_stem(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "run".into()
    } else {
        s
    }
}

/// File stems of the runs, made unique (distinct names can map to one stem, e.g. `a b`, `a_b`).
pub fn run_stems(c: &Comparison) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for r in &c.runs {
        let base = file_stem(&r.name);
        let mut stem = base.clone();
        let mut k = 2;
        while out.contains(&stem) {
            stem = format!("{base}_{k}");
            k += 1;
        }
        out.push(stem);
    }
    out
}

/// Writes report.html, report.json and the CSVs into `dir` (created if missing); returns the
/// paths written.
pub fn write_report(dir: &Path, c: &Comparison) -> Result<Vec<PathBuf>, ReportError> {
    write_report_with(dir, c, None)
}

/// report.json: the comparison's keys, then `predicted_msf` when there is a prediction.
#[derive(serde::Serialize)]
struct ReportJson<'a> {
    #[serde(flatten)]
    comparison: &'a Comparison,
    #[serde(skip_serializing_if = "Option::is_none")]
    predicted_msf: Option<&'a [PredictedMsf]>,
}

/// [`write_report`] plus, when given, the demo's "Predicted MSF per bonnet" section (HTML) and
/// the `predicted_msf` array (JSON).
pub fn write_report_with(
    dir: &Path,
    c: &Comparison,
    predicted_msf: Option<&[PredictedMsf]>,
) -> Result<Vec<PathBuf>, ReportError> {
    write_report_full(dir, c, predicted_msf, None)
}

/// [`write_report_with`] plus, for runs given by their recipes, the bonnets section (HTML) and
/// the `predicted`, `calibration`, `vibration_forcing` and `difference` fields (JSON).
pub fn write_report_full(
    dir: &Path,
    c: &Comparison,
    predicted_msf: Option<&[PredictedMsf]>,
    bonnets: Option<&BonnetsComparison>,
) -> Result<Vec<PathBuf>, ReportError> {
    // Everything is rendered before anything is staged, and staged before anything is published.
    let html = render_html_full(c, predicted_msf, bonnets)?;
    let mut set = write::Set::begin(dir, "compare")?;
    let mut written = Vec::new();
    let json_path = dir.join("report.json");
    let doc = ReportJson {
        comparison: c,
        predicted_msf,
    };
    match bonnets {
        Some(b) => set.json("report.json", &super::bonnets::extended_json(&doc, b)?)?,
        None => set.json("report.json", &doc)?,
    }
    written.push(json_path);
    for (r, stem) in c.runs.iter().zip(run_stems(c)) {
        for (axis, b, a) in [
            ("x", &r.psd.x_before, &r.psd.x_after),
            ("y", &r.psd.y_before, &r.psd.y_after),
        ] {
            if let (Some(b), Some(a)) = (b, a) {
                let name = format!("psd_{axis}_{stem}.csv");
                let p = dir.join(&name);
                set.csv_columns(
                    &name,
                    &["freq_per_mm", "psd_before_nm2_mm", "psd_after_nm2_mm"],
                    &[&b.freq_per_mm, &b.psd_nm2_mm, &a.psd_nm2_mm],
                )?;
                written.push(p);
            }
        }
    }
    let html_path = dir.join("report.html");
    set.bytes("report.html", html.as_bytes())?;
    written.push(html_path);
    set.commit()?;
    Ok(written)
}

/// The self-contained HTML report.
pub fn render_html(c: &Comparison) -> Result<String, ReportError> {
    render_html_with(c, None)
}

/// [`render_html`] with the predicted MSF section after the ripple section.
pub fn render_html_with(
    c: &Comparison,
    predicted_msf: Option<&[PredictedMsf]>,
) -> Result<String, ReportError> {
    render_html_full(c, predicted_msf, None)
}

/// [`render_html_with`] with the bonnets section after the predicted MSF section.
pub fn render_html_full(
    c: &Comparison,
    predicted_msf: Option<&[PredictedMsf]>,
    bonnets: Option<&BonnetsComparison>,
) -> Result<String, ReportError> {
    let mut page = Page::new("Bonnet run comparison");
    page.note(&format!(
        "{} {} \u{2014} {} run(s); form terms removed: {}; PSD window: {}{}.",
        c.tool,
        c.version,
        c.runs.len(),
        c.settings.removed.join(", "),
        c.settings.window,
        c.settings
            .pitch_mm
            .map(|p| format!("; grating spacing {} mm", fmt_sig(p)))
            .unwrap_or_default()
    ));
    summary(&mut page, c);
    noise_section(&mut page, c);
    bands_section(&mut page, c);
    if c.settings.pitch_mm.is_some() {
        ripple_section(&mut page, c);
    }
    if let Some(p) = predicted_msf {
        let measured: Vec<(String, f64)> = c
            .runs
            .iter()
            .filter_map(|r| {
                r.ripple_after
                    .as_ref()
                    .map(|a| (r.name.clone(), a.sigma1_nm))
            })
            .collect();
        super::msf_prediction::section(&mut page, p, &measured);
    }
    if let Some(b) = bonnets {
        super::bonnets::section(&mut page, b);
    }
    psd_section(&mut page, c)?;
    maps_section(&mut page, c)?;
    settings_section(&mut page, c);
    Ok(page.render())
}

fn summary(page: &mut Page, c: &Comparison) {
    page.section("Convergence summary");
    let mut t = Table::new([
        "run",
        "RMS before (nm)",
        "RMS after (nm)",
        "PV before (nm)",
        "PV after (nm)",
        "CR (RMS)",
        "CR (PV)",
        "improvement CR (RMS)",
        "improvement CR (PV)",
    ])
    .caption(format!(
        "PV and RMS after removing {} on the common aperture of each run; CR = (before - after) / before; \
         improvement = (CR - CR of '{}') / CR of '{}'",
        c.settings.removed.join(", "),
        c.runs.first().map(|r| r.name.as_str()).unwrap_or(""),
        c.runs.first().map(|r| r.name.as_str()).unwrap_or("")
    ));
    for r in &c.runs {
        let sd = r.spread.as_ref();
        let with_sd = |v: f64, s: Option<f64>| match s {
            Some(s) => format!("{} \u{b1} {}", nm(v), nm(s)),
            None => nm(v),
        };
        let imp_sd = |rms: bool| {
            r.improvement
                .as_ref()
                .and_then(|i| i.noise.as_ref())
                .map(|n| {
                    if rms {
                        n.improvement_cr_rms_sd
                    } else {
                        n.improvement_cr_pv_sd
                    }
                })
        };
        t.row([
            r.name.clone(),
            with_sd(r.rms_before_nm, sd.map(|s| s.rms_before_sd_nm)),
            with_sd(r.rms_after_nm, sd.map(|s| s.rms_after_sd_nm)),
            with_sd(r.pv_before_nm, sd.map(|s| s.pv_before_sd_nm)),
            with_sd(r.pv_after_nm, sd.map(|s| s.pv_after_sd_nm)),
            pct_pm(r.cr_rms, sd.map(|s| s.cr_rms_sd)),
            pct_pm(r.cr_pv, sd.map(|s| s.cr_pv_sd)),
            r.improvement_cr_rms
                .map(|v| pct_pm(v, imp_sd(true)))
                .unwrap_or_else(|| "reference".into()),
            r.improvement_cr_pv
                .map(|v| pct_pm(v, imp_sd(false)))
                .unwrap_or_else(|| "reference".into()),
        ]);
    }
    page.table(&t);
    if c.runs.iter().any(|r| r.spread.is_some()) {
        page.note(
            "With repeat measurements, values are means over the repeats \u{b1} the sample standard \
             deviation of one measurement; CR and improvement \u{b1} their standard deviation \
             propagated from the standard errors of the means.",
        );
    }
}

fn noise_section(page: &mut Page, c: &Comparison) {
    let Some(first) = c.runs.first() else { return };
    page.section("Is the difference real?");
    for r in &c.runs[1..] {
        let Some(imp) = &r.improvement else { continue };
        match &imp.noise {
            Some(n) => {
                let verdict = |within: bool| {
                    if within {
                        "WITHIN the measurement noise"
                    } else {
                        "beyond the measurement noise"
                    }
                };
                page.paragraph(&format!("'{}' vs '{}': CR(RMS) differs by {} \u{b1} {} percentage points ({}); \
                     CR(PV) by {} \u{b1} {} points ({}). Rule: a difference is within noise when it is \
                     smaller than twice its standard deviation.", r.name, first.name, fixed(100.0 * n.cr_rms_difference, 2), fixed(100.0 * n.cr_rms_difference_sd, 2), verdict(n.rms_within_noise), fixed(100.0 * n.cr_pv_difference, 2), fixed(100.0 * n.cr_pv_difference_sd, 2), verdict(n.pv_within_noise)));
            }
            None => {
                page.paragraph(&format!("'{}' vs '{}': no repeat measurements on both runs, so the noise of the convergence \
                     ratios is unknown. Give repeats as NAME=B1+B2,A1+A2 to test whether the {} % \
                     improvement (RMS) exceeds the measurement noise.", r.name, first.name, fixed(100.0 * imp.improvement_cr_rms, 2)));
            }
        }
    }
    if c.runs.len() < 2 {
        page.paragraph("Only one run: nothing to compare against.");
    }
}

fn bands_section(page: &mut Page, c: &Comparison) {
    page.section("Convergence per spatial-frequency band");
    let header = [
        "run",
        "band",
        "edges (1/mm)",
        "periods (mm)",
        "RMS before (nm)",
        "RMS after (nm)",
        "CR",
        "how measured / why absent",
    ];
    let mut t = Table::new(header).caption(
        "Band RMS of the maps themselves (areal split by radial frequency on the run's aperture: brick-wall bands of the map's 2-D transform, projected over its valid pixels): figure, \
         MSF and fine add up in quadrature to the RMS of the summary table. A band the maps \
         cannot resolve is absent, with the reason.",
    );
    for r in &c.runs {
        let (main, ripple): (Vec<&BandCr>, Vec<&BandCr>) =
            r.bands.iter().partition(|b| b.band != "ripple");
        for b in main.into_iter().chain([&r.band_fine]).chain(ripple) {
            t.row(band_row(&r.name, b));
        }
    }
    page.table(&t);
    let mut p = Table::new(header).caption(
        "For reference, a PSD quantity: the same edges integrated over the windowed 2-D PSD \
         (annulus sums). The window's loss on non-stationary maps makes these disagree with \
         the map RMS; read the table above for band RMS.",
    );
    for r in &c.runs {
        for b in &r.bands_psd {
            p.row(band_row(&r.name, b));
        }
    }
    page.table(&p);
}

/// One row of a band table: values or "absent", and the reason.
fn band_row(run: &str, b: &BandCr) -> Vec<String> {
    let period = |f: f64| {
        if f > 0.0 {
            fmt_sig(1.0 / f)
        } else {
            "\u{221e}".into()
        }
    };
    let opt_nm = |v: Option<f64>| v.map(nm).unwrap_or_else(|| "absent".into());
    let (f1, f2) = (b.f1_per_mm, b.f2_per_mm);
    let (edges, periods) = if f2 > f1 {
        (
            format!("{} to {}", fmt_sig(f1), fmt_sig(f2)),
            format!("{} to {}", period(f1), period(f2)),
        )
    } else {
        (fmt_sig(f1), period(f1))
    };
    vec![
        run.to_string(),
        b.band.clone(),
        edges,
        periods,
        opt_nm(b.rms_before_nm),
        opt_nm(b.rms_after_nm),
        b.cr.map(pct).unwrap_or_else(|| "absent".into()),
        match &b.reason {
            Some(why) => format!("{}; {why}", b.method),
            None => b.method.clone(),
        },
    ]
}

fn ripple_section(page: &mut Page, c: &Comparison) {
    page.section("Ripple at the grating spacing (Y PSD, feed direction)");
    let mut t = Table::new([
        "run",
        "map",
        "sigma1 (nm)",
        "sigma total (nm)",
        "A_eq (nm)",
        "PV_eq (nm)",
        "prominence (dB)",
        "detected",
        "Y/X at f0",
    ]);
    for r in &c.runs {
        for (state, rip) in [("before", &r.ripple_before), ("after", &r.ripple_after)] {
            if let Some(p) = rip {
                t.row([
                    r.name.clone(),
                    state.to_string(),
                    nm(p.sigma1_nm),
                    nm(p.sigma_total_nm),
                    nm(p.a_eq_nm),
                    nm(p.pv_eq_nm),
                    fixed(p.prominence_db, 1),
                    p.verdict.clone(),
                    p.y_over_x
                        .map(|v| fixed(v, 2))
                        .unwrap_or_else(|| "n/a".into()),
                ]);
            }
        }
    }
    page.table(&t);
    for r in &c.runs {
        if let Some(why) = &r.ripple_reason {
            page.paragraph(&format!("{}: ripple absent ({why}).", r.name));
        }
    }
    if let Some(p) = c.runs.iter().find_map(|r| r.ripple_before.as_ref()) {
        page.note(&format!(
            "f0 = 1/{} mm = {} 1/mm; sigma_k = band RMS of the one-sided Y PSD over |f - k f0| <= {} 1/mm, \
             sigma total over k = 1..{}; A_eq = sqrt(2) sigma1, PV_eq = 2 sqrt(2) sigma1; prominence over the \
             local background, detected at >= {} dB.",
            fmt_sig(p.pitch_mm),
            fmt_sig(p.f0_per_mm),
            fmt_sig(p.band_halfwidth_per_mm),
            p.harmonics.len(),
            p.prominence_threshold_db
        ));
    }
}

/// A PSD's values from its first unbiased bin up (docs/conventions.md: the bins the
/// detrending biases are left out of band sums and plots).
fn unbiased(p: &Psd1d, v: &[f64]) -> Vec<f64> {
    v[p.biased_bins.min(v.len())..].to_vec()
}

fn psd_plot(c: &Comparison, axis: &str) -> LinePlot {
    let dir = if axis == "x" { "X (scan)" } else { "Y (feed)" };
    let mut plot = LinePlot::new(
        format!("PSD along {dir}, one-sided, {} window", c.settings.window),
        "spatial frequency (1/mm)",
        "PSD (nm^2 mm)",
    )
    .log_log()
    .size(900, 520);
    for (i, r) in c.runs.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let (b, a) = if axis == "x" {
            (&r.psd.x_before, &r.psd.x_after)
        } else {
            (&r.psd.y_before, &r.psd.y_after)
        };
        if let Some(b) = b {
            plot = plot.series(
                Series::new(
                    format!("{} before", r.name),
                    unbiased(b, &b.freq_per_mm),
                    unbiased(b, &b.psd_nm2_mm),
                )
                .colour(colour)
                .dashed(),
            );
        }
        if let Some(a) = a {
            plot = plot.series(
                Series::new(
                    format!("{} after", r.name),
                    unbiased(a, &a.freq_per_mm),
                    unbiased(a, &a.psd_nm2_mm),
                )
                .colour(colour),
            );
        }
    }
    if let Some(p) = c.settings.pitch_mm {
        plot = plot.grating_markers(p, c.settings.harmonics.min(3));
    }
    plot
}

fn psd_section(page: &mut Page, c: &Comparison) -> Result<(), ReportError> {
    page.section("PSD overlays");
    for axis in ["x", "y"] {
        let svg = psd_plot(c, axis).to_svg()?;
        let caption = format!(
            "One-sided 1-D PSD along {} averaged over lines{}; dashed = before, solid = after. \
             Data: psd_{axis}_<run>.csv.{}",
            axis.to_uppercase(),
            if c.runs.iter().any(|r| r.spread.is_some()) {
                " and repeat maps"
            } else {
                ""
            },
            if c.settings.pitch_mm.is_some() {
                " Vertical lines: grating frequency f0 and harmonics."
            } else {
                ""
            }
        );
        page.svg(&svg, &caption);
    }
    Ok(())
}

fn maps_section(page: &mut Page, c: &Comparison) -> Result<(), ReportError> {
    page.section("Maps");
    page.note(&format!(
        "False colour (viridis), grey = invalid or outside the common aperture; {} removed from each map. \
         Before and after of a run share one colour scale; removal = before - after. Row 0 at the bottom.",
        c.settings.removed.join(", ")
    ));
    for r in &c.runs {
        let Some(m) = &r.maps else { continue };
        page.subsection(&r.name);
        let (lo, hi) = match (valid_range(&m.before), valid_range(&m.after)) {
            (Some(a), Some(b)) => (a.0.min(b.0), a.1.max(b.1)),
            (a, b) => a.or(b).unwrap_or((0.0, 1.0)),
        };
        for (label, s, shared) in [
            ("before", &m.before, true),
            ("after", &m.after, true),
            ("removal (before - after)", &m.removal, false),
        ] {
            let mut o = MapOptions::new(format!("{}: {label}", r.name), "nm");
            o.width = 520;
            o.height = 440;
            if shared {
                o = o.range(lo, hi);
            }
            let png = false_colour_png_with(s, &o)?;
            page.png(
                &png,
                &format!("{} {label} map", r.name),
                &format!("{}: {label}", r.name),
            );
        }
    }
    Ok(())
}

fn settings_section(page: &mut Page, c: &Comparison) {
    page.section("Settings and inputs");
    let s = &c.settings;
    let mut t = Table::new(["setting", "value"]);
    t.row(["tool".to_string(), format!("{} {}", c.tool, c.version)]);
    t.row(["form terms removed".to_string(), s.removed.join(", ")]);
    t.row(["PSD".to_string(), s.psd.clone()]);
    t.row(["window".to_string(), s.window.clone()]);
    t.row([
        "grating spacing".to_string(),
        s.pitch_mm
            .map(|p| format!("{} mm", fmt_sig(p)))
            .unwrap_or("not given".into()),
    ]);
    t.row([
        "figure band".to_string(),
        format!(
            "{} to {} 1/mm",
            fmt_sig(s.figure_band_per_mm.0),
            fmt_sig(s.figure_band_per_mm.1)
        ),
    ]);
    t.row([
        "MSF band".to_string(),
        format!(
            "{} to {} 1/mm (periods {} to {} mm), clipped to Nyquist",
            fmt_sig(s.msf_band_per_mm.0),
            fmt_sig(s.msf_band_per_mm.1),
            fmt_sig(1.0 / s.msf_band_per_mm.0),
            fmt_sig(1.0 / s.msf_band_per_mm.1)
        ),
    ]);
    t.row(["ripple harmonics".to_string(), s.harmonics.to_string()]);
    t.row(["aperture".to_string(), s.aperture.clone()]);
    t.row(["noise rule".to_string(), s.noise_rule.clone()]);
    page.table(&t);
    let mut inputs = Table::new([
        "run",
        "before maps",
        "after maps",
        "grid",
        "pixel (mm)",
        "common valid pixels",
    ]);
    for r in &c.runs {
        inputs.row(run_input_row(r));
    }
    page.table(&inputs);
}

fn run_input_row(r: &RunResult) -> Vec<String> {
    vec![
        r.name.clone(),
        r.before_files.join(" + "),
        r.after_files.join(" + "),
        format!("{} x {}", r.rows, r.cols),
        format!(
            "{} x {}",
            r.dx_mm.map(fmt_sig).unwrap_or("?".into()),
            r.dy_mm.map(fmt_sig).unwrap_or("?".into())
        ),
        r.common_valid.to_string(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_stems_are_safe() {
        assert_eq!(file_stem("orig bonnet/1"), "orig_bonnet_1");
        assert_eq!(file_stem(""), "run");
        assert_eq!(file_stem("a-b_c"), "a-b_c");
    }

    /// The compare report's PSD plots start at the first unbiased bin (they once drew the two
    /// bins the per-line detrending biases, 0.01 and 0.02 per mm on the demo maps).
    #[test]
    fn plotted_psds_leave_out_the_biased_bins() {
        let p = Psd1d {
            axis: bonnetlab_spectrum::Axis::Y,
            freq_per_mm: vec![0.01, 0.02, 0.03, 0.04],
            psd_nm2_mm: vec![9.0, 8.0, 7.0, 6.0],
            df_per_mm: 0.01,
            spacing_mm: 0.25,
            window: bonnetlab_spectrum::Window::Hann,
            enbw_bins: 1.5,
            n_lines: 1,
            n_segments: 1,
            biased_bins: 2,
            removed: vec![],
        };
        assert_eq!(unbiased(&p, &p.freq_per_mm), vec![0.03, 0.04]);
        assert_eq!(unbiased(&p, &p.psd_nm2_mm), vec![7.0, 6.0]);
        let all = Psd1d {
            biased_bins: 9,
            ..p.clone()
        };
        assert!(unbiased(&all, &all.freq_per_mm).is_empty());
    }
}
