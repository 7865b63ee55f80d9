//! The fast coupling on the process crate's one removal model: the unperturbed removal (and
//! the executed path's) is [`bonnetlab_process::removal::FastRemoval`]'s (motion-aware kernels,
//! raster line phases), the vibration's part an expansion of the instantaneous TIF in the small
//! displacements (second order, the spindle-harmonic offset to fourth), evaluated as FFT convolutions of weighted dwell maps with the
//! TIF's derivative kernels ([`bonnetlab_process::perturb`]).
//!
//! With q = x − p(t), u the lateral and δ = δ_det + δ_noise the offset displacement,
//! T(q − u e_l; δ) ≈ T − u K_l + ½u² K_ll + δ K_h + ½δ² K_hh − u δ K_lh, so the vibration's
//! removal is Σ_c W_c ⊛ K_c with W_c the dwell maps weighted by −u, ½u², δ, ½δ², −u δ. The
//! spindle-harmonic offset δ_det is carried to fourth order (+ δ_det³/6 K_hhh + δ_det⁴/24
//! K_hhhh): the footprint's width enters the transfer at f as exp(−2π²σ²s²f²), so in the
//! imprint band the removal is far from quadratic in δ_det (on the sample run at 5 N the
//! second-order expansion's imprint power was 7 / 16 / 24 / 36 % below the exact deposition's
//! at 0.30 / 0.36 / 0.40 / 0.46 per mm). Each mechanism's map collects its own terms; the cross
//! terms (δ_det δ_noise, u δ) form `interaction`.

use super::stream::{CouplingSample, SampleStream};
use super::{CouplingInput, CouplingOptions, MechanismMaps, Mechanisms};
use crate::error::VibrationError;
use crate::params::{Bonnet, LateralAxis, VibrationParams};
use bonnetlab_process::path::kinematics::{apply_limits, Limits};
use bonnetlab_process::path::PathLog;
use bonnetlab_process::perturb::{
    Axis, Derivative, DerivativeKernels, KernelConvolver, OffsetTif, WeightedDwell,
};
use bonnetlab_process::tif::RateField;
use ndarray::{Array2, ArrayView2};

/// Weighted dwell channels: −u, ½u², δ_det, ½δ_det², δ_noise, ½δ_noise², δ_det δ_noise, −u δ,
/// δ_det³/6, δ_det⁴/24.
const NV: usize = 10;
/// Samples per message between the integrating and the splatting thread.
const CHUNK: usize = 1 << 14;

/// The commanded motion of a run: its path log read with the corners its samples cut restored
/// ([`PathLog::with_corners`], the one reading of a log that `simulate` and calibration use).
/// A logged chord across a corner is not where the robot went: re-timing it stretched the
/// sample run's clock (65.59 s against the 64.85 s of the generator's motion re-timed the same
/// way), and the unperturbed removal would differ from `simulate`'s.
pub fn commanded_path(input: &CouplingInput<'_>) -> PathLog {
    input.path.with_corners()
}

/// The path the robot executes: the commanded motion ([`commanded_path`]) re-timed under its
/// acceleration limit when `dwell_execution` is on
/// (bonnetlab_process::path::kinematics::apply_limits), else the commanded motion itself.
pub fn executed_path(
    input: &CouplingInput<'_>,
    mech: &Mechanisms,
) -> Result<PathLog, VibrationError> {
    executed_from(input, &commanded_path(input), mech)
}

fn executed_from(
    input: &CouplingInput<'_>,
    commanded: &PathLog,
    mech: &Mechanisms,
) -> Result<PathLog, VibrationError> {
    if !mech.dwell_execution {
        return Ok(commanded.clone());
    }
    let limits = Limits {
        a_max_mm_per_s2: input.params.accel_max_mm_per_s2,
        ..Limits::default()
    };
    let ds = 0.5 * input.grid.dx_mm.min(input.grid.dy_mm);
    apply_limits(commanded, &limits, ds).map_err(|e| VibrationError::Process(e.to_string()))
}

/// The instantaneous TIF of the run's tool under an offset change (process's [`OffsetTif`]).
pub fn offset_tif<'a>(field: &'a dyn RateField, p: &VibrationParams) -> OffsetTif<'a> {
    OffsetTif::new(field, p.offset_mm, p.bonnet_radius_mm, p.pressure_exponent)
}

/// The lateral map axis as process's [`Axis`].
pub fn axis(l: LateralAxis) -> Axis {
    match l {
        LateralAxis::X => Axis::X,
        LateralAxis::Y => Axis::Y,
    }
}

fn perr(e: impl ToString) -> VibrationError {
    VibrationError::Process(e.to_string())
}

/// `path` with every sample moved back by `lag_mm` along its direction of travel (the
/// direction of the segment to the next sample; the last sample takes the previous segment's),
/// at the same times: where a servo lag puts the tool. Not to be re-timed: moved corners are
/// sharper than the path's and the acceleration limit would stretch the run's clock.
pub fn direction_lag_path(path: &PathLog, lag_mm: f64) -> Result<PathLog, VibrationError> {
    let n = path.len();
    let (mut x, mut y) = (path.x_mm.clone(), path.y_mm.clone());
    for k in 0..n {
        let (a, b) = if k + 1 < n {
            (k, k + 1)
        } else {
            (k.saturating_sub(1), k)
        };
        let (dx, dy) = (path.x_mm[b] - path.x_mm[a], path.y_mm[b] - path.y_mm[a]);
        let d = dx.hypot(dy);
        if d > 1e-12 {
            x[k] -= lag_mm * dx / d;
            y[k] -= lag_mm * dy / d;
        }
    }
    PathLog::new(path.t_s.clone(), x, y).map_err(perr)
}

