//! The orthonormal 2-D transforms behind the areal band split, and the choice of border
//! treatment per axis.
//!
//! Along each axis the map is continued past its border either by *mirroring* (the DCT-II:
//! the DFT of the line mirrored about each end, so the continuation has no jump; index k has
//! frequency k / (2 N d)) or *periodically* (the DFT itself, in its real, orthonormal Hartley
//! form H_k = (Re F_k - Im F_k) / sqrt(N), which is its own inverse; indices k and N - k share
//! the frequency min(k, N - k) / (N d)). Both are orthonormal, so a brick-wall band by radial
//! frequency splits a complete map's mean square exactly (Parseval), and the 2-D transform is
//! the product of the two 1-D ones (rows = X first, then columns = Y).
//!
//! Which continuation leaks less depends on the map: a line with a trend or a figure term has a
//! jump at the periodic join (its DFT leaks like 1/k^2 in power), while a sinusoid with a whole
//! number of periods has a slope jump at the mirror (its DCT leaks a tail into every band, a few
//! 0.1 % of its power) and none at the periodic join. [`forward_chosen`] therefore continues an
//! axis periodically only when the map is periodic along it, in three tests: both border lines
//! of that axis are measured (a fill is no border); the jump across the periodic join is no
//! rougher than the map's own steps along the axis (mean square of the join's differences at
//! most 4 times the mean square of neighbour differences: a sinusoid with whole periods gives
//! at most 2, a trend or a figure term far more); and the power spectrum along the axis is more
//! concentrated that way, by the Shannon entropy of the marginal power on bins of 1 / (N d)
//! (the best-basis rule of Coifman and Wickerhauser, 1992). Otherwise, and on a tie, mirrored.
//! The join test is what keeps a generic sinusoid (no whole periods, so a jump at the join)
//! mirrored, where it leaks less; one that happens to join within its steps (coarse sampling,
//! or a lucky phase) leaks about as much either way, and the entropy decides.

use std::sync::Arc;

use ndarray::Array2;
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};

/// How a map is continued past its border along one axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Border {
    /// Mirrored about each end (DCT-II).
    Mirrored,
    /// Periodic (DFT, Hartley form).
    Periodic,
}

impl Border {
    /// Name written in the method text.
    pub fn name(self) -> &'static str {
        match self {
            Border::Mirrored => "mirrored",
            Border::Periodic => "periodic",
        }
    }

    /// Frequency (cycles/mm) of coefficient `k` of a line of `n` pixels of `d_mm`.
    pub fn freq_per_mm(self, k: usize, n: usize, d_mm: f64) -> f64 {
        match self {
            Border::Mirrored => k as f64 / (2.0 * n as f64 * d_mm),
            Border::Periodic => k.min(n - k) as f64 / (n as f64 * d_mm),
        }
    }

    /// Frequency bin of width 1 / (n d) of coefficient `k` (the entropy's common grid).
    fn bin(self, k: usize, n: usize) -> usize {
        match self {
            Border::Mirrored => k.div_ceil(2),
            Border::Periodic => k.min(n - k),
        }
    }
}

/// Orthonormal 2-D transform of `a` (rows = X with `bx`, then columns = Y with `by`), or its
/// inverse.
pub fn transform2(a: &Array2<f64>, bx: Border, by: Border, inverse: bool) -> Array2<f64> {
    if inverse {
        let t = a.t().as_standard_layout().into_owned();
        let c = rows(&t, by, true);
        let back = c.t().as_standard_layout().into_owned();
        rows(&back, bx, true)
    } else {
        let r = rows(a, bx, false);
        let t = r.t().as_standard_layout().into_owned();
        let c = rows(&t, by, false);
        c.t().as_standard_layout().into_owned()
    }
}

