//! The demo report's "Predicted MSF per bonnet" section: the vibration coupling's prediction
//! (bonnetlab_vibration::coupling::predict) for each bonnet on a run matching the sample, as an
//! HTML section and as the `predicted_msf` array of report.json.
//!
//! Conventions: band RMS values are along Y (feed), from one-sided Y PSDs, in nm; `share` is a
//! fraction of the summed band power of the mechanisms and their interaction (as the vibration
//! crate defines it); the band edges are in cycles/mm with the upper edge clipped to Nyquist.

use crate::report::format::fixed;
use serde::Serialize;

use bonnetlab_vibration::coupling::predict::{BonnetPrediction, MechanismResult};

use super::comparison::fmt_sig;
use super::html::{Page, Table};

/// The run the prediction was made for (what a reader needs to reproduce it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredictionRun {
    pub part_mm: (f64, f64),
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// TIF model, e.g. "paper bonnet (R 20 mm, Hertz pressure, four-step precession)".
    pub tif: String,
    pub tif_peak_rate_nm_per_s: f64,
    pub pitch_mm: f64,
    pub feed_mm_per_s: f64,
    pub spindle_rpm: f64,
    pub offset_mm: f64,
    pub precession_deg: f64,
    pub inner_pressure_mpa: f64,
    pub sample_hz: f64,
    pub seed: u64,
}

/// One bonnet's entry of `predicted_msf`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PredictedMsf {
    pub bonnet: String,
    pub run: PredictionRun,
    /// MSF band along Y, cycles/mm (upper edge clipped to Nyquist).
    pub msf_band_per_mm: (f64, f64),
    /// σ1 at 1/pitch along Y of the predicted and of the baseline removal, nm.
    pub ripple_sigma1_nm: Option<f64>,
    pub baseline_ripple_sigma1_nm: Option<f64>,
    /// MSF band RMS (Y) of the predicted removal, of the baseline and of the induced part, nm.
    pub removal_msf_band_rms_nm: f64,
    pub baseline_msf_band_rms_nm: f64,
    pub induced_msf_band_rms_nm: f64,
    pub mechanisms: Vec<MechanismResult>,
    pub assumptions: String,
}

/// The model's assumptions, stated once for the HTML and the JSON (values from the vibration
/// crate's documented defaults, bonnetlab_vibration::params).
pub const ASSUMPTIONS: &str = "The robot is modelled as two principal modes from the paper's \
stiffness matrix (k1 = 1.476e3, k2 = 3.289e2 N/mm, theta = 13.2 deg) with equivalent masses from \
the measured natural frequencies and the vibration crate's documented default modal damping, \
driven by the contact force F_n (mu, 1) sin(wt) at the spindle frequency (default force and \
friction coefficient), its harmonics, seeded broadband force noise and the ring-down after each \
raster line reversal executed at the acceleration limit. The suppression bonnet adds damping \
zeta_e = eta / 2 = 0.0575 in both principal directions and a series compliance (wave spring \
50 N/mm, assumed) in front of the inflated bonnet's contact stiffness. Removal depends on the \
offset non-linearly (spot radius and peak pressure grow with offset, Hertzian exponent 0.5); the \
four mechanisms (normal offset, lateral spot jitter, slow envelope, acceleration-limited dwell \
execution) are computed with the fast second-order expansion of the vibration crate, which is \
validated against direct deposition of the instantaneous TIF. Shares are band powers over the \
summed power of the mechanisms and their interaction, so they describe uncorrelated parts; the \
prediction is for a uniform raster of the whole part (no dwell correction), not a fit to the \
measured maps.";

impl PredictedMsf {
    pub fn new(run: PredictionRun, p: &BonnetPrediction) -> PredictedMsf {
        let bonnet = match p.bonnet {
            bonnetlab_vibration::params::Bonnet::Original => "original",
            bonnetlab_vibration::params::Bonnet::Suppression => "suppression",
        };
        PredictedMsf {
            bonnet: bonnet.to_string(),
            run,
            msf_band_per_mm: p.msf_band_per_mm,
            ripple_sigma1_nm: p.ripple_sigma1_nm,
            baseline_ripple_sigma1_nm: p.baseline_ripple_sigma1_nm,
            removal_msf_band_rms_nm: p.removal_msf_band_rms_nm,
            baseline_msf_band_rms_nm: p.baseline_msf_band_rms_nm,
            induced_msf_band_rms_nm: p.induced_msf_band_rms_nm,
            mechanisms: p.mechanisms.clone(),
            assumptions: ASSUMPTIONS.to_string(),
        }
    }
}

fn opt_nm(v: Option<f64>) -> String {
    v.map(|x| fixed(x, 4)).unwrap_or_else(|| "\u{2014}".into())
}

/// Appends the "Predicted MSF per bonnet" section.
pub fn section(page: &mut Page, preds: &[PredictedMsf]) {
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
        let mut page = Page::new("t");
        section(&mut page, &[p]);
        let html = page.render();
        assert!(html.contains("Predicted MSF per bonnet"));
        assert!(html.contains("lateral_jitter"));
        assert!(html.contains("37.50 %"));
        assert!(html.contains("2.500e-1"));
    }
}
