//! Linear (non-circular) 2-D convolution of dwell maps with kernels by real FFT, with plans and
//! kernel spectra kept so that the many convolutions of a calibration share the set-up.
//!
//! Conventions: the dwell map lives on an *extended* grid, the map grid padded by the kernel
//! half-size (`hr` rows, `hc` columns) on every side, so that dwell spent just off the map
//! (over-travel) still removes material on it. Kernels are `(2 hr + 1) x (2 hc + 1)` with the
//! tool centre at `(hr, hc)`. The output has the map's shape: `out[i, j] = sum_p D(p) K(x_ij - p)`.

use std::sync::Arc;

use ndarray::Array2;
use rayon::prelude::*;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

/// The spectrum of a zero-padded array, stored column-major over `kx` (`ncx` blocks of `ny`).
#[derive(Clone)]
pub struct Spectrum {
    data: Vec<Complex64>,
}

/// FFT convolver for one map grid and one kernel half-size.
pub struct Convolver {
    /// Map rows and columns.
    pub rows: usize,
    pub cols: usize,
    /// Kernel half-sizes (rows, columns).
    pub hr: usize,
    pub hc: usize,
    ny: usize,
    nx: usize,
    ncx: usize,
    r2c: Arc<dyn RealToComplex<f64>>,
    c2r: Arc<dyn ComplexToReal<f64>>,
    fwd: Arc<dyn Fft<f64>>,
    inv: Arc<dyn Fft<f64>>,
}

/// Smallest n' >= n whose only prime factors are 2, 3 and 5.
pub fn fast_len(n: usize) -> usize {
    smooth_len(n, &[2, 3, 5], false)
}

/// Smallest n' >= n (odd when `odd`) whose prime factors are all in `primes`.
pub fn smooth_len(n: usize, primes: &[usize], odd: bool) -> usize {
    let step = if odd { 2 } else { 1 };
    let mut m = if odd { n.max(1) | 1 } else { n.max(1) };
    loop {
        let mut k = m;
        for &p in primes {
            while k.is_multiple_of(p) {
                k /= p;
            }
        }
        if k == 1 {
            return m;
        }
        m += step;
    }
}

impl Convolver {
    pub fn new(rows: usize, cols: usize, hr: usize, hc: usize) -> Self {
        // Extended dwell grid (rows + 2 hr) convolved with a (2 hr + 1) kernel has
        // rows + 4 hr samples: an FFT at least that long never wraps around.
        let ny = fast_len(rows + 4 * hr);
        let nx = fast_len(cols + 4 * hc);
        let mut rp = RealFftPlanner::<f64>::new();
        let mut cp = FftPlanner::<f64>::new();
        Convolver {
            rows,
            cols,
            hr,
            hc,
            ny,
            nx,
            ncx: nx / 2 + 1,
            r2c: rp.plan_fft_forward(nx),
            c2r: rp.plan_fft_inverse(nx),
            fwd: cp.plan_fft_forward(ny),
            inv: cp.plan_fft_inverse(ny),
        }
    }

    /// Shape of the extended dwell grid.
    pub fn ext_dim(&self) -> (usize, usize) {
        (self.rows + 2 * self.hr, self.cols + 2 * self.hc)
    }

    /// Shape of a kernel.
    pub fn kernel_dim(&self) -> (usize, usize) {
        (2 * self.hr + 1, 2 * self.hc + 1)
    }

    /// Spectrum of an array placed at the top-left corner of the FFT frame.
    pub fn spectrum(&self, a: &Array2<f64>) -> Spectrum {
        self.spectrum_at(a, 0, 0)
    }

