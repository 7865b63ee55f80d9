//! Areal band split (`band_split`) against independent truths: a known sine on square,
//! rectangular and round apertures with dropouts (A = 10 nm, p = 3 mm as in the spec's
//! self-check, on a 0.05 mm grid so that both default edges cut: band RMS A / sqrt 2 =
//! 7.0711 nm), the quadrature identity on textured maps with power down to the pixel scale,
//! sinusoids in each band on a full rectangle (the windowless 2-D PSD's annulus sums as the
//! reference) and on a round aperture with dropouts and texture (their power summed over the
//! aperture pixel by pixel as the truth), two real maps of shared/data (a brute-force
//! least-squares projection solved here as the reference), and absent-with-a-reason for bands
//! a map cannot resolve.

#[path = "../../../tests/common/shared_data.rs"]
mod shared_data;

use std::f64::consts::{PI, SQRT_2};

use bonnetlab_spectrum::areal::{lowpass, AMBIGUOUS_CROSS_FRACTION};
use bonnetlab_spectrum::*;
use bonnetlab_surface::{height_stats, remove_terms, rng::Rng, Surface, Term};
use ndarray::Array2;

const A: f64 = 10.0;
const P: f64 = 3.0;
const D: f64 = 0.05;

/// Sine along X (or Y) plus, optionally, a figure term and fine noise, on an aperture.
fn sine_map(rows: usize, cols: usize, along_y: bool, round: bool, dropouts: f64) -> Surface {
    let mut r = Rng::new(rows as u64 * 31 + cols as u64);
    let (cy, cx) = (0.5 * (rows as f64 - 1.0), 0.5 * (cols as f64 - 1.0));
    let rad = 0.5 * rows.min(cols) as f64 - 1.0;
    let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
        let t = if along_y { i } else { j } as f64 * D;
        A * (2.0 * PI * t / P).sin()
    });
    let valid = Array2::from_shape_fn((rows, cols), |(i, j)| {
        let inside = !round || {
            let (y, x) = (i as f64 - cy, j as f64 - cx);
            (x * x + y * y).sqrt() <= rad
        };
        inside && r.uniform() >= dropouts
    });
    Surface::with_mask(z, valid, Some(D), Some(D)).unwrap()
}

#[test]
fn sine_band_rms_within_half_a_percent_on_square_rectangular_and_round_apertures() {
    // Default edges [1/33, 1/0.12] 1/mm; f0 = 1/3 1/mm sits 11x above F1 and 25x below F2.
    let expected = A / SQRT_2;
    for (rows, cols, along_y, round, drop) in [
        (800, 800, false, false, 0.0),
        (600, 800, false, false, 0.0),
        (800, 600, true, false, 0.02),
        (800, 800, false, true, 0.02),
        (800, 800, true, true, 0.02),
    ] {
        let s = sine_map(rows, cols, along_y, round, drop);
        let b = band_split(&s, &[Term::Piston], BAND_EDGES_DEFAULT_PER_MM).unwrap();
        let msf = b.msf_rms_nm.unwrap();
        eprintln!(
            "{rows}x{cols} along_y={along_y} round={round} dropouts={drop}: msf {msf:.5} nm, \
             figure {:?}, fine {:?}, cross {:.2e}",
            b.figure_rms_nm, b.fine_rms_nm, b.cross_term_fraction
        );
        assert!(
            (msf / expected - 1.0).abs() < 5e-3,
            "{rows}x{cols} round={round}: {msf} vs {expected}"
        );
        let sum = b.figure_rms_nm.unwrap().powi(2) + msf * msf + b.fine_rms_nm.unwrap().powi(2);
        assert!((sum.sqrt() / b.total_rms_nm - 1.0).abs() < 1e-9);
    }
}