/// Per-mechanism removal maps (nm, on the map grid) by the fast expansion.
pub fn fast_maps(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
) -> Result<MechanismMaps, VibrationError> {
    fast_maps_lagged(input, bonnet, opts, 0.0)
}

/// [`fast_maps`] of a run whose tool trails its path by `lag_mm` along the direction of travel
/// (a servo lag, as calibrated: executed = path − lag · u at the same instant). The path is
/// re-timed first (when `dwell_execution` is on) and moved after, so the clock, the spindle
/// phase along each raster line and the ring-down are the unlagged run's; only where the tool
/// is at each instant moves (lagging the path before re-timing stretched the sample run's clock
/// by 4.1 s in 65.6 s at 0.3 mm and scrambled the imprint's phase from line to line).
pub fn fast_maps_lagged(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
    lag_mm: f64,
) -> Result<MechanismMaps, VibrationError> {
    let p = input.params;
    let g = input.grid;
    let mech = &opts.mechanisms;
    let commanded = commanded_path(input);
    let exec = executed_from(input, &commanded, mech)?;
    let zeros = || Array2::<f64>::zeros((g.rows, g.cols));

    // Unperturbed removal of the commanded path and of the executed one: the one fast model.
    let mut fast = input.tool.fast_removal(&g).map_err(perr)?;
    let baseline = if lag_mm != 0.0 {
        fast.removal(&direction_lag_path(&commanded, lag_mm)?, None)
    } else {
        fast.removal(&commanded, None)
    }
    .map_err(perr)?;
    let dwell_execution = if mech.dwell_execution {
        let removal = if lag_mm != 0.0 {
            fast.removal(&direction_lag_path(&exec, lag_mm)?, None)
        } else {
            fast.removal(&exec, None)
        };
        removal.map_err(perr)? - &baseline
    } else {
        zeros()
    };
    drop(fast);
    let any_vib = mech.normal_offset || mech.lateral_jitter || mech.envelope;
    let mut maps = MechanismMaps {
        baseline,
        dwell_execution,
        normal_offset: zeros(),
        lateral_jitter: zeros(),
        envelope: zeros(),
        interaction: zeros(),
    };
    if !any_vib {
        return Ok(maps);
    }

    let inst = offset_tif(input.tool.field(), p);
    let kern = DerivativeKernels::sample_seen(
        &inst,
        g.dx_mm,
        g.dy_mm,
        axis(p.lateral_axis),
        input.tool.response(),
    );
    let (hy, hx) = kern.half;
    let ext = g.grown(hy, hx);
    let mut ch = WeightedDwell::<NV>::new(ext);
    // Two-stage pipeline: one thread integrates the vibration, this one splats its samples.
    let stream = SampleStream::new(&exec, p, bonnet, mech, opts.sample_hz, opts.seed)?
        .with_direction_lag(lag_mm);
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<CouplingSample>>(4);
        scope.spawn(move || {
            let mut buf = Vec::with_capacity(CHUNK);
            for s in stream {
                buf.push(s);
                if buf.len() == CHUNK
                    && tx
                        .send(std::mem::replace(&mut buf, Vec::with_capacity(CHUNK)))
                        .is_err()
                {
                    return;
                }
            }
            let _ = tx.send(buf);
        });
        for chunk in rx {
            for s in chunk {
                let (u, dd, dn) = (s.u_mm, s.delta_det_mm, s.delta_noise_mm);
                let w = [
                    -u,
                    0.5 * u * u,
                    dd,
                    0.5 * dd * dd,
                    dn,
                    0.5 * dn * dn,
                    dd * dn,
                    -u * (dd + dn),
                    dd * dd * dd / 6.0,
                    dd * dd * dd * dd / 24.0,
                ];
                ch.add(s.x_mm, s.y_mm, s.dt_s, &w);
            }
        }
    });
    ch.finish();

    let mut conv = KernelConvolver::new(&kern, &ext);
    // The channels are read in place (strided views of the interleaved splat) and only the
    // map grid's window of each convolution is formed.
    let live: Vec<bool> = (0..NV).map(|c| !ch.is_zero(c)).collect();
    let mut out = |terms: &[(usize, Derivative)]| -> Array2<f64> {
        let t: Vec<(ArrayView2<f64>, Derivative)> = terms
            .iter()
            .filter(|&&(c, _)| live[c])
            .map(|&(c, k)| (ch.channel_view(c), k))
            .collect();
        if t.is_empty() {
            return zeros();
        }
        conv.apply_window(&t, (hy, hx), (g.rows, g.cols))
    };
    maps.lateral_jitter = out(&[(0, Derivative::L), (1, Derivative::Ll)]);
    maps.normal_offset = out(&[
        (2, Derivative::H),
        (3, Derivative::Hh),
        (8, Derivative::Hhh),
        (9, Derivative::Hhhh),
    ]);
    maps.envelope = out(&[(4, Derivative::H), (5, Derivative::Hh)]);
    maps.interaction = out(&[(6, Derivative::Hh), (7, Derivative::Lh)]);
    Ok(maps)
}
