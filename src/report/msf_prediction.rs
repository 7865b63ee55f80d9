//! The demo report's "Predicted MSF per bonnet" section: the vibration coupling's prediction
//! (bonnetlab_vibration::coupling::predict) for each bonnet on a run matching the sample, as an
//! HTML section and as the `predicted_msf` array of report.json.
//!
//! Conventions: band RMS values are along Y (feed), from one-sided Y PSDs, in nm; `share` is a
//! fraction of the summed band power of the mechanisms and their interaction (as the vibration
//! crate defines it); the band edges are in cycles/mm with the upper edge clipped to Nyquist.

use crate::report::format::fixed;

pub use crate::pipeline::msf_prediction::{PredictedMsf, PredictionRun, ASSUMPTIONS};

use super::comparison::fmt_sig;
use super::html::{Page, Table};

fn opt_nm(v: Option<f64>) -> String {
    v.map(|x| fixed(x, 4)).unwrap_or_else(|| "\u{2014}".into())
}

/// What the prediction says about the measured difference between two bonnets: the predicted
/// and the measured σ1 difference (nm, other − first) and a sentence. `measured` holds each
/// run's name and its measured σ1 after polishing (nm); a prediction is matched to the run of
/// its bonnet's name; a pair with no measured run (or no predicted σ1) gets no sentence.
pub fn against_measured(preds: &[PredictedMsf], measured: &[(String, f64)]) -> Vec<String> {
    let sigma = |name: &str| measured.iter().find(|(n, _)| n == name).map(|m| m.1);
    let Some((first, rest)) = preds.split_first() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for p in rest {
        let (Some(pa), Some(pb), Some(ma), Some(mb)) = (
            first.ripple_sigma1_nm,
            p.ripple_sigma1_nm,
            sigma(&first.bonnet),
            sigma(&p.bonnet),
        ) else {
            continue;
        };
        let (dp, dm) = (pb - pa, mb - ma);
        let verdict = if dm == 0.0 {
            "the measured runs do not differ at all".to_string()
        } else if dp * dm <= 0.0 || (dp / dm).abs() < 0.1 {
            format!(
                "the prediction does not explain the measured difference ({} of it): at these \
                 settings the spindle imprint's period along the scan is {} mm (feed over \
                 spindle frequency), which the spot averages out, so the modelled vibration \
                 makes no ripple difference of this size. Either the measured runs differ \
                 in what the prediction holds fixed (forcing, spindle speed, feed, spot), or \
                 the difference has another cause. `compare --run NAME=RECIPE.toml` fits each \
                 run's forcing to its maps and attributes the difference cause by cause",
                pct_of(dp, dm),
                fmt_sig(p.run.feed_mm_per_s / (p.run.spindle_rpm / 60.0)),
            )
        } else {
            format!(
                "the prediction accounts for {} of the measured difference at the default \
                 forcing; `compare --run NAME=RECIPE.toml` fits each run's forcing to its maps",
                pct_of(dp, dm)
            )
        };
        out.push(format!(
            "Against the measured runs of this report: predicted σ1 {} − {} = {:+.4} nm, \
             measured {:+.4} nm (σ1 after polishing, table above); {verdict}.",
            p.bonnet, first.bonnet, dp, dm
        ));
    }
    out
}

fn pct_of(part: f64, whole: f64) -> String {
    format!("{} %", fixed(100.0 * part / whole, 1))
}

