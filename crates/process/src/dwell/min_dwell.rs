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
//! Optional coarse dwell grid (`max_coarsening > 1`, off by default; [`super::coarse`]): steps
//! 1-3 run on nodes every `s` fine pixels (cubic B-spline prolongation by default, exact coarse
//! TIF, desired removal low-passed below the coarse Nyquist frequency and sampled at the nodes),
//! then `corrections` cycles of defect correction (FAS: a linear term makes the coarse gradient
//! the fine objective's gradient at the current map, then `correction_iterations` coarse
//! passes) and `fine_iterations` fine passes. On case B at s = 5 it solves a point in ~1/20 of
//! the fine grid's CPU time with less total dwell, but its residual stays 0.4 % above the
//! target (0.3010 nm; reports/performance_process.md), so it is not the default.
//!
//! Tried and dropped (see reports/performance_process.md): a scaled projection with RIFTA's
//! Fourier preconditioner inside the projected step diverges (a non-diagonal metric with a
//! Euclidean clip amplifies the clipped error); active-set preconditioned CG on the free pixels
//! is stable but gains less per transform than FISTA (pixels reach zero on nearly every pass);
//! gradient-based adaptive restart of FISTA never fired on these cases.

use ndarray::Array2;
use rustfft::num_complex::Complex;
use serde::Serialize;

use super::coarse::{self, CoarseGrid};
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
    /// Largest coarse dwell-grid factor (fine pixels per node, per axis); 1: solve on the fine
    /// dwell grid. The factor used is the largest one whose coarse Nyquist band the TIF passes
    /// with at most `coarse_tol` of its peak transfer (see [`super::coarse`]).
    pub max_coarsening: usize,
    /// Relative TIF transfer allowed above the coarse grid's Nyquist frequency.
    pub coarse_tol: f64,
    /// Defect-correction cycles (fine residual fed back to the coarse grid).
    pub corrections: usize,
    /// Coarse healing iterations per correction cycle.
    pub correction_iterations: usize,
    /// Healing iterations on the fine dwell grid at the end (coarse grid only; 0: none).
    pub fine_iterations: usize,
    /// Coarse-node spline: 1 bilinear (tent), 2 cubic B-spline (images of the node lattice
    /// weaker by about the square of the tent's).
    pub spline_order: usize,
}

