//! Dwell-time solving: find a non-negative dwell map T (s per pixel) on the dwell grid whose
//! removal B * T matches the desired removal Z inside the clear aperture (CA), up to piston and
//! tilt.
//!
//! Conventions (as `shared/data/dwell/README.md` states them for the public cases):
//! - desired removal = surface - min(surface inside the CA);
//! - the dwell grid is the CA grown by the TIF half-width (floor of diameter / 2 / pixel), so
//!   every CA pixel sees the whole TIF and a constant added to T is a pure piston in the CA;
//! - residual = desired - simulated removal inside the CA, piston and tilt removed (least
//!   squares over the CA pixels).
//!
//! Because the CA lies at least a TIF half-width inside the dwell grid, an FFT of the dwell
//! grid's own size (rounded up to a fast length) gives the exact linear convolution on the CA.
//!
//! Two solvers, both returning T >= 0 and both exposing the residual vs total dwell trade-off:
//! [`rifta::solve_rifta`] (thresholded inverse filter, two levels, refinement) and
//! [`iterative::solve_iterative`] (accelerated projected gradient with an optional dwell-time
//! penalty).

pub mod case;
mod coarse;
pub mod feed;
pub mod floor;
pub mod iterative;
pub mod min_dwell;
pub mod rifta;

use ndarray::{Array2, Zip};
use serde::Serialize;

use crate::error::ProcessError;
use crate::fft::{fast_len, Convolver};
use crate::tif::Tif;

pub use case::DwellCase;
pub use floor::dwell_floor_s;
pub use iterative::{solve_iterative, IterativeOptions};
pub use min_dwell::{
    auto_coarsening, tif_rms_width_px, Convergence, DwellTarget, Healer, MinDwell, MinDwellOptions,
    AUTO_SIGMA_NODES,
};
pub use rifta::{solve_rifta, RiftaOptions};

/// A dwell problem on the dwell grid.
#[derive(Debug, Clone)]
pub struct DwellProblem {
    /// Desired removal (nm) on the dwell grid; only CA pixels matter.
    pub desired_nm: Array2<f64>,
    /// The clear aperture on the dwell grid.
    pub aperture: Array2<bool>,
    /// The TIF at the dwell grid's pitch.
    pub tif: Tif,
}

/// One point of the residual vs total dwell trade-off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TradeOffPoint {
    /// The solver's knob (RIFTA: relative threshold; iterative: dwell penalty nm^2/s).
    pub parameter: f64,
    pub residual_rms_nm: f64,
    pub total_dwell_s: f64,
}

/// A solved dwell map and its figures of merit.
#[derive(Debug, Clone)]
pub struct DwellSolution {
    /// Dwell per pixel (s) on the dwell grid, >= 0.
    pub dwell_s: Array2<f64>,
    /// Simulated removal (nm) on the dwell grid (exact on the CA).
    pub removal_nm: Array2<f64>,
    /// Residual (nm) on the dwell grid, piston and tilt removed on the CA, 0 outside it.
    pub residual_nm: Array2<f64>,
    pub residual_rms_nm: f64,
    pub residual_pv_nm: f64,
    pub total_dwell_s: f64,
    pub method: String,
    pub iterations: usize,
    /// Real 2-D FFTs of the dwell grid the solve ran (kernel spectrum and final evaluation
    /// included): the solver's work in units that do not depend on the machine's load.
    pub fft_count: usize,
    /// Residual vs total dwell for the knob values the solver tried.
    pub trade_off: Vec<TradeOffPoint>,
}

impl DwellProblem {
    pub fn new(
        desired_nm: Array2<f64>,
        aperture: Array2<bool>,
        tif: Tif,
    ) -> Result<DwellProblem, ProcessError> {
        if desired_nm.dim() != aperture.dim() {
            return Err(ProcessError::invalid(
                "desired removal and aperture differ in shape",
            ));
        }
        if desired_nm.iter().any(|v| !v.is_finite()) {
            return Err(ProcessError::invalid("desired removal must be finite"));
        }
        let n_ca = aperture.iter().filter(|&&v| v).count();
        if n_ca < 3 {
            return Err(ProcessError::Processing(
                "the clear aperture holds fewer than 3 pixels".into(),
            ));
        }
        // Every CA pixel must be at least the TIF half-width inside the dwell grid.
        let (h0, h1) = tif.half_widths();
        let (r, c) = aperture.dim();
        for ((i, j), &a) in aperture.indexed_iter() {
            if a && (i < h0 || j < h1 || i + h0 >= r || j + h1 >= c) {
                return Err(ProcessError::invalid(
                    "the clear aperture must lie a TIF half-width inside the dwell grid",
                ));
            }
        }
        Ok(DwellProblem {
            desired_nm,
            aperture,
            tif,
        })
    }

    pub fn dim(&self) -> (usize, usize) {
        self.desired_nm.dim()
    }

    /// A convolver for this problem (dwell-grid-sized FFT, exact on the CA).
    pub(crate) fn convolver(&self) -> Convolver {
        let (r, c) = self.dim();
        Convolver::with_fft_size(
            r,
            c,
            self.tif.rate_nm_per_s.view(),
            fast_len(r),
            fast_len(c),
        )
    }

