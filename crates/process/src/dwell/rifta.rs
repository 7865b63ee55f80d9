//! RIFTA-class dwell solver: an inverse filter in the Fourier domain, refined iteratively, made
//! non-negative by a uniform dwell offset.
//!
//! Level 1 is the regularised inverse filter T0 = F^-1[Z(f) B*(f) / (|B(f)|^2 + mu)] of the
//! desired removal on the dwell grid (mu = (gamma max|B|)^2: frequencies where the TIF is weaker
//! than gamma of its peak are not chased). Level 1 ignores that only the clear aperture matters
//! and that the dwell grid is not periodic, so level 2 refines it: preconditioned conjugate
//! gradients on the normal equations
//!
//!   (B^T P B + mu I) T = B^T P Z,
//!
//! where P keeps the CA and removes piston and tilt there, with the level-1 filter
//! (|B|^2 + mu)^-1 as the preconditioner. Each pass costs three FFT pairs.
//!
//! Non-negativity: T - min(T). On the CA a uniform dwell is a pure piston (the CA lies a TIF
//! half-width inside the dwell grid), so the residual is unchanged; the price is total dwell.
//!
//! Trade-off: gamma is the knob. A smaller gamma lets T reach finer detail (smaller residual)
//! but lets it oscillate more, and the offset that lifts its negative lobes costs total dwell.
//! [`rifta_trade_off`] sweeps it.

use ndarray::Array2;
use rustfft::num_complex::Complex;

use super::{finish, DwellProblem, DwellSolution, PistonTilt, TradeOffPoint};
use crate::error::ProcessError;
use crate::fft::Fft2;

/// Options of [`solve_rifta`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RiftaOptions {
    /// Relative threshold gamma (fraction of the TIF's peak transfer).
    pub gamma: f64,
    /// Level-2 conjugate-gradient passes (the most; it stops earlier on `rel_tol`).
    pub max_passes: usize,
    /// Stop when the preconditioned residual norm falls below this fraction of its start.
    pub rel_tol: f64,
}

impl Default for RiftaOptions {
    fn default() -> Self {
        RiftaOptions {
            gamma: 1e-3,
            max_passes: 40,
            rel_tol: 1e-4,
        }
    }
}

type C64 = Complex<f64>;

/// Frequency-domain workspace: transforms between dwell-grid arrays and half spectra.
struct Spectral<'a> {
    fft: &'a Fft2,
    rows: usize,
    cols: usize,
    real: Vec<f64>,
    tmp: Vec<C64>,
    weights: Vec<f64>,
}

impl Spectral<'_> {
    fn forward(&mut self, x: &Array2<f64>, out: &mut [C64]) {
        let n1 = self.fft.shape().1;
        self.real.iter_mut().for_each(|v| *v = 0.0);
        for (i, row) in x.rows().into_iter().enumerate() {
            self.real[i * n1..i * n1 + self.cols]
                .iter_mut()
                .zip(row)
                .for_each(|(d, s)| *d = *s);
        }
        self.fft.forward(&mut self.real, &mut self.tmp, out);
    }

    /// Inverse transform of `spec` (kept), cropped to the dwell grid.
    fn inverse(&mut self, spec: &[C64], scratch: &mut [C64]) -> Array2<f64> {
        let n1 = self.fft.shape().1;
        scratch.copy_from_slice(spec);
        self.fft.inverse(scratch, &mut self.tmp, &mut self.real);
        Array2::from_shape_fn((self.rows, self.cols), |(i, j)| self.real[i * n1 + j])
    }

    fn dot(&self, a: &[C64], b: &[C64]) -> f64 {
        a.iter()
            .zip(b)
            .zip(&self.weights)
            .map(|((x, y), w)| w * (x * y.conj()).re)
            .sum()
    }
}

