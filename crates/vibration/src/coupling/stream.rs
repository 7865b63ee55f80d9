//! The tool's state at the coupling's sampling rate: position along the (commanded or executed)
//! path and the vibration displacements split by mechanism, streamed sample by sample so a
//! 60-minute run at 1 kHz needs no 3.6-million-sample arrays.
//!
//! Each sample stands for the interval dt around its time (midpoint rule): it carries the tool
//! centre (x, y) in mm, the lateral displacement u (mm, along the lateral map axis), and the
//! offset changes at the contact δ_det (spindle harmonics + ring-down, mechanism
//! `normal_offset`) and δ_noise (broadband noise, mechanism `envelope`), each zero when its
//! mechanism is off.

use crate::coupling::Mechanisms;
use crate::error::VibrationError;
use crate::params::{Bonnet, LateralAxis, VibrationParams};
use crate::timeseries::{velocity_change_pulses, Excitations, TipSample, ToolTipGenerator};
use bonnetlab_process::path::PathLog;

/// One coupling sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CouplingSample {
    pub x_mm: f64,
    pub y_mm: f64,
    pub dt_s: f64,
    pub u_mm: f64,
    pub delta_det_mm: f64,
    pub delta_noise_mm: f64,
}

/// Streams [`CouplingSample`]s along a path.
pub struct SampleStream<'a> {
    path: &'a PathLog,
    gen: Option<ToolTipGenerator>,
    dt: f64,
    n: usize,
    k: usize,
    seg: usize,
    t0: f64,
    duration: f64,
    lateral: bool,
    normal: bool,
    envelope: bool,
    e_lat: [f64; 2],
    e_nrm: [f64; 2],
    transfer: f64,
    lag_mm: f64,
}

impl<'a> SampleStream<'a> {
    pub fn new(
        path: &'a PathLog,
        p: &VibrationParams,
        bonnet: Bonnet,
        mech: &Mechanisms,
        sample_hz: f64,
        seed: u64,
    ) -> Result<Self, VibrationError> {
        if path.len() < 2 {
            return Err(VibrationError::InvalidArgument(
                "path has fewer than 2 samples".into(),
            ));
        }
        if !(sample_hz.is_finite() && sample_hz > 0.0) {
            return Err(VibrationError::InvalidArgument(format!(
                "sample rate {sample_hz} Hz"
            )));
        }
        let t0 = path.t_s[0];
        let duration = path.duration_s();
        let n = (duration * sample_hz).ceil().max(1.0) as usize;
        if n > 200_000_000 {
            return Err(VibrationError::InvalidArgument(format!(
                "{n} coupling samples is too many"
            )));
        }
        let any_vib = mech.normal_offset || mech.lateral_jitter || mech.envelope;
        let gen = if any_vib {
            let t: Vec<f64> = path.t_s.iter().map(|t| t - t0).collect();
            let lat = match p.lateral_axis {
                LateralAxis::X => &path.x_mm,
                LateralAxis::Y => &path.y_mm,
            };
            let pulses = velocity_change_pulses(&t, lat, p.accel_max_mm_per_s2);
            // Ring-down and steady parts belong to `normal_offset` (normal) and `lateral_jitter`
            // (lateral); noise to `envelope` (normal) and `lateral_jitter` (lateral).
            let ex = Excitations {
                steady: mech.normal_offset || mech.lateral_jitter,
                noise: mech.envelope || mech.lateral_jitter,
                ringdown: mech.normal_offset || mech.lateral_jitter,
            };
            Some(ToolTipGenerator::new(
                p, bonnet, sample_hz, pulses, ex, seed,
            )?)
        } else {
            None
        };
        let (e1, e2) = p.axes();
        Ok(SampleStream {
            path,
            gen,
            dt: duration / n as f64,
            n,
            k: 0,
            seg: 0,
            t0,
            duration,
            lateral: mech.lateral_jitter,
            normal: mech.normal_offset,
            envelope: mech.envelope,
            e_lat: [e1[0], e2[0]],
            e_nrm: [e1[1], e2[1]],
            transfer: p.offset_transfer(bonnet),
            lag_mm: 0.0,
        })
    }

    /// The same stream with the tool centre moved back by `lag_mm` along the path's direction
    /// of travel at every sample (a servo lag: the executed position trails the path at the
    /// same instant). Only the positions move: the clock, hence the spindle phase, and the
    /// ring-down after the path's velocity changes are the path's own.
    pub fn with_direction_lag(mut self, lag_mm: f64) -> Self {
        self.lag_mm = lag_mm;
        self
    }