    /// Figures of merit of a dwell map (the public, solver-independent evaluation).
    pub fn evaluate(&self, dwell_s: &Array2<f64>) -> Result<DwellSolution, ProcessError> {
        if dwell_s.dim() != self.dim() {
            return Err(ProcessError::invalid(
                "dwell map does not match the dwell grid",
            ));
        }
        let mut conv = self.convolver();
        let proj = PistonTilt::new(&self.aperture);
        Ok(finish(
            self,
            &proj,
            &mut conv,
            dwell_s.clone(),
            "given",
            0,
            Vec::new(),
        ))
    }
}

/// Residual of a removal map against a problem: the CA residual map (piston and tilt removed,
/// 0 outside the CA), its RMS and PV (nm).
#[derive(Debug, Clone)]
pub struct RemovalResidual {
    pub residual_nm: Array2<f64>,
    pub rms_nm: f64,
    pub pv_nm: f64,
}

impl DwellProblem {
    /// The residual a removal map (nm, on the dwell grid; only CA pixels matter) leaves: the
    /// evaluation any forward model (FFT, exact deposition of a path) is judged by.
    pub fn residual_of_removal(
        &self,
        removal_nm: &Array2<f64>,
    ) -> Result<RemovalResidual, ProcessError> {
        if removal_nm.dim() != self.dim() {
            return Err(ProcessError::invalid(
                "removal map does not match the dwell grid",
            ));
        }
        let proj = PistonTilt::new(&self.aperture);
        let residual = proj.residual(&(&self.desired_nm - removal_nm));
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        Zip::from(&residual).and(&self.aperture).for_each(|&r, &m| {
            if m {
                lo = lo.min(r);
                hi = hi.max(r);
            }
        });
        Ok(RemovalResidual {
            rms_nm: proj.rms(&residual),
            pv_nm: hi - lo,
            residual_nm: residual,
        })
    }
}

/// Orthonormal piston + tilt basis over the CA pixels, to project them out of residuals.
pub(crate) struct PistonTilt {
    idx: Vec<(usize, usize)>,
    q: Vec<Vec<f64>>,
}

impl PistonTilt {
    pub(crate) fn new(mask: &Array2<bool>) -> PistonTilt {
        let idx: Vec<(usize, usize)> = mask
            .indexed_iter()
            .filter(|(_, &m)| m)
            .map(|(ij, _)| ij)
            .collect();
        let n = idx.len();
        let (mi, mj) = idx
            .iter()
            .fold((0.0, 0.0), |(a, b), &(i, j)| (a + i as f64, b + j as f64));
        let (mi, mj) = (mi / n.max(1) as f64, mj / n.max(1) as f64);
        let raw = [
            vec![1.0; n],
            idx.iter().map(|&(_, j)| j as f64 - mj).collect::<Vec<_>>(),
            idx.iter().map(|&(i, _)| i as f64 - mi).collect::<Vec<_>>(),
        ];
        let mut q: Vec<Vec<f64>> = Vec::new();
        for mut v in raw {
            for u in &q {
                let d: f64 = v.iter().zip(u).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(u).for_each(|(a, b)| *a -= d * b);
            }
            let norm = v.iter().map(|a| a * a).sum::<f64>().sqrt();
            if norm > 1e-9 * (n as f64).sqrt() {
                v.iter_mut().for_each(|a| *a /= norm);
                q.push(v);
            }
        }
        PistonTilt { idx, q }
    }

    /// Returns `a` restricted to the CA with piston and tilt removed (0 outside).
    pub(crate) fn residual(&self, a: &Array2<f64>) -> Array2<f64> {
        let mut v: Vec<f64> = self.idx.iter().map(|&ij| a[ij]).collect();
        for u in &self.q {
            let d: f64 = v.iter().zip(u).map(|(x, y)| x * y).sum();
            v.iter_mut().zip(u).for_each(|(x, y)| *x -= d * y);
        }
        let mut out = Array2::zeros(a.dim());
        for (&ij, x) in self.idx.iter().zip(v) {
            out[ij] = x;
        }
        out
    }

    pub(crate) fn count(&self) -> usize {
        self.idx.len()
    }

    /// RMS over the CA of an array that is zero outside it.
    pub(crate) fn rms(&self, r: &Array2<f64>) -> f64 {
        (r.iter().map(|v| v * v).sum::<f64>() / self.count().max(1) as f64).sqrt()
    }
}

/// Builds the solution record of a final dwell map.
pub(crate) fn finish(
    p: &DwellProblem,
    proj: &PistonTilt,
    conv: &mut Convolver,
    dwell_s: Array2<f64>,
    method: &str,
    iterations: usize,
    trade_off: Vec<TradeOffPoint>,
) -> DwellSolution {
    let removal = conv.apply(dwell_s.view());
    let residual = proj.residual(&(&p.desired_nm - &removal));
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    Zip::from(&residual).and(&p.aperture).for_each(|&r, &m| {
        if m {
            lo = lo.min(r);
            hi = hi.max(r);
        }
    });
    DwellSolution {
        residual_rms_nm: proj.rms(&residual),
        residual_pv_nm: hi - lo,
        total_dwell_s: dwell_s.sum(),
        dwell_s,
        removal_nm: removal,
        residual_nm: residual,
        method: method.to_string(),
        iterations,
        fft_count: conv.fft().transforms(),
        trade_off,
    }
}
