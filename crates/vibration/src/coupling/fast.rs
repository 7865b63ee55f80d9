//! The fast coupling on the process crate's one removal model. The unperturbed removal (and
//! the executed path's) is [`bonnetlab_process::removal::FastRemoval`]'s (motion-aware kernels,
//! raster line phases); the vibration's part is a second-order expansion of the instantaneous
//! TIF in the small displacements whose kernels are the derivative fields of the one TIF
//! ([`bonnetlab_process::tif::derived`]'s channels, with the bonnet's offset law), sampled as
//! the fast removal samples a moving tool (the one-pixel average along the path's dominant
//! motion, point values across it: `tif::motion::along_x_at_phase` / `along_y_at_phase`), and
//! whose dwell is weighted per sample (process's `channels::weighted_dwell_maps`, the cubic
//! splat of the fast removal's dwell maps, all weights in one pass).
//!
//! Cost: the coupling is linear in the channels, so one FFT workspace holds the five channel
//! kernels, every weighted dwell map is transformed once and every mechanism map inverted once
//! (5 + 8 + 4 transforms of the grown grid); the kernels are built in parallel and the
//! unperturbed removal runs while the vibration is integrated. The vibration's dwell is not
//! split by motion kind or line phase as the unperturbed removal's is: the line changes (motion
//! across the scan) take the scan's kernel and lines between pixel rows are interpolated
//! cubically across rows, which `tests/coupling.rs` bounds against direct deposition.
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
use bonnetlab_process::channels::weighted_dwell_maps;
use bonnetlab_process::fft::{fast_len, MultiConvolver};
use bonnetlab_process::grid::Grid;
use bonnetlab_process::path::kinematics::{apply_limits, Limits};
use bonnetlab_process::path::PathLog;
use bonnetlab_process::perturb::Axis;
use bonnetlab_process::tif::derived::{Channel, Derived, OffsetLaw};
use bonnetlab_process::tif::motion::{along_x_at_phase, along_y_at_phase};
use bonnetlab_process::tif::{RateField, Tif};
use ndarray::{s, Array2, ArrayView2};
use rayon::prelude::*;
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

/// The process crate's [`Axis`] of the lateral displacement. Transitional: kept only for
/// `src/pipeline/recipe_samples.rs` (with [`bonnetlab_process::perturb`]) until the lead ports
/// it to [`lateral_unit`] and the modulated exact deposition.
pub fn axis(l: LateralAxis) -> Axis {
    match l {
        LateralAxis::X => Axis::X,
        LateralAxis::Y => Axis::Y,
    }
}

