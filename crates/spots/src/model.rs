//! The precessing-bonnet removal model used to predict spot trends and to fit to spots.
//!
//! Geometry and physics (DOMAIN.md section 1, Preston's law):
//! - A spherical bonnet of radius `R` pressed into a flat by the offset `h` touches a disc of
//!   radius `a = sqrt(2 R h - h^2)` (the contact is treated as flat, at depth `d = R - h`
//!   below the sphere centre).
//! - Contact pressure `p(r) = p0 (1 - r^2/a^2)^gamma` with peak
//!   `p0 = p_inner + (2/pi) E a / R`: the inflation pressure plus a Hertz-like stiffness term with
//!   a lumped effective contact modulus `E` (membrane, rubber and pad together; not a material
//!   constant). `gamma = 1/2` is Hertz; the default `gamma = 1` (parabolic) stands for the pad
//!   and membrane bending smoothing the edge, which gives the bell-shaped spots bonnets are known
//!   for. Both are profiles of `bonnetlab_process`'s bonnet TIF (`pressure = "hertz"` /
//!   `"parabolic"`), whose geometry and speed field are the same as here, so a fitted model is
//!   exported to a recipe's `[tif] model` without loss (checked by a test).
//! - The spin axis is tilted by the precession angle `theta` (azimuth `phi`); the in-plane sliding
//!   speed at contact point `r` is `omega cos(theta) |r - c_phi|`, where
//!   `c_phi = -d tan(theta) (cos phi, sin phi)` is where the spin axis pierces the surface
//!   (exact for a rigid rotation of the contact point about the tilted axis).
//! - Four-step coalesced precession: the speed is averaged over `phi = 0, 90, 180, 270 deg`
//!   (equal dwell per step), so the spot is symmetric under quarter turns and mirror images.
//! - Preston: `rate = k p |v|`, with `k` in nm per (MPa mm), `p` in MPa, `|v|` in mm/s, so the
//!   rate is in nm/s. `k` in nm/(MPa mm) equals `k` in m^2/N times 1e12.
//!
//! The spot's centre is at the origin; x and y in mm.

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

use crate::error::SpotsError;

/// Default pressure-profile exponent (see the module doc).
pub const DEFAULT_PRESSURE_EXPONENT: f64 = 1.0;

/// The process settings of one spot: the four factors of the paper's single-factor sweeps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Factors {
    pub precession_deg: f64,
    pub offset_mm: f64,
    pub spindle_rpm: f64,
    pub inner_pressure_mpa: f64,
}

impl Factors {
    /// The paper's fixed-point baseline (Table 5): 20 deg, 0.8 mm, 500 rpm, 0.25 MPa.
    pub const PAPER_BASELINE: Factors = Factors {
        precession_deg: 20.0,
        offset_mm: 0.8,
        spindle_rpm: 500.0,
        inner_pressure_mpa: 0.25,
    };

    /// The value of one named factor.
    pub fn get(&self, f: Factor) -> f64 {
        match f {
            Factor::PrecessionDeg => self.precession_deg,
            Factor::OffsetMm => self.offset_mm,
            Factor::SpindleRpm => self.spindle_rpm,
            Factor::InnerPressureMpa => self.inner_pressure_mpa,
        }
    }
}

/// One of the four swept factors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Factor {
    PrecessionDeg,
    OffsetMm,
    SpindleRpm,
    InnerPressureMpa,
}

impl Factor {
    pub const ALL: [Factor; 4] = [
        Factor::PrecessionDeg,
        Factor::OffsetMm,
        Factor::SpindleRpm,
        Factor::InnerPressureMpa,
    ];

    /// Key as used in manifests, JSON and CSV.
    pub fn key(&self) -> &'static str {
        match self {
            Factor::PrecessionDeg => "precession_deg",
            Factor::OffsetMm => "offset_mm",
            Factor::SpindleRpm => "spindle_rpm",
            Factor::InnerPressureMpa => "inner_pressure_mpa",
        }
    }

    /// Human label with unit, for tables and plot axes.
    pub fn label(&self) -> &'static str {
        match self {
            Factor::PrecessionDeg => "precession angle (deg)",
            Factor::OffsetMm => "offset (mm)",
            Factor::SpindleRpm => "spindle speed (rpm)",
            Factor::InnerPressureMpa => "inner pressure (MPa)",
        }
    }

    pub fn from_key(s: &str) -> Option<Factor> {
        Factor::ALL.into_iter().find(|f| f.key() == s)
    }
}

