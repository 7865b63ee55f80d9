//! Two-dimensional PSD (TWO-SIDED, nm^2 mm^2), its folded 1-D marginals and radial forms.
//!
//! P2[l, k] = dx dy |FFT2(w2 z)[l, k]|^2 / E with the separable window w2 = wy (x) wx and
//! E = sum over valid pixels of w2^2 (= Nx Ny U2 on a full map, as metrology.md writes it).
//! z is the map after global form removal and removal of its valid-pixel mean; invalid
//! pixels are 0. Only the half plane kx = 0..=Nx/2 is stored (all ky in FFT order); the
//! other half follows from P2(-f) = P2(f) for a real map. Sums over the full plane weight
//! column k by `kx_weight(k)` (1 at kx = 0 and the Nyquist column, 2 otherwise).
//!
//! Radial forms use bins of width dfr = max(dfx, dfy) centred on b dfr:
//! the azimuthally *integrated* PSD (nm^2 mm) = annulus sum of P2 dfx dfy / dfr, whose sum
//! times dfr is the mean square exactly; the azimuthal *average* (nm^2 mm^2) = mean of P2 over
//! the annulus. They are different quantities: label which one a plot shows.

use ndarray::Array2;
use rayon::prelude::*;
use realfft::num_complex::Complex;
use realfft::RealFftPlanner;
use rustfft::FftPlanner;
use serde::Serialize;

use bonnetlab_surface::{Surface, Term};

use crate::error::SpectrumError;
use crate::form::prepare;
use crate::lines::Axis;
use crate::psd1d::{Psd1d, PsdOptions};
use crate::window::Window;

/// A two-sided 2-D PSD on the half plane kx >= 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Psd2d {
    /// TWO-SIDED density, nm^2 mm^2, shape (Ny, Nx/2 + 1): row l is fy = fy(l) (FFT order,
    /// negative frequencies in the upper half), column k is fx = k dfx.
    pub psd_nm2_mm2: Array2<f64>,
    pub nx: usize,
    pub ny: usize,
    pub dfx_per_mm: f64,
    pub dfy_per_mm: f64,
    pub window: Window,
    pub removed: Vec<Term>,
}

/// Radial PSD in both forms.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RadialPsd {
    /// Bin centres b dfr, mm^-1.
    pub freq_per_mm: Vec<f64>,
    /// Bin width dfr = max(dfx, dfy), mm^-1.
    pub dfr_per_mm: f64,
    /// Azimuthally INTEGRATED PSD, nm^2 mm: sum(integrated) * dfr = mean square.
    pub integrated_nm2_mm: Vec<f64>,
    /// Azimuthal AVERAGE of the two-sided 2-D PSD, nm^2 mm^2 (`None` where a bin holds no
    /// frequency pixel: no value, rather than a 0 that reads as "no power").
    pub average_nm2_mm2: Vec<Option<f64>>,
    /// Full-plane frequency pixels in each bin.
    pub counts: Vec<usize>,
}

impl Psd2d {
    /// Signed fy of row l (FFT order), mm^-1.
    pub fn fy_per_mm(&self, l: usize) -> f64 {
        let li = if l <= self.ny / 2 {
            l as f64
        } else {
            l as f64 - self.ny as f64
        };
        li * self.dfy_per_mm
    }

    /// fx of stored column k, mm^-1.
    pub fn fx_per_mm(&self, k: usize) -> f64 {
        k as f64 * self.dfx_per_mm
    }

    /// How many full-plane pixels stored column k stands for (1 or 2).
    pub fn kx_weight(&self, k: usize) -> f64 {
        if k == 0 || (self.nx.is_multiple_of(2) && k == self.nx / 2) {
            1.0
        } else {
            2.0
        }
    }

    /// P2 at any full-plane index (l, kx), kx in 0..Nx, via Hermitian symmetry.
    pub fn get(&self, l: usize, kx: usize) -> f64 {
        let nh = self.nx / 2 + 1;
        if kx < nh {
            self.psd_nm2_mm2[(l, kx)]
        } else {
            self.psd_nm2_mm2[((self.ny - l) % self.ny, self.nx - kx)]
        }
    }

    /// sum P2 dfx dfy over the full plane: the mean square (nm^2) of the windowed map.
    pub fn total_power(&self) -> f64 {
        let mut s = 0.0;
        for (k, col) in self.psd_nm2_mm2.columns().into_iter().enumerate() {
            s += self.kx_weight(k) * col.sum();
        }
        s * self.dfx_per_mm * self.dfy_per_mm
    }

    /// Folded marginal along X, ONE-SIDED nm^2 mm: P1x(fx) = 2 sum_l P2(fx, f_l) dfy
    /// (factor 1 at fx = 0 and Nyquist).
    pub fn marginal_x(&self) -> Psd1d {
        let psd: Vec<f64> = self
            .psd_nm2_mm2
            .columns()
            .into_iter()
            .enumerate()
            .map(|(k, col)| self.kx_weight(k) * col.sum() * self.dfy_per_mm)
            .collect();
        self.as_psd1d(Axis::X, psd, self.nx, self.dfx_per_mm)
    }

