//! The fast coupling: a second-order expansion of the instantaneous TIF in the small
//! displacements, evaluated as FFT convolutions of weighted dwell maps with the TIF and its
//! derivative kernels ([`super::instant`]).
//!
//! With q = x − p(t), u the lateral and δ = δ_det + δ_noise the offset displacement,
//! T(q − u e_l; δ) ≈ K0 − u K_l + ½u² K_ll + δ K_h + ½δ² K_hh − u δ K_lh, so the removal is
//! Σ_c W_c ⊛ K_c with W_c the dwell maps weighted by 1, u, u², δ, δ², u δ. Each mechanism's map
//! collects its own terms; the cross terms (δ_det δ_noise, u δ) form `interaction`.

use super::instant::{InstantTif, Kernels};
use super::splat::DwellChannels;
use super::stream::{CouplingSample, SampleStream};
use super::{CouplingInput, CouplingOptions, MechanismMaps, Mechanisms};
use crate::error::VibrationError;
use crate::params::Bonnet;
use bonnetlab_process::fft::{fast_len, Fft2};
use bonnetlab_process::path::kinematics::{apply_limits, Limits};
use bonnetlab_process::path::PathLog;
use bonnetlab_process::removal::{dwell_map_with, Splat};
use bonnetlab_process::Grid;
use ndarray::Array2;
use rayon::prelude::*;
use rustfft::num_complex::Complex;

/// Channel indices: W0 (cubic splat) is channel 0; the correction channels 1..=8 are splatted
/// bilinearly (stored at index c − 1 of their own maps).
const W0: usize = 0;
const WU: usize = 1;
const WUU: usize = 2;
const WD: usize = 3;
const WDD: usize = 4;
const WN: usize = 5;
const WNN: usize = 6;
const WDN: usize = 7;
const WUD: usize = 8;
const NC: usize = 9;
const NV: usize = NC - 1;
/// Samples per message between the integrating and the splatting thread.
const CHUNK: usize = 1 << 14;

/// Kernel indices.
const K0: usize = 0;
const KL: usize = 1;
const KLL: usize = 2;
const KH: usize = 3;
const KHH: usize = 4;
const KLH: usize = 5;

/// Output indices.
const O_BASE: usize = 0;
const O_EXEC: usize = 1;
const O_NORMAL: usize = 2;
const O_ENV: usize = 3;
const O_LAT: usize = 4;
const O_INTER: usize = 5;
const NO: usize = 6;

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

