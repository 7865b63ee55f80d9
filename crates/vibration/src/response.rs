//! Steady-state forced response of the two decoupled principal directions (DOMAIN.md section 2),
//! the frequency-response curves over the spindle band, and the response to the spindle
//! harmonics.
//!
//! Conventions: the force is F(t) = F_n (μ, 1) sin(ω t) in the (t, n) frame; each principal
//! coordinate is x_i(t) = A_i sin(ω t − φ_i) with A_i ≥ 0 in mm and φ_i the phase lag behind the
//! normal force, in degrees, wrapped to (−180, 180] (a negative force projection adds 180°).
//! The closed form is, with λ_i = ω / ω_i,
//! X_i = (F_i0 / k_i) / sqrt((1 − λ_i²)² + (2 ζ_i λ_i)²), φ_i = atan2(2 ζ_i λ_i, 1 − λ_i²).

use crate::modal::SPINDLE_BAND_RPM;
use crate::params::{Bonnet, VibrationParams};
use rustfft::num_complex::Complex64;
use serde::Serialize;
use std::f64::consts::PI;

/// Closed-form steady state of one degree of freedom: signed amplitude (F0 / k) |H| in mm and
/// the phase lag φ in radians for forcing F0 sin(ω t) (k in N/mm, F0 in N).
pub fn sdof_steady(f0_n: f64, k_n_per_mm: f64, zeta: f64, lambda: f64) -> (f64, f64) {
    let a = 1.0 - lambda * lambda;
    let b = 2.0 * zeta * lambda;
    ((f0_n / k_n_per_mm) / (a * a + b * b).sqrt(), b.atan2(a))
}

/// Complex amplitude (phasor) of one direction, mm: x(t) = Im(X e^{iωt}).
fn phasor(f0_n: f64, k: f64, zeta: f64, lambda: f64) -> Complex64 {
    let (amp, phi) = sdof_steady(f0_n, k, zeta, lambda);
    Complex64::from_polar(amp, -phi)
}

/// The steady response to the spindle's once-per-revolution force (the JSON contract of
/// `bonnetlab vibration`), plus the displacements the coupling needs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Response {
    pub bonnet: Bonnet,
    pub spindle_rpm: f64,
    pub excitation_hz: f64,
    pub x1_amplitude_mm: f64,
    pub x2_amplitude_mm: f64,
    pub x1_phase_deg: f64,
    pub x2_phase_deg: f64,
    pub zeta1_effective: f64,
    pub zeta2_effective: f64,
    pub natural_freq1_hz: f64,
    pub natural_freq2_hz: f64,
    /// Amplitude of the holder displacement along the normal, mm.
    pub normal_amplitude_mm: f64,
    /// Amplitude of the holder displacement along the tangential (lateral) direction, mm.
    pub lateral_amplitude_mm: f64,
    /// Amplitude of the offset change at the contact (normal amplitude times the series
    /// transfer of the bonnet), mm.
    pub offset_amplitude_mm: f64,
}

/// Complex amplitudes of one excitation frequency: principal (x1, x2) and (t, n), mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HarmonicPhasors {
    pub freq_hz: f64,
    pub x: [Complex64; 2],
    pub tn: [Complex64; 2],
}

/// Phasors of the response to the force F_scale (μ, 1) sin(2π f t).
pub fn harmonic_phasors(
    p: &VibrationParams,
    bonnet: Bonnet,
    freq_hz: f64,
    fn_scale_n: f64,
) -> HarmonicPhasors {
    let f = p.project([p.mu * fn_scale_n, fn_scale_n]);
    let k = p.stiffness_n_per_mm();
    let wn = p.omega_n_rad_per_s();
    let z = p.zeta_effective(bonnet);
    let w = 2.0 * PI * freq_hz;
    let x = [
        phasor(f[0], k[0], z[0], w / wn[0]),
        phasor(f[1], k[1], z[1], w / wn[1]),
    ];
    let (e1, e2) = p.axes();
    let tn = [x[0] * e1[0] + x[1] * e2[0], x[0] * e1[1] + x[1] * e2[1]];
    HarmonicPhasors { freq_hz, x, tn }
}

fn phase_lag_deg(c: Complex64) -> f64 {
    let mut d = -c.arg().to_degrees();
    if d <= -180.0 {
        d += 360.0;
    }
    d
}

/// Steady response to F_n sin(ω t), ω = 2π n / 60 (fundamental only, as the paper).
pub fn forced_response(p: &VibrationParams, bonnet: Bonnet, spindle_rpm: f64) -> Response {
    let f_hz = spindle_rpm / 60.0;
    let h = harmonic_phasors(p, bonnet, f_hz, p.fn_n);
    let z = p.zeta_effective(bonnet);
    let fnat = p.natural_freq_hz();
    Response {
        bonnet,
        spindle_rpm,
        excitation_hz: f_hz,
        x1_amplitude_mm: h.x[0].norm(),
        x2_amplitude_mm: h.x[1].norm(),
        x1_phase_deg: phase_lag_deg(h.x[0]),
        x2_phase_deg: phase_lag_deg(h.x[1]),
        zeta1_effective: z[0],
        zeta2_effective: z[1],
        natural_freq1_hz: fnat[0],
        natural_freq2_hz: fnat[1],
        normal_amplitude_mm: h.tn[1].norm(),
        lateral_amplitude_mm: h.tn[0].norm(),
        offset_amplitude_mm: h.tn[1].norm() * p.offset_transfer(bonnet),
    }
}

