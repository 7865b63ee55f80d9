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
//! (|B|^2 + mu)^-1 as the preconditioner. The iterate lives in the frequency domain, so each
//! pass costs one inverse and one forward real FFT of the dwell grid (B d back to space for P,
//! then B^T of the projected result) and a few fused passes over the spectra; nothing is
//! allocated inside the loop.
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

/// The CA pixels of the dwell grid as flat indices into the transform's real array, with an
/// orthonormal piston + tilt basis over them (the projection P of the module docs).
pub(crate) struct CaProjector {
    pub(crate) flat: Vec<usize>,
    basis: Vec<Vec<f64>>,
    /// The basis interleaved per pixel (missing vectors as zeros), for the fused passes.
    basis_pp: Vec<[f64; 3]>,
}

impl CaProjector {
    pub(crate) fn new(p: &DwellProblem, n1: usize) -> CaProjector {
        let idx: Vec<(usize, usize)> = p
            .aperture
            .indexed_iter()
            .filter(|(_, &m)| m)
            .map(|(ij, _)| ij)
            .collect();
        let n = idx.len().max(1) as f64;
        let (mi, mj) = idx
            .iter()
            .fold((0.0, 0.0), |(a, b), &(i, j)| (a + i as f64, b + j as f64));
        let (mi, mj) = (mi / n, mj / n);
        let raw = [
            vec![1.0; idx.len()],
            idx.iter().map(|&(_, j)| j as f64 - mj).collect::<Vec<_>>(),
            idx.iter().map(|&(i, _)| i as f64 - mi).collect::<Vec<_>>(),
        ];
        let mut basis: Vec<Vec<f64>> = Vec::new();
        for mut v in raw {
            for u in &basis {
                let d: f64 = v.iter().zip(u).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(u).for_each(|(a, b)| *a -= d * b);
            }
            let norm = v.iter().map(|a| a * a).sum::<f64>().sqrt();
            if norm > 1e-9 * n.sqrt() {
                v.iter_mut().for_each(|a| *a /= norm);
                basis.push(v);
            }
        }
        let basis_pp = (0..idx.len())
            .map(|k| {
                let mut u = [0.0; 3];
                for (x, b) in u.iter_mut().zip(&basis) {
                    *x = b[k];
                }
                u
            })
            .collect();
        CaProjector {
            flat: idx.iter().map(|&(i, j)| i * n1 + j).collect(),
            basis,
            basis_pp,
        }
    }

    /// Replaces `real` by P `real`: CA values with piston and tilt removed (also left in `v`),
    /// zero elsewhere. Two passes: gather with the basis dot products, then subtract and scatter.
    pub(crate) fn project_in_place(&self, real: &mut [f64], v: &mut [f64]) {
        let mut dots = [0.0; 3];
        for ((d, &f), u) in v.iter_mut().zip(&self.flat).zip(&self.basis_pp) {
            *d = real[f];
            dots[0] += *d * u[0];
            dots[1] += *d * u[1];
            dots[2] += *d * u[2];
        }
        real.iter_mut().for_each(|x| *x = 0.0);
        for ((d, &f), u) in v.iter_mut().zip(&self.flat).zip(&self.basis_pp) {
            *d -= dots[0] * u[0] + dots[1] * u[1] + dots[2] * u[2];
            real[f] = *d;
        }
    }

    fn project(&self, v: &mut [f64]) {
        for u in &self.basis {
            let d: f64 = v.iter().zip(u).map(|(x, y)| x * y).sum();
            v.iter_mut().zip(u).for_each(|(x, y)| *x -= d * y);
        }
    }

    /// Writes `v` onto the CA of a zeroed `real`.
    fn scatter(&self, v: &[f64], real: &mut [f64]) {
        real.iter_mut().for_each(|x| *x = 0.0);
        v.iter().zip(&self.flat).for_each(|(s, &k)| real[k] = *s);
    }