    /// Folded marginal along Y, ONE-SIDED nm^2 mm: P1y(fy) = 2 sum_kx P2(f_kx, fy) dfx.
    pub fn marginal_y(&self) -> Psd1d {
        let ny = self.ny;
        let row_sum = |l: usize| -> f64 {
            self.psd_nm2_mm2
                .row(l)
                .iter()
                .enumerate()
                .map(|(k, p)| self.kx_weight(k) * p)
                .sum()
        };
        let psd: Vec<f64> = (0..=ny / 2)
            .map(|l| {
                let mirror = (ny - l) % ny;
                let v = if mirror == l {
                    row_sum(l)
                } else {
                    row_sum(l) + row_sum(mirror)
                };
                v * self.dfx_per_mm
            })
            .collect();
        self.as_psd1d(Axis::Y, psd, ny, self.dfy_per_mm)
    }

    fn as_psd1d(&self, axis: Axis, psd: Vec<f64>, n: usize, df: f64) -> Psd1d {
        Psd1d {
            axis,
            freq_per_mm: (0..psd.len()).map(|k| k as f64 * df).collect(),
            psd_nm2_mm: psd,
            df_per_mm: df,
            spacing_mm: 1.0 / (n as f64 * df),
            window: self.window,
            enbw_bins: self.window.enbw_bins(n),
            n_lines: match axis {
                Axis::X => self.ny,
                Axis::Y => self.nx,
            },
            n_segments: 0,
            biased_bins: self.window.main_lobe_half_width_bins() + 1,
            removed: self.removed.clone(),
        }
    }

    /// Calls f(|f|, full-plane weight, P2) for every stored pixel.
    fn for_each_radius(&self, mut f: impl FnMut(f64, f64, f64)) {
        for l in 0..self.ny {
            let fy = self.fy_per_mm(l);
            for (k, p) in self.psd_nm2_mm2.row(l).iter().enumerate() {
                let fx = self.fx_per_mm(k);
                f((fx * fx + fy * fy).sqrt(), self.kx_weight(k), *p);
            }
        }
    }

    /// Radial PSD (both forms).
    pub fn radial(&self) -> RadialPsd {
        let dfr = self.dfx_per_mm.max(self.dfy_per_mm);
        let fxn = (self.nx / 2) as f64 * self.dfx_per_mm;
        let fyn = (self.ny / 2) as f64 * self.dfy_per_mm;
        let nb = ((fxn * fxn + fyn * fyn).sqrt() / dfr + 0.5).floor() as usize + 1;
        let mut sum = vec![0.0; nb];
        let mut cnt = vec![0.0; nb];
        self.for_each_radius(|r, w, p| {
            let b = ((r / dfr + 0.5).floor() as usize).min(nb - 1);
            sum[b] += w * p;
            cnt[b] += w;
        });
        let da = self.dfx_per_mm * self.dfy_per_mm;
        RadialPsd {
            freq_per_mm: (0..nb).map(|b| b as f64 * dfr).collect(),
            dfr_per_mm: dfr,
            integrated_nm2_mm: sum.iter().map(|s| s * da / dfr).collect(),
            average_nm2_mm2: sum
                .iter()
                .zip(&cnt)
                .map(|(s, c)| (*c > 0.0).then(|| s / c))
                .collect(),
            counts: cnt.iter().map(|c| *c as usize).collect(),
        }
    }

    /// Band RMS (nm) over the annulus f1 <= |f| <= f2 mm^-1 (pixel sums).
    pub fn annulus_rms(&self, f1_per_mm: f64, f2_per_mm: f64) -> f64 {
        let mut s = 0.0;
        self.for_each_radius(|r, w, p| {
            if r >= f1_per_mm && r <= f2_per_mm {
                s += w * p;
            }
        });
        (s * self.dfx_per_mm * self.dfy_per_mm).sqrt()
    }
}

