//! Tool-tip displacement in time: the steady response to the spindle harmonics (closed form),
//! the response to seeded broadband force noise that excites every mode, and the ring-down
//! after each velocity change of the commanded path (line reversals of the raster). The last two
//! are integrated in time (classical RK4 on each principal equation; the system is linear, so
//! the three parts are kept separate and summed by the caller).
//!
//! Conventions: principal coordinates (x1, x2) in mm; time from 0 at the first sample;
//! broadband noise is a scalar force F(t) acting along (μ, 1) like the polishing force,
//! white samples at 2 × `noise_band_hz` joined linearly, scaled so the time-averaged RMS of F is
//! `noise_force_rms_n`; path accelerations act as base excitation, x_i'' + 2ζω x_i' + ω² x_i =
//! −a(t) (e_t · e_i), with a(t) the commanded acceleration along the lateral axis (mm/s²).
//! The offset change at the contact is Δh = −T u_n: a holder motion away from the part
//! (+n) reduces the offset, scaled by the bonnet's series transfer T.

use crate::error::VibrationError;
use crate::params::{Bonnet, VibrationParams};
use crate::response::{spindle_harmonics, HarmonicPhasors};
use bonnetlab_surface::rng::Rng;
use rustfft::num_complex::Complex64;
use serde::Serialize;
use std::f64::consts::PI;

/// A constant-acceleration interval of the commanded holder motion along the lateral axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AccelPulse {
    pub t0_s: f64,
    pub duration_s: f64,
    pub accel_mm_per_s2: f64,
}

/// The velocity changes of a commanded path along one axis (samples `t_s`, positions `pos_mm`),
/// executed at the acceleration limit: one pulse of |Δv| / a_max seconds centred on each sample
/// where the velocity changes.
pub fn velocity_change_pulses(
    t_s: &[f64],
    pos_mm: &[f64],
    accel_max_mm_per_s2: f64,
) -> Vec<AccelPulse> {
    let n = t_s.len().min(pos_mm.len());
    let mut out = Vec::new();
    if n < 3 || accel_max_mm_per_s2 <= 0.0 {
        return out;
    }
    let vel = |k: usize| {
        let dt = t_s[k + 1] - t_s[k];
        if dt > 0.0 {
            (pos_mm[k + 1] - pos_mm[k]) / dt
        } else {
            0.0
        }
    };
    let mut v_prev = vel(0);
    for (k, &tk) in t_s.iter().enumerate().take(n - 1).skip(1) {
        let v = vel(k);
        let dv = v - v_prev;
        if dv.abs() > 1e-9 && dv.is_finite() {
            let dur = dv.abs() / accel_max_mm_per_s2;
            out.push(AccelPulse {
                t0_s: tk - 0.5 * dur,
                duration_s: dur,
                accel_mm_per_s2: dv.signum() * accel_max_mm_per_s2,
            });
        }
        v_prev = v;
    }
    out
}

/// Which excitations to include.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Excitations {
    pub steady: bool,
    pub noise: bool,
    pub ringdown: bool,
}

impl Excitations {
    pub const ALL: Excitations = Excitations {
        steady: true,
        noise: true,
        ringdown: true,
    };
}

/// One time sample, principal coordinates of each excitation part, mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TipSample {
    pub t_s: f64,
    pub steady: [f64; 2],
    pub noise: [f64; 2],
    pub ringdown: [f64; 2],
}

/// One RK4 step of x'' + 2ζω x' + ω² x = g(t) from t to t + h; `g` in mm/s².
pub fn rk4_step(
    state: [f64; 2],
    t: f64,
    h: f64,
    omega: f64,
    zeta: f64,
    g: &mut impl FnMut(f64) -> f64,
) -> [f64; 2] {
    let gv = [g(t), g(t + 0.5 * h), g(t + h)];
    rk4_step_values(state, h, omega, zeta, gv)
}

