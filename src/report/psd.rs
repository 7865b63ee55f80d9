//! Rendering of a PSD report (`pipeline::psd`): the summary text, the long-form CSV and the
//! log-log plot.

use bonnetlab_surface::Term;

use super::format::{self, fixed};
use super::plot::{LinePlot, PlotError, Series};
use crate::pipeline::psd::{AxisReport, PsdReport};

fn names(terms: &[Term]) -> String {
    if terms.is_empty() {
        return "none".into();
    }
    serde_json::to_value(terms)
        .ok()
        .and_then(|v| v.as_array().cloned())
        .map(|a| {
            a.iter()
                .filter_map(|t| t.as_str().map(String::from))
                .collect::<Vec<_>>()
                .join(", ")
        })
        .unwrap_or_default()
}

pub fn summary(r: &PsdReport) -> String {
    let mut o = String::new();
    let mut line = |s: String| {
        o.push_str(&s);
        o.push('\n');
    };
    line(format!(
        "{} ({}): {} x {} pixels, dx {} mm, dy {} mm",
        r.file,
        r.format,
        r.rows,
        r.cols,
        format::f32_value(r.dx_mm),
        format::f32_value(r.dy_mm)
    ));
    line(format!("removed: {}; per-segment detrend: {:?}; window: {} (ENBW {} bins); gaps <= {} px interpolated", names(&r.removed), r.detrend, r.window, fixed(r.enbw_bins, 3), r.max_gap_px));
    line("PSDs are one-sided, nm^2 mm; band RMS by bin sums".into());
    for (name, a) in [("X (rows)", &r.x), ("Y (columns)", &r.y)] {
        let Some(a) = a else { continue };
        line(format!(
            "{name}: {} lines, {} segments, df {} mm^-1, first unbiased bin {}",
            a.n_lines,
            a.n_segments,
            fixed(a.df_per_mm, 6),
            a.biased_bins
        ));
        match (a.rms_unbiased_nm, &a.rms_unbiased_reason) {
            (Some(v), _) => line(format!(
                "  PSD-integrated RMS over the unbiased bins: {v_s} nm",
                v_s = fixed(v, 4)
            )),
            (None, why) => line(format!(
                "  PSD-integrated RMS over the unbiased bins: absent ({})",
                why.as_deref().unwrap_or("no unbiased bin")
            )),
        }
        match (a.msf.rms_nm, a.msf.f1_used_per_mm, a.msf.f2_used_per_mm) {
            (Some(v), Some(lo), Some(hi)) => line(format!(
                "  PSD-integrated MSF band [{}, {}] mm^-1 (used [{lo_s}, {hi_s}]): {v_s} nm",
                fixed(a.msf.f1_per_mm, 6),
                fixed(a.msf.f2_per_mm, 6),
                lo_s = fixed(lo, 6),
                hi_s = fixed(hi, 6),
                v_s = fixed(v, 4)
            )),
            _ => line(format!(
                "  PSD-integrated MSF band [{}, {}] mm^-1: absent ({})",
                fixed(a.msf.f1_per_mm, 6),
                fixed(a.msf.f2_per_mm, 6),
                a.msf.reason.as_deref().unwrap_or("not computed")
            )),
        }
        if let Some(l) = &a.limit {
            line(format!(
                "  limit {} f^-{} ({}) over [{}, {}] mm^-1: worst ratio {} at {} mm^-1: {}",
                l.line.a,
                l.line.b,
                l.sidedness,
                format::sig(l.line.f1_per_mm, 6),
                format::sig(l.line.f2_per_mm, 6),
                fixed(l.worst_ratio, 3),
                fixed(l.worst_freq_per_mm, 4),
                if l.pass { "PASS" } else { "FAIL" }
            ));
        }
    }
    line("band RMS of the map (areal split, adds up to the RMS):".into());
    for l in super::stats::bands_table(&r.bands).lines() {
        line(format!("  {l}"));
    }
    if let Some(why) = &r.ripple_reason {
        line(format!("ripple along Y: absent ({why})"));
    }
    if let Some(rp) = &r.ripple {
        line(format!(
            "ripple along Y at pitch {} mm (f0 {} mm^-1, bands |f - k f0| <= {} mm^-1):",
            rp.pitch_mm,
            fixed(rp.f0_per_mm, 6),
            fixed(rp.band_halfwidth_per_mm, 6)
        ));
        line(format!(
            "  sigma_1 {} nm, sigma_total {} nm, A_eq {} nm, PV_eq {} nm",
            fixed(rp.sigma1_nm, 4),
            fixed(rp.sigma_total_nm, 4),
            fixed(rp.a_eq_nm, 4),
            fixed(rp.pv_eq_nm, 4)
        ));
        line(format!(
            "  {} (prominence over the flanking median)",
            rp.verdict
        ));
        line(format!(
            "  Y/X at f0: {}",
            match (rp.y_over_x, &rp.y_over_x_reason) {
                (Some(v), _) => format!("{v:.3}"),
                (None, why) => format!(
                    "absent ({})",
                    why.as_deref().unwrap_or("no X power in the band")
                ),
            }
        ));
        if let Some(hint) = &rp.hint {
            line(format!("  hint: {hint}"));
        }
        let h: Vec<String> = rp
            .harmonics
            .iter()
            .map(|h| format!("{}f0 {} nm", h.k, fixed(h.sigma_nm, 4)))
            .collect();
        line(format!("  harmonics: {}", h.join(", ")));
    }
    o.trim_end().to_string()
}