#[test]
fn sine_on_a_coarse_grid_has_no_fine_band() {
    // On a 0.1 mm grid, F2 = 8.33 1/mm is above Nyquist (5 1/mm): fine is absent with a reason
    // and MSF runs from F1 to Nyquist.
    let mut s = sine_map(560, 560, false, true, 0.02);
    s.dx_mm = Some(0.1);
    s.dy_mm = Some(0.1);
    let b = band_split(&s, &[Term::Piston, Term::Tilt], BAND_EDGES_DEFAULT_PER_MM).unwrap();
    assert!(b.fine_rms_nm.is_none());
    assert!(b.fine_reason.as_deref().unwrap().contains("Nyquist"));
    let msf = b.msf_rms_nm.unwrap();
    let fig = b.figure_rms_nm.unwrap();
    // The sine has period 3 mm on this grid only if x is read with dx 0.05: here its period
    // is 6 mm, still 5.5x above F1.
    eprintln!("coarse grid: msf {msf:.5} figure {fig:.5}");
    assert!((msf / (A / SQRT_2) - 1.0).abs() < 5e-3, "{msf}");
    assert!(((fig * fig + msf * msf).sqrt() / b.total_rms_nm - 1.0).abs() < 1e-9);
}

/// A map with power down to the pixel scale: a power-law (1-D slope -2) random field from
/// random-phase Fourier modes, a figure term and 1 % dropouts, on a round or full aperture.
fn textured(n: usize, round: bool, seed: u64) -> Surface {
    let mut r = Rng::new(seed);
    let modes: Vec<(f64, f64, f64, f64)> = (0..600)
        .map(|_| {
            // log-uniform radial frequency from 1/L to Nyquist, amplitude ~ f^-1
            let f = (1.0 / (n as f64 * D)) * (0.5 * n as f64).powf(r.uniform());
            let th = 2.0 * PI * r.uniform();
            (
                f * th.cos(),
                f * th.sin(),
                20.0 / (f * n as f64 * D).max(1.0),
                2.0 * PI * r.uniform(),
            )
        })
        .collect();
    let c = 0.5 * (n as f64 - 1.0);
    let z = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * D, i as f64 * D);
        let u = (j as f64 - c) / c;
        let mut v = 50.0 * u * u;
        for &(fx, fy, a, ph) in &modes {
            v += a * (2.0 * PI * (fx * x + fy * y) + ph).cos();
        }
        v + r.normal()
    });
    let valid = Array2::from_shape_fn((n, n), |(i, j)| {
        let (y, x) = (i as f64 - c, j as f64 - c);
        (!round || (x * x + y * y).sqrt() <= c) && r.uniform() >= 0.01
    });
    Surface::with_mask(z, valid, Some(D), Some(D)).unwrap()
}

#[test]
fn bands_add_in_quadrature_to_sq_on_textured_maps() {
    for (round, seed) in [(false, 1), (true, 2)] {
        let s = textured(200, round, seed);
        for terms in [
            vec![Term::Piston],
            vec![Term::Piston, Term::Tilt, Term::Power],
        ] {
            let b = band_split(&s, &terms, (0.2, 2.0)).unwrap();
            let (r, _) = remove_terms(&s, &terms).unwrap();
            let sq = height_stats(&r).unwrap().rms_nm;
            let parts = [b.figure_rms_nm, b.msf_rms_nm, b.fine_rms_nm].map(Option::unwrap);
            let sum: f64 = parts.iter().map(|v| v * v).sum();
            eprintln!(
                "round={round} {terms:?}: parts {parts:?}, Sq {sq:.4}, cross {:.3e}",
                b.cross_term_fraction
            );
            assert!((b.total_rms_nm / sq - 1.0).abs() < 1e-9);
            assert!((sum.sqrt() / sq - 1.0).abs() < 1e-9);
            // Every band holds power on this map.
            assert!(parts.iter().all(|v| *v > 0.1));
            // The hole fill keeps the components close to orthogonal on the round aperture
            // (cross terms, summed over band pairs, 9.6e-3 and 1.5e-2 with the front-by-front
            // fill; the multi-scale normalised Gaussian fill it replaced left 3.4e-2 and
            // 3.7e-2); a full rectangle with dropouts, 3e-4. Below the ambiguity threshold.
            let limit = if round { 0.02 } else { 1e-3 };
            assert!(b.cross_term_fraction < limit, "{}", b.cross_term_fraction);
            assert!(b.cross_term_fraction < AMBIGUOUS_CROSS_FRACTION && b.ambiguity.is_none());
        }
    }
}

