//! The self-check table of shared/spec/metrology.md, row by row, plus the ripple verdicts.
//! Setup: z = A sin(2 pi x / p), A = 10 nm, p = 3 mm, L = 60 mm, N = 600 (dx = 0.1 mm).

use std::f64::consts::{PI, SQRT_2};

use bonnetlab_spectrum::*;
use bonnetlab_surface::{height_stats, rng::Rng, Surface, Term};
use ndarray::Array2;

const A: f64 = 10.0;
const P: f64 = 3.0;
const D: f64 = 0.1;

fn expected_rms() -> f64 {
    A / SQRT_2 // 7.0711
}

/// A sine along X (columns) or Y (rows) on a rows x cols grid.
fn sine(rows: usize, cols: usize, along_y: bool) -> Surface {
    let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
        let t = if along_y { i } else { j } as f64 * D;
        A * (2.0 * PI * t / P).sin()
    });
    Surface::new(z, Some(D), Some(D)).unwrap()
}

fn opts(window: Window) -> PsdOptions {
    PsdOptions {
        window,
        remove: vec![Term::Piston],
        ..PsdOptions::default()
    }
}

fn band_1d(psd: &Psd1d) -> f64 {
    band_rms(psd, 0.8 / P, 1.2 / P)
}

/// Mean square of the map after per-row mean removal (the 1-D X detrend), brute force.
fn row_detrended_mean_square(s: &Surface) -> f64 {
    let h = s.heights_nm();
    let mut acc = 0.0;
    for row in h.rows() {
        let m = row.mean().unwrap();
        acc += row.iter().map(|v| (v - m).powi(2)).sum::<f64>();
    }
    acc / h.len() as f64
}

fn total(psd: &Psd1d) -> f64 {
    psd.psd_nm2_mm.iter().sum::<f64>() * psd.df_per_mm
}

#[test]
fn x_psd_hann_band_rms_is_a_over_root_two() {
    let s = sine(64, 600, false);
    let p = psd_x(&s, &opts(Window::Hann)).unwrap();
    assert!(
        (band_1d(&p) - expected_rms()).abs() < 1e-9,
        "{}",
        band_1d(&p)
    );
    // The default options (piston + tilt removed first) stay within 0.05 %.
    let p = psd_x(&s, &PsdOptions::default()).unwrap();
    assert!(
        (band_1d(&p) / expected_rms() - 1.0).abs() < 5e-4,
        "{}",
        band_1d(&p)
    );
}

#[test]
fn x_psd_parseval_exact_without_window_and_within_0_2_percent_with_hann() {
    // A sine plus seeded noise so the check is not specific to one tone.
    let mut r = Rng::new(1);
    let base = sine(40, 600, false);
    let z = base.heights_nm().mapv(|v| v + 2.0 * r.normal() + 0.5);
    let s = Surface::new(z, Some(D), Some(D)).unwrap();
    let ms = row_detrended_mean_square(&s);
    let p = psd_x(
        &s,
        &PsdOptions {
            remove: vec![],
            ..opts(Window::None)
        },
    )
    .unwrap();
    assert!(
        (total(&p) / ms - 1.0).abs() < 1e-12,
        "{} vs {ms}",
        total(&p)
    );
    let p = psd_x(
        &s,
        &PsdOptions {
            remove: vec![],
            ..opts(Window::Hann)
        },
    )
    .unwrap();
    assert!((total(&p) / ms - 1.0).abs() < 2e-3, "{} vs {ms}", total(&p));
}

#[test]
fn peak_bin_is_a_squared_over_two_enbw_df() {
    let s = sine(8, 600, false);
    for (w, expect) in [(Window::Hann, 2000.0), (Window::None, 3000.0)] {
        let p = psd_x(&s, &opts(w)).unwrap();
        let k0 = 20; // 1/3 mm^-1 with df = 1/60 mm^-1
        assert!((p.freq_per_mm[k0] - 1.0 / P).abs() < 1e-12);
        let formula = A * A / (2.0 * p.enbw_bins * p.df_per_mm);
        assert!(
            (p.psd_nm2_mm[k0] - expect).abs() < 1e-8,
            "{w}: {}",
            p.psd_nm2_mm[k0]
        );
        assert!((formula - expect).abs() < 1e-8);
    }
}

