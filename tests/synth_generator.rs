//! The synthetic-run generator itself (crates/calibrate/src/synth), against analytic values:
//! the power-law surface's PSD slope, the deposited removal against rate x dwell, the spot
//! depth, seeded determinism, and null twins sharing surface and noise. Fast (a few seconds).

use bonnetlab::calibrate::synth::field::power_law;
use bonnetlab::calibrate::synth::true_tif::TrueTif;
use bonnetlab::calibrate::synth::{generate, InitialSurface, Injected, SynthConfig};
use bonnetlab::process::tif::{GaussianTif, RateField};
use bonnetlab::process::Grid;
use bonnetlab::spectrum::{psd_x, PsdOptions};
use bonnetlab::surface::rng::Rng;
use bonnetlab::surface::Surface;

/// Least-squares slope of log PSD against log f over `f1..f2` (cycles/mm).
fn loglog_slope(f: &[f64], p: &[f64], f1: f64, f2: f64) -> f64 {
    let pts: Vec<(f64, f64)> = f
        .iter()
        .zip(p)
        .filter(|(&f, &p)| f >= f1 && f <= f2 && p > 0.0)
        .map(|(&f, &p)| (f.ln(), p.ln()))
        .collect();
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

#[test]
fn power_law_surface_has_the_requested_one_sided_psd_slope() {
    // 512 x 512 at 0.1 mm: the 1-D one-sided PSD along X (the project's PSD, Hann window)
    // between 10 cycles per map and a third of Nyquist.
    let g = Grid::new(512, 512, 0.1, 0.1, 0.0, 0.0).unwrap();
    for (seed, beta) in [(1u64, 1.8), (2, 2.2), (3, 2.6)] {
        let h = power_law(&mut Rng::new(seed), &g, beta, 140.0);
        let rms = (h.iter().map(|v| v * v).sum::<f64>() / h.len() as f64).sqrt();
        assert!((rms - 140.0).abs() < 1e-6, "rms {rms}");
        let s = Surface::new(h, Some(0.1), Some(0.1)).unwrap();
        let p = psd_x(&s, &PsdOptions::default()).unwrap();
        let slope = loglog_slope(&p.freq_per_mm, &p.psd_nm2_mm, 10.0 / 51.2, 5.0 / 3.0);
        assert!(
            (slope + beta).abs() < 0.15,
            "exponent {beta}: fitted PSD slope {slope}"
        );
    }
}

fn gaussian() -> GaussianTif {
    GaussianTif {
        sigma_mm: 2.0,
        diameter_mm: 14.0,
        peak_rate_nm_per_s: 30.0,
    }
}

/// A flat part (zero surface): the dwell density is uniform, D = (1/(vmax p) + 1/(vmin p)) / 2.
fn flat(effects: Vec<Injected>) -> SynthConfig {
    SynthConfig {
        rows: 121,
        cols: 101,
        pixel_mm: 0.5,
        surface: InitialSurface::Smooth {
            figure_rms_nm: 0.0,
            msf_rms_nm: 0.0,
        },
        tif: TrueTif::Gaussian(gaussian()),
        noise_nm: 0.0,
        setup_tilt_nm: 0.0,
        setup_piston_nm: 0.0,
        dropout_fraction: 0.0,
        spot_noise_nm: 0.0,
        effects,
        ..SynthConfig::default()
    }
}

#[test]
fn deposited_removal_is_volume_rate_times_dwell_density() {
    let cfg = flat(vec![]);
    let d_density = 0.5 * (1.0 / (12.0 * 3.0) + 1.0 / (2.0 * 3.0));
    let vol = gaussian().volume_rate_nm_mm2_per_s().unwrap();
    let expect = vol * d_density;
    // Interior rows spanning whole pitches (the raster ripple averages out): rows 20..104
    // (42 mm = 14 pitches), columns 20..80.
    let mean = |r: &ndarray::Array2<f64>, i0: usize, i1: usize| {
        let v = r.slice(ndarray::s![i0..i1, 20..80]);
        v.sum() / v.len() as f64
    };
    let run = generate(&cfg).unwrap();
    let m = mean(&run.true_removal_nm, 20, 104);
    assert!(
        (m / expect - 1.0).abs() < 2e-3,
        "mean removal {m} nm vs {expect} nm"
    );
    // A rate step of +20 % at mid-run: lines well before it remove V D, lines well after
    // V D 1.2 (the raster runs in +y, so early lines are low rows).
    let step = generate(&flat(vec![Injected::RateStep {
        at_tau: 0.5,
        fraction: 0.2,
    }]))
    .unwrap();
    let (lo, hi) = (
        mean(&step.true_removal_nm, 8, 32),
        mean(&step.true_removal_nm, 92, 116),
    );
    assert!(
        (lo / expect - 1.0).abs() < 2e-3,
        "before the step {lo} vs {expect}"
    );
    assert!(
        (hi / (1.2 * expect) - 1.0).abs() < 2e-3,
        "after the step {hi} vs {}",
        1.2 * expect
    );
    // A working spot 10 % wider removes 1.21 times the volume at the same dwell.
    let wide = generate(&flat(vec![Injected::TifScale { scale: 1.1 }])).unwrap();
    let w = mean(&wide.true_removal_nm, 20, 104);
    assert!(
        (w / (1.21 * expect) - 1.0).abs() < 3e-3,
        "{w} vs {}",
        1.21 * expect
    );
    // The measured spot: depth dwell x peak at its centre, on the map pixel.
    let s = &run.spot;
    let (r, c) = s.dim();
    let centre = s.get(r / 2, c / 2).unwrap();
    assert!((3.0 - centre - 20.0 * 30.0).abs() < 1e-9);
}

#[test]
fn runs_are_seeded_and_null_twins_share_surface_and_noise() {
    let cfg = SynthConfig {
        rows: 80,
        cols: 90,
        surface: InitialSurface::PowerLaw {
            exponent: 2.2,
            rms_nm: 140.0,
        },
        noise_nm: 1.0,
        dropout_discs: 3,
        aperture_diameter_mm: Some(38.0),
        effects: vec![Injected::DirectionRate { fraction: 0.06 }],
        ..SynthConfig::default()
    };
    let a = generate(&cfg).unwrap();
    let b = generate(&cfg).unwrap();
    assert_eq!(a.before.heights_nm(), b.before.heights_nm());
    assert_eq!(a.after.heights_nm(), b.after.heights_nm());
    assert_eq!(a.after.valid(), b.after.valid());
    assert_eq!(a.path, b.path);
    let other = generate(&SynthConfig {
        seed: 2,
        ..cfg.clone()
    })
    .unwrap();
    assert_ne!(a.before.heights_nm(), other.before.heights_nm());
    // The null twin: same surface, noise, path and masks; only the removal differs.
    let null = generate(&SynthConfig {
        effects: vec![],
        ..cfg.clone()
    })
    .unwrap();
    assert_eq!(a.before.heights_nm(), null.before.heights_nm());
    assert_eq!(a.path, null.path);
    assert_eq!(a.after.valid(), null.after.valid());
    let diff = (&a.true_removal_nm - &null.true_removal_nm)
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        diff > 0.5,
        "a +-6 % direction rate changes the removal: {diff} nm"
    );
    // Round aperture and circular dropouts: masked pixels exist in the after map only
    // beyond the aperture's.
    let nb = a.before.valid().iter().filter(|v| !**v).count();
    let na = a.after.valid().iter().filter(|v| !**v).count();
    assert!(na > nb, "after {na} invalid vs before {nb}");
    // The log is sampled at 10 Hz.
    assert!(a.path.t_s.windows(2).all(|w| w[1] - w[0] <= 0.1 + 1e-9));
}