/// Parameters of the bonnet model that belong to the tool (fitted per bonnet).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BonnetModel {
    /// Bonnet (sphere) radius in mm.
    pub radius_mm: f64,
    /// Preston coefficient in nm per (MPa mm) (= m^2/N x 1e12).
    pub preston_nm_per_mpa_mm: f64,
    /// Lumped effective contact modulus in MPa.
    pub modulus_mpa: f64,
    /// Exponent of the pressure profile `(1 - r^2/a^2)^gamma`.
    pub pressure_exponent: f64,
}

/// The model's spot metrics, comparable with the measured ones.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ModelMetrics {
    pub contact_radius_mm: f64,
    pub peak_pressure_mpa: f64,
    pub centre_speed_mm_per_s: f64,
    pub peak_rate_nm_per_s: f64,
    /// Integral of the rate over the spot, nm mm^2/s (x 1e-6 = mm^3/s).
    pub volume_rate_nm_mm2_per_s: f64,
    pub fwhm_x_mm: f64,
    pub fwhm_y_mm: f64,
}

/// Everything the rate at a point needs, precomputed for one set of factors.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Footprint {
    pub a_mm: f64,
    pub p0_mpa: f64,
    gamma: f64,
    /// k * omega * cos(theta), nm / (MPa mm) * rad/s.
    k_omega_cos: f64,
    /// Distance of the spin-axis pivots from the centre, d tan(theta), mm.
    pivot_mm: f64,
}

impl Footprint {
    pub fn rate(&self, x: f64, y: f64) -> f64 {
        let q = 1.0 - (x * x + y * y) / (self.a_mm * self.a_mm);
        if q <= 0.0 {
            return 0.0;
        }
        let c = self.pivot_mm;
        let speed = 0.25 * ((x + c).hypot(y) + (x - c).hypot(y) + x.hypot(y + c) + x.hypot(y - c));
        self.k_omega_cos * self.p0_mpa * q.powf(self.gamma) * speed
    }
}

impl BonnetModel {
    /// A model with the default pressure exponent.
    pub fn new(radius_mm: f64, preston_nm_per_mpa_mm: f64, modulus_mpa: f64) -> Self {
        BonnetModel {
            radius_mm,
            preston_nm_per_mpa_mm,
            modulus_mpa,
            pressure_exponent: DEFAULT_PRESSURE_EXPONENT,
        }
    }

    pub(crate) fn footprint(&self, f: &Factors) -> Result<Footprint, SpotsError> {
        let r = self.radius_mm;
        let bad = |what: String| Err(SpotsError::Model(what));
        if !(r.is_finite() && r > 0.0) {
            return bad(format!("bonnet radius {r} mm must be positive"));
        }
        if !(self.preston_nm_per_mpa_mm.is_finite() && self.preston_nm_per_mpa_mm > 0.0) {
            return bad(format!(
                "Preston coefficient {} must be positive",
                self.preston_nm_per_mpa_mm
            ));
        }
        if !(self.modulus_mpa.is_finite() && self.modulus_mpa >= 0.0) {
            return bad(format!(
                "effective modulus {} MPa must be >= 0",
                self.modulus_mpa
            ));
        }
        if !(self.pressure_exponent.is_finite() && self.pressure_exponent > 0.0) {
            return bad(format!(
                "pressure exponent {} must be positive",
                self.pressure_exponent
            ));
        }
        let h = f.offset_mm;
        if !(h.is_finite() && h > 0.0 && h < r) {
            return bad(format!(
                "offset {h} mm must lie in (0, bonnet radius {r} mm)"
            ));
        }
        if !(f.precession_deg.is_finite() && f.precession_deg > 0.0 && f.precession_deg < 90.0) {
            return bad(format!(
                "precession angle {} deg must lie in (0, 90)",
                f.precession_deg
            ));
        }
        if !(f.spindle_rpm.is_finite() && f.spindle_rpm > 0.0) {
            return bad(format!(
                "spindle speed {} rpm must be positive",
                f.spindle_rpm
            ));
        }
        if !(f.inner_pressure_mpa.is_finite() && f.inner_pressure_mpa >= 0.0) {
            return bad(format!(
                "inner pressure {} MPa must be >= 0",
                f.inner_pressure_mpa
            ));
        }
        let a = (2.0 * r * h - h * h).sqrt();
        let theta = f.precession_deg.to_radians();
        let omega = 2.0 * PI * f.spindle_rpm / 60.0;
        let p0 = f.inner_pressure_mpa + 2.0 / PI * self.modulus_mpa * a / r;
        if p0 <= 0.0 {
            return bad("zero contact pressure (inner pressure and modulus both 0)".into());
        }
        Ok(Footprint {
            a_mm: a,
            p0_mpa: p0,
            gamma: self.pressure_exponent,
            k_omega_cos: self.preston_nm_per_mpa_mm * omega * theta.cos(),
            pivot_mm: (r - h) * theta.tan(),
        })
    }