/// The 2-D transform of `a` with each axis's border chosen as the module docs say.
/// `measured_x` / `measured_y`: both border columns / rows are measured pixels.
pub fn forward_chosen(
    a: &Array2<f64>,
    measured_x: bool,
    measured_y: bool,
) -> (Array2<f64>, Border, Border) {
    let (r, bx) = rows_chosen(a, measured_x);
    let t = r.t().as_standard_layout().into_owned();
    drop(r);
    let (c, by) = rows_chosen(&t, measured_y);
    (c.t().as_standard_layout().into_owned(), bx, by)
}

/// Every row of `a` transformed, periodically when `may_wrap` (both border lines measured), the
/// rows join smoothly and the periodic spectrum has the lower entropy; mirrored otherwise.
fn rows_chosen(a: &Array2<f64>, may_wrap: bool) -> (Array2<f64>, Border) {
    let mirrored = rows(a, Border::Mirrored, false);
    if !may_wrap || a.ncols() < 3 || !smooth_join(a) {
        return (mirrored, Border::Mirrored);
    }
    let periodic = rows(a, Border::Periodic, false);
    let hm = entropy(&marginal(&mirrored, Border::Mirrored));
    let hp = entropy(&marginal(&periodic, Border::Periodic));
    // A tie (a line constant along the axis, or rounding) keeps the mirrored border.
    if hp < hm - 1e-9 * hm.max(1e-3) {
        (periodic, Border::Periodic)
    } else {
        (mirrored, Border::Mirrored)
    }
}

/// The rows of `a` join across the periodic border (last to first pixel) no more roughly than
/// their neighbours join: mean square of the join's differences <= 4 x that of neighbour
/// differences. (Along Y, `a` holds the X transform's coefficients; by Parseval along X both
/// mean squares are those of the map itself.)
fn smooth_join(a: &Array2<f64>) -> bool {
    let (rows, n) = a.dim();
    let src = a.as_slice().unwrap_or(&[]);
    let parts: Vec<[f64; 2]> = src
        .par_chunks(n * 64)
        .map(|chunk| {
            let mut s = [0.0; 2];
            for row in chunk.chunks(n) {
                let j = row[0] - row[n - 1];
                s[0] += j * j;
                s[1] += row.windows(2).map(|w| (w[1] - w[0]).powi(2)).sum::<f64>();
            }
            s
        })
        .collect();
    let (mut join, mut steps) = (0.0, 0.0);
    for [a, b] in parts {
        join += a;
        steps += b;
    }
    join / rows as f64 <= 4.0 * steps / (rows * (n - 1)) as f64
}

/// Power per frequency bin of width 1 / (N d), summed over the rows (fixed chunks summed in
/// order, so the result does not depend on the thread count).
fn marginal(c: &Array2<f64>, border: Border) -> Vec<f64> {
    let (_, n) = c.dim();
    let nb = n / 2 + 1;
    let src = c.as_slice().unwrap_or(&[]);
    let parts: Vec<Vec<f64>> = src
        .par_chunks(n * 64)
        .map(|chunk| {
            let mut p = vec![0.0; nb];
            for row in chunk.chunks(n) {
                for (k, v) in row.iter().enumerate() {
                    p[border.bin(k, n)] += v * v;
                }
            }
            p
        })
        .collect();
    let mut p = vec![0.0; nb];
    for part in parts {
        for (a, b) in p.iter_mut().zip(part) {
            *a += b;
        }
    }
    p
}

/// Shannon entropy (nats) of a power distribution; 0 for no power.
fn entropy(p: &[f64]) -> f64 {
    let total: f64 = p.iter().sum();
    if total <= 0.0 {
        return 0.0;
    }
    -p.iter()
        .filter(|v| **v > 0.0)
        .map(|v| {
            let q = v / total;
            q * q.ln()
        })
        .sum::<f64>()
}

