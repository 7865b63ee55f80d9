//! Band-limited RMS from the map itself: the band values every report shows (`stats --bands`,
//! `compare`, and the lead's simulate / calibrate through [`band_split`]).
//!
//! Bands (edges F1 <= F2 in cycles/mm, default [`BAND_EDGES_DEFAULT_PER_MM`]): *figure* below
//! F1, *MSF* from F1 to F2, *fine* above F2, by radial frequency |f| = sqrt(fx^2 + fy^2).
//!
//! Method: exact spectral (brick-wall) filtering in the cosine basis, after the joint removal of
//! the requested form terms and of the valid-pixel mean (z is that residual, n its valid
//! pixels):
//! 1. edge handling, part 1 (holes, round apertures): invalid pixels are filled by the
//!    project's one hole fill (`bonnetlab_surface::fill`: front by front, each pixel the mean of
//!    its known 8-neighbours; a small dropout takes the local mean, the corners outside a round
//!    aperture continue the rim). The fill only carries the data across holes; it is never
//!    counted. (It replaced a multi-scale normalised Gaussian fill: the same sine band RMS to
//!    2e-5, and cross terms 3.5x smaller on a round textured map; `tests/areal_bands.rs`.);
//! 2. edge handling, part 2 (the map border): the 2-D DCT-II, i.e. the DFT of the map mirrored
//!    about each border, so the periodic continuation has no jump at the border and no window
//!    is needed. DCT index (k, l) has frequency (k / (2 Nx dx), l / (2 Ny dy));
//! 3. components: c_b = inverse DCT of the coefficients with |f| in band b (figure |f| < F1,
//!    MSF F1 <= |f| < F2, fine |f| >= F2). On a full rectangle they are orthogonal (the DCT is)
//!    and their mean squares add up to Sq^2 exactly;
//! 4. band power = covariance of the component with the map over the valid pixels,
//!    P_b = <c_b, z>_valid / n, band RMS = sqrt(P_b). The components add up to z on every
//!    valid pixel, so the three powers add up to <z, z> / n = Sq^2 exactly on any aperture; on
//!    a full rectangle P_b is the component's own mean square. With holes the two differ by
//!    the cross terms <c_a, c_b>_valid, reported as `cross_term_fraction` (sum over bands of
//!    |P_b - own_b| / Sq^2) so a reader can see how far from orthogonal the split was.
//!
//! A band the map cannot resolve is `None` with a reason: no pixel size, the band lies
//! below the lowest measured frequency 1 / (the valid field's longest side), or above the
//! Nyquist frequency of the coarser axis. An edge outside the measured range makes no cut:
//! the content on its side belongs to the neighbouring band (e.g. with F2 above Nyquist, MSF
//! runs from F1 to Nyquist and fine is absent).
//!
//! The PSD-integrated band RMS (bin sums of a windowed PSD, `band`) is a different, labelled
//! quantity: its window loss on non-stationary maps makes it disagree with Sq.

use std::sync::Arc;

use bonnetlab_surface::fill::fill_invalid;
use bonnetlab_surface::surface::mask_bounds;
use bonnetlab_surface::{remove_terms, Surface, Term};
use ndarray::Array2;
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use serde::Serialize;

use crate::error::SpectrumError;

/// Why a frequency-domain quantity of a map without a pixel size is absent (band RMS, ripple).
pub const UNKNOWN_PIXEL_REASON: &str =
    "not resolvable: the pixel size is unknown, so no spatial frequency can be assigned";

/// Default band edges, mm^-1: figure above 33 mm periods, MSF 33 mm to 0.12 mm, fine below
/// 0.12 mm. Source: shared/spec/metrology.md ("1/33 mm to 1/0.12 mm"), the large-optics
/// (NIF / LLNL) convention for mid-spatial frequencies.
pub const BAND_EDGES_DEFAULT_PER_MM: (f64, f64) = (1.0 / 33.0, 1.0 / 0.12);

