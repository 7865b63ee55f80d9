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

#[test]
fn asymmetric_spot_half_widths_match_the_analytic_shape() {
    // A dip made of two half-paraboloids: semi-axes 4 mm (-x), 5 mm (+x), 4.5 mm (y), 300 nm
    // deep, on a tilted plane. Half maximum lies at semi-axis / sqrt(2) on each side.
    let (dx, n) = (0.1, 241);
    let (cx, cy) = (12.03, 11.96);
    let z = ndarray::Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * dx - cx, i as f64 * dx - cy);
        let wx = if x < 0.0 { 4.0 } else { 5.0 };
        let q = 1.0 - (x / wx).powi(2) - (y / 4.5).powi(2);
        0.5 * j as f64 * dx - 300.0 * q.max(0.0)
    });
    let s = bonnetlab_surface::Surface::new(z, Some(dx), Some(dx)).unwrap();
    let m = measure_spot(&s, 60.0, &SpotOptions::default())
        .unwrap()
        .metrics;
    let r2 = std::f64::consts::SQRT_2;
    assert!(
        rel(m.peak_rate_nm_per_s, 5.0) < 0.01,
        "{}",
        m.peak_rate_nm_per_s
    );
    // The full widths are exact; the split into half-widths depends on the centre, and a
    // paraboloid fitted to a lopsided cap puts its vertex about 0.1 mm towards the wide side
    // (here: a kinked apex, the worst case), so the half-widths carry that offset.
    assert!(rel(m.fwhm_x_mm, 9.0 / r2) < 0.01, "{}", m.fwhm_x_mm);
    assert!(
        rel(m.half_width_left_mm, 4.0 / r2) < 0.05,
        "{}",
        m.half_width_left_mm
    );
    assert!(
        rel(m.half_width_right_mm, 5.0 / r2) < 0.05,
        "{}",
        m.half_width_right_mm
    );
    assert!(rel(m.fwhm_y_mm, 9.0 / r2) < 0.01, "{}", m.fwhm_y_mm);
    assert!(
        m.asymmetry_x > 1.12 && m.asymmetry_x < 1.26,
        "{}",
        m.asymmetry_x
    );
    assert!((m.asymmetry_y - 1.0).abs() < 0.02);
    // Volume of the two half elliptic paraboloids: pi/4 * P * wy * (wl + wr), per second.
    let vol = std::f64::consts::PI / 4.0 * 300.0 * 4.5 * 9.0 / 60.0;
    assert!(
        rel(m.volume_rate_nm_mm2_per_s, vol) < 0.01,
        "{} vs {vol}",
        m.volume_rate_nm_mm2_per_s
    );
    // The centroid sits on the wide side.
    assert!(m.centroid_offset_x_mm > 0.1, "{}", m.centroid_offset_x_mm);
}
