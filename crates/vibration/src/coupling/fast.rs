//! The fast coupling on the process crate's one removal model. The unperturbed removal (and
//! the executed path's) is [`bonnetlab_process::removal::FastRemoval`]'s (motion-aware kernels,
//! raster line phases); the vibration's part is a second-order expansion of the instantaneous
//! TIF in the small displacements whose terms are the same fast removal, run on the derivative
//! fields of the one TIF ([`bonnetlab_process::tif::derived`]'s channels, with the bonnet's
//! offset law) with the dwell weighted per sample.
//!
//! With q = x − p(t), u the lateral and δ = δ_det + δ_noise the offset displacement,
//! T(q − u e_l; δ) ≈ T − u K_l + ½u² K_ll + δ K_h + ½δ² K_hh − u δ K_lh, so the vibration's
//! removal is Σ_c R_c(w_c), R_c the fast removal through channel c's field and w_c the dwell
//! weights −u, ½u², δ, ½δ², −u δ. Each mechanism's map collects its own terms; the cross terms
//! (δ_det δ_noise, u δ) form `interaction`.
//!
//! The vibration is sampled at `sample_hz` (a 60-minute run at 1 kHz is 3.6 million samples);
//! before the fast removal sees them, consecutive samples are merged into blocks along the path
//! no longer than 1/16 pixel (dwell-weighted mean weights at the block's time and position
//! centroid), which keeps the dwell's mass and centroid per block and the path short.

use super::stream::{CouplingSample, SampleStream};
use super::{CouplingInput, CouplingOptions, MechanismMaps, Mechanisms};
use crate::error::VibrationError;
use crate::params::{LateralAxis, VibrationParams};
use bonnetlab_process::path::kinematics::{apply_limits, Limits};
use bonnetlab_process::path::PathLog;
use bonnetlab_process::removal::FastRemoval;
use bonnetlab_process::tif::derived::{Channel, Derived, OffsetLaw};
use bonnetlab_process::tif::RateField;
use ndarray::Array2;
use std::sync::Arc;

/// Weighted dwell channels: −u, ½u², δ_det, ½δ_det², δ_noise, ½δ_noise², δ_det δ_noise, −u δ.
const NV: usize = 8;
/// Samples per message between the integrating and the merging thread.
const CHUNK: usize = 1 << 14;
/// Longest block of merged samples, in pixels along the path.
const BLOCK_PX: f64 = 1.0 / 16.0;

/// The path the robot executes: re-timed under its acceleration limit when `dwell_execution`
/// is on (bonnetlab_process::path::kinematics::apply_limits), else the commanded one.
pub fn executed_path(
    input: &CouplingInput<'_>,
    mech: &Mechanisms,
) -> Result<PathLog, VibrationError> {
    if !mech.dwell_execution {
        return Ok(input.path.clone());
    }
    let limits = Limits {
        a_max_mm_per_s2: input.params.accel_max_mm_per_s2,
        ..Limits::default()
    };
    let ds = 0.5 * input.grid.dx_mm.min(input.grid.dy_mm);
    apply_limits(input.path, &limits, ds).map_err(|e| VibrationError::Process(e.to_string()))
}

/// The bonnet's offset law (process's [`OffsetLaw`]: contact radius and pressure with the
/// offset).
pub fn offset_law(p: &VibrationParams) -> Result<OffsetLaw, VibrationError> {
    OffsetLaw::new(p.offset_mm, p.bonnet_radius_mm, p.pressure_exponent).ok_or_else(|| {
        VibrationError::InvalidArgument(format!(
            "offset {} mm on a bonnet of radius {} mm has no contact law",
            p.offset_mm, p.bonnet_radius_mm
        ))
    })
}

/// Unit vector (x, y) of the lateral displacement.
pub fn lateral_unit(l: LateralAxis) -> (f64, f64) {
    match l {
        LateralAxis::X => (1.0, 0.0),
        LateralAxis::Y => (0.0, 1.0),
    }
}

fn perr(e: impl ToString) -> VibrationError {
    VibrationError::Process(e.to_string())
}

/// The vibration samples merged into blocks along the path: times (s), positions (mm) and the
/// dwell-weighted mean of each weight channel.
struct Blocks {
    t: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    w: [Vec<f64>; NV],
    /// Channels that received a non-zero weight.
    used: [bool; NV],
}

/// Accumulates samples into [`Blocks`].
struct Merger {
    out: Blocks,
    max_len_mm: f64,
    clock: f64,
    start: Option<(f64, f64)>,
    sdt: f64,
    st: f64,
    sx: f64,
    sy: f64,
    sw: [f64; NV],
}

impl Merger {
    fn new(t0: f64, max_len_mm: f64) -> Merger {
        Merger {
            out: Blocks {
                t: Vec::new(),
                x: Vec::new(),
                y: Vec::new(),
                w: std::array::from_fn(|_| Vec::new()),
                used: [false; NV],
            },
            max_len_mm,
            clock: t0,
            start: None,
            sdt: 0.0,
            st: 0.0,
            sx: 0.0,
            sy: 0.0,
            sw: [0.0; NV],
        }
    }