/// Appends the "Predicted MSF per bonnet" section; `measured` as in [`against_measured`].
pub fn section(page: &mut Page, preds: &[PredictedMsf], measured: &[(String, f64)]) {
    page.section("Predicted MSF per bonnet");
    if let Some(p) = preds.first() {
        let r = &p.run;
        page.paragraph(&format!(
            "Vibration coupling prediction on a run matching the sample: {} x {} mm part on a \
             {} x {} grid of {} mm pixels, {} TIF (peak {} nm/s), bidirectional raster at a {} mm \
             pitch and {} mm/s feed, spindle {} rpm, offset {} mm, precession {} deg, inner \
             pressure {} MPa; vibration sampled at {} Hz, seed {}. MSF band along Y: {} to {} \
             cycles/mm.",
            fmt_sig(r.part_mm.0),
            fmt_sig(r.part_mm.1),
            r.rows,
            r.cols,
            fmt_sig(r.dx_mm),
            r.tif,
            fmt_sig(r.tif_peak_rate_nm_per_s),
            fmt_sig(r.pitch_mm),
            fmt_sig(r.feed_mm_per_s),
            fmt_sig(r.spindle_rpm),
            fmt_sig(r.offset_mm),
            fmt_sig(r.precession_deg),
            fmt_sig(r.inner_pressure_mpa),
            fmt_sig(r.sample_hz),
            r.seed,
            fmt_sig(p.msf_band_per_mm.0),
            fmt_sig(p.msf_band_per_mm.1),
        ));
    }
    let mut summary = Table::new([
        "bonnet",
        "Y ripple \u{3c3}1 (nm)",
        "baseline \u{3c3}1 (nm)",
        "MSF band RMS of removal (nm)",
        "baseline (nm)",
        "induced (nm)",
        "MSF band (cycles/mm)",
    ])
    .caption("Predicted Y ripple at 1/pitch and MSF band RMS of the predicted removal");
    for p in preds {
        summary.row([
            p.bonnet.clone(),
            opt_nm(p.ripple_sigma1_nm),
            opt_nm(p.baseline_ripple_sigma1_nm),
            fixed(p.removal_msf_band_rms_nm, 4),
            fixed(p.baseline_msf_band_rms_nm, 4),
            format!("{:.3e}", p.induced_msf_band_rms_nm),
            format!(
                "{} \u{2013} {}",
                fmt_sig(p.msf_band_per_mm.0),
                fmt_sig(p.msf_band_per_mm.1)
            ),
        ]);
    }
    page.table(&summary);
    for w in against_measured(preds, measured) {
        page.paragraph(&w);
    }
    for p in preds {
        page.subsection(&format!("{} bonnet", p.bonnet));
        let mut t = Table::new(["mechanism", "enabled", "MSF band RMS (nm)", "share"])
            .caption(format!("Mechanisms of the {} bonnet", p.bonnet));
        for m in &p.mechanisms {
            t.row([
                m.name.clone(),
                if m.enabled { "yes" } else { "no" }.to_string(),
                format!("{:.3e}", m.msf_band_rms_nm),
                format!("{} %", fixed(100.0 * m.share, 2)),
            ]);
        }
        page.table(&t);
    }
    page.paragraph(ASSUMPTIONS);
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_vibration::coupling::predict::MechanismResult;

    #[test]
    fn section_lists_every_mechanism_with_its_share() {
        let run = PredictionRun {
            part_mm: (100.0, 100.0),
            rows: 2,
            cols: 2,
            dx_mm: 0.4,
            dy_mm: 0.4,
            tif: "gaussian".into(),
            tif_peak_rate_nm_per_s: 1.0,
            pitch_mm: 3.0,
            feed_mm_per_s: 1.6,
            spindle_rpm: 1000.0,
            offset_mm: 0.6,
            precession_deg: 20.0,
            inner_pressure_mpa: 0.25,
            sample_hz: 1000.0,
            seed: 1,
        };
        let p = PredictedMsf {
            bonnet: "original".into(),
            run,
            msf_band_per_mm: (0.0333, 1.25),
            ripple_sigma1_nm: Some(0.5),
            baseline_ripple_sigma1_nm: None,
            removal_msf_band_rms_nm: 1.0,
            baseline_msf_band_rms_nm: 0.5,
            induced_msf_band_rms_nm: 0.5,
            mechanisms: vec![MechanismResult {
                name: "lateral_jitter".into(),
                enabled: true,
                msf_band_rms_nm: 0.25,
                share: 0.375,
            }],
            assumptions: ASSUMPTIONS.into(),
        };
        let mut other = p.clone();
        other.bonnet = "suppression".into();
        other.ripple_sigma1_nm = Some(0.5004);
        // Measured: suppression 3.76 nm lower. Predicted +0.0004 nm: not explained.
        let measured = vec![
            ("original".to_string(), 6.97),
            ("suppression".to_string(), 3.21),
        ];
        let words = against_measured(&[p.clone(), other.clone()], &measured);
        assert_eq!(words.len(), 1);
        assert!(words[0].contains("+0.0004 nm") && words[0].contains("-3.7600 nm"));
        assert!(words[0].contains("does not explain"), "{}", words[0]);
        // A prediction of 80 % of the difference is said to account for it.
        other.ripple_sigma1_nm = Some(0.5 - 0.8 * 3.76);
        let words = against_measured(&[p.clone(), other], &measured);
        assert!(words[0].contains("accounts for 80.0 %"), "{}", words[0]);
        // No measured run of that name: nothing said.
        assert!(against_measured(std::slice::from_ref(&p), &measured).is_empty());
        let mut page = Page::new("t");
        section(&mut page, &[p], &[]);
        let html = page.render();
        assert!(html.contains("Predicted MSF per bonnet"));
        assert!(html.contains("lateral_jitter"));
        assert!(html.contains("37.50 %"));
        assert!(html.contains("2.500e-1"));
    }
}