pub fn axis_rows(r: &PsdReport) -> impl Iterator<Item = (&'static str, &AxisReport)> {
    [("x", r.x.as_ref()), ("y", r.y.as_ref())]
        .into_iter()
        .filter_map(|(n, a)| a.map(|a| (n, a)))
}

/// The spectra as CSV text in long form (axis,freq_per_mm,psd_nm2_mm[,q_rad_per_mm,
/// CONVENTION_nm2_mm]).
pub fn csv_text(r: &PsdReport) -> String {
    let mut text = String::new();
    let conv = axis_rows(r)
        .next()
        .and_then(|(_, a)| a.converted.as_ref())
        .map(|c| c.convention);
    match conv {
        Some(c) => text.push_str(&format!(
            "axis,freq_per_mm,psd_nm2_mm,q_rad_per_mm,{}_nm2_mm\n",
            c.replace('-', "_")
        )),
        None => text.push_str("axis,freq_per_mm,psd_nm2_mm\n"),
    }
    for (name, a) in axis_rows(r) {
        for (k, (f, p)) in a.freq_per_mm.iter().zip(&a.psd_nm2_mm).enumerate() {
            match &a.converted {
                Some(c) => text.push_str(&format!(
                    "{name},{f:e},{p:e},{:e},{:e}\n",
                    c.q_rad_per_mm[k], c.values_nm2_mm[k]
                )),
                None => text.push_str(&format!("{name},{f:e},{p:e}\n")),
            }
        }
    }
    text
}

/// Both PSDs log-log with the limit line as tested and the grating frequency and its harmonics
/// marked; `svg` chooses SVG over PNG.
pub fn plot_bytes(
    r: &PsdReport,
    pitch: Option<f64>,
    harmonics: usize,
    svg: bool,
) -> Result<Vec<u8>, PlotError> {
    let mut plot = LinePlot::new(
        format!("1-D PSD ({}, window {})", r.file, r.window),
        "spatial frequency f (mm^-1)",
        "one-sided PSD (nm^2 mm)",
    )
    .log_log();
    for (name, a) in axis_rows(r) {
        // Biased lowest bins are left out of the plot.
        let skip = a.biased_bins;
        plot = plot.series(Series::new(
            if name == "x" {
                "X (along rows)"
            } else {
                "Y (along columns, feed)"
            },
            a.freq_per_mm[skip.min(a.freq_per_mm.len())..].to_vec(),
            a.psd_nm2_mm[skip.min(a.psd_nm2_mm.len())..].to_vec(),
        ));
    }
    // The limit line as tested (on the one-sided PSD: a two-sided A counts twice).
    if let Some(l) = axis_rows(r).find_map(|(_, a)| a.limit.as_ref()) {
        let line = l.line;
        let scale = if line.two_sided { 2.0 } else { 1.0 };
        let mut f: Vec<f64> = axis_rows(r)
            .flat_map(|(_, a)| a.freq_per_mm[a.biased_bins.min(a.freq_per_mm.len())..].iter())
            .copied()
            .filter(|&f| f > 0.0 && f >= line.f1_per_mm && f <= line.f2_per_mm)
            .collect();
        f.sort_by(f64::total_cmp);
        f.dedup();
        let y = f
            .iter()
            .map(|&f| scale * line.a * f.powf(-line.b))
            .collect();
        plot = plot.series(
            Series::new(
                format!(
                    "limit {} f^-{} ({})",
                    format::sig(line.a, 6),
                    format::sig(line.b, 6),
                    l.sidedness
                ),
                f,
                y,
            )
            .colour((0, 0, 0))
            .dashed(),
        );
    }
    // Only the harmonics inside the plotted frequencies (up to Nyquist): the log axis' margin
    // reaches past the last bin, and a marker there would claim a frequency the PSD lacks.
    let f_max = axis_rows(r)
        .filter_map(|(_, a)| a.freq_per_mm.last().copied())
        .fold(0.0, f64::max);
    if let Some(p) = pitch {
        let inside = (1..=harmonics)
            .take_while(|&k| k as f64 / p <= f_max * (1.0 + 1e-12))
            .count();
        plot = plot.grating_markers(p, inside);
    }
    if svg {
        plot.to_svg().map(String::into_bytes)
    } else {
        plot.to_png()
    }
}
