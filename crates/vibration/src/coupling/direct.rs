//! The reference: exact time-domain deposition of the instantaneous TIF T(q − u e_l; δ) at
//! every pixel of the footprint, with no expansion, no splat and no kernel: it shares nothing
//! with the fast path but the vibration time series and the TIF model. It is the process
//! crate's one exact deposition ([`deposit_exact_modulated`], the synthetic-run generator's
//! truth) with the vibration as its modulation: at every sub-step the lateral displacement u
//! moves the tool and the offset change δ sets the rate factor and the footprint's widening
//! ([`bonnetlab_process::perturb::OffsetTif::modulation`]).
//!
//! Sub-steps: at most 1/`substeps` of a coupling sample's interval (the vibration generated at
//! `sample_hz`) in time, and the exact deposition's own bound in length; the displacements
//! between samples are the piecewise-linear interpolant through the samples (held constant
//! before the first and after the last, [`Track`]), so the deposition converges as `substeps`
//! grows (halving the step is a test). Costly (pixels in the footprint x sub-steps): for
//! validation runs and the synthetic truth, not for production.

use super::fast::{axis, executed_path, offset_tif};
use super::stream::{SampleStream, Track};
use super::{CouplingInput, CouplingOptions, Mechanisms};
use crate::error::VibrationError;
use crate::params::{Bonnet, VibrationParams};
use bonnetlab_process::modulated::{deposit_exact_modulated, Modulation, SubStep};
use bonnetlab_process::removal::ExactOptions;
use bonnetlab_process::tif::RateField;
use bonnetlab_process::{Grid, PathLog};
use ndarray::Array2;

/// Default sub-steps per coupling sample.
pub const DEFAULT_SUBSTEPS: usize = 2;

/// Removal (nm) on the map grid with the mechanisms of `opts` switched on (executed path when
/// `dwell_execution` is on), [`DEFAULT_SUBSTEPS`] sub-steps per sample.
pub fn direct_removal(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
) -> Result<Array2<f64>, VibrationError> {
    direct_removal_with(input, bonnet, opts, DEFAULT_SUBSTEPS)
}

/// [`direct_removal`] with `substeps` sub-steps per coupling sample (at least 1).
pub fn direct_removal_with(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
    substeps: usize,
) -> Result<Array2<f64>, VibrationError> {
    let exec = executed_path(input, &opts.mechanisms)?;
    let v = Vibrating {
        params: input.params,
        bonnet,
        mechanisms: opts.mechanisms,
        sample_hz: opts.sample_hz,
        seed: opts.seed,
        substeps,
    };
    // Area pixels: the pixel-mean field, which the offset's change then widens with the
    // footprint (by a factor sqrt(1 + delta / h0), about 1 + delta / (2 h0)), so the box is
    // off by that fraction of its own effect (a few per cent of it at the paper's offset
    // swings). The fast kernels take the box outermost (`DerivativeKernels::sample_seen`).
    v.deposit(&exec, &input.tool.seen_field(), &input.grid, |_| {
        Modulation::default()
    })
}

/// A vibrating tool for the exact deposition: the vibration model of `bonnet` with the
/// `mechanisms` switched on, sampled at `sample_hz` with `seed`.
#[derive(Debug, Clone, Copy)]
pub struct Vibrating<'a> {
    pub params: &'a VibrationParams,
    pub bonnet: Bonnet,
    pub mechanisms: Mechanisms,
    pub sample_hz: f64,
    pub seed: u64,
    /// Sub-steps per vibration sample (at least 1).
    pub substeps: usize,
}

impl Vibrating<'_> {
    /// Exact deposition (nm on `grid`) of `field` (the TIF at the nominal offset) moved along
    /// `path` (the path the robot executes: [`executed_path`] re-times it when
    /// `dwell_execution` is on) under the vibration, with the caller's own modulation `also`
    /// applied at every sub-step on top of it (displacements add, rate factors and widenings
    /// multiply).
    pub fn deposit(
        &self,
        path: &PathLog,
        field: &dyn RateField,
        grid: &Grid,
        mut also: impl FnMut(&SubStep) -> Modulation,
    ) -> Result<Array2<f64>, VibrationError> {
        if self.substeps == 0 {
            return Err(VibrationError::InvalidArgument(
                "direct deposition needs at least one sub-step per sample".into(),
            ));
        }
        let p = self.params;
        let inst = offset_tif(field, p);
        let lateral = axis(p.lateral_axis);
        let stream = SampleStream::new(
            path,
            p,
            self.bonnet,
            &self.mechanisms,
            self.sample_hz,
            self.seed,
        )?;
        let opts = ExactOptions {
            max_step_mm: None,
            max_dt_s: stream.dt_s() / self.substeps as f64,
        };
        let mut track = Track::new(stream);
        deposit_exact_modulated(path, field, grid, &opts, |s| {
            let d = track.at(s.t_s);
            inst.modulation(d.u_mm, lateral, d.delta_mm).and(also(s))
        })
        .map_err(|e| VibrationError::Process(e.to_string()))
    }
}