/// The three band RMS values of one map (field names as `stats --bands` writes them).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArealBands {
    /// Requested edges [F1, F2], mm^-1.
    pub edges_per_mm: [f64; 2],
    /// RMS below F1, nm; `None` when not resolvable (see `figure_reason`).
    pub figure_rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub figure_reason: Option<String>,
    /// RMS from F1 to F2, nm.
    pub msf_rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub msf_reason: Option<String>,
    /// RMS above F2, nm.
    pub fine_rms_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fine_reason: Option<String>,
    /// Sq of the same residual, nm: the quadrature sum of the resolvable bands.
    pub total_rms_nm: f64,
    /// [lowest, highest] frequency the map measures, mm^-1 (1 / longest side of the valid
    /// field, Nyquist of the coarser axis); `None` without a pixel size.
    pub measured_range_per_mm: Option<[f64; 2]>,
    /// sum over band pairs of |2 <c_a, c_b>| / <z, z>: 0 for an orthogonal split.
    pub cross_term_fraction: f64,
    pub removed: Vec<Term>,
    pub method: String,
}

impl ArealBands {
    /// (name, value, reason) of the three bands, figure first.
    pub fn bands(&self) -> [(&'static str, Option<f64>, Option<&str>); 3] {
        [
            ("figure", self.figure_rms_nm, self.figure_reason.as_deref()),
            ("msf", self.msf_rms_nm, self.msf_reason.as_deref()),
            ("fine", self.fine_rms_nm, self.fine_reason.as_deref()),
        ]
    }
}

/// The method string written beside the values.
pub const AREAL_METHOD: &str = "areal split of the map: brick-wall bands of the 2-D DCT \
     (mirrored borders, no window) by radial frequency, holes filled by normalised Gaussian \
     continuation; band power = covariance of the band component with the map over the valid \
     pixels, so the bands add up to Sq^2 exactly";

/// Band RMS of `s` after removing `remove` jointly (and the mean), split at `edges_per_mm`.
pub fn band_split(
    s: &Surface,
    remove: &[Term],
    edges_per_mm: (f64, f64),
) -> Result<ArealBands, SpectrumError> {
    let (f1, f2) = edges_per_mm;
    crate::band::check_band(f1, f2)?;
    let (r, _) = remove_terms(s, remove)?;
    let n = r.valid_count();
    if n == 0 {
        return Err(bonnetlab_surface::SurfaceError::NoValidPixel.into());
    }
    let valid = r.valid().clone();
    let mean = r.valid_heights().sum::<f64>() / n as f64;
    let z = Array2::from_shape_fn(r.dim(), |ij| {
        if valid[ij] {
            r.heights_nm()[ij] - mean
        } else {
            0.0
        }
    });
    let zz: f64 = z.iter().map(|v| v * v).sum();
    let total = (zz / n as f64).sqrt();
    let mut out = ArealBands {
        edges_per_mm: [f1, f2],
        figure_rms_nm: None,
        figure_reason: None,
        msf_rms_nm: None,
        msf_reason: None,
        fine_rms_nm: None,
        fine_reason: None,
        total_rms_nm: total,
        measured_range_per_mm: None,
        cross_term_fraction: 0.0,
        removed: r.removed.clone(),
        method: AREAL_METHOD.into(),
    };
    let (Some(dx), Some(dy)) = (s.dx_mm, s.dy_mm) else {
        let why = UNKNOWN_PIXEL_REASON.to_string();
        out.figure_reason = Some(why.clone());
        out.msf_reason = Some(why.clone());
        out.fine_reason = Some(why);
        return Ok(out);
    };
    let (lx, ly) = valid_extent_mm(&valid, dx, dy);
    let field = lx.max(ly);
    let f_lo = 1.0 / field;
    let f_hi = 0.5 / dx.max(dy);
    out.measured_range_per_mm = Some([f_lo, f_hi]);
    let fmt = |v: f64| crate::band::fmt_short(v);
    let below = |what: &str, edge: f64| {
        format!(
            "not resolvable: {what} (periods longer than {} mm) lies below the lowest measured \
             frequency {} 1/mm (the valid field is {} mm long)",
            fmt(1.0 / edge),
            fmt(f_lo),
            fmt(field)
        )
    };
    let above = |what: &str, edge: f64| {
        format!(
            "not resolvable: {what} (periods shorter than {} mm) lies above the Nyquist \
             frequency {} 1/mm (pixel {} mm)",
            fmt(1.0 / edge),
            fmt(f_hi),
            fmt(dx.max(dy))
        )
    };
    // Low-pass at an edge: None = nothing passes (edge below the range), Some(None) = all
    // passes (edge above the range), Some(Some(map)) = filtered.
    let cut = |f: f64| f > f_lo && f < f_hi;
    // DCT coefficients of the filled map, once for both edges.
    let coeffs = if cut(f1) || cut(f2) {
        let filled = if n == valid.len() {
            z.clone()
        } else {
            fill_invalid(&z, &valid)
        };
        Some(dct2(&filled, false))
    } else {
        None
    };
    let lowpass = |f: f64| -> Option<Option<Array2<f64>>> {
        if f <= f_lo {
            None
        } else if f >= f_hi {
            Some(None)
        } else {
            coeffs.as_ref().map(|c| Some(radial_lowpass(c, dx, dy, f)))
        }
    };
    let l1 = lowpass(f1);
    let l2 = if f2 == f1 { l1.clone() } else { lowpass(f2) };
    // Components as closures over pixels (value at a valid pixel index).
    let value = |l: &Option<Option<Array2<f64>>>, ij: (usize, usize)| -> f64 {
        match l {
            None => 0.0,
            Some(None) => z[ij],
            Some(Some(m)) => m[ij],
        }
    };
    let mut p = [0.0f64; 3];
    let mut own = [0.0f64; 3];
    for (ij, &ok) in valid.indexed_iter() {
        if !ok {
            continue;
        }
        let zv = z[ij];
        let a = value(&l1, ij);
        let b = value(&l2, ij);
        let c = [a, b - a, zv - b];
        for k in 0..3 {
            p[k] += c[k] * zv;
            own[k] += c[k] * c[k];
        }
    }
    out.cross_term_fraction = if zz > 0.0 {
        // <z, z> = sum_b own_b + 2 sum_{a<b} <c_a, c_b>; P_b - own_b = sum_{a != b} <c_a, c_b>.
        (0..3).map(|k| (p[k] - own[k]).abs()).sum::<f64>() / zz
    } else {
        0.0
    };
    let rms = |pk: f64| (pk.max(0.0) / n as f64).sqrt();
    // figure [0, F1]
    if f1 <= f_lo {
        out.figure_reason = Some(below("the figure band", f1));
    } else {
        out.figure_rms_nm = Some(rms(p[0]));
    }
    // MSF [F1, F2]
    if f2 <= f_lo {
        out.msf_reason = Some(below("the MSF band", f2));
    } else if f1 >= f_hi {
        out.msf_reason = Some(above("the MSF band", f1));
    } else {
        out.msf_rms_nm = Some(rms(p[1]));
    }
    // fine [F2, inf)
    if f2 >= f_hi {
        out.fine_reason = Some(above("the fine band", f2));
    } else {
        out.fine_rms_nm = Some(rms(p[2]));
    }
    Ok(out)
}

/// The low-pass component of a masked map: the same brick-wall split as [`band_split`] (holes
/// filled by the project's hole fill, 2-D DCT with mirrored borders, coefficients with radial
/// frequency below `f_per_mm` kept), returned as a map on the full grid. `z - lowpass` is the
/// component at and above `f_per_mm`; both add up to `z` on every valid pixel. No mean or form
/// is removed (the caller's map is taken as it is); invalid pixels carry the fill's low-pass.
pub fn lowpass(
    z: &Array2<f64>,
    valid: &Array2<bool>,
    dx_mm: f64,
    dy_mm: f64,
    f_per_mm: f64,
) -> Array2<f64> {
    let filled = if valid.iter().all(|v| *v) {
        z.clone()
    } else {
        fill_invalid(z, valid)
    };
    radial_lowpass(&dct2(&filled, false), dx_mm, dy_mm, f_per_mm)
}

/// Lengths (mm) of the bounding box of the valid pixels along X and Y (pixel counts times
/// the pixel size: a field of N pixels measures periods up to N d).
fn valid_extent_mm(valid: &Array2<bool>, dx: f64, dy: f64) -> (f64, f64) {
    match mask_bounds(valid) {
        Some((r0, r1, c0, c1)) => ((c1 - c0 + 1) as f64 * dx, (r1 - r0 + 1) as f64 * dy),
        None => (0.0, 0.0),
    }
}

/// 2-D orthonormal DCT-II of `a` (`inverse`: its inverse, the DCT-III), along rows then
/// columns.
fn dct2(a: &Array2<f64>, inverse: bool) -> Array2<f64> {
    let r = dct_rows(a, inverse);
    let t = r.t().as_standard_layout().into_owned();
    let c = dct_rows(&t, inverse);
    c.t().as_standard_layout().into_owned()
}

/// The low-pass of the map whose DCT is `c`: coefficients with radial frequency
/// sqrt((k / (2 Nx dx))^2 + (l / (2 Ny dy))^2) < f kept, the rest zeroed, transformed back.
fn radial_lowpass(c: &Array2<f64>, dx: f64, dy: f64, f: f64) -> Array2<f64> {
    let (ny, nx) = c.dim();
    let (ux, uy) = (1.0 / (2.0 * nx as f64 * dx), 1.0 / (2.0 * ny as f64 * dy));
    let kept = Array2::from_shape_fn((ny, nx), |(l, k)| {
        let (fx, fy) = (k as f64 * ux, l as f64 * uy);
        if fx * fx + fy * fy < f * f {
            c[(l, k)]
        } else {
            0.0
        }
    });
    dct2(&kept, true)
}

/// Orthonormal DCT-II (or its inverse) of every row, through a real FFT of length 2N of the
/// row mirrored about its end: Y_k = 2 e^{i pi k / 2N} X_k for the unnormalised DCT-II X.
fn dct_rows(a: &Array2<f64>, inverse: bool) -> Array2<f64> {
    let (rows, n) = a.dim();
    let p = 2 * n;
    let mut planner = RealFftPlanner::<f64>::new();
    let fwd: Arc<dyn RealToComplex<f64>> = planner.plan_fft_forward(p);
    let inv: Arc<dyn ComplexToReal<f64>> = planner.plan_fft_inverse(p);
    let tw: Vec<Complex<f64>> = (0..n)
        .map(|k| Complex::from_polar(1.0, std::f64::consts::PI * k as f64 / p as f64))
        .collect();
    // Orthonormal scaling: s_0 = sqrt(1 / N), s_k = sqrt(2 / N).
    let s0 = (1.0 / n as f64).sqrt();
    let sk = (2.0 / n as f64).sqrt();
    let src = a.as_standard_layout();
    let src = src.as_slice().unwrap_or(&[]);
    let mut out = vec![0.0; rows * n];
    out.par_chunks_mut(n).enumerate().for_each_init(
        || {
            (
                fwd.make_input_vec(),
                fwd.make_output_vec(),
                fwd.make_scratch_vec(),
                inv.make_scratch_vec(),
            )
        },
        |(buf, spec, fs, is): &mut (Vec<f64>, Vec<Complex<f64>>, _, _), (i, dst)| {
            let x = &src[i * n..(i + 1) * n];
            if !inverse {
                buf[..n].copy_from_slice(x);
                for (d, v) in buf[n..].iter_mut().zip(x.iter().rev()) {
                    *d = *v;
                }
                // Lengths come from the plans, so these cannot fail.
                let _ = fwd.process_with_scratch(buf, spec, fs);
                for (k, d) in dst.iter_mut().enumerate() {
                    // X_k = Re(e^{-i pi k / 2N} Y_k) / 2
                    let xk = 0.5 * (spec[k] * tw[k].conj()).re;
                    *d = xk * if k == 0 { s0 } else { sk };
                }
            } else {
                // Unnormalised X_k from the orthonormal coefficients, then Y_k = 2 e^{..} X_k,
                // Y_N = 0, and the inverse real FFT of the mirrored sequence.
                for (k, c) in spec.iter_mut().enumerate().take(n) {
                    let xk = x[k] / if k == 0 { s0 } else { sk };
                    *c = tw[k] * (2.0 * xk);
                }
                spec[n] = Complex::new(0.0, 0.0);
                spec[0].im = 0.0;
                let _ = inv.process_with_scratch(spec, buf, is);
                // realfft's inverse is unnormalised: divide by 2N; the mirrored sequence's
                // energy is twice the row's, which the orthonormal scaling already accounts for.
                let scale = 1.0 / p as f64;
                for (d, v) in dst.iter_mut().zip(buf.iter()) {
                    *d = v * scale;
                }
            }
        },
    );
    Array2::from_shape_vec((rows, n), out).unwrap_or_else(|_| Array2::zeros((rows, n)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    /// The low-pass keeps a wave below the edge and drops one above it, across a hole.
    #[test]
    fn lowpass_separates_waves_across_a_hole() {
        let (n, d) = (128, 0.25);
        let lo =
            |i: usize, j: usize| 5.0 * (std::f64::consts::TAU * 0.1 * (i + j) as f64 * d).cos();
        let hi = |j: usize| 2.0 * (std::f64::consts::TAU * 1.2 * j as f64 * d).sin();
        let z = Array2::from_shape_fn((n, n), |(i, j)| lo(i, j) + hi(j));
        let valid = Array2::from_shape_fn((n, n), |(i, j)| {
            (i as f64 - 60.0).hypot(j as f64 - 70.0) > 6.0
        });
        let l = lowpass(&z, &valid, d, d, 0.5);
        // Away from the border and the hole (the brick wall rings over a few pixels there).
        let mut worst: f64 = 0.0;
        for i in 20..n - 20 {
            for j in 20..n - 20 {
                if (i as f64 - 60.0).hypot(j as f64 - 70.0) > 16.0 {
                    worst = worst.max((l[(i, j)] - lo(i, j)).abs());
                }
            }
        }
        assert!(worst < 0.25, "low-pass off by {worst} nm");
    }

    /// Brute-force orthonormal DCT-II of a vector.
    fn dct_brute(x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n)
            .map(|k| {
                let s: f64 = x
                    .iter()
                    .enumerate()
                    .map(|(j, v)| {
                        v * (std::f64::consts::PI * k as f64 * (2 * j + 1) as f64 / (2 * n) as f64)
                            .cos()
                    })
                    .sum();
                s * if k == 0 {
                    (1.0 / n as f64).sqrt()
                } else {
                    (2.0 / n as f64).sqrt()
                }
            })
            .collect()
    }

    #[test]
    fn dct_matches_brute_force_and_inverts() {
        let mut r = Rng::new(4);
        for (ny, nx) in [(5, 8), (7, 13), (1, 4)] {
            let a = Array2::from_shape_fn((ny, nx), |_| r.normal());
            let d = dct_rows(&a, false);
            for i in 0..ny {
                let b = dct_brute(&a.row(i).to_vec());
                for k in 0..nx {
                    assert!((d[(i, k)] - b[k]).abs() < 1e-12, "{ny}x{nx} ({i},{k})");
                }
            }
            let back = dct2(&dct2(&a, false), true);
            for (x, y) in back.iter().zip(a.iter()) {
                assert!((x - y).abs() < 1e-12);
            }
            // Orthonormal: Parseval.
            let e0: f64 = a.iter().map(|v| v * v).sum();
            let e1: f64 = dct2(&a, false).iter().map(|v| v * v).sum();
            assert!((e0 - e1).abs() < 1e-10 * e0);
        }
    }
}
