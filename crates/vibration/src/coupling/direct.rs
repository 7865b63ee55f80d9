//! The reference: exact time-domain deposition of the instantaneous TIF T(q − u e_l; δ)
//! (process's [`bonnetlab_process::perturb::deposit_perturbed`]) at every pixel of the
//! footprint, with no expansion, no splat and no kernel: it shares nothing with the fast path
//! but the vibration time series and the TIF model.
//!
//! Sub-steps: every coupling sample (the vibration generated at `sample_hz`) is split into
//! `substeps` sub-steps; position and displacements between samples are the piecewise-linear
//! interpolant through the samples (held constant before the first and after the last), so
//! the deposition converges as `substeps` grows (halving the step is a test). Costly (pixels in
//! the footprint x sub-steps): for validation runs, not for production.

use super::fast::{axis, executed_path, offset_tif};
use super::stream::{CouplingSample, SampleStream};
use super::{CouplingInput, CouplingOptions};
use crate::error::VibrationError;
use crate::params::Bonnet;
use bonnetlab_process::perturb::{deposit_perturbed, PerturbedSample};
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
    if substeps == 0 {
        return Err(VibrationError::InvalidArgument(
            "direct deposition needs at least one sub-step per sample".into(),
        ));
    }
    let p = input.params;
    let g = input.grid;
    let inst = offset_tif(input.tool.field(), p);
    let lateral = axis(p.lateral_axis);
    let exec = executed_path(input, &opts.mechanisms)?;
    let mut stream = SampleStream::new(
        &exec,
        p,
        bonnet,
        &opts.mechanisms,
        opts.sample_hz,
        opts.seed,
    )?;
    let mut out = Array2::zeros((g.rows, g.cols));
    let mut buf: Vec<PerturbedSample> = Vec::with_capacity(1 << 16);
    let flush = |buf: &mut Vec<PerturbedSample>, out: &mut Array2<f64>| {
        let dmax = buf.iter().fold(0.0f64, |m, s| m.max(s.delta_mm.abs()));
        deposit_perturbed(out, &g, &inst, lateral, dmax, buf);
        buf.clear();
    };
    let m = substeps as f64;
    let lerp = |a: &CouplingSample, b: &CouplingSample, f: f64, dt: f64| PerturbedSample {
        x_mm: a.x_mm + f * (b.x_mm - a.x_mm),
        y_mm: a.y_mm + f * (b.y_mm - a.y_mm),
        dt_s: dt,
        u_mm: a.u_mm + f * (b.u_mm - a.u_mm),
        delta_mm: (a.delta_det_mm + a.delta_noise_mm)
            + f * ((b.delta_det_mm + b.delta_noise_mm) - (a.delta_det_mm + a.delta_noise_mm)),
    };
    let mut prev: Option<CouplingSample> = None;
    let mut cur = stream.next();
    while let Some(c) = cur {
        let next = stream.next();
        let dt = c.dt_s / m;
        for k in 0..substeps {
            // Offset of the sub-step from the sample's time, in sample intervals (−½..½).
            let tau = (k as f64 + 0.5) / m - 0.5;
            let s = if tau < 0.0 {
                match &prev {
                    Some(a) => lerp(&c, a, -tau, dt),
                    None => lerp(&c, &c, 0.0, dt),
                }
            } else {
                match &next {
                    Some(b) => lerp(&c, b, tau, dt),
                    None => lerp(&c, &c, 0.0, dt),
                }
            };
            buf.push(s);
        }
        if buf.len() >= (1 << 16) - substeps {
            flush(&mut buf, &mut out);
        }
        prev = Some(c);
        cur = next;
    }
    flush(&mut buf, &mut out);
    Ok(out)
}