#[test]
fn two_d_parseval_and_annulus_band_rms() {
    let mut r = Rng::new(2);
    let base = sine(600, 600, false);
    let noisy = base
        .with_heights(base.heights_nm().mapv(|v| v + r.normal()))
        .unwrap();
    let p2 = psd_2d(
        &noisy,
        &PsdOptions {
            remove: vec![],
            ..opts(Window::None)
        },
    )
    .unwrap();
    let h = noisy.heights_nm();
    let m = h.mean().unwrap();
    let ms = h.iter().map(|v| (v - m).powi(2)).sum::<f64>() / h.len() as f64;
    assert!((p2.total_power() / ms - 1.0).abs() < 1e-12);
    let p2 = psd_2d(&base, &opts(Window::Hann)).unwrap();
    let ann = p2.annulus_rms(0.8 / P, 1.2 / P);
    assert!((ann - expected_rms()).abs() < 1e-9, "{ann}");
}

#[test]
fn y_psd_equals_folded_2d_marginal_to_1e_12() {
    let s = sine(600, 600, true);
    for w in [Window::Hann, Window::None] {
        let o = opts(w);
        let y = psd_y(&s, &o).unwrap();
        let m = psd_2d(&s, &o).unwrap().marginal_y();
        let peak = y.psd_nm2_mm.iter().cloned().fold(0.0, f64::max);
        assert_eq!(y.len(), m.len());
        for (a, b) in y.psd_nm2_mm.iter().zip(&m.psd_nm2_mm) {
            assert!((a - b).abs() <= 1e-12 * peak, "{w}: {a} vs {b}");
        }
        assert!((band_1d(&y) - expected_rms()).abs() < 1e-9);
    }
    // The X marginal of the 2-D PSD folds the same way.
    let s = sine(600, 600, false);
    let o = opts(Window::Hann);
    let x = psd_x(&s, &o).unwrap();
    let m = psd_2d(&s, &o).unwrap().marginal_x();
    let peak = x.psd_nm2_mm.iter().cloned().fold(0.0, f64::max);
    for (a, b) in x.psd_nm2_mm.iter().zip(&m.psd_nm2_mm) {
        assert!((a - b).abs() <= 1e-12 * peak);
    }
}

#[test]
fn non_square_400_by_600_uses_each_axis_own_df() {
    let s = sine(400, 600, false);
    let p = psd_x(&s, &opts(Window::Hann)).unwrap();
    assert!(
        (band_1d(&p) - expected_rms()).abs() < 1e-9,
        "{}",
        band_1d(&p)
    );
    let t = sine(600, 400, true);
    let p = psd_y(&t, &opts(Window::Hann)).unwrap();
    assert!((band_1d(&p) - expected_rms()).abs() < 1e-9);
    let p2 = psd_2d(&s, &opts(Window::Hann)).unwrap();
    assert!((p2.annulus_rms(0.8 / P, 1.2 / P) - expected_rms()).abs() < 1e-9);
    // The wrong answer the spec warns about, for contrast: one df for both axes.
    let wrong = (band_1d(&p).powi(2) * 600.0 / 400.0).sqrt();
    assert!((wrong - 8.660).abs() < 1e-3);
}

/// 56 mm circular aperture centred on a 60 mm map, 2 % seeded random dropouts.
fn aperture_with_dropouts(along_y: bool, seed: u64) -> Surface {
    let s = sine(600, 600, along_y);
    let mut r = Rng::new(seed);
    let c = 299.5 * D;
    let valid = Array2::from_shape_fn((600, 600), |(i, j)| {
        let (x, y) = (j as f64 * D - c, i as f64 * D - c);
        x * x + y * y <= 28.0 * 28.0 && r.uniform() >= 0.02
    });
    s.with_valid(valid).unwrap()
}

#[test]
fn circular_aperture_with_two_percent_dropouts_within_half_a_percent() {
    for (along_y, seed) in [(false, 7), (true, 8), (false, 9)] {
        let s = aperture_with_dropouts(along_y, seed);
        let o = PsdOptions::default();
        let p = if along_y {
            psd_y(&s, &o)
        } else {
            psd_x(&s, &o)
        }
        .unwrap();
        let b = band_1d(&p);
        eprintln!("aperture along_y={along_y} seed={seed}: band RMS {b:.5} nm");
        assert!(
            (b / expected_rms() - 1.0).abs() < 5e-3,
            "along_y={along_y}: {b}"
        );
    }
}

#[test]
fn sine_height_parameters() {
    let s = sine(10, 600, false);
    let st = height_stats(&s).unwrap();
    assert!((st.rms_nm - expected_rms()).abs() < 1e-9);
    assert!(st.ssk.unwrap().abs() < 1e-9);
    assert!((st.sku.unwrap() - 1.5).abs() < 1e-9);
}

