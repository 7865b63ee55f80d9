//! Minimum-dwell solver: the least total dwell that reaches a residual target.
//!
//! On the clear aperture (CA) a uniform dwell is a pure piston, so every dwell solver chooses an
//! extra uniform removal; RIFTA ([`super::rifta`]) takes the one that lifts the most negative
//! lobe of its unconstrained map to zero, which costs 2-5x the total dwell of published
//! non-negative methods. Here that choice is the trade-off knob:
//!
//! 1. T0 = the refined inverse filter of RIFTA *before* its lift (negative lobes included);
//! 2. for an extra uniform removal `offset_nm` (nm; the lift is offset / TIF volume per pixel),
//!    start from max(T0 + lift, 0): the clipped lobes leave a local error;
//! 3. heal it by accelerated projected gradient (FISTA, Euclidean, T >= 0) on
//!    1/2 || P (Z - B T) ||^2, P = CA with piston and tilt removed. Because P removes piston,
//!    the gradient B^T P r sums to zero: the iterations keep the total dwell (up to what the
//!    projection adds), so the start sets it and the residual falls.
//!
//! [`MinDwell::trade_off`] sweeps the offset (residual vs total dwell); [`MinDwell::pick`]
//! returns the solved point that meets a target (least total dwell with residual <= target, or
//! least residual with total dwell <= a budget).
//!
//! Tried and dropped (see reports/performance_process.md): a scaled projection with RIFTA's
//! Fourier preconditioner inside the projected step diverges (a non-diagonal metric with a
//! Euclidean clip amplifies the clipped error); active-set preconditioned CG on the free pixels
//! is stable but gains less per transform than FISTA (pixels reach zero on nearly every pass);
//! gradient-based adaptive restart of FISTA never fired on these cases.

use ndarray::Array2;
use rustfft::num_complex::Complex;
use serde::Serialize;

use super::rifta::{rifta_unlifted, CaProjector};
use super::{finish, DwellProblem, DwellSolution, PistonTilt, RiftaOptions, TradeOffPoint};
use crate::error::ProcessError;
use crate::fft::Convolver;

type C64 = Complex<f64>;

/// Options of the minimum-dwell solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MinDwellOptions {
    /// The unconstrained start (RIFTA refinement).
    pub rifta: RiftaOptions,
    /// Projected-gradient iterations per offset.
    pub iterations: usize,
    /// Offsets of the trade-off sweep, as fractions of RIFTA's own lift (the removal that makes
    /// its map non-negative).
    pub offsets: [f64; 7],
}

impl Default for MinDwellOptions {
    fn default() -> Self {
        MinDwellOptions {
            rifta: RiftaOptions::default(),
            iterations: 300,
            offsets: [-0.1, -0.05, -0.025, 0.0, 0.03, 0.08, 0.25],
        }
    }
}

/// What the user asks of the trade-off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum DwellTarget {
    /// Least total dwell with residual RMS <= this (nm).
    ResidualRms { nm: f64 },
    /// Least residual with total dwell <= this (s).
    MaxDwell { s: f64 },
    /// No extra uniform removal (offset 0).
    NoOffset,
}

/// A minimum-dwell workspace for one problem: the unconstrained start is computed once and every
/// offset is solved from it.
pub struct MinDwell<'a> {
    p: &'a DwellProblem,
    o: MinDwellOptions,
    conv: Convolver,
    t0: Array2<f64>,
    /// RIFTA's own lift, as a removal (nm): -min(T0) times the TIF volume per pixel.
    rifta_lift_nm: f64,
    vol: f64,
    /// Transforms of the start (kernel spectrum, RIFTA passes).
    start_ffts: usize,
}

