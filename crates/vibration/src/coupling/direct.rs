//! The reference: exact time-domain deposition of the instantaneous TIF T(q − u e_l; δ)
//! through process's one exact deposition with a per-instant hook
//! ([`bonnetlab_process::modulated::deposit_exact_modulated`]: at every sub-step the tool is
//! displaced by u along the lateral axis, its footprint widened and its rate scaled by the
//! offset law at δ), evaluated at every pixel of the footprint with no expansion, no splat and
//! no kernel: it shares nothing with the fast path but the vibration time series and the TIF
//! model.
//!
//! Sub-steps: the executed path is walked in sub-steps of at most 1 / (`substeps` ·
//! `sample_hz`) s (and the exact deposition's own spatial bound: a quarter pixel, 1/80 of the
//! footprint's half-extent), midpoint rule. The vibration samples stand at the middle of their
//! intervals (the coupling stream's convention); between them the displacements are
//! interpolated linearly (held before the first and after the last), so the deposition
//! converges as `substeps` grows (halving the step is a test). Costly (pixels in the footprint x
//! sub-steps): for validation runs, not for production.

use super::fast::{executed_path, lateral_unit, offset_law};
use super::stream::{CouplingSample, SampleStream};
use super::{CouplingInput, CouplingOptions};
use crate::error::VibrationError;
use crate::params::Bonnet;
use bonnetlab_process::modulated::{deposit_exact_modulated, Modulation};
use bonnetlab_process::removal::ExactOptions;
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

/// The displacements (u, δ) at a time, linear between the stream's samples.
struct Interp<'a> {
    stream: SampleStream<'a>,
    /// (time, u, δ) of the samples around the last time asked for.
    a: (f64, f64, f64),
    b: Option<(f64, f64, f64)>,
    clock: f64,
}

impl Interp<'_> {
    fn pull(&mut self) -> Option<(f64, f64, f64)> {
        let s: CouplingSample = self.stream.next()?;
        let t = self.clock + 0.5 * s.dt_s;
        self.clock += s.dt_s;
        Some((t, s.u_mm, s.delta_det_mm + s.delta_noise_mm))
    }

    /// (u, δ) at time `t` (non-decreasing between calls).
    fn at(&mut self, t: f64) -> (f64, f64) {
        while let Some(b) = self.b {
            if b.0 > t {
                break;
            }
            self.a = b;
            self.b = self.pull();
        }
        match self.b {
            Some(b) if self.a.0.is_finite() && t > self.a.0 => {
                let f = (t - self.a.0) / (b.0 - self.a.0);
                (
                    self.a.1 + f * (b.1 - self.a.1),
                    self.a.2 + f * (b.2 - self.a.2),
                )
            }
            _ => (self.a.1, self.a.2),
        }
    }
}

/// [`direct_removal`] with `substeps` sub-steps per coupling sample (at least 1).
pub fn direct_removal_with(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
    substeps: usize,
) -> Result<Array2<f64>, VibrationError> {
    if substeps == 0 {
        return Err(VibrationError::InvalidArgument(
            "direct deposition needs at least one sub-step per sample".into(),
        ));
    }
    let p = input.params;
    let law = offset_law(p)?;
    let (lx, ly) = lateral_unit(p.lateral_axis);
    let exec = executed_path(input, &opts.mechanisms)?;
    let stream = SampleStream::new(
        &exec,
        p,
        bonnet,
        &opts.mechanisms,
        opts.sample_hz,
        opts.seed,
    )?;
    let dt = exec.duration_s() / stream.len() as f64;
    let mut vib = Interp {
        stream,
        a: (f64::NEG_INFINITY, 0.0, 0.0),
        b: None,
        clock: exec.t_s[0],
    };
    vib.b = vib.pull();
    if let Some(b) = vib.b {
        vib.a = (f64::NEG_INFINITY, b.1, b.2);
    }
    let eo = ExactOptions {
        max_step_mm: None,
        max_dt_s: dt / substeps as f64,
    };
    deposit_exact_modulated(&exec, input.tool.field(), &input.grid, &eo, |s| {
        let (u, d) = vib.at(s.t_s);
        let (rate, scale) = law.factors(d);
        Modulation {
            dx_mm: u * lx,
            dy_mm: u * ly,
            rate,
            scale,
        }
    })
    .map_err(|e| VibrationError::Process(e.to_string()))
}
