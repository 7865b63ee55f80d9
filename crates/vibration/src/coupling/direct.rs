//! The reference: direct time-domain deposition of the instantaneous TIF, T(q − u e_l; δ),
//! evaluated at every pixel for every coupling sample (no expansion, no splat), in parallel.
//! Costly (pixels in the footprint x samples): for validation runs, not for production.

use super::fast::executed_path;
use super::instant::InstantTif;
use super::stream::{CouplingSample, SampleStream};
use super::{CouplingInput, CouplingOptions};
use crate::error::VibrationError;
use crate::params::{Bonnet, LateralAxis};
use ndarray::Array2;
use rayon::prelude::*;

/// Removal (nm) on the map grid with the mechanisms of `opts` switched on (executed path when
/// `dwell_execution` is on).
pub fn direct_removal(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
) -> Result<Array2<f64>, VibrationError> {
    let p = input.params;
    let g = input.grid;
    let inst = InstantTif::new(input.base_tif, p);
    let exec = executed_path(input, &opts.mechanisms)?;
    let stream = SampleStream::new(
        &exec,
        p,
        bonnet,
        &opts.mechanisms,
        opts.sample_hz,
        opts.seed,
    )?;
    let (ex, ey) = inst.half_extent_mm(0.2 * p.offset_mm);
    let lat = p.lateral_axis;
    let threads = rayon::current_num_threads().max(1);
    let mut accs: Vec<Array2<f64>> = (0..threads)
        .map(|_| Array2::zeros((g.rows, g.cols)))
        .collect();
    let mut buf: Vec<CouplingSample> = Vec::with_capacity(1 << 15);
    let flush = |buf: &mut Vec<CouplingSample>, accs: &mut Vec<Array2<f64>>| {
        let chunk = buf.len().div_ceil(threads).max(1);
        accs.par_iter_mut()
            .zip(buf.par_chunks(chunk))
            .for_each(|(acc, part)| {
                for s in part {
                    let (cx, cy) = match lat {
                        LateralAxis::X => (s.x_mm + s.u_mm, s.y_mm),
                        LateralAxis::Y => (s.x_mm, s.y_mm + s.u_mm),
                    };
                    let d = s.delta_det_mm + s.delta_noise_mm;
                    let j0 = ((cx - ex - g.x0_mm) / g.dx_mm).ceil().max(0.0) as usize;
                    let j1 = ((cx + ex - g.x0_mm) / g.dx_mm)
                        .floor()
                        .min(g.cols as f64 - 1.0);
                    let i0 = ((cy - ey - g.y0_mm) / g.dy_mm).ceil().max(0.0) as usize;
                    let i1 = ((cy + ey - g.y0_mm) / g.dy_mm)
                        .floor()
                        .min(g.rows as f64 - 1.0);
                    if j1 < 0.0 || i1 < 0.0 {
                        continue;
                    }
                    for i in i0..=i1 as usize {
                        let oy = g.y_mm(i) - cy;
                        let mut row = acc.row_mut(i);
                        for j in j0..=j1 as usize {
                            row[j] += s.dt_s * inst.rate(g.x_mm(j) - cx, oy, d);
                        }
                    }
                }
            });
        buf.clear();
    };
    for s in stream {
        buf.push(s);
        if buf.len() == buf.capacity() {
            flush(&mut buf, &mut accs);
        }
    }
    flush(&mut buf, &mut accs);
    let mut out = Array2::zeros((g.rows, g.cols));
    for a in accs {
        out += &a;
    }
    Ok(out)
}