impl<'a> MinDwell<'a> {
    pub fn new(p: &'a DwellProblem, o: &MinDwellOptions) -> Result<MinDwell<'a>, ProcessError> {
        if o.iterations == 0 || o.iterations > 100_000 {
            return Err(ProcessError::invalid("iterations must be in 1..=100000"));
        }
        let mut conv = p.convolver();
        let (t0, _) = rifta_unlifted(p, &o.rifta, &mut conv)?;
        let vol = p.tif.rate_nm_per_s.sum();
        let min = t0.iter().fold(f64::INFINITY, |m, &v| m.min(v));
        let start_ffts = conv.fft().transforms();
        Ok(MinDwell {
            p,
            o: *o,
            conv,
            t0,
            rifta_lift_nm: (-min).max(0.0) * vol,
            vol,
            start_ffts,
        })
    }

    /// RIFTA's lift as a uniform removal (nm): the offset scale of the sweep.
    pub fn rifta_lift_nm(&self) -> f64 {
        self.rifta_lift_nm
    }

    /// Solves at one extra uniform removal `offset_nm` (nm), from the shared start.
    pub fn solve(&mut self, offset_nm: f64) -> Result<DwellSolution, ProcessError> {
        if !offset_nm.is_finite() {
            return Err(ProcessError::invalid("offset must be finite"));
        }
        let before = self.conv.fft().transforms();
        let lift = offset_nm / self.vol;
        let t = heal(self.p, &mut self.conv, &self.t0, lift, self.o.iterations);
        let proj = PistonTilt::new(&self.p.aperture);
        let mut sol = finish(
            self.p,
            &proj,
            &mut self.conv,
            t,
            "min-dwell",
            self.o.iterations,
            Vec::new(),
        );
        // Work of this point: the shared start plus its own healing and evaluation.
        sol.fft_count = self.start_ffts + (self.conv.fft().transforms() - before);
        sol.trade_off = vec![TradeOffPoint {
            parameter: offset_nm,
            residual_rms_nm: sol.residual_rms_nm,
            total_dwell_s: sol.total_dwell_s,
        }];
        Ok(sol)
    }

    /// Solves every offset of the sweep (fractions of RIFTA's lift); points in offset order.
    pub fn sweep(&mut self) -> Result<Vec<DwellSolution>, ProcessError> {
        let offs: Vec<f64> = self
            .o
            .offsets
            .iter()
            .map(|f| f * self.rifta_lift_nm)
            .collect();
        offs.iter().map(|&e| self.solve(e)).collect()
    }

    /// The solved point meeting `target`, and the trade-off curve it was chosen from. When no
    /// point meets a residual target, the least residual; when none fits a dwell budget, the
    /// least dwell (the caller reports whether the target was met).
    pub fn pick(
        &mut self,
        target: DwellTarget,
    ) -> Result<(DwellSolution, Vec<TradeOffPoint>), ProcessError> {
        let sols = self.sweep()?;
        let curve: Vec<TradeOffPoint> = sols.iter().map(|s| s.trade_off[0]).collect();
        let rms = |a: &&DwellSolution, b: &&DwellSolution| {
            a.residual_rms_nm.total_cmp(&b.residual_rms_nm)
        };
        let dwell =
            |a: &&DwellSolution, b: &&DwellSolution| a.total_dwell_s.total_cmp(&b.total_dwell_s);
        let chosen = match target {
            DwellTarget::ResidualRms { nm } => sols
                .iter()
                .filter(|s| s.residual_rms_nm <= nm)
                .min_by(dwell)
                .or_else(|| sols.iter().min_by(rms)),
            DwellTarget::MaxDwell { s: budget } => sols
                .iter()
                .filter(|s| s.total_dwell_s <= budget)
                .min_by(rms)
                .or_else(|| sols.iter().min_by(dwell)),
            DwellTarget::NoOffset => sols.iter().min_by(|a, b| {
                a.trade_off[0]
                    .parameter
                    .abs()
                    .total_cmp(&b.trade_off[0].parameter.abs())
            }),
        };
        let chosen = chosen
            .cloned()
            .ok_or_else(|| ProcessError::Processing("the trade-off sweep is empty".into()))?;
        Ok((chosen, curve))
    }
}

/// FISTA from max(t0 + lift, 0), projected on T >= 0 (dwell grid only), step 1 / max|B|^2.
fn heal(
    p: &DwellProblem,
    conv: &mut Convolver,
    t0: &Array2<f64>,
    lift: f64,
    iterations: usize,
) -> Array2<f64> {
    let bh: Vec<C64> = conv.kernel_spectrum().to_vec();
    let bmax2 = bh.iter().fold(0.0f64, |m, k| m.max(k.norm_sqr()));
    let fft = conv.fft();
    let (rows, cols) = p.dim();
    let len = fft.spectrum_len();
    let (n0, n1) = fft.shape();
    let ca = CaProjector::new(p, n1);
    let zero = C64::new(0.0, 0.0);
    // Gradient filter B* / L (the adjoint with the step folded in).
    let filt: Vec<C64> = bh.iter().map(|b| b.conj() / bmax2).collect();
    let mut z = vec![0.0; n0 * n1];
    let mut t = vec![0.0; n0 * n1];
    for i in 0..rows {
        for j in 0..cols {
            z[i * n1 + j] = p.desired_nm[(i, j)];
            t[i * n1 + j] = (t0[(i, j)] + lift).max(0.0);
        }
    }
    let mut y = t.clone();
    let mut real = vec![0.0; n0 * n1];
    let mut tmp = vec![zero; len];
    let mut spec = vec![zero; len];
    let mut v = vec![0.0; ca.flat.len()];
    let mut tk = 1.0f64;
    for _ in 0..iterations {
        real.copy_from_slice(&y);
        fft.forward(&mut real, &mut tmp, &mut spec);
        spec.iter_mut().zip(&bh).for_each(|(s, b)| *s *= b);
        fft.inverse(&mut spec, &mut tmp, &mut real);
        for &f in &ca.flat {
            real[f] = z[f] - real[f];
        }
        ca.project_in_place(&mut real, &mut v);
        fft.forward(&mut real, &mut tmp, &mut spec);
        spec.iter_mut().zip(&filt).for_each(|(s, b)| *s *= b);
        fft.inverse(&mut spec, &mut tmp, &mut real);
        let tk1 = 0.5 * (1.0 + (1.0 + 4.0 * tk * tk).sqrt());
        let beta = (tk - 1.0) / tk1;
        tk = tk1;
        for i in 0..rows {
            let r = i * n1..i * n1 + cols;
            for ((yk, tk_), g) in y[r.clone()]
                .iter_mut()
                .zip(t[r.clone()].iter_mut())
                .zip(&real[r])
            {
                let tn = (*yk + g).max(0.0);
                *yk = (tn + beta * (tn - *tk_)).max(0.0);
                *tk_ = tn;
            }
        }
    }
    Array2::from_shape_fn((rows, cols), |(i, j)| t[i * n1 + j])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::Tif;

    /// A small problem with texture at the pixel scale (seeded): the healed map is
    /// non-negative, the total dwell rises with the offset, and the residual of a solved point
    /// is what the public evaluation of its map gives.
    #[test]
    fn offsets_trade_dwell_for_residual() {
        let mut rng = bonnetlab_surface::rng::Rng::new(7);
        let tif = Tif::gaussian(1.5, 8.0, 1.0, 1.0, 1.0).unwrap();
        let (h0, _) = tif.half_widths();
        let (r, c) = (30 + 2 * h0, 50 + 2 * h0);
        let z = Array2::from_shape_fn((r, c), |(i, j)| {
            20.0 + 5.0 * ((i as f64) / 6.0).sin() * ((j as f64) / 9.0).cos() + rng.normal()
        });
        let a = Array2::from_shape_fn((r, c), |(i, j)| {
            (h0..r - h0).contains(&i) && (h0..c - h0).contains(&j)
        });
        let p = DwellProblem::new(z, a, tif).unwrap();
        let mut md = MinDwell::new(&p, &MinDwellOptions::default()).unwrap();
        let sols = md.sweep().unwrap();
        for w in sols.windows(2) {
            assert!(w[1].total_dwell_s >= w[0].total_dwell_s - 1e-9);
        }
        for s in &sols {
            assert!(s.dwell_s.iter().all(|&v| v >= 0.0));
            let e = p.evaluate(&s.dwell_s).unwrap();
            assert!((e.residual_rms_nm - s.residual_rms_nm).abs() < 1e-12);
        }
        let rifta = super::super::solve_rifta(&p, &RiftaOptions::default()).unwrap();
        let (best, _) = md
            .pick(DwellTarget::MaxDwell {
                s: rifta.total_dwell_s,
            })
            .unwrap();
        assert!(best.total_dwell_s <= rifta.total_dwell_s);
    }
}