#[test]
fn radial_integral_equals_mean_square_and_forms_are_consistent() {
    let mut r = Rng::new(4);
    let base = sine(300, 500, false);
    let s = base
        .with_heights(base.heights_nm().mapv(|v| v + r.normal()))
        .unwrap();
    let p2 = psd_2d(&s, &opts(Window::None)).unwrap();
    let rad = p2.radial();
    let integral: f64 = rad.integrated_nm2_mm.iter().sum::<f64>() * rad.dfr_per_mm;
    let h = s.heights_nm();
    let m = h.mean().unwrap();
    let ms = h.iter().map(|v| (v - m).powi(2)).sum::<f64>() / h.len() as f64;
    assert!((integral / ms - 1.0).abs() < 1e-12, "{integral} vs {ms}");
    let npix: usize = rad.counts.iter().sum();
    assert_eq!(npix, 300 * 500);
    // integrated = average * count * dfx dfy / dfr, bin by bin.
    for b in 0..rad.counts.len() {
        let via_avg = rad.average_nm2_mm2[b].unwrap_or(0.0)
            * rad.counts[b] as f64
            * p2.dfx_per_mm
            * p2.dfy_per_mm
            / rad.dfr_per_mm;
        assert!(
            (via_avg - rad.integrated_nm2_mm[b]).abs()
                <= 1e-12 * rad.integrated_nm2_mm[b].max(1e-30)
        );
    }
}

#[test]
fn conversions_keep_each_tools_own_mean_square_identity() {
    let s = sine(16, 600, false);
    let p = psd_x(&s, &opts(Window::None)).unwrap();
    let ms = total(&p);
    let g = to_gwyddion_w1(&p);
    let dk = g.q_rad_per_mm[1] - g.q_rad_per_mm[0];
    // Gwyddion: W1 is a density over both signs of K; DC holds nothing after detrending.
    let gw: f64 = 2.0 * g.values_nm2_mm.iter().skip(1).sum::<f64>() * dk + g.values_nm2_mm[0] * dk;
    assert!((gw / ms - 1.0).abs() < 1e-12);
    // SurfaceTopography: mean square = (1/pi) * integral_0^inf C1D dq.
    let c = to_surfacetopography_c1d(&p);
    let st: f64 = c.values_nm2_mm.iter().sum::<f64>() * dk / PI;
    assert!((st / ms - 1.0).abs() < 1e-12);
    // The spec's relations at one bin: P1 = 4 pi W1 = 2 C1D.
    let k = 20;
    assert!((p.psd_nm2_mm[k] - 4.0 * PI * g.values_nm2_mm[k]).abs() < 1e-9);
    assert!((p.psd_nm2_mm[k] - 2.0 * c.values_nm2_mm[k]).abs() < 1e-9);
}

#[test]
fn ripple_on_a_known_ripple_and_on_noise() {
    let mut r = Rng::new(12);
    let base = sine(600, 400, true);
    let s = base
        .with_heights(base.heights_nm().mapv(|v| v + r.normal()))
        .unwrap();
    let rp = ripple(&s, P, &PsdOptions::default()).unwrap();
    assert!(
        (rp.sigma1_nm / expected_rms() - 1.0).abs() < 5e-3,
        "{}",
        rp.sigma1_nm
    );
    assert!((rp.a_eq_nm / A - 1.0).abs() < 5e-3);
    assert!(
        rp.detected && rp.prominence_db > 20.0,
        "{}",
        rp.prominence_db
    );
    assert!(rp.y_over_x.unwrap() > 10.0);
    assert_eq!(rp.harmonics.len(), 5);
    assert!(rp.sigma_total_nm >= rp.sigma1_nm);

    let noise = Array2::from_shape_fn((600, 400), |_| 3.0 * r.normal());
    let n = Surface::new(noise, Some(D), Some(D)).unwrap();
    let rn = ripple(&n, P, &PsdOptions::default()).unwrap();
    eprintln!(
        "ripple: sigma1 {:.5} prominence {:.2} dB; noise prominence {:.2} dB",
        rp.sigma1_nm, rp.prominence_db, rn.prominence_db
    );
    assert!(
        !rn.detected && rn.prominence_db < PROMINENCE_THRESHOLD_DB,
        "{}",
        rn.prominence_db
    );
}

#[test]
fn band_profile_locates_ripple_rows() {
    // Ripple along X only in the upper half of the rows.
    let s = sine(64, 600, false);
    let z = Array2::from_shape_fn(
        (64, 600),
        |(i, j)| if i < 32 { s.heights_nm()[(i, j)] } else { 0.0 },
    );
    let s = Surface::new(z, Some(D), Some(D)).unwrap();
    let o = PsdOptions {
        remove: vec![],
        ..PsdOptions::default()
    };
    let prof = band_rms_profile(&s, Axis::X, 0.8 / P, 1.2 / P, &o).unwrap();
    assert_eq!(prof.len(), 64);
    assert!((prof[0].unwrap() - expected_rms()).abs() < 1e-9);
    assert!(prof[40].unwrap() < 1e-9);
}
