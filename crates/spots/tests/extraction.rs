//! Metric extraction against the generating model's own metrics (the truth): noise, tilt,
//! piston and an off-centre spot included.

use bonnetlab_spots::{generate_spot, measure_spot, BonnetModel, Factors, SpotOptions, SpotSpec};

fn spec(factors: Factors, seed: u64) -> SpotSpec {
    SpotSpec {
        model: BonnetModel::new(20.0, 0.06, 2.0),
        factors,
        dwell_s: 120.0,
        rows: 161,
        cols: 171,
        dx_mm: 0.15,
        dy_mm: 0.15,
        centre_offset_mm: (0.37, -0.23),
        piston_nm: 40.0,
        tilt_nm_per_mm: (3.0, -2.0),
        noise_rms_nm: 2.0,
        seed,
    }
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn extracted_metrics_are_within_two_percent_across_the_paper_ranges() {
    let base = Factors::PAPER_BASELINE;
    let cases = [
        base,
        Factors {
            offset_mm: 0.2,
            ..base
        },
        Factors {
            offset_mm: 1.0,
            ..base
        },
        Factors {
            precession_deg: 10.0,
            ..base
        },
        Factors {
            precession_deg: 30.0,
            ..base
        },
        Factors {
            spindle_rpm: 250.0,
            ..base
        },
        Factors {
            inner_pressure_mpa: 0.05,
            ..base
        },
    ];
    for (k, f) in cases.iter().enumerate() {
        let sp = spec(*f, 11 + k as u64);
        let truth = sp.model.metrics(f).unwrap();
        let s = generate_spot(&sp).unwrap();
        let m = measure_spot(&s, sp.dwell_s, &SpotOptions::default())
            .unwrap()
            .metrics;
        let (tx, ty) = sp.centre_mm();
        eprintln!(
            "{f:?}: peak {:.4} vs {:.4}, vol {:.2} vs {:.2}, fwhm {:.4}/{:.4} vs {:.4}, centre err {:.4} {:.4}, noise {:.3}, region rms {:.1} pv {:.1}",
            m.peak_rate_nm_per_s, truth.peak_rate_nm_per_s, m.volume_rate_nm_mm2_per_s,
            truth.volume_rate_nm_mm2_per_s, m.fwhm_x_mm, m.fwhm_y_mm, truth.fwhm_x_mm,
            m.centre_x_mm - tx, m.centre_y_mm - ty, m.noise_rms_nm, m.region_rms_nm, m.region_pv_nm
        );
        assert!(
            rel(m.peak_rate_nm_per_s, truth.peak_rate_nm_per_s) < 0.02,
            "peak {f:?}"
        );
        assert!(
            rel(m.volume_rate_nm_mm2_per_s, truth.volume_rate_nm_mm2_per_s) < 0.02,
            "vol {f:?}"
        );
        assert!(rel(m.fwhm_x_mm, truth.fwhm_x_mm) < 0.02, "fwhm x {f:?}");
        assert!(rel(m.fwhm_y_mm, truth.fwhm_y_mm) < 0.02, "fwhm y {f:?}");
        assert!((m.centre_x_mm - tx).abs() < 0.05 && (m.centre_y_mm - ty).abs() < 0.05);
        assert!(
            (m.noise_rms_nm - 2.0).abs() < 0.2,
            "noise {}",
            m.noise_rms_nm
        );
        assert!((m.asymmetry_x - 1.0).abs() < 0.03 && (m.aspect_yx - 1.0).abs() < 0.03);
    }
}