    /// Spectrum of an array placed at (r0, c0) in the FFT frame.
    fn spectrum_at(&self, a: &Array2<f64>, r0: usize, c0: usize) -> Spectrum {
        let (ar, ac) = a.dim();
        let (ny, nx, ncx) = (self.ny, self.nx, self.ncx);
        let mut rows_spec = vec![Complex64::new(0.0, 0.0); ny * ncx];
        rows_spec
            .par_chunks_mut(ncx)
            .enumerate()
            .for_each(|(i, out)| {
                if i < r0 || i - r0 >= ar {
                    return;
                }
                let mut buf = vec![0.0; nx];
                for (j, b) in buf.iter_mut().enumerate().skip(c0).take(ac) {
                    *b = a[(i - r0, j - c0)];
                }
                if buf.iter().any(|&v| v != 0.0) {
                    let _ = self.r2c.process(&mut buf, out);
                }
            });
        let mut data = vec![Complex64::new(0.0, 0.0); ncx * ny];
        data.par_chunks_mut(ny).enumerate().for_each(|(kx, col)| {
            for (i, c) in col.iter_mut().enumerate() {
                *c = rows_spec[i * ncx + kx];
            }
            self.fwd.process(col);
        });
        Spectrum { data }
    }

    /// Spectrum of a kernel `(2 hr + 1) x (2 hc + 1)`.
    pub fn kernel_spectrum(&self, k: &Array2<f64>) -> Spectrum {
        self.spectrum(k)
    }

    /// Spectrum of a dwell map on the extended grid.
    pub fn dwell_spectrum(&self, d_ext: &Array2<f64>) -> Spectrum {
        self.spectrum(d_ext)
    }

    /// `D * K` cropped to the map grid.
    pub fn apply(&self, d: &Spectrum, k: &Spectrum) -> Array2<f64> {
        self.apply_sum(&[(d, k)])
    }

    /// `sum_m D_m * K_m` cropped to the map grid (one inverse FFT for all pairs).
    pub fn apply_sum(&self, pairs: &[(&Spectrum, &Spectrum)]) -> Array2<f64> {
        let (ny, nx, ncx) = (self.ny, self.nx, self.ncx);
        let mut prod = vec![Complex64::new(0.0, 0.0); ncx * ny];
        prod.par_chunks_mut(ny).enumerate().for_each(|(kx, col)| {
            let off = kx * ny;
            for (d, k) in pairs {
                for (c, (a, b)) in col
                    .iter_mut()
                    .zip(d.data[off..off + ny].iter().zip(&k.data[off..off + ny]))
                {
                    *c += a * b;
                }
            }
            self.inv.process(col);
        });
        let scale = 1.0 / (nx as f64 * ny as f64);
        let (r0, c0) = (2 * self.hr, 2 * self.hc);
        let mut out = Array2::<f64>::zeros((self.rows, self.cols));
        let cols = self.cols;
        out.as_slice_mut()
            .expect("standard layout")
            .par_chunks_mut(cols)
            .enumerate()
            .for_each(|(i, orow)| {
                let row = i + r0;
                let mut spec: Vec<Complex64> = (0..ncx).map(|kx| prod[kx * ny + row]).collect();
                spec[0].im = 0.0;
                if nx % 2 == 0 {
                    spec[ncx - 1].im = 0.0;
                }
                let mut real = vec![0.0; nx];
                let _ = self.c2r.process(&mut spec, &mut real);
                for (j, o) in orow.iter_mut().enumerate() {
                    *o = real[j + c0] * scale;
                }
            });
        out
    }
}