#[test]
fn bands_outside_the_measured_range_are_absent_with_a_reason() {
    // A micron-scale map: 70 x 70 pixels of 1 um (field 0.07 mm): both default edges lie
    // below the lowest measured frequency (14.3 1/mm).
    let mut r = Rng::new(3);
    let z = Array2::from_shape_fn((70, 70), |_| r.normal());
    let s = Surface::new(z, Some(0.001), Some(0.001)).unwrap();
    let b = band_split(&s, &[Term::Piston], BAND_EDGES_DEFAULT_PER_MM).unwrap();
    assert!(b.figure_rms_nm.is_none() && b.msf_rms_nm.is_none());
    assert!(b
        .figure_reason
        .as_deref()
        .unwrap()
        .contains("the valid field is 0.07 mm long"));
    assert!(b.msf_reason.as_deref().unwrap().contains("lowest measured"));
    assert!((b.fine_rms_nm.unwrap() / b.total_rms_nm - 1.0).abs() < 1e-12);
    let j = serde_json::to_value(&b).unwrap();
    assert!(j["msf_rms_nm"].is_null() && j["msf_reason"].is_string());
    // Unknown pixel size: every band absent, Sq still there.
    let s = Surface::new(
        Array2::from_shape_fn((20, 20), |(i, j)| (i * j) as f64),
        None,
        None,
    )
    .unwrap();
    let b = band_split(&s, &[Term::Piston], BAND_EDGES_DEFAULT_PER_MM).unwrap();
    assert!(b
        .bands()
        .iter()
        .all(|(_, v, why)| v.is_none() && why.is_some()));
    assert!(b.total_rms_nm > 0.0);
}

/// Band index (0 figure, 1 MSF, 2 fine) of a radial frequency for edges (f1, f2).
fn band_of(f: f64, (f1, f2): (f64, f64)) -> usize {
    if f < f1 {
        0
    } else if f < f2 {
        1
    } else {
        2
    }
}

/// Checks every split must pass: bands >= 0, none above Sq, squares adding up to Sq^2.
fn assert_adds_up(b: &ArealBands, what: &str) -> [f64; 3] {
    let parts = [b.figure_rms_nm, b.msf_rms_nm, b.fine_rms_nm].map(|v| v.unwrap_or(0.0));
    let sum: f64 = parts.iter().map(|v| v * v).sum();
    let total = b.total_rms_nm;
    for v in parts {
        assert!(v.is_finite() && v >= 0.0, "{what}: {parts:?}");
        assert!(v <= total * (1.0 + 1e-12), "{what}: {v} above Sq {total}");
    }
    assert!(
        (sum / (total * total) - 1.0).abs() < 1e-9,
        "{what}: bands {parts:?} add up to {} vs Sq {total}",
        sum.sqrt()
    );
    parts
}

/// A sinusoid with whole periods along X (`mx`) and Y (`my`) over the field, A = 10 nm.
fn whole_period_sine(rows: usize, cols: usize, mx: f64, my: f64, phase: f64) -> Array2<f64> {
    Array2::from_shape_fn((rows, cols), |(i, j)| {
        A * (2.0 * PI * (mx * j as f64 / cols as f64 + my * i as f64 / rows as f64) + phase).sin()
    })
}