/// The instrument's drift (`drift_nm`): the after map gains a smooth field of the requested
/// RMS, and nothing else changes (the before map, the removal, the masks and the white noise
/// are the drift-free twin's). Smooth: its pixel-to-pixel differences are a small fraction of
/// its RMS, as a white field's would be about 1.4x.
#[test]
fn the_drift_is_a_smooth_field_added_to_the_after_map_alone() {
    let cfg = SynthConfig {
        rows: 120,
        cols: 120,
        surface: InitialSurface::PowerLaw {
            exponent: 2.2,
            rms_nm: 140.0,
        },
        noise_nm: 1.0,
        ..SynthConfig::default()
    };
    let still = generate(&cfg).unwrap();
    let drifting = generate(&SynthConfig {
        drift_nm: 1.5,
        drift_correlation_mm: 20.0,
        ..cfg.clone()
    })
    .unwrap();
    assert_eq!(still.before.heights_nm(), drifting.before.heights_nm());
    assert_eq!(still.after.valid(), drifting.after.valid());
    assert_eq!(still.true_removal_nm, drifting.true_removal_nm);
    // On the valid pixels (the map's dropouts hold no height).
    let d = drifting.after.heights_nm() - still.after.heights_nm();
    let ok = still.after.valid();
    let vals: Vec<f64> = d
        .iter()
        .zip(ok.iter())
        .filter(|(_, v)| **v)
        .map(|(h, _)| *h)
        .collect();
    let n = vals.len() as f64;
    assert!(n > 0.9 * d.len() as f64);
    let mean = vals.iter().sum::<f64>() / n;
    let rms = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    assert!((rms - 1.5).abs() < 0.05 * 1.5, "drift RMS {rms}");
    let mut steps = Vec::new();
    for i in 0..d.nrows() {
        for j in 1..d.ncols() {
            if ok[(i, j)] && ok[(i, j - 1)] {
                steps.push(d[(i, j)] - d[(i, j - 1)]);
            }
        }
    }
    let step_rms = (steps.iter().map(|v| v * v).sum::<f64>() / steps.len() as f64).sqrt();
    assert!(
        step_rms < 0.1 * rms,
        "pixel steps {step_rms} nm vs RMS {rms} nm"
    );
}