/// [`rk4_step`] with the forcing given at the step's start, midpoint and end.
#[inline]
pub fn rk4_step_values(state: [f64; 2], h: f64, omega: f64, zeta: f64, g: [f64; 3]) -> [f64; 2] {
    let c = 2.0 * zeta * omega;
    let k = omega * omega;
    let f = |s: [f64; 2], gt: f64| [s[1], gt - c * s[1] - k * s[0]];
    let k1 = f(state, g[0]);
    let k2 = f(
        [state[0] + 0.5 * h * k1[0], state[1] + 0.5 * h * k1[1]],
        g[1],
    );
    let k3 = f(
        [state[0] + 0.5 * h * k2[0], state[1] + 0.5 * h * k2[1]],
        g[1],
    );
    let k4 = f([state[0] + h * k3[0], state[1] + h * k3[1]], g[2]);
    [
        state[0] + h / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
        state[1] + h / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
    ]
}

/// Seeded band-limited force noise: white samples at `rate_hz`, joined linearly.
#[derive(Debug, Clone)]
pub struct NoiseForce {
    rng: Rng,
    rate_hz: f64,
    scale: f64,
    k: u64,
    v0: f64,
    v1: f64,
}

impl NoiseForce {
    /// RMS `rms_n` (time average) over the band up to about `band_hz`.
    pub fn new(rms_n: f64, band_hz: f64, seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        // Linear interpolation between independent samples keeps 2/3 of their variance.
        let scale = rms_n * 1.5f64.sqrt();
        let v0 = scale * rng.normal();
        let v1 = scale * rng.normal();
        NoiseForce {
            rng,
            rate_hz: 2.0 * band_hz,
            scale,
            k: 0,
            v0,
            v1,
        }
    }

    /// Sample interval of the underlying white sequence, s.
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// Force at time t (N); t must not decrease between calls by more than one sample.
    pub fn at(&mut self, t_s: f64) -> f64 {
        let pos = (t_s * self.rate_hz).max(0.0);
        while pos >= (self.k + 1) as f64 {
            self.k += 1;
            self.v0 = self.v1;
            self.v1 = self.scale * self.rng.normal();
        }
        let u = (pos - self.k as f64).clamp(0.0, 1.0);
        self.v0 + (self.v1 - self.v0) * u
    }
}

/// Streams the tool-tip displacement sample by sample (no allocation proportional to the
/// duration: a 60-minute run at 1 kHz is 3.6 million samples).
#[derive(Debug, Clone)]
pub struct ToolTipGenerator {
    dt_s: f64,
    n: u64,
    omega: [f64; 2],
    zeta: [f64; 2],
    harmonics: Vec<HarmonicPhasors>,
    rot: Vec<Complex64>,
    rot_step: Vec<Complex64>,
    noise_dir_accel: [f64; 2],
    lateral_dir: [f64; 2],
    noise: NoiseForce,
    noise_state: [[f64; 2]; 2],
    ring_state: [[f64; 2]; 2],
    pulses: Vec<AccelPulse>,
    cursor: usize,
    active: Vec<usize>,
    excitations: Excitations,
}

impl ToolTipGenerator {
    /// `pulses` are the commanded lateral accelerations (any order); `seed` fixes the noise.
    pub fn new(
        p: &VibrationParams,
        bonnet: Bonnet,
        sample_hz: f64,
        mut pulses: Vec<AccelPulse>,
        excitations: Excitations,
        seed: u64,
    ) -> Result<Self, VibrationError> {
        if !(sample_hz.is_finite() && sample_hz > 0.0) {
            return Err(VibrationError::InvalidArgument(format!(
                "sample rate {sample_hz} Hz"
            )));
        }
        let omega = p.omega_n_rad_per_s();
        // RK4 is stable for ω dt < 2.8; keep a margin so the integrated parts stay accurate.
        let wmax = omega[0].max(omega[1]);
        if wmax / sample_hz > 0.5 {
            return Err(VibrationError::InvalidArgument(format!(
                "sample rate {sample_hz} Hz too low for a {:.1} Hz mode (need at least {:.0} Hz)",
                wmax / (2.0 * PI),
                2.0 * wmax
            )));
        }
        pulses.retain(|q| q.duration_s > 0.0 && q.duration_s.is_finite() && q.t0_s.is_finite());
        pulses.sort_by(|a, b| a.t0_s.total_cmp(&b.t0_s));
        let (e1, e2) = p.axes();
        let f = p.project([p.mu, 1.0]);
        let harmonics = spindle_harmonics(p, bonnet, p.spindle_rpm);
        Ok(ToolTipGenerator {
            dt_s: 1.0 / sample_hz,
            n: 0,
            omega,
            zeta: p.zeta_effective(bonnet),
            rot: vec![Complex64::new(1.0, 0.0); harmonics.len()],
            rot_step: harmonics
                .iter()
                .map(|h| Complex64::from_polar(1.0, 2.0 * PI * h.freq_hz / sample_hz))
                .collect(),
            harmonics,
            // Unit force along (μ, 1) as acceleration of each principal equation: 1e3 F / m.
            noise_dir_accel: [1e3 * f[0] / p.mass_kg, 1e3 * f[1] / p.mass_kg],
            lateral_dir: [e1[0], e2[0]],
            noise: NoiseForce::new(p.noise_force_rms_n, p.noise_band_hz, seed),
            noise_state: [[0.0; 2]; 2],
            ring_state: [[0.0; 2]; 2],
            pulses,
            cursor: 0,
            active: Vec::new(),
            excitations,
        })
    }