/// Every row of `a` through the orthonormal transform of `border` (or its inverse).
pub fn rows(a: &Array2<f64>, border: Border, inverse: bool) -> Array2<f64> {
    match border {
        Border::Mirrored => dct_rows(a, inverse),
        // The orthonormal Hartley transform is its own inverse.
        Border::Periodic => dht_rows(a),
    }
}

/// Orthonormal DCT-II (or its inverse) of every row, through a real FFT of length 2N of the
/// row mirrored about its end: Y_k = 2 e^{i pi k / 2N} X_k for the unnormalised DCT-II X.
fn dct_rows(a: &Array2<f64>, inverse: bool) -> Array2<f64> {
    let (rows, n) = a.dim();
    if n == 0 || rows == 0 {
        return a.clone();
    }
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

/// Orthonormal discrete Hartley transform of every row, H_k = sum_j x_j cas(2 pi j k / N) /
/// sqrt(N) with cas = cos + sin, from one real FFT: H_k = (Re F_k - Im F_k) / sqrt(N), and
/// F_{N-k} = conj(F_k) for the upper half.
fn dht_rows(a: &Array2<f64>) -> Array2<f64> {
    let (rows, n) = a.dim();
    if n == 0 || rows == 0 {
        return a.clone();
    }
    let mut planner = RealFftPlanner::<f64>::new();
    let fwd: Arc<dyn RealToComplex<f64>> = planner.plan_fft_forward(n);
    let scale = 1.0 / (n as f64).sqrt();
    let src = a.as_standard_layout();
    let src = src.as_slice().unwrap_or(&[]);
    let mut out = vec![0.0; rows * n];
    out.par_chunks_mut(n).enumerate().for_each_init(
        || {
            (
                fwd.make_input_vec(),
                fwd.make_output_vec(),
                fwd.make_scratch_vec(),
            )
        },
        |(buf, spec, fs): &mut (Vec<f64>, Vec<Complex<f64>>, _), (i, dst)| {
            buf.copy_from_slice(&src[i * n..(i + 1) * n]);
            // The lengths come from the plan, so this cannot fail.
            let _ = fwd.process_with_scratch(buf, spec, fs);
            for (k, d) in dst.iter_mut().enumerate() {
                let h = if k <= n / 2 {
                    spec[k].re - spec[k].im
                } else {
                    spec[n - k].re + spec[n - k].im
                };
                *d = h * scale;
            }
        },
    );
    Array2::from_shape_vec((rows, n), out).unwrap_or_else(|_| Array2::zeros((rows, n)))
}

/// Radial frequency (cycles/mm) of every coefficient of an `(ny, nx)` transform.
pub fn radial_freq(
    (ny, nx): (usize, usize),
    (bx, by): (Border, Border),
    dx: f64,
    dy: f64,
) -> impl Fn(usize, usize) -> f64 {
    let fx: Vec<f64> = (0..nx).map(|k| bx.freq_per_mm(k, nx, dx)).collect();
    let fy: Vec<f64> = (0..ny).map(|l| by.freq_per_mm(l, ny, dy)).collect();
    move |l, k| fx[k].hypot(fy[l])
}

/// The low-pass of the map whose transform is `c`: coefficients with radial frequency below
/// `f` kept, the rest zeroed, transformed back.
pub fn radial_lowpass(
    c: &Array2<f64>,
    borders: (Border, Border),
    dx: f64,
    dy: f64,
    f: f64,
) -> Array2<f64> {
    let freq = radial_freq(c.dim(), borders, dx, dy);
    let kept = Array2::from_shape_fn(
        c.dim(),
        |(l, k)| {
            if freq(l, k) < f {
                c[(l, k)]
            } else {
                0.0
            }
        },
    );
    transform2(&kept, borders.0, borders.1, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;
    use std::f64::consts::PI;

    /// Brute-force orthonormal DCT-II of a vector.
    fn dct_brute(x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n)
            .map(|k| {
                let s: f64 = x
                    .iter()
                    .enumerate()
                    .map(|(j, v)| v * (PI * k as f64 * (2 * j + 1) as f64 / (2 * n) as f64).cos())
                    .sum();
                s * if k == 0 {
                    (1.0 / n as f64).sqrt()
                } else {
                    (2.0 / n as f64).sqrt()
                }
            })
            .collect()
    }

    /// Brute-force orthonormal Hartley transform of a vector.
    fn dht_brute(x: &[f64]) -> Vec<f64> {
        let n = x.len();
        (0..n)
            .map(|k| {
                let s: f64 = x
                    .iter()
                    .enumerate()
                    .map(|(j, v)| {
                        let t = 2.0 * PI * (j * k) as f64 / n as f64;
                        v * (t.cos() + t.sin())
                    })
                    .sum();
                s / (n as f64).sqrt()
            })
            .collect()
    }

    #[test]
    fn transforms_match_brute_force_invert_and_keep_the_energy() {
        let mut r = Rng::new(4);
        for (ny, nx) in [(5, 8), (7, 13), (1, 4), (6, 1)] {
            let a = Array2::from_shape_fn((ny, nx), |_| r.normal());
            let d = rows(&a, Border::Mirrored, false);
            let h = rows(&a, Border::Periodic, false);
            for i in 0..ny {
                let bd = dct_brute(&a.row(i).to_vec());
                let bh = dht_brute(&a.row(i).to_vec());
                for k in 0..nx {
                    assert!((d[(i, k)] - bd[k]).abs() < 1e-12, "dct {ny}x{nx} ({i},{k})");
                    assert!((h[(i, k)] - bh[k]).abs() < 1e-12, "dht {ny}x{nx} ({i},{k})");
                }
            }
            let e0: f64 = a.iter().map(|v| v * v).sum();
            for (bx, by) in [
                (Border::Mirrored, Border::Mirrored),
                (Border::Periodic, Border::Mirrored),
                (Border::Mirrored, Border::Periodic),
                (Border::Periodic, Border::Periodic),
            ] {
                let c = transform2(&a, bx, by, false);
                let back = transform2(&c, bx, by, true);
                for (x, y) in back.iter().zip(a.iter()) {
                    assert!((x - y).abs() < 1e-12, "{bx:?} {by:?}");
                }
                let e1: f64 = c.iter().map(|v| v * v).sum();
                assert!((e0 - e1).abs() < 1e-10 * e0, "Parseval {bx:?} {by:?}");
            }
        }
    }

    #[test]
    fn the_periodic_border_is_taken_for_whole_periods_and_never_for_a_trend() {
        // 7 whole periods along Y (rows), constant along X; a trend along X on a second map.
        let (ny, nx) = (64, 48);
        let sine = Array2::from_shape_fn((ny, nx), |(i, _)| {
            (2.0 * PI * 7.0 * i as f64 / ny as f64 + 0.4).sin()
        });
        let (_, bx, by) = forward_chosen(&sine, true, true);
        assert_eq!((bx, by), (Border::Mirrored, Border::Periodic));
        // Not when a border line is not measured.
        let (_, _, by) = forward_chosen(&sine, true, false);
        assert_eq!(by, Border::Mirrored);
        // A finely sampled sinusoid without whole periods (3.37 over 256 rows) jumps at the
        // join by 0.78, 13 times its RMS step: mirrored.
        let generic = Array2::from_shape_fn((256, 8), |(i, _)| {
            (2.0 * PI * 3.37 * i as f64 / 256.0).sin()
        });
        let (_, _, by) = forward_chosen(&generic, true, true);
        assert_eq!(by, Border::Mirrored);
        let mut r = Rng::new(9);
        let trend = Array2::from_shape_fn((ny, nx), |(_, j)| 0.1 * j as f64 + 0.05 * r.normal());
        let (_, bx, _) = forward_chosen(&trend, true, true);
        assert_eq!(bx, Border::Mirrored);
    }
}