/// Issue (review of the areal split, defect 2): on a full rectangle a sinusoid keeps its power
/// in its own band, along X, along Y and obliquely, in each band. Whole periods make it a pure
/// frequency of the field, so the truth is exact: A / sqrt 2 in its band, nothing elsewhere.
#[test]
fn whole_period_sinusoids_stay_in_their_own_band_on_a_full_rectangle() {
    let (rows, cols, d) = (256, 320, 0.1);
    let edges = (0.4, 2.5);
    // (periods along X, periods along Y): fields 32 mm (X) and 25.6 mm (Y).
    let cases = [
        (5.0, 0.0),
        (0.0, 4.0),
        (3.0, 3.0),
        (32.0, 0.0),
        (0.0, 26.0),
        (24.0, 17.0),
        (122.0, 0.0),
        (0.0, 97.0),
        (96.0, 60.0),
    ];
    for (mx, my) in cases {
        let f = (mx / (cols as f64 * d)).hypot(my / (rows as f64 * d));
        let band = band_of(f, edges);
        let s = Surface::new(whole_period_sine(rows, cols, mx, my, 0.7), Some(d), Some(d)).unwrap();
        let b = band_split(&s, &[Term::Piston], edges).unwrap();
        let parts = assert_adds_up(&b, &format!("({mx}, {my})"));
        let total: f64 = parts.iter().map(|v| v * v).sum();
        let leak = 1.0 - parts[band].powi(2) / total;
        eprintln!(
            "periods ({mx}, {my}), |f| {f:.4} 1/mm: bands {parts:?}, leak {leak:.1e}; {}",
            b.method.rsplit("this map: ").next().unwrap_or("")
        );
        assert!(
            leak < 1e-4,
            "({mx}, {my}): {leak:e} of the power left band {band}"
        );
        assert!((parts[band] / (A / SQRT_2) - 1.0).abs() < 1e-4, "{parts:?}");
    }
}

/// The reviewer's case: a 10 nm sine along Y of period 2 mm on a full 30 mm square, edges
/// 0.05 and 2 1/mm. It gave 0.298 / 7.064 / 0.070 nm (0.18 % of its power outside MSF); the
/// windowless 2-D PSD's annulus sums (metrology.md: band RMS = bin sums) give 0 / 7.0711 / 0.
#[test]
fn a_sine_along_y_matches_the_windowless_psd_annulus_sums() {
    let (n, d) = (300, 0.1);
    let z = Array2::from_shape_fn((n, n), |(i, _)| A * (2.0 * PI * i as f64 * d / 2.0).sin());
    let s = Surface::new(z, Some(d), Some(d)).unwrap();
    let edges = (0.05, 2.0);
    let b = band_split(&s, &[Term::Piston], edges).unwrap();
    let parts = assert_adds_up(&b, "sine along Y");
    let opts = PsdOptions {
        window: Window::None,
        remove: vec![Term::Piston],
        ..PsdOptions::default()
    };
    let p = psd_2d(&s, &opts).unwrap();
    let psd = [
        p.annulus_rms(0.0, edges.0 - 1e-9),
        p.annulus_rms(edges.0, edges.1 - 1e-9),
        p.annulus_rms(edges.1, f64::INFINITY),
    ];
    eprintln!("sine along Y: bands {parts:?}, PSD annulus sums {psd:?}");
    for k in 0..3 {
        assert!(
            (parts[k] - psd[k]).abs() < 1e-6,
            "band {k}: {parts:?} vs {psd:?}"
        );
    }
    assert!((parts[1] / (A / SQRT_2) - 1.0).abs() < 1e-9);
}

/// Without whole periods a finite record of a sinusoid is not a pure frequency under any
/// windowless orthogonal split: the limits the module documents, measured (axis-aligned: the
/// mirrored border's leak, a few 0.1 %; oblique: the X and Y leaks multiply).
#[test]
fn generic_sinusoids_on_a_full_rectangle_leak_within_the_documented_limits() {
    let (rows, cols, d) = (256, 320, 0.1);
    let edges = (0.4, 2.5);
    let mut r = Rng::new(21);
    let (mut worst_axis, mut worst_oblique): (f64, f64) = (0.0, 0.0);
    for k in 0..12 {
        // MSF, 2.5 to 5 times above F1 and 2 times below F2 at least.
        let f0 = 1.0 + 0.25 * r.uniform();
        let phase = 2.0 * PI * r.uniform();
        let angle = if k % 2 == 0 {
            0.5 * PI * (k % 4) as f64 / 2.0
        } else {
            0.3 + 0.9 * r.uniform()
        };
        let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
            let (x, y) = (j as f64 * d, i as f64 * d);
            A * (2.0 * PI * f0 * (angle.cos() * x + angle.sin() * y) + phase).sin()
        });
        let s = Surface::new(z, Some(d), Some(d)).unwrap();
        let b = band_split(&s, &[Term::Piston], edges).unwrap();
        let parts = assert_adds_up(&b, "generic sinusoid");
        let leak = 1.0 - parts[1].powi(2) / parts.iter().map(|v| v * v).sum::<f64>();
        if k % 2 == 0 {
            worst_axis = worst_axis.max(leak);
        } else {
            worst_oblique = worst_oblique.max(leak);
        }
        eprintln!("f0 {f0:.3} angle {angle:.2}: bands {parts:?}, leak {leak:.1e}");
    }
    assert!(worst_axis < 1e-2, "axis-aligned leak {worst_axis:e}");
    assert!(worst_oblique < 2e-3, "oblique leak {worst_oblique:e}");
}