/// Solves the dwell problem with the RIFTA-class inverse filter and refinement.
pub fn solve_rifta(p: &DwellProblem, o: &RiftaOptions) -> Result<DwellSolution, ProcessError> {
    if !(o.gamma > 0.0 && o.gamma < 1.0) {
        return Err(ProcessError::invalid("RIFTA gamma must be in (0, 1)"));
    }
    let mut conv = p.convolver();
    let proj = PistonTilt::new(&p.aperture);
    let bh: Vec<C64> = conv.kernel_spectrum().to_vec();
    let bmax2 = bh.iter().fold(0.0f64, |m, k| m.max(k.norm_sqr()));
    if bmax2 <= 0.0 {
        return Err(ProcessError::Processing("the TIF removes nothing".into()));
    }
    let mu = o.gamma * o.gamma * bmax2;
    let (rows, cols) = p.dim();
    let t_best = {
        let fft = conv.fft();
        let len = fft.spectrum_len();
        let (n0, n1) = fft.shape();
        let mut sp = Spectral {
            fft,
            rows,
            cols,
            real: vec![0.0; n0 * n1],
            tmp: vec![C64::new(0.0, 0.0); len],
            weights: (0..len).map(|k| fft.parseval_weight(k)).collect(),
        };
        let zero = C64::new(0.0, 0.0);
        let mut scratch = vec![zero; len];
        let mut buf = vec![zero; len];
        // Level 1: regularised inverse filter of the desired removal.
        let mut zh = vec![zero; len];
        sp.forward(&p.desired_nm, &mut zh);
        let mut th: Vec<C64> = zh
            .iter()
            .zip(&bh)
            .map(|(z, b)| z * b.conj() / (b.norm_sqr() + mu))
            .collect();
        // q = P B x (spatial) for a spectrum x.
        let pb = |sp: &mut Spectral, x: &[C64], scratch: &mut [C64]| {
            let bx: Vec<C64> = x.iter().zip(&bh).map(|(a, b)| a * b).collect();
            proj.residual(&sp.inverse(&bx, scratch))
        };
        // Residual of the current iterate on the CA and the gradient side.
        let mut res = proj.residual(
            &(&p.desired_nm
                - &{
                    let bt: Vec<C64> = th.iter().zip(&bh).map(|(a, b)| a * b).collect();
                    sp.inverse(&bt, &mut scratch)
                }),
        );
        // r = B^T P (Z - B t) - mu t, in the frequency domain.
        sp.forward(&res, &mut buf);
        let mut rh: Vec<C64> = buf
            .iter()
            .zip(&bh)
            .zip(&th)
            .map(|((q, b), t)| q * b.conj() - t * mu)
            .collect();
        let precond = |r: &[C64]| -> Vec<C64> {
            r.iter()
                .zip(&bh)
                .map(|(x, b)| x / (b.norm_sqr() + mu))
                .collect()
        };
        let mut zr = precond(&rh);
        let mut dh = zr.clone();
        let mut rz = sp.dot(&rh, &zr);
        let rz0 = rz.abs().max(f64::MIN_POSITIVE);
        let mut best = (proj.rms(&res), th.clone());
        let mut passes = 0;
        for _ in 0..o.max_passes {
            if rz.abs() <= o.rel_tol * o.rel_tol * rz0 {
                break;
            }
            let q = pb(&mut sp, &dh, &mut scratch);
            sp.forward(&q, &mut buf);
            let adh: Vec<C64> = buf
                .iter()
                .zip(&bh)
                .zip(&dh)
                .map(|((q, b), d)| q * b.conj() + d * mu)
                .collect();
            let dad = sp.dot(&dh, &adh);
            if dad <= 0.0 {
                break;
            }
            let alpha = rz / dad;
            th.iter_mut().zip(&dh).for_each(|(t, d)| *t += d * alpha);
            rh.iter_mut().zip(&adh).for_each(|(r, a)| *r -= a * alpha);
            res.scaled_add(-alpha, &q);
            passes += 1;
            let rms = proj.rms(&res);
            if rms < best.0 {
                best = (rms, th.clone());
            }
            zr = precond(&rh);
            let rz_new = sp.dot(&rh, &zr);
            let beta = rz_new / rz;
            rz = rz_new;
            dh.iter_mut().zip(&zr).for_each(|(d, z)| *d = z + *d * beta);
        }
        (sp.inverse(&best.1, &mut scratch), passes)
    };
    let (mut t, passes) = t_best;
    let min = t.iter().fold(f64::INFINITY, |m, &v| m.min(v));
    if min < 0.0 {
        t.mapv_inplace(|v| v - min);
    }
    let mut sol = finish(p, &proj, &mut conv, t, "rifta", passes, Vec::new());
    sol.trade_off = vec![TradeOffPoint {
        parameter: o.gamma,
        residual_rms_nm: sol.residual_rms_nm,
        total_dwell_s: sol.total_dwell_s,
    }];
    Ok(sol)
}

/// Residual vs total dwell over a set of thresholds gamma (each a full solve).
pub fn rifta_trade_off(
    p: &DwellProblem,
    gammas: &[f64],
    base: &RiftaOptions,
) -> Result<Vec<TradeOffPoint>, ProcessError> {
    gammas
        .iter()
        .map(|&g| solve_rifta(p, &RiftaOptions { gamma: g, ..*base }).map(|s| s.trade_off[0]))
        .collect()
}