/// Two-sided 2-D PSD of a map (form removal per `opts.remove`, then the valid-pixel mean).
pub fn psd_2d(s: &Surface, opts: &PsdOptions) -> Result<Psd2d, SpectrumError> {
    opts.window.validate()?;
    let (dx, dy) = s.pixel_mm("a 2-D PSD")?;
    let p = prepare(s, &opts.remove)?;
    let model = p.model.as_ref();
    let (ny, nx) = p.surface.dim();
    if nx < 2 || ny < 2 {
        return Err(SpectrumError::TooSmall(format!(
            "{ny} x {nx} map (at least 2 x 2 needed)"
        )));
    }
    let h = p.surface.heights_nm();
    let v = p.surface.valid();
    let mean = match model {
        Some(m) => m.residual_mean,
        None => p.surface.valid_heights().sum::<f64>() / p.surface.valid_count() as f64,
    };
    let wx = opts.window.coefficients(nx);
    let wy = opts.window.coefficients(ny);
    let mut energy = 0.0;
    for ((i, j), &ok) in v.indexed_iter() {
        if ok {
            let w = wy[i] * wx[j];
            energy += w * w;
        }
    }
    if energy <= 0.0 {
        return Err(SpectrumError::TooSmall(
            "the window is zero on every valid pixel".into(),
        ));
    }
    let nh = nx / 2 + 1;

    // Rows: real FFT of the windowed, masked map.
    let rplan = RealFftPlanner::<f64>::new().plan_fft_forward(nx);
    let mut spec = vec![Complex::new(0.0, 0.0); ny * nh];
    spec.par_chunks_mut(nh).enumerate().for_each_init(
        || {
            (
                rplan.make_input_vec(),
                rplan.make_scratch_vec(),
                vec![0.0; nx],
            )
        },
        |(input, scratch, mrow), (i, out)| {
            match model {
                Some(m) => m.row(i, mrow),
                None => mrow.fill(0.0),
            }
            let (hz, hv) = (h.row(i), v.row(i));
            let wyi = wy[i];
            for ((((dst, &z), &ok), &mv), &wxj) in
                input.iter_mut().zip(hz).zip(hv).zip(mrow.iter()).zip(&wx)
            {
                *dst = if ok { (z - mv - mean) * wyi * wxj } else { 0.0 };
            }
            let _ = rplan.process_with_scratch(input, out, scratch);
        },
    );

    // Columns: complex FFTs over blocks of columns gathered into contiguous buffers; the
    // output is written column-major so every block owns a contiguous slice.
    const B: usize = 16;
    let cplan = FftPlanner::<f64>::new().plan_fft_forward(ny);
    let scale = dx * dy / energy;
    let mut out = vec![0.0f64; nh * ny];
    out.par_chunks_mut(ny * B).enumerate().for_each_init(
        || {
            (
                vec![Complex::new(0.0, 0.0); ny * B],
                vec![Complex::new(0.0, 0.0); cplan.get_inplace_scratch_len()],
            )
        },
        |(buf, scratch), (b, dst)| {
            let k0 = b * B;
            let cnt = dst.len() / ny;
            for l in 0..ny {
                let row = &spec[l * nh + k0..l * nh + k0 + cnt];
                for (c, val) in row.iter().enumerate() {
                    buf[c * ny + l] = *val;
                }
            }
            cplan.process_with_scratch(&mut buf[..cnt * ny], scratch);
            for (d, s) in dst.iter_mut().zip(buf.iter()) {
                *d = s.norm_sqr() * scale;
            }
        },
    );
    let psd = Array2::from_shape_vec((nh, ny), out)
        .map_err(|e| SpectrumError::TooSmall(e.to_string()))?
        .reversed_axes();
    Ok(Psd2d {
        psd_nm2_mm2: psd,
        nx,
        ny,
        dfx_per_mm: 1.0 / (nx as f64 * dx),
        dfy_per_mm: 1.0 / (ny as f64 * dy),
        window: opts.window,
        removed: p.removed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use bonnetlab_surface::rng::Rng;

    #[test]
    fn matches_brute_force_2d_dft() {
        let (ny, nx, dx, dy) = (6, 9, 0.3, 0.2);
        let mut r = Rng::new(5);
        let z = Array2::from_shape_fn((ny, nx), |_| r.normal());
        let s = Surface::new(z.clone(), Some(dx), Some(dy)).unwrap();
        let opts = PsdOptions {
            remove: vec![],
            window: Window::Hann,
            ..PsdOptions::default()
        };
        let p = psd_2d(&s, &opts).unwrap();
        let mean = z.sum() / (nx * ny) as f64;
        let wx = Window::Hann.coefficients(nx);
        let wy = Window::Hann.coefficients(ny);
        let e: f64 = wy.iter().map(|a| a * a).sum::<f64>() * wx.iter().map(|a| a * a).sum::<f64>();
        for l in 0..ny {
            for kx in 0..nx {
                let (mut re, mut im) = (0.0, 0.0);
                for i in 0..ny {
                    for j in 0..nx {
                        let ph = -2.0
                            * std::f64::consts::PI
                            * ((l * i) as f64 / ny as f64 + (kx * j) as f64 / nx as f64);
                        let a = (z[(i, j)] - mean) * wy[i] * wx[j];
                        re += a * ph.cos();
                        im += a * ph.sin();
                    }
                }
                let expect = dx * dy * (re * re + im * im) / e;
                let got = p.get(l, kx);
                assert!(
                    (got - expect).abs() < 1e-10 * expect.max(1e-8),
                    "({l},{kx}) {got} vs {expect}"
                );
            }
        }
    }
}