    fn add(&mut self, s: &CouplingSample) {
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
        ];
        // The sample stands for the interval around its time (midpoint rule).
        let t = self.clock + 0.5 * s.dt_s;
        self.clock += s.dt_s;
        if let Some((x0, y0)) = self.start {
            if (s.x_mm - x0).hypot(s.y_mm - y0) > self.max_len_mm {
                self.close();
            }
        }
        if self.start.is_none() {
            self.start = Some((s.x_mm, s.y_mm));
        }
        let dt = s.dt_s;
        self.sdt += dt;
        self.st += dt * t;
        self.sx += dt * s.x_mm;
        self.sy += dt * s.y_mm;
        for (a, v) in self.sw.iter_mut().zip(w) {
            *a += dt * v;
        }
    }

    fn close(&mut self) {
        if self.sdt > 0.0 {
            let inv = 1.0 / self.sdt;
            let b = &mut self.out;
            b.t.push(self.st * inv);
            b.x.push(self.sx * inv);
            b.y.push(self.sy * inv);
            for c in 0..NV {
                b.w[c].push(self.sw[c] * inv);
                b.used[c] |= self.sw[c] != 0.0;
            }
        }
        self.start = None;
        self.sdt = 0.0;
        self.st = 0.0;
        self.sx = 0.0;
        self.sy = 0.0;
        self.sw = [0.0; NV];
    }

    fn finish(mut self) -> Blocks {
        self.close();
        self.out
    }
}

/// Per-mechanism removal maps (nm, on the map grid) by the fast expansion.
pub fn fast_maps(
    input: &CouplingInput<'_>,
    bonnet: crate::params::Bonnet,
    opts: &CouplingOptions,
) -> Result<MechanismMaps, VibrationError> {
    let p = input.params;
    let g = input.grid;
    let mech = &opts.mechanisms;
    let exec = executed_path(input, mech)?;
    let zeros = || Array2::<f64>::zeros((g.rows, g.cols));

    // Unperturbed removal of the commanded path and of the executed one: the one fast model.
    let mut fast = input.tool.fast_removal(&g).map_err(perr)?;
    let baseline = fast.removal(input.path, None).map_err(perr)?;
    let dwell_execution = if mech.dwell_execution {
        fast.removal(&exec, None).map_err(perr)? - &baseline
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
    let law = offset_law(p)?;

    // Two-stage pipeline: one thread integrates the vibration, this one merges its samples.
    let stream = SampleStream::new(&exec, p, bonnet, mech, opts.sample_hz, opts.seed)?;
    let mut merger = Merger::new(exec.t_s[0], BLOCK_PX * g.dx_mm.min(g.dy_mm));
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
            for s in &chunk {
                merger.add(s);
            }
        }
    });
    let blocks = merger.finish();
    if blocks.t.len() < 2 {
        return Ok(maps);
    }
    let Blocks { t, x, y, w, used } = blocks;
    let path = PathLog::new(t, x, y).map_err(perr)?;

    // The derivative fields of the one TIF; each channel's workspace built when first needed.
    let base: Arc<dyn RateField + Send> = Arc::new(input.tool.clone());
    let step = 0.1 * g.dx_mm.min(g.dy_mm);
    let (k_l, k_ll, k_lh) = Channel::lateral(p.lateral_axis == LateralAxis::X);
    let mut spaces: Vec<Option<FastRemoval>> = (0..Channel::ALL.len()).map(|_| None).collect();
    let mut removal = |ch: Channel, c: usize| -> Result<Option<Array2<f64>>, VibrationError> {
        if !used[c] {
            return Ok(None);
        }
        let ws = match &mut spaces[ch.index()] {
            Some(ws) => ws,
            slot => {
                let field = Derived::new(base.clone(), 1.0, ch, step).with_offset(law);
                slot.insert(FastRemoval::from_field(&field, &g).map_err(perr)?)
            }
        };
        ws.removal(&path, Some(&w[c])).map(Some).map_err(perr)
    };
    let sum = |parts: [Option<Array2<f64>>; 2]| -> Array2<f64> {
        let mut out = zeros();
        for m in parts.into_iter().flatten() {
            out += &m;
        }
        out
    };
    maps.lateral_jitter = sum([removal(k_l, 0)?, removal(k_ll, 1)?]);
    maps.normal_offset = sum([removal(Channel::Dh, 2)?, removal(Channel::Dhh, 3)?]);
    maps.envelope = sum([removal(Channel::Dh, 4)?, removal(Channel::Dhh, 5)?]);
    maps.interaction = sum([removal(Channel::Dhh, 6)?, removal(k_lh, 7)?]);
    Ok(maps)
}