/// Whether the path spends more of its moving time along X than along Y (segments split by
/// cos² / sin² of their direction, as the fast removal's motion kinds).
fn along_x_dominant(path: &PathLog, g: &Grid) -> bool {
    let (mut ax, mut ay) = (0.0, 0.0);
    for k in 0..path.len().saturating_sub(1) {
        let (dx, dy) = (
            (path.x_mm[k + 1] - path.x_mm[k]) / g.dx_mm,
            (path.y_mm[k + 1] - path.y_mm[k]) / g.dy_mm,
        );
        let l2 = dx * dx + dy * dy;
        if l2 > 0.0 {
            let dt = path.t_s[k + 1] - path.t_s[k];
            ax += dt * dx * dx / l2;
            ay += dt * dy * dy / l2;
        }
    }
    ax >= ay
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

    let any_vib = mech.normal_offset || mech.lateral_jitter || mech.envelope;
    let law = offset_law(p)?;
    // Unperturbed removal of the commanded path and of the executed one (the one fast model),
    // alongside the vibration's integration (one thread integrates, one merges its samples).
    let unperturbed = || -> Result<(Array2<f64>, Array2<f64>), VibrationError> {
        let mut fast = input.tool.fast_removal(&g).map_err(perr)?;
        let baseline = fast.removal(input.path, None).map_err(perr)?;
        let dwell_execution = if mech.dwell_execution {
            fast.removal(&exec, None).map_err(perr)? - &baseline
        } else {
            zeros()
        };
        Ok((baseline, dwell_execution))
    };
    let vibration = || -> Result<Option<Blocks>, VibrationError> {
        if !any_vib {
            return Ok(None);
        }
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
        Ok(Some(merger.finish()))
    };
    let (unperturbed, blocks) = rayon::join(unperturbed, vibration);
    let (baseline, dwell_execution) = unperturbed?;
    let mut maps = MechanismMaps {
        baseline,
        dwell_execution,
        normal_offset: zeros(),
        lateral_jitter: zeros(),
        envelope: zeros(),
        interaction: zeros(),
    };
    let Some(blocks) = blocks? else {
        return Ok(maps);
    };
    if blocks.t.len() < 2 {
        return Ok(maps);
    }
    let Blocks { t, x, y, w, used } = blocks;
    let path = PathLog::new(t, x, y).map_err(perr)?;

    // The derivative fields of the one TIF, sampled as the fast removal's moving-tool kernel
    // (the one-pixel average along the path's dominant motion, process's
    // `tif::motion::along_x_at_phase` / `along_y_at_phase` at phase 0), built in parallel; the
    // eight weighted dwell maps (cubic splat of the blocks' path on the grown grid, process's
    // `dwell_map_with`) convolved through one shared FFT workspace: one forward transform per
    // weight map, one inverse per mechanism map (the coupling is linear in the channels).
    let base: Arc<dyn RateField + Send> = Arc::new(input.tool.clone());
    let step = 0.1 * g.dx_mm.min(g.dy_mm);
    let (k_l, k_ll, k_lh) = Channel::lateral(p.lateral_axis == LateralAxis::X);
    // (channel, weight) of each term, by mechanism: lateral jitter, normal offset, envelope,
    // interaction.
    let terms: [[(Channel, usize); 2]; 4] = [
        [(k_l, 0), (k_ll, 1)],
        [(Channel::Dh, 2), (Channel::Dhh, 3)],
        [(Channel::Dh, 4), (Channel::Dhh, 5)],
        [(Channel::Dhh, 6), (k_lh, 7)],
    ];
    let mut chans: Vec<Channel> = Vec::new();
    for &(ch, c) in terms.iter().flatten() {
        if used[c] && !chans.contains(&ch) {
            chans.push(ch);
        }
    }
    if chans.is_empty() {
        return Ok(maps);
    }
    let along_x = along_x_dominant(&path, &g);
    let kernels: Vec<Tif> = chans
        .par_iter()
        .map(|&ch| {
            let field = Derived::new(base.clone(), 1.0, ch, step).with_offset(law);
            if along_x {
                along_x_at_phase(&field, g.dx_mm, g.dy_mm, 0.0)
            } else {
                along_y_at_phase(&field, g.dx_mm, g.dy_mm, 0.0)
            }
        })
        .collect::<Result<_, _>>()
        .map_err(perr)?;
    let (h0, h1) = kernels.iter().fold((0, 0), |(a, b), k| {
        let (r, c) = k.half_widths();
        (a.max(r), b.max(c))
    });
    let ext = g.grown(h0, h1);
    let views: Vec<_> = kernels.iter().map(|k| k.rate_nm_per_s.view()).collect();
    let mut conv = MultiConvolver::with_fft_size(
        ext.rows,
        ext.cols,
        &views,
        fast_len(ext.rows),
        fast_len(ext.cols),
    );
    let wv: Vec<Option<&[f64]>> = (0..NV).map(|c| used[c].then_some(&w[c][..])).collect();
    let dwell = weighted_dwell_maps(&path, &wv, &ext).map_err(perr)?;
    let mut mech_map = |pair: &[(Channel, usize); 2]| -> Array2<f64> {
        let mut inputs: Vec<Option<ArrayView2<f64>>> = vec![None; chans.len()];
        for &(ch, c) in pair {
            if let (Some(d), Some(k)) = (&dwell[c], chans.iter().position(|&x| x == ch)) {
                inputs[k] = Some(d.view());
            }
        }
        if inputs.iter().all(Option::is_none) {
            return zeros();
        }
        let full = conv.apply_sum(&inputs);
        full.slice(s![h0..h0 + g.rows, h1..h1 + g.cols]).to_owned()
    };
    maps.lateral_jitter = mech_map(&terms[0]);
    maps.normal_offset = mech_map(&terms[1]);
    maps.envelope = mech_map(&terms[2]);
    maps.interaction = mech_map(&terms[3]);
    Ok(maps)
}