    pub fn dt_s(&self) -> f64 {
        self.dt_s
    }

    fn lateral_accel(&mut self, t: f64) -> f64 {
        while self.cursor < self.pulses.len() && self.pulses[self.cursor].t0_s <= t {
            self.active.push(self.cursor);
            self.cursor += 1;
        }
        let pulses = &self.pulses;
        self.active
            .retain(|&i| pulses[i].t0_s + pulses[i].duration_s > t);
        self.active
            .iter()
            .filter(|&&i| pulses[i].t0_s <= t)
            .map(|&i| pulses[i].accel_mm_per_s2)
            .sum()
    }

    /// The next sample (the first is at t = 0).
    pub fn next_sample(&mut self) -> TipSample {
        let t = self.n as f64 * self.dt_s;
        let mut s = TipSample {
            t_s: t,
            steady: [0.0; 2],
            noise: [0.0; 2],
            ringdown: [0.0; 2],
        };
        if self.excitations.steady {
            // Rotating unit phasors e^{iωt}, re-anchored exactly every 4096 samples so rounding
            // cannot drift (a sin_cos per harmonic per sample was a third of the stream's cost).
            let exact = self.n.is_multiple_of(4096);
            for (k, h) in self.harmonics.iter().enumerate() {
                if exact {
                    let (sn, cs) = (2.0 * PI * h.freq_hz * t).sin_cos();
                    self.rot[k] = Complex64::new(cs, sn);
                }
                let (sn, cs) = (self.rot[k].im, self.rot[k].re);
                self.rot[k] *= self.rot_step[k];
                for i in 0..2 {
                    // Im(X e^{iφ}) = X.re sin φ + X.im cos φ
                    s.steady[i] += h.x[i].re * sn + h.x[i].im * cs;
                }
            }
        }
        s.noise = [self.noise_state[0][0], self.noise_state[1][0]];
        s.ringdown = [self.ring_state[0][0], self.ring_state[1][0]];
        let h = self.dt_s;
        if self.excitations.noise {
            // The force samples are shared by both equations: tabulate the three RK4 times once.
            let g = [
                self.noise.at(t),
                self.noise.at(t + 0.5 * h),
                self.noise.at(t + h),
            ];
            for i in 0..2 {
                let a = self.noise_dir_accel[i];
                let gv = [a * g[0], a * g[1], a * g[2]];
                self.noise_state[i] =
                    rk4_step_values(self.noise_state[i], h, self.omega[i], self.zeta[i], gv);
            }
        }
        // Between ring-downs the base-excited state is below 1e-12 mm and nothing drives it:
        // skip the integration (most of a raster line).
        let quiet = self.active.is_empty()
            && self.pulses.get(self.cursor).is_none_or(|q| q.t0_s > t + h)
            && self
                .ring_state
                .iter()
                .all(|s| s[0].abs() < 1e-12 && s[1].abs() < 1e-9);
        if self.excitations.ringdown && !quiet {
            let a = [
                self.lateral_accel(t),
                self.lateral_accel(t + 0.5 * h),
                self.lateral_accel(t + h),
            ];
            for i in 0..2 {
                let d = -self.lateral_dir[i];
                let gv = [d * a[0], d * a[1], d * a[2]];
                self.ring_state[i] =
                    rk4_step_values(self.ring_state[i], h, self.omega[i], self.zeta[i], gv);
            }
        }
        self.n += 1;
        s
    }
}