    /// Removal rate (nm/s) at (x, y) mm from the spot centre.
    pub fn rate_nm_per_s(&self, f: &Factors, x_mm: f64, y_mm: f64) -> Result<f64, SpotsError> {
        Ok(self.footprint(f)?.rate(x_mm, y_mm))
    }

    /// Peak rate, volumetric rate, FWHM and the contact quantities for one set of factors.
    pub fn metrics(&self, f: &Factors) -> Result<ModelMetrics, SpotsError> {
        let fp = self.footprint(f)?;
        let a = fp.a_mm;
        let peak = [
            (1.0, 0.0),
            (
                std::f64::consts::FRAC_1_SQRT_2,
                std::f64::consts::FRAC_1_SQRT_2,
            ),
        ]
        .into_iter()
        .map(|(ux, uy)| max_along(|t| fp.rate(t * ux, t * uy), a))
        .fold(0.0, f64::max);
        let half = 0.5 * peak;
        let fwhm_x = half_crossing(|t| fp.rate(t, 0.0), half, a)
            + half_crossing(|t| fp.rate(-t, 0.0), half, a);
        let fwhm_y = half_crossing(|t| fp.rate(0.0, t), half, a)
            + half_crossing(|t| fp.rate(0.0, -t), half, a);
        Ok(ModelMetrics {
            contact_radius_mm: a,
            peak_pressure_mpa: fp.p0_mpa,
            centre_speed_mm_per_s: fp.k_omega_cos / self.preston_nm_per_mpa_mm * fp.pivot_mm,
            peak_rate_nm_per_s: peak,
            volume_rate_nm_mm2_per_s: volume(&fp),
            fwhm_x_mm: fwhm_x,
            fwhm_y_mm: fwhm_y,
        })
    }
}

/// Integral of the rate over the contact disc by the midpoint rule in polar coordinates over one
/// quadrant (the four-step average is symmetric under quarter turns).
fn volume(fp: &Footprint) -> f64 {
    const NR: usize = 160;
    const NPHI: usize = 64;
    let a = fp.a_mm;
    let dr = a / NR as f64;
    let dphi = 0.5 * PI / NPHI as f64;
    let mut sum = 0.0;
    for i in 0..NR {
        let r = (i as f64 + 0.5) * dr;
        let mut ring = 0.0;
        for k in 0..NPHI {
            let phi = (k as f64 + 0.5) * dphi;
            ring += fp.rate(r * phi.cos(), r * phi.sin());
        }
        sum += ring * r;
    }
    4.0 * sum * dr * dphi
}

/// Maximum of `g(t)` for t in [0, a], sampled then refined by a parabola through the best
/// sample and its neighbours (g is even in t, so g(-dt) = g(dt) at the origin).
fn max_along(g: impl Fn(f64) -> f64, a: f64) -> f64 {
    const N: usize = 400;
    let dt = a / N as f64;
    let vals: Vec<f64> = (0..=N).map(|i| g(i as f64 * dt)).collect();
    let (imax, &vmax) = vals
        .iter()
        .enumerate()
        .fold((0, &f64::NEG_INFINITY), |acc, (i, v)| {
            if *v > *acc.1 {
                (i, v)
            } else {
                acc
            }
        });
    if imax >= N {
        return vmax;
    }
    let left = if imax == 0 { vals[1] } else { vals[imax - 1] };
    let right = vals[imax + 1];
    let denom = left - 2.0 * vmax + right;
    if denom >= 0.0 {
        return vmax;
    }
    let s = 0.5 * (left - right) / denom;
    vmax - 0.25 * (left - right) * s
}