    /// Number of samples the stream yields.
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    fn position(&mut self, t: f64) -> (f64, f64) {
        let p = self.path;
        while self.seg + 2 < p.len() && p.t_s[self.seg + 1] <= t {
            self.seg += 1;
        }
        let k = self.seg;
        let f = ((t - p.t_s[k]) / (p.t_s[k + 1] - p.t_s[k])).clamp(0.0, 1.0);
        let (dx, dy) = (p.x_mm[k + 1] - p.x_mm[k], p.y_mm[k + 1] - p.y_mm[k]);
        let (mut x, mut y) = (p.x_mm[k] + f * dx, p.y_mm[k] + f * dy);
        let d = dx.hypot(dy);
        if self.lag_mm != 0.0 && d > 1e-12 {
            x -= self.lag_mm * dx / d;
            y -= self.lag_mm * dy / d;
        }
        (x, y)
    }
}

impl Iterator for SampleStream<'_> {
    type Item = CouplingSample;

    fn next(&mut self) -> Option<CouplingSample> {
        if self.k >= self.n {
            return None;
        }
        let tr = (self.k as f64 + 0.5) * self.dt;
        let (x, y) = self.position(self.t0 + tr.min(self.duration));
        let mut s = CouplingSample {
            x_mm: x,
            y_mm: y,
            dt_s: self.dt,
            u_mm: 0.0,
            delta_det_mm: 0.0,
            delta_noise_mm: 0.0,
        };
        if let Some(g) = self.gen.as_mut() {
            // The generator samples at k dt; the half-sample offset is immaterial at >= 1 kHz.
            let v: TipSample = g.next_sample();
            let lat = |x: [f64; 2], e: [f64; 2]| x[0] * e[0] + x[1] * e[1];
            if self.lateral {
                let tot = [
                    v.steady[0] + v.noise[0] + v.ringdown[0],
                    v.steady[1] + v.noise[1] + v.ringdown[1],
                ];
                s.u_mm = lat(tot, self.e_lat);
            }
            if self.normal {
                let det = [v.steady[0] + v.ringdown[0], v.steady[1] + v.ringdown[1]];
                s.delta_det_mm = -self.transfer * lat(det, self.e_nrm);
            }
            if self.envelope {
                s.delta_noise_mm = -self.transfer * lat(v.noise, self.e_nrm);
            }
        }
        self.k += 1;
        Some(s)
    }
}

impl SampleStream<'_> {
    /// Interval of one sample, s.
    pub fn dt_s(&self) -> f64 {
        self.dt
    }
}

/// The vibration displacements at any time along the path: piecewise-linear through the
/// stream's samples (each at the middle of its interval), held before the first and after the
/// last. Times asked must not decrease (the stream is integrated once, forward).
pub struct Track<'a> {
    stream: SampleStream<'a>,
    a: Option<(f64, CouplingSample)>,
    b: Option<(f64, CouplingSample)>,
}

/// Lateral displacement u and offset change δ = δ_det + δ_noise (mm) at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Displacement {
    pub u_mm: f64,
    pub delta_mm: f64,
}

impl<'a> Track<'a> {
    pub fn new(stream: SampleStream<'a>) -> Track<'a> {
        let mut t = Track {
            stream,
            a: None,
            b: None,
        };
        t.b = t.pull();
        t
    }

    fn pull(&mut self) -> Option<(f64, CouplingSample)> {
        let s = self.stream.next()?;
        let t = self.stream.t0 + (self.stream.k as f64 - 0.5) * self.stream.dt;
        Some((t, s))
    }

    /// The displacements at time `t_s` (the path's clock).
    pub fn at(&mut self, t_s: f64) -> Displacement {
        while matches!(self.b, Some((tb, _)) if tb <= t_s) {
            self.a = self.b.take();
            self.b = self.pull();
        }
        let d = |s: &CouplingSample| Displacement {
            u_mm: s.u_mm,
            delta_mm: s.delta_det_mm + s.delta_noise_mm,
        };
        match (&self.a, &self.b) {
            (Some((ta, a)), Some((tb, b))) => {
                let (da, db) = (d(a), d(b));
                let f = (t_s - ta) / (tb - ta);
                Displacement {
                    u_mm: da.u_mm + f * (db.u_mm - da.u_mm),
                    delta_mm: da.delta_mm + f * (db.delta_mm - da.delta_mm),
                }
            }
            (Some((_, s)), None) | (None, Some((_, s))) => d(s),
            (None, None) => Displacement {
                u_mm: 0.0,
                delta_mm: 0.0,
            },
        }
    }
}