/// Per-mechanism removal maps (nm, on the map grid) by the fast expansion.
pub fn fast_maps(
    input: &CouplingInput<'_>,
    bonnet: Bonnet,
    opts: &CouplingOptions,
) -> Result<MechanismMaps, VibrationError> {
    let p = input.params;
    let g = input.grid;
    let inst = InstantTif::new(input.base_tif, p);
    let kern = Kernels::sample(&inst, g.dx_mm, g.dy_mm, p.lateral_axis);
    let (hy, hx) = kern.half;
    let ext = g.grown(hy, hx);
    let (n0, n1) = (fast_len(ext.rows), fast_len(ext.cols));
    let fft = Fft2::new(n0, n1);
    let slen = fft.spectrum_len();
    let mut real = vec![0.0; n0 * n1];
    let mut tmp = vec![Complex::new(0.0, 0.0); slen];

    let kernels = [
        &kern.k0, &kern.kl, &kern.kll, &kern.kh, &kern.khh, &kern.klh,
    ];
    let mut khat = Vec::with_capacity(kernels.len());
    for k in kernels {
        real.iter_mut().for_each(|v| *v = 0.0);
        let (k0, k1) = k.dim();
        for ((a, b), &v) in k.indexed_iter() {
            let i = (a as isize - (k0 / 2) as isize).rem_euclid(n0 as isize) as usize;
            let j = (b as isize - (k1 / 2) as isize).rem_euclid(n1 as isize) as usize;
            real[i * n1 + j] += v;
        }
        let mut spec = vec![Complex::new(0.0, 0.0); slen];
        fft.forward(&mut real, &mut tmp, &mut spec);
        khat.push(spec);
    }

    let mech = &opts.mechanisms;
    let exec = executed_path(input, mech)?;
    let any_vib = mech.normal_offset || mech.lateral_jitter || mech.envelope;
    let mut ch0 = DwellChannels::<1>::new(ext);
    let mut chv = DwellChannels::<NV>::new(if any_vib {
        ext
    } else {
        Grid {
            rows: 1,
            cols: 1,
            ..ext
        }
    });
    // Two-stage pipeline: one thread integrates the vibration, this one splats its samples.
    let stream = SampleStream::new(&exec, p, bonnet, mech, opts.sample_hz, opts.seed)?;
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
                ch0.add(s.x_mm, s.y_mm, s.dt_s, &[1.0]);
                if !any_vib {
                    continue;
                }
                let d = s.delta_det_mm + s.delta_noise_mm;
                let w = [
                    s.u_mm,
                    s.u_mm * s.u_mm,
                    s.delta_det_mm,
                    s.delta_det_mm * s.delta_det_mm,
                    s.delta_noise_mm,
                    s.delta_noise_mm * s.delta_noise_mm,
                    s.delta_det_mm * s.delta_noise_mm,
                    s.u_mm * d,
                ];
                chv.add_bilinear(s.x_mm, s.y_mm, s.dt_s, &w);
            }
        }
    });
    // The commanded dwell carries no vibration weight: bonnetlab_process's own cubic splat of
    // the path in half-pixel sub-steps gives it without a 1 kHz pass.
    let commanded_w0 = if mech.dwell_execution {
        let d = dwell_map_with(input.path, None, &ext, Splat::Cubic);
        Some(d.iter().copied().collect::<Vec<f64>>())
    } else {
        None
    };

    // (channel, output, kernel, coefficient)
    let mut terms: Vec<(usize, usize, usize, f64)> = vec![
        (WU, O_LAT, KL, -1.0),
        (WUU, O_LAT, KLL, 0.5),
        (WD, O_NORMAL, KH, 1.0),
        (WDD, O_NORMAL, KHH, 0.5),
        (WN, O_ENV, KH, 1.0),
        (WNN, O_ENV, KHH, 0.5),
        (WDN, O_INTER, KHH, 1.0),
        (WUD, O_INTER, KLH, -1.0),
    ];
    if commanded_w0.is_some() {
        terms.push((W0, O_EXEC, K0, 1.0));
    } else {
        terms.push((W0, O_BASE, K0, 1.0));
    }
    let mut out_hat = vec![vec![Complex::new(0.0, 0.0); slen]; NO];
    let mut spec = vec![Complex::new(0.0, 0.0); slen];
    let mut load = |data: &[f64], spec: &mut Vec<Complex<f64>>| {
        real.iter_mut().for_each(|v| *v = 0.0);
        for i in 0..ext.rows {
            real[i * n1..i * n1 + ext.cols]
                .copy_from_slice(&data[i * ext.cols..(i + 1) * ext.cols]);
        }
        fft.forward(&mut real, &mut tmp, spec);
    };
    for c in 0..NC {
        let mine: Vec<_> = terms.iter().filter(|t| t.0 == c).collect();
        if mine.is_empty() {
            continue;
        }
        if c > 0 && !any_vib {
            continue;
        }
        let data = if c == 0 {
            ch0.channel(0)
        } else {
            chv.channel(c - 1)
        };
        if data.iter().all(|&v| v == 0.0) {
            continue;
        }
        load(&data, &mut spec);
        for &&(_, o, k, coef) in &mine {
            out_hat[o]
                .par_iter_mut()
                .zip(spec.par_iter().zip(khat[k].par_iter()))
                .for_each(|(acc, (s, kk))| {
                    *acc += s * kk * coef;
                });
        }
    }
    if let Some(w0c) = commanded_w0 {
        load(&w0c, &mut spec);
        // Baseline from the commanded dwell; execution = executed − commanded.
        for (o, coef) in [(O_BASE, 1.0), (O_EXEC, -1.0)] {
            out_hat[o]
                .par_iter_mut()
                .zip(spec.par_iter().zip(khat[K0].par_iter()))
                .for_each(|(acc, (s, kk))| {
                    *acc += s * kk * coef;
                });
        }
    }
    let mut maps: Vec<Array2<f64>> = Vec::with_capacity(NO);
    let mut rbuf = vec![0.0; n0 * n1];
    let mut tmp2 = vec![Complex::new(0.0, 0.0); slen];
    for mut h in out_hat {
        fft.inverse(&mut h, &mut tmp2, &mut rbuf);
        maps.push(crop(&rbuf, n1, hy, hx, &g));
    }
    let mut it = maps.into_iter();
    let mut next = || it.next().unwrap_or_else(|| Array2::zeros((g.rows, g.cols)));
    Ok(MechanismMaps {
        baseline: next(),
        dwell_execution: next(),
        normal_offset: next(),
        envelope: next(),
        lateral_jitter: next(),
        interaction: next(),
    })
}

fn crop(real: &[f64], n1: usize, hy: usize, hx: usize, g: &Grid) -> Array2<f64> {
    Array2::from_shape_fn((g.rows, g.cols), |(i, j)| real[(i + hy) * n1 + j + hx])
}