/// Distance from the centre, walking outward along `g`, at which `g` first falls to `level`;
/// found by stepping then bisection. Returns `a` when it never falls below within [0, a].
fn half_crossing(g: impl Fn(f64) -> f64, level: f64, a: f64) -> f64 {
    const N: usize = 800;
    let dt = a / N as f64;
    let mut prev = 0.0;
    for i in 1..=N {
        let t = i as f64 * dt;
        if g(t) < level {
            let (mut lo, mut hi) = (prev, t);
            for _ in 0..50 {
                let mid = 0.5 * (lo + hi);
                if g(mid) >= level {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return 0.5 * (lo + hi);
        }
        prev = t;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> BonnetModel {
        BonnetModel::new(20.0, 0.06, 2.0)
    }

    #[test]
    fn centre_rate_and_contact_radius_are_analytic() {
        let f = Factors::PAPER_BASELINE;
        let m = model();
        let a = (2.0 * 20.0 * 0.8 - 0.64f64).sqrt();
        let p0 = 0.25 + 2.0 / PI * 2.0 * a / 20.0;
        let omega = 2.0 * PI * 500.0 / 60.0;
        // At the centre every pivot is d tan(theta) away, so |v| = omega cos(theta) d tan(theta).
        let v0 = omega * (20.0 - 0.8) * 20f64.to_radians().sin();
        let expect = 0.06 * p0 * v0;
        let got = m.rate_nm_per_s(&f, 0.0, 0.0).unwrap();
        assert!((got - expect).abs() < 1e-9 * expect, "{got} vs {expect}");
        let mm = m.metrics(&f).unwrap();
        assert!((mm.contact_radius_mm - a).abs() < 1e-12);
        assert!((mm.centre_speed_mm_per_s - v0).abs() < 1e-9 * v0);
        // The baseline spot is bell shaped: its peak is the centre value.
        assert!((mm.peak_rate_nm_per_s - expect).abs() < 1e-9 * expect);
        assert_eq!(m.rate_nm_per_s(&f, a * 1.001, 0.0).unwrap(), 0.0);
    }

    #[test]
    fn volume_and_fwhm_match_brute_force() {
        let f = Factors {
            precession_deg: 12.0,
            offset_mm: 0.5,
            ..Factors::PAPER_BASELINE
        };
        let m = model();
        let mm = m.metrics(&f).unwrap();
        // Brute-force Cartesian sum on a fine grid.
        let a = mm.contact_radius_mm;
        let n = 1200;
        let h = 2.0 * a / n as f64;
        let mut vol = 0.0;
        for i in 0..n {
            for j in 0..n {
                let x = -a + (j as f64 + 0.5) * h;
                let y = -a + (i as f64 + 0.5) * h;
                vol += m.rate_nm_per_s(&f, x, y).unwrap();
            }
        }
        vol *= h * h;
        let rel = (mm.volume_rate_nm_mm2_per_s - vol).abs() / vol;
        assert!(
            rel < 1e-3,
            "volume {} vs {vol}",
            mm.volume_rate_nm_mm2_per_s
        );
        // FWHM by dense sampling of the x profile.
        let peak = (0..=20000)
            .map(|i| {
                m.rate_nm_per_s(&f, -a + 2.0 * a * i as f64 / 20000.0, 0.0)
                    .unwrap()
            })
            .fold(0.0, f64::max);
        let above: Vec<f64> = (0..=20000)
            .map(|i| -a + 2.0 * a * i as f64 / 20000.0)
            .filter(|&x| m.rate_nm_per_s(&f, x, 0.0).unwrap() >= 0.5 * peak)
            .collect();
        let width = above.last().unwrap() - above.first().unwrap();
        assert!(
            (mm.fwhm_x_mm - width).abs() < 3.0 * 2.0 * a / 20000.0,
            "{} vs {width}",
            mm.fwhm_x_mm
        );
        assert!((mm.fwhm_x_mm - mm.fwhm_y_mm).abs() < 1e-9);
        assert!((mm.peak_rate_nm_per_s - peak).abs() < 1e-4 * peak);
    }

    #[test]
    fn trends_follow_the_physics() {
        let m = model();
        let base = Factors::PAPER_BASELINE;
        let at = |f: Factors| m.metrics(&f).unwrap();
        // Preston: the rate is linear in spindle speed and the shape does not change.
        let slow = at(Factors {
            spindle_rpm: 250.0,
            ..base
        });
        let fast = at(Factors {
            spindle_rpm: 1000.0,
            ..base
        });
        assert!((fast.peak_rate_nm_per_s / slow.peak_rate_nm_per_s - 4.0).abs() < 1e-9);
        assert!((fast.fwhm_x_mm - slow.fwhm_x_mm).abs() < 1e-9);
        // More offset: a wider and faster spot.
        let shallow = at(Factors {
            offset_mm: 0.2,
            ..base
        });
        assert!(shallow.fwhm_x_mm < at(base).fwhm_x_mm);
        assert!(shallow.volume_rate_nm_mm2_per_s < at(base).volume_rate_nm_mm2_per_s);
        assert!(m
            .metrics(&Factors {
                offset_mm: 25.0,
                ..base
            })
            .is_err());
    }
}