impl Default for MinDwellOptions {
    fn default() -> Self {
        MinDwellOptions {
            rifta: RiftaOptions::default(),
            iterations: 300,
            offsets: [-0.1, -0.05, -0.025, 0.0, 0.03, 0.08, 0.25],
            max_coarsening: 1,
            coarse_tol: 1e-4,
            corrections: 2,
            correction_iterations: 100,
            fine_iterations: 0,
            spline_order: 2,
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
    /// The fine dwell grid's convolver (evaluation, corrections, fine healing).
    conv: Convolver,
    proj: PistonTilt,
    /// The coarse dwell grid, when the TIF allows one.
    coarse: Option<Coarse>,
    /// The unconstrained start on the grid the healing runs on (coarse if any).
    t0: Array2<f64>,
    /// RIFTA's own lift, as a removal (nm): -min(T0) times the TIF volume per node.
    rifta_lift_nm: f64,
    /// Removal (nm) of a unit uniform dwell per node of the healing grid.
    vol: f64,
    /// Transforms of the start (kernel spectra, RIFTA passes).
    start_ffts: usize,
}

/// The coarse level: its grid and problem, convolver and the coarse desired removal before
/// defect correction.
struct Coarse {
    grid: CoarseGrid,
    conv: Convolver,
    proj: PistonTilt,
}

impl<'a> MinDwell<'a> {
    pub fn new(p: &'a DwellProblem, o: &MinDwellOptions) -> Result<MinDwell<'a>, ProcessError> {
        if o.iterations == 0 || o.iterations > 100_000 {
            return Err(ProcessError::invalid("iterations must be in 1..=100000"));
        }
        if o.correction_iterations > 100_000 || o.fine_iterations > 100_000 || o.corrections > 100 {
            return Err(ProcessError::invalid(
                "correction and fine iterations must be at most 100000, corrections at most 100",
            ));
        }
        if !(1..=2).contains(&o.spline_order) {
            return Err(ProcessError::invalid(
                "spline_order must be 1 (bilinear) or 2 (cubic)",
            ));
        }
        if !(o.coarse_tol.is_finite() && o.coarse_tol >= 0.0) {
            return Err(ProcessError::invalid("coarse_tol must be >= 0"));
        }
        let mut conv = p.convolver();
        let (s0, s1) = {
            let (n0, n1) = conv.fft_shape();
            coarse::factors(
                conv.kernel_spectrum(),
                n0,
                n1,
                o.max_coarsening,
                o.coarse_tol,
            )
        };
        let mut coarse = match CoarseGrid::new(p, s0, s1, o.spline_order)? {
            Some(grid) => {
                let conv = grid.problem.convolver();
                let proj = PistonTilt::new(&grid.problem.aperture);
                Some(Coarse { grid, conv, proj })
            }
            None => None,
        };
        let (t0, vol) = match &mut coarse {
            Some(c) => {
                let (mut t0, _) = rifta_unlifted(&c.grid.problem, &o.rifta, &mut c.conv)?;
                ndarray::Zip::from(&mut t0)
                    .and(&c.grid.free)
                    .for_each(|t, &f| {
                        if !f {
                            *t = 0.0
                        }
                    });
                (t0, c.grid.problem.tif.rate_nm_per_s.sum())
            }
            None => {
                let (t0, _) = rifta_unlifted(p, &o.rifta, &mut conv)?;
                (t0, p.tif.rate_nm_per_s.sum())
            }
        };
        let min = t0.iter().fold(f64::INFINITY, |m, &v| m.min(v));
        let start_ffts =
            conv.fft().transforms() + coarse.as_ref().map_or(0, |c| c.conv.fft().transforms());
        Ok(MinDwell {
            p,
            o: *o,
            conv,
            proj: PistonTilt::new(&p.aperture),
            coarse,
            t0,
            rifta_lift_nm: (-min).max(0.0) * vol,
            vol,
            start_ffts,
        })
    }

    /// The coarse dwell-grid factors (rows, cols) in use ((1, 1): the fine grid).
    pub fn coarsening(&self) -> (usize, usize) {
        self.coarse
            .as_ref()
            .map_or((1, 1), |c| (c.grid.rows.s, c.grid.cols.s))
    }

    fn transforms(&self) -> usize {
        self.conv.fft().transforms()
            + self
                .coarse
                .as_ref()
                .map_or(0, |c| c.conv.fft().transforms())
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
        let before = self.transforms();
        let lift = offset_nm / self.vol;
        let o = self.o;
        let mut t = match &mut self.coarse {
            None => heal(
                self.p,
                &mut self.conv,
                &self.t0,
                lift,
                o.iterations,
                None,
                None,
            ),
            Some(c) => {
                let free = Some(&c.grid.free);
                let mut tc = heal(
                    &c.grid.problem,
                    &mut c.conv,
                    &self.t0,
                    lift,
                    o.iterations,
                    free,
                    None,
                );
                let (s0, s1) = (c.grid.rows.s as f64, c.grid.cols.s as f64);
                for _ in 0..o.corrections {
                    // Minus the fine objective's gradient in the node dwell, per node area.
                    let tf = c.grid.prolong(&tc);
                    let removal = self.conv.apply(tf.view());
                    let rf = self.proj.residual(&(&self.p.desired_nm - &removal));
                    let gf =
                        c.grid.prolong_adjoint(&self.conv.apply_adjoint(rf.view())) / (s0 * s1);
                    // Minus the coarse objective's gradient there.
                    let rc = c
                        .proj
                        .residual(&(&c.grid.problem.desired_nm - &c.conv.apply(tc.view())));
                    let gc = c.conv.apply_adjoint(rc.view());
                    // The linear term that makes the coarse gradient the fine one at tc.
                    let bias = gf - gc;
                    tc = heal(
                        &c.grid.problem,
                        &mut c.conv,
                        &tc,
                        0.0,
                        o.correction_iterations,
                        free,
                        Some(&bias),
                    );
                }
                c.grid.prolong(&tc)
            }
        };
        if self.coarse.is_some() && o.fine_iterations > 0 {
            t = heal(
                self.p,
                &mut self.conv,
                &t,
                0.0,
                o.fine_iterations,
                None,
                None,
            );
        }
        let mut sol = finish(
            self.p,
            &self.proj,
            &mut self.conv,
            t,
            "min-dwell",
            o.iterations,
            Vec::new(),
        );
        // Work of this point: the shared start plus its own healing and evaluation.
        sol.fft_count = self.start_ffts + (self.transforms() - before);
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

/// FISTA from max(t0 + lift, 0), projected on T >= 0 (and T = 0 where `free` is false), step
/// 1 / max|B|^2, on 1/2 ||P (Z - B T)||^2 - <bias, T> (the linear term: defect correction).
fn heal(
    p: &DwellProblem,
    conv: &mut Convolver,
    t0: &Array2<f64>,
    lift: f64,
    iterations: usize,
    free: Option<&Array2<bool>>,
    bias: Option<&Array2<f64>>,
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
    // Upper bound per pixel: infinity where free, 0 where held; the linear term's step.
    let mut cap = vec![0.0; n0 * n1];
    let mut lin = vec![0.0; n0 * n1];
    for i in 0..rows {
        for j in 0..cols {
            let k = i * n1 + j;
            z[k] = p.desired_nm[(i, j)];
            cap[k] = if free.is_none_or(|f| f[(i, j)]) {
                f64::INFINITY
            } else {
                0.0
            };
            t[k] = (t0[(i, j)] + lift).max(0.0).min(cap[k]);
            lin[k] = bias.map_or(0.0, |b| b[(i, j)] / bmax2);
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
            for ((((yk, tk_), g), c), l) in y[r.clone()]
                .iter_mut()
                .zip(t[r.clone()].iter_mut())
                .zip(&real[r.clone()])
                .zip(&cap[r.clone()])
                .zip(&lin[r])
            {
                let tn = (*yk + g + l).max(0.0).min(*c);
                *yk = (tn + beta * (tn - *tk_)).max(0.0).min(*c);
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

#[cfg(test)]
mod coarse_tests {
    use super::*;
    use crate::tif::Tif;

    /// With a TIF several pixels wide the coarse grid is chosen (factor > 1), the map it returns
    /// is non-negative on the fine grid, its figures are the public evaluation of that map, and
    /// defect correction lowers the fine residual of the coarse solve.
    #[test]
    fn coarse_grid_solves_on_the_fine_grid() {
        let mut rng = bonnetlab_surface::rng::Rng::new(11);
        let tif = Tif::gaussian(2.0, 20.0, 1.0, 0.5, 0.5).unwrap();
        let (h0, _) = tif.half_widths();
        let (r, c) = (30 + 2 * h0, 60 + 2 * h0);
        let z = Array2::from_shape_fn((r, c), |(i, j)| {
            20.0 + 5.0 * ((i as f64) / 9.0).sin() * ((j as f64) / 13.0).cos() + 0.1 * rng.normal()
        });
        let a = Array2::from_shape_fn((r, c), |(i, j)| {
            (h0..r - h0).contains(&i) && (h0..c - h0).contains(&j)
        });
        let p = DwellProblem::new(z, a, tif).unwrap();
        let base = MinDwellOptions {
            max_coarsening: 4,
            corrections: 0,
            ..MinDwellOptions::default()
        };
        let mut md = MinDwell::new(&p, &base).unwrap();
        assert!(
            md.coarsening().0 > 1 && md.coarsening().1 > 1,
            "{:?}",
            md.coarsening()
        );
        let plain = md.solve(0.0).unwrap();
        let o = MinDwellOptions {
            corrections: 2,
            ..base
        };
        let corrected = MinDwell::new(&p, &o).unwrap().solve(0.0).unwrap();
        for s in [&plain, &corrected] {
            assert!(s.dwell_s.iter().all(|&v| v >= 0.0));
            let e = p.evaluate(&s.dwell_s).unwrap();
            assert!((e.residual_rms_nm - s.residual_rms_nm).abs() < 1e-12);
        }
        assert!(
            corrected.residual_rms_nm < plain.residual_rms_nm,
            "{} vs {}",
            corrected.residual_rms_nm,
            plain.residual_rms_nm
        );
    }
}