    pub(crate) fn rms(&self, v: &[f64]) -> f64 {
        (v.iter().map(|x| x * x).sum::<f64>() / self.flat.len().max(1) as f64).sqrt()
    }
}

/// Solves the dwell problem with the RIFTA-class inverse filter and refinement.
///
/// FFT count: the kernel spectrum, one forward of the desired removal, one inverse + forward
/// for the start residual, one inverse + forward per pass, one inverse for the dwell map and
/// two for the final evaluation ([`DwellProblem::evaluate`]'s convolution): 2 passes + 7.
pub fn solve_rifta(p: &DwellProblem, o: &RiftaOptions) -> Result<DwellSolution, ProcessError> {
    let mut conv = p.convolver();
    let (mut t, passes) = rifta_unlifted(p, o, &mut conv)?;
    let min = t.iter().fold(f64::INFINITY, |m, &v| m.min(v));
    if min < 0.0 {
        t.mapv_inplace(|v| v - min);
    }
    let proj = PistonTilt::new(&p.aperture);
    let mut sol = finish(p, &proj, &mut conv, t, "rifta", passes, Vec::new());
    sol.trade_off = vec![TradeOffPoint {
        parameter: o.gamma,
        residual_rms_nm: sol.residual_rms_nm,
        total_dwell_s: sol.total_dwell_s,
    }];
    Ok(sol)
}