/// Phasors at every spindle harmonic h = 1..: frequency h n / 60, force harmonics[h−1] F_n.
pub fn spindle_harmonics(
    p: &VibrationParams,
    bonnet: Bonnet,
    spindle_rpm: f64,
) -> Vec<HarmonicPhasors> {
    p.harmonics
        .iter()
        .enumerate()
        .map(|(i, &w)| harmonic_phasors(p, bonnet, (i + 1) as f64 * spindle_rpm / 60.0, w * p.fn_n))
        .collect()
}

/// One point of a frequency-response curve (amplitudes for the force F_n at that frequency).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrfPoint {
    pub freq_hz: f64,
    pub x1_amplitude_mm: f64,
    pub x2_amplitude_mm: f64,
}

/// Amplitude curves on `n` linearly spaced frequencies over [f_lo, f_hi] Hz, with the two
/// resonance peaks (damped peak frequencies) inserted when they fall inside, so a plot or a
/// maximum taken from the curve does not miss them.
pub fn frf(
    p: &VibrationParams,
    bonnet: Bonnet,
    f_lo_hz: f64,
    f_hi_hz: f64,
    n: usize,
) -> Vec<FrfPoint> {
    let n = n.max(2);
    let mut freqs: Vec<f64> = (0..n)
        .map(|i| f_lo_hz + (f_hi_hz - f_lo_hz) * i as f64 / (n - 1) as f64)
        .collect();
    for peak in resonance_peaks(p, bonnet) {
        if peak.freq_hz > f_lo_hz && peak.freq_hz < f_hi_hz {
            freqs.push(peak.freq_hz);
        }
    }
    freqs.sort_by(f64::total_cmp);
    freqs.dedup();
    freqs
        .into_iter()
        .map(|f| {
            let h = harmonic_phasors(p, bonnet, f, p.fn_n);
            FrfPoint {
                freq_hz: f,
                x1_amplitude_mm: h.x[0].norm(),
                x2_amplitude_mm: h.x[1].norm(),
            }
        })
        .collect()
}

/// The FRF over the spindle band 250–2000 rpm (4.17–33.3 Hz), 351 points plus the peaks.
pub fn spindle_band_frf(p: &VibrationParams, bonnet: Bonnet) -> Vec<FrfPoint> {
    frf(
        p,
        bonnet,
        SPINDLE_BAND_RPM.0 / 60.0,
        SPINDLE_BAND_RPM.1 / 60.0,
        351,
    )
}

/// The amplitude peak of one principal direction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Peak {
    pub direction: u8,
    pub freq_hz: f64,
    pub amplitude_mm: f64,
}

/// Damped amplitude peaks: λ = sqrt(1 − 2ζ²), X_max = (F/k) / (2ζ sqrt(1 − ζ²)) for
/// ζ < 1/√2 (no peak otherwise: the static amplitude at f → 0 is the maximum).
pub fn resonance_peaks(p: &VibrationParams, bonnet: Bonnet) -> Vec<Peak> {
    let f = p.project(p.force_vector_n());
    let k = p.stiffness_n_per_mm();
    let fnat = p.natural_freq_hz();
    let z = p.zeta_effective(bonnet);
    (0..2)
        .filter(|&i| z[i] < std::f64::consts::FRAC_1_SQRT_2)
        .map(|i| Peak {
            direction: i as u8 + 1,
            freq_hz: fnat[i] * (1.0 - 2.0 * z[i] * z[i]).sqrt(),
            amplitude_mm: (f[i] / k[i]).abs() / (2.0 * z[i] * (1.0 - z[i] * z[i]).sqrt()),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phase_is_quarter_cycle_at_resonance_and_amplitude_is_static_over_2zeta() {
        let (a, phi) = sdof_steady(3.0, 100.0, 0.05, 1.0);
        assert!((a - 0.03 / 0.1).abs() < 1e-15);
        assert!((phi - PI / 2.0).abs() < 1e-15);
        let (a0, phi0) = sdof_steady(3.0, 100.0, 0.05, 0.0);
        assert!((a0 - 0.03).abs() < 1e-15 && phi0 == 0.0);
    }

    #[test]
    fn peaks_are_the_maxima_of_a_fine_curve() {
        let p = VibrationParams::default();
        for b in Bonnet::ALL {
            let peaks = resonance_peaks(&p, b);
            for pk in &peaks {
                let i = (pk.direction - 1) as usize;
                let curve = frf(&p, b, pk.freq_hz * 0.8, pk.freq_hz * 1.2, 20001);
                let max = curve
                    .iter()
                    .map(|c| {
                        if i == 0 {
                            c.x1_amplitude_mm
                        } else {
                            c.x2_amplitude_mm
                        }
                    })
                    .fold(0.0, f64::max);
                assert!(
                    (max - pk.amplitude_mm).abs() < 1e-12 * max,
                    "{max} {}",
                    pk.amplitude_mm
                );
            }
        }
    }
}