/// A recorded tool-tip displacement (sum of the enabled parts).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimeSeries {
    pub sample_hz: f64,
    pub t_s: Vec<f64>,
    pub x1_mm: Vec<f64>,
    pub x2_mm: Vec<f64>,
    /// Holder displacement along the normal n, mm.
    pub normal_mm: Vec<f64>,
    /// Holder displacement along the tangential t (the lateral map axis), mm.
    pub lateral_mm: Vec<f64>,
    /// Offset change at the contact, Δh = −T u_n, mm.
    pub offset_change_mm: Vec<f64>,
}

/// Records `duration_s` of tool-tip displacement at `sample_hz`.
pub fn tool_tip_displacement(
    p: &VibrationParams,
    bonnet: Bonnet,
    duration_s: f64,
    sample_hz: f64,
    pulses: Vec<AccelPulse>,
    excitations: Excitations,
    seed: u64,
) -> Result<TimeSeries, VibrationError> {
    if !(duration_s.is_finite() && duration_s > 0.0) {
        return Err(VibrationError::InvalidArgument(format!(
            "duration {duration_s} s"
        )));
    }
    let n = (duration_s * sample_hz).floor() as usize + 1;
    if n > 50_000_000 {
        return Err(VibrationError::InvalidArgument(format!(
            "{n} samples is too many to record"
        )));
    }
    let mut g = ToolTipGenerator::new(p, bonnet, sample_hz, pulses, excitations, seed)?;
    let (e1, e2) = p.axes();
    let tr = p.offset_transfer(bonnet);
    let mut ts = TimeSeries {
        sample_hz,
        t_s: Vec::with_capacity(n),
        x1_mm: Vec::with_capacity(n),
        x2_mm: Vec::with_capacity(n),
        normal_mm: Vec::with_capacity(n),
        lateral_mm: Vec::with_capacity(n),
        offset_change_mm: Vec::with_capacity(n),
    };
    for _ in 0..n {
        let s = g.next_sample();
        let x1 = s.steady[0] + s.noise[0] + s.ringdown[0];
        let x2 = s.steady[1] + s.noise[1] + s.ringdown[1];
        let un = x1 * e1[1] + x2 * e2[1];
        ts.t_s.push(s.t_s);
        ts.x1_mm.push(x1);
        ts.x2_mm.push(x2);
        ts.normal_mm.push(un);
        ts.lateral_mm.push(x1 * e1[0] + x2 * e2[0]);
        ts.offset_change_mm.push(-tr * un);
    }
    Ok(ts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_force_has_the_requested_rms() {
        let mut nf = NoiseForce::new(0.5, 200.0, 3);
        let n = 400_000;
        let ms: f64 = (0..n)
            .map(|k| nf.at(k as f64 * 1e-3 + 0.000_37).powi(2))
            .sum::<f64>()
            / n as f64;
        assert!((ms.sqrt() - 0.5).abs() < 0.01, "{}", ms.sqrt());
    }

    #[test]
    fn pulses_carry_the_velocity_change() {
        // Raster line x: 0 -> 10 mm at 2 mm/s, then back: one reversal of Δv = −4 mm/s.
        let t: Vec<f64> = (0..=10).map(|k| k as f64).collect();
        let x: Vec<f64> = t
            .iter()
            .map(|&t| if t <= 5.0 { 2.0 * t } else { 20.0 - 2.0 * t })
            .collect();
        let p = velocity_change_pulses(&t, &x, 100.0);
        assert_eq!(p.len(), 1);
        assert!((p[0].accel_mm_per_s2 * p[0].duration_s + 4.0).abs() < 1e-12);
        assert!((p[0].t0_s + 0.5 * p[0].duration_s - 5.0).abs() < 1e-12);
    }
}