impl Convolver {
    /// Correlation of a map-sized array with a kernel, on the extended grid:
    /// `C[e] = sum_x r(x) K(x - p_e)`, `p_e` the position of extended pixel `e`.
    pub fn correlate(&self, r: &Array2<f64>, k: &Spectrum) -> Array2<f64> {
        let (ny, nx, ncx) = (self.ny, self.nx, self.ncx);
        let rs = self.spectrum_at(r, 2 * self.hr, 2 * self.hc);
        let mut prod = rs.data;
        prod.par_chunks_mut(ny).enumerate().for_each(|(kx, col)| {
            let off = kx * ny;
            for (c, b) in col.iter_mut().zip(&k.data[off..off + ny]) {
                *c *= b.conj();
            }
            self.inv.process(col);
        });
        let scale = 1.0 / (nx as f64 * ny as f64);
        let (er, ec) = self.ext_dim();
        let mut out = Array2::<f64>::zeros((er, ec));
        out.as_slice_mut()
            .expect("standard layout")
            .par_chunks_mut(ec)
            .enumerate()
            .for_each(|(i, orow)| {
                let mut spec: Vec<Complex64> = (0..ncx).map(|kx| prod[kx * ny + i]).collect();
                spec[0].im = 0.0;
                if nx % 2 == 0 {
                    spec[ncx - 1].im = 0.0;
                }
                let mut real = vec![0.0; nx];
                let _ = self.c2r.process(&mut spec, &mut real);
                for (j, o) in orow.iter_mut().enumerate() {
                    *o = real[j] * scale;
                }
            });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_brute_force_linear_convolution() {
        let (rows, cols, hr, hc) = (7, 9, 2, 3);
        let conv = Convolver::new(rows, cols, hr, hc);
        let (er, ec) = conv.ext_dim();
        let d = Array2::from_shape_fn((er, ec), |(i, j)| ((i * 7 + j * 3) % 5) as f64 - 1.3);
        let k = Array2::from_shape_fn((2 * hr + 1, 2 * hc + 1), |(i, j)| {
            (i as f64 + 0.5) * (j as f64 - 1.7)
        });
        let out = conv.apply(&conv.dwell_spectrum(&d), &conv.kernel_spectrum(&k));
        for i in 0..rows {
            for j in 0..cols {
                // map pixel (i, j) <-> extended (i + hr, j + hc); kernel offset (a - hr, b - hc)
                let mut s = 0.0;
                for a in 0..2 * hr + 1 {
                    for b in 0..2 * hc + 1 {
                        let pi = i as isize + hr as isize - (a as isize - hr as isize);
                        let pj = j as isize + hc as isize - (b as isize - hc as isize);
                        if pi >= 0 && pj >= 0 && (pi as usize) < er && (pj as usize) < ec {
                            s += d[(pi as usize, pj as usize)] * k[(a, b)];
                        }
                    }
                }
                assert!(
                    (out[(i, j)] - s).abs() < 1e-9,
                    "({i},{j}) {} vs {s}",
                    out[(i, j)]
                );
            }
        }
    }

    #[test]
    fn correlation_matches_brute_force() {
        let (rows, cols, hr, hc) = (6, 8, 2, 1);
        let conv = Convolver::new(rows, cols, hr, hc);
        let (er, ec) = conv.ext_dim();
        let r = Array2::from_shape_fn((rows, cols), |(i, j)| ((i * 5 + j * 2) % 7) as f64 - 2.0);
        let k = Array2::from_shape_fn((2 * hr + 1, 2 * hc + 1), |(i, j)| {
            i as f64 * 0.3 + j as f64 - 0.7
        });
        let c = conv.correlate(&r, &conv.kernel_spectrum(&k));
        for e in 0..er {
            for f in 0..ec {
                // extended (e, f) is map position (e - hr, f - hc)
                let mut s = 0.0;
                for i in 0..rows {
                    for j in 0..cols {
                        let a = i as isize - (e as isize - hr as isize) + hr as isize;
                        let b = j as isize - (f as isize - hc as isize) + hc as isize;
                        if a >= 0 && b >= 0 && a <= 2 * hr as isize && b <= 2 * hc as isize {
                            s += r[(i, j)] * k[(a as usize, b as usize)];
                        }
                    }
                }
                assert!(
                    (c[(e, f)] - s).abs() < 1e-9,
                    "({e},{f}) {} vs {s}",
                    c[(e, f)]
                );
            }
        }
    }

    #[test]
    fn fast_len_has_small_factors() {
        assert_eq!(fast_len(7), 8);
        assert_eq!(fast_len(1201), 1215);
        assert_eq!(fast_len(1000), 1000);
    }
}