/// A sinusoid in one band on a round aperture of 90 % of the side with 2 % random dropouts,
/// plus a power-law texture (amplitude ~ 1/f) from above F1 down to the pixel scale. Returns
/// the surface and the truth per band: each component's mean square about its mean over the
/// valid pixels, summed pixel by pixel (the texture's modes are placed away from the edges).
fn round_sine_with_texture(f0: f64, angle: f64, edges: (f64, f64)) -> (Surface, [f64; 3]) {
    let (n, d) = (256, 0.1);
    let mut r = Rng::new(77 + (100.0 * f0) as u64);
    let c = 0.5 * (n as f64 - 1.0);
    let valid = Array2::from_shape_fn((n, n), |(i, j)| {
        (i as f64 - c).hypot(j as f64 - c) <= 0.45 * n as f64 && r.uniform() >= 0.02
    });
    let nyq = 0.5 / d;
    let mut comps: Vec<(f64, f64, f64, f64, f64)> = vec![(f0, angle, A, 1.0, f0)];
    while comps.len() < 200 {
        let f = edges.0 * (0.95 * nyq / edges.0).powf(r.uniform());
        let th = 2.0 * PI * r.uniform();
        if ((f - edges.0) / edges.0).abs() < 0.05 || ((f - edges.1) / edges.1).abs() < 0.05 {
            continue;
        }
        comps.push((f, th, 0.6 * edges.0 / f, 2.0 * PI * r.uniform(), f));
    }
    let mut z = Array2::zeros((n, n));
    let mut truth = [0.0; 3];
    let nv = valid.iter().filter(|v| **v).count() as f64;
    for &(f, th, a, ph, fr) in &comps {
        let m = Array2::from_shape_fn((n, n), |(i, j)| {
            let (x, y) = (j as f64 * d, i as f64 * d);
            a * (2.0 * PI * f * (th.cos() * x + th.sin() * y) + ph).sin()
        });
        let mean: f64 = m
            .iter()
            .zip(&valid)
            .filter(|(_, v)| **v)
            .map(|(x, _)| x)
            .sum::<f64>()
            / nv;
        let msq: f64 = m
            .iter()
            .zip(&valid)
            .filter(|(_, v)| **v)
            .map(|(x, _)| (x - mean).powi(2))
            .sum::<f64>()
            / nv;
        truth[band_of(fr, edges)] += msq;
        z += &m;
    }
    (
        Surface::with_mask(z, valid, Some(d), Some(d)).unwrap(),
        truth,
    )
}

/// Issue (review, defect 1), on a synthetic aperture with a known truth: the bands add up to
/// 1e-9, none is negative or above Sq, and the band holding the sinusoid is within 3 % of its
/// truth, for a sinusoid in each band, oblique and along an axis.
#[test]
fn round_aperture_with_dropouts_and_texture_keeps_each_sinusoid_in_its_band() {
    let edges = (0.4, 2.5);
    for (f0, angle) in [
        (0.15, 0.5),
        (0.15, 0.0),
        (1.0, 0.3),
        (1.0, 0.5 * PI),
        (3.8, 0.9),
        (3.8, 0.0),
    ] {
        let (s, truth) = round_sine_with_texture(f0, angle, edges);
        let b = band_split(&s, &[Term::Piston], edges).unwrap();
        let parts = assert_adds_up(&b, &format!("f0 {f0}"));
        let k = band_of(f0, edges);
        let want = truth.map(f64::sqrt);
        eprintln!(
            "round, f0 {f0} angle {angle:.2}: bands {parts:?}, truth {want:?}, cross {:.1e}",
            b.cross_term_fraction
        );
        assert!(
            (parts[k] / want[k] - 1.0).abs() < 0.03,
            "f0 {f0}: band {k} {} vs truth {}",
            parts[k],
            want[k]
        );
        assert!(b.method.contains("X mirrored, Y mirrored"), "{}", b.method);
    }
}