/// The refined inverse-filter dwell map before the offset that makes it non-negative (it has
/// negative lobes), and the number of refinement passes, computed with `conv` (the problem's
/// convolver, whose transform count then includes this solve).
pub(crate) fn rifta_unlifted(
    p: &DwellProblem,
    o: &RiftaOptions,
    conv: &mut crate::fft::Convolver,
) -> Result<(Array2<f64>, usize), ProcessError> {
    if !(o.gamma > 0.0 && o.gamma < 1.0) {
        return Err(ProcessError::invalid("RIFTA gamma must be in (0, 1)"));
    }
    let bh: Vec<C64> = conv.kernel_spectrum().to_vec();
    let bmax2 = bh.iter().fold(0.0f64, |m, k| m.max(k.norm_sqr()));
    if bmax2 <= 0.0 {
        return Err(ProcessError::Processing("the TIF removes nothing".into()));
    }
    let mu = o.gamma * o.gamma * bmax2;
    let (rows, cols) = p.dim();
    let (t, passes) = {
        let fft = conv.fft();
        let len = fft.spectrum_len();
        let (n0, n1) = fft.shape();
        let ca = CaProjector::new(p, n1);
        let zero = C64::new(0.0, 0.0);
        // Preconditioner (|B|^2 + mu)^-1, the level-1 filter.
        let inv_m: Vec<f64> = bh.iter().map(|b| 1.0 / (b.norm_sqr() + mu)).collect();
        let mut real = vec![0.0; n0 * n1];
        let mut tmp = vec![zero; len];
        let mut work = vec![zero; len];
        // Level 1: regularised inverse filter of the desired removal.
        for (i, row) in p.desired_nm.rows().into_iter().enumerate() {
            real[i * n1..i * n1 + cols]
                .iter_mut()
                .zip(row)
                .for_each(|(d, s)| *d = *s);
        }
        fft.forward(&mut real, &mut tmp, &mut work);
        let mut th: Vec<C64> = work
            .iter()
            .zip(&bh)
            .zip(&inv_m)
            .map(|((z, b), m)| z * b.conj() * m)
            .collect();
        // Start residual P (Z - B t) on the CA.
        let mut zca = vec![0.0; ca.flat.len()];
        for (d, &k) in zca.iter_mut().zip(&ca.flat) {
            *d = p.desired_nm[(k / n1, k % n1)];
        }
        work.iter_mut()
            .zip(&th)
            .zip(&bh)
            .for_each(|((w, t), b)| *w = t * b);
        fft.inverse(&mut work, &mut tmp, &mut real);
        let mut res = vec![0.0; ca.flat.len()];
        res.iter_mut()
            .zip(&ca.flat)
            .zip(&zca)
            .for_each(|((r, &k), z)| *r = z - real[k]);
        ca.project(&mut res);
        // r = B^T P (Z - B t) - mu t, in the frequency domain.
        ca.scatter(&res, &mut real);
        fft.forward(&mut real, &mut tmp, &mut work);
        let mut rh: Vec<C64> = work
            .iter()
            .zip(&bh)
            .zip(&th)
            .map(|((q, b), t)| q * b.conj() - t * mu)
            .collect();
        // Parseval weight of each transposed-spectrum row, and M^-1 with it folded in.
        let row_w: Vec<f64> = (0..len / n0)
            .map(|k1| fft.parseval_weight(k1 * n0))
            .collect();
        let mut rz = 0.0;
        for (k1, (rr, mm)) in rh.chunks(n0).zip(inv_m.chunks(n0)).enumerate() {
            rz += row_w[k1]
                * rr.iter()
                    .zip(mm)
                    .map(|(x, m)| x.norm_sqr() * m)
                    .sum::<f64>();
        }
        let rz0 = rz.abs().max(f64::MIN_POSITIVE);
        let mut best_rms = ca.rms(&res);
        let mut best = th.clone();
        // d = M^-1 r + beta d is formed at the start of each pass (beta = 0 on the first).
        let mut dh = vec![zero; len];
        let mut beta = 0.0;
        let mut q = vec![0.0; ca.flat.len()];
        let mut passes = 0;
        for _ in 0..o.max_passes {
            if rz.abs() <= o.rel_tol * o.rel_tol * rz0 {
                break;
            }
            // q = P B d (spatial, CA only), then A d = B^T q + mu d (into `work`).
            for (((d, w), b), (r, m)) in dh
                .iter_mut()
                .zip(work.iter_mut())
                .zip(&bh)
                .zip(rh.iter().zip(&inv_m))
            {
                *d = r * m + *d * beta;
                *w = *d * b;
            }
            fft.inverse(&mut work, &mut tmp, &mut real);
            ca.project_in_place(&mut real, &mut q);
            fft.forward(&mut real, &mut tmp, &mut work);
            let mut dad = 0.0;
            for (k1, ((wr, br), dr)) in work
                .chunks_mut(n0)
                .zip(bh.chunks(n0))
                .zip(dh.chunks(n0))
                .enumerate()
            {
                let mut part = 0.0;
                for ((w, b), d) in wr.iter_mut().zip(br).zip(dr) {
                    *w = *w * b.conj() + d * mu;
                    part += d.re * w.re + d.im * w.im;
                }
                dad += row_w[k1] * part;
            }
            if dad <= 0.0 {
                break;
            }
            let alpha = rz / dad;
            let mut rz_new = 0.0;
            for (k1, (((tr, rr), (dr, ar)), mr)) in th
                .chunks_mut(n0)
                .zip(rh.chunks_mut(n0))
                .zip(dh.chunks(n0).zip(work.chunks(n0)))
                .zip(inv_m.chunks(n0))
                .enumerate()
            {
                let mut part = 0.0;
                for ((((t, r), d), a), m) in
                    tr.iter_mut().zip(rr.iter_mut()).zip(dr).zip(ar).zip(mr)
                {
                    *t += d * alpha;
                    *r -= a * alpha;
                    part += r.norm_sqr() * m;
                }
                rz_new += row_w[k1] * part;
            }
            let mut ss = 0.0;
            for (r, x) in res.iter_mut().zip(&q) {
                *r -= alpha * x;
                ss += *r * *r;
            }
            passes += 1;
            let rms = (ss / res.len().max(1) as f64).sqrt();
            if rms < best_rms {
                best_rms = rms;
                best.copy_from_slice(&th);
            }
            beta = rz_new / rz;
            rz = rz_new;
        }
        fft.inverse(&mut best, &mut tmp, &mut real);
        (
            Array2::from_shape_fn((rows, cols), |(i, j)| real[i * n1 + j]),
            passes,
        )
    };
    Ok((t, passes))
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