/// Issue (review, defect 1), on the real maps it was found on: pykat CVI1-S1-BC (external;
/// before: figure 96.78 nm above Sq 92.24, MSF clipped to 0 from a power of -931 nm^2) and
/// 801B (real; fine clipped to 0), piston and tilt removed, edges 0.05 and 0.5 1/mm. The
/// values must match the least-squares projection solved here from the public `lowpass`
/// components (figure: <z, L1>^2 / <L1, L1>; figure + MSF: b' G^-1 b over {L1, L2}).
#[test]
fn real_maps_add_up_and_match_a_brute_force_projection() {
    let edges = (0.05, 0.5);
    for (sub, name) in [
        ("external", "pykat_CVI1-S1-BC.asc"),
        ("real", "pyxsurf_01_801B.dat"),
    ] {
        let path = shared_data::data_file(sub, name);
        let s = bonnetlab_io::read_surface(&path).unwrap();
        let terms = [Term::Piston, Term::Tilt];
        let b = band_split(&s, &terms, edges).unwrap();
        let parts = assert_adds_up(&b, name);
        // The reference, from the components alone.
        let (r, _) = remove_terms(&s, &terms).unwrap();
        let valid = r.valid().clone();
        let n = r.valid_count() as f64;
        let mean = r.valid_heights().sum::<f64>() / n;
        let z = Array2::from_shape_fn(r.dim(), |ij| {
            if valid[ij] {
                r.heights_nm()[ij] - mean
            } else {
                0.0
            }
        });
        let (dx, dy) = (s.dx_mm.unwrap(), s.dy_mm.unwrap());
        let l1 = lowpass(&z, &valid, dx, dy, edges.0);
        let l2 = lowpass(&z, &valid, dx, dy, edges.1);
        let dot = |a: &Array2<f64>, b: &Array2<f64>| -> f64 {
            a.iter()
                .zip(b.iter())
                .zip(valid.iter())
                .filter(|(_, v)| **v)
                .map(|((x, y), _)| x * y)
                .sum()
        };
        let (g11, g12, g22) = (dot(&l1, &l1), dot(&l1, &l2), dot(&l2, &l2));
        let (b1, b2, zz) = (dot(&z, &l1), dot(&z, &l2), dot(&z, &z));
        let fig = b1 * b1 / g11;
        let det = g11 * g22 - g12 * g12;
        let both = (g22 * b1 * b1 - 2.0 * g12 * b1 * b2 + g11 * b2 * b2) / det;
        let want = [fig, both - fig, zz - both].map(|p| (p / n).sqrt());
        eprintln!(
            "{name}: bands {parts:?}, brute force {want:?}, Sq {}, components {:?}, cross {:.3}",
            b.total_rms_nm, b.component_rms_nm, b.cross_term_fraction
        );
        for k in 0..3 {
            assert!(
                (parts[k] - want[k]).abs() < 1e-6 * b.total_rms_nm,
                "{name} band {k}: {parts:?} vs {want:?}"
            );
            assert!(parts[k] > 0.0, "{name}: band {k} is 0");
        }
        assert_eq!(
            b.ambiguity.is_some(),
            b.cross_term_fraction > AMBIGUOUS_CROSS_FRACTION,
            "{name}"
        );
        if name.starts_with("pykat") {
            // The components overlap by more than Sq^2: reported as ambiguous.
            assert!(b.cross_term_fraction > 1.0, "{}", b.cross_term_fraction);
            assert!(b.component_rms_nm[0].unwrap() > b.total_rms_nm);
        }
    }
}
