//! The precessing-bonnet TIF from Preston's law: rate = k p(r) |v(x, y)|, averaged over the
//! precession azimuths, scaled to a given peak or volumetric rate.
//!
//! Geometry: a spherical bonnet of radius R pressed by the offset h touches the part in a disc of
//! radius a = sqrt(2 R h - h^2); its centre of curvature sits R - h above the spot centre. The
//! spin axis passes through that centre, tilted from the normal by the precession angle theta at
//! azimuth phi: omega = Omega (sin theta cos phi, sin theta sin phi, cos theta). A bonnet point
//! at (x, y) in the spot moves with v = omega x (x, y, -(R - h)), whose in-plane speed is
//!
//! |v| = Omega sqrt((cos theta x + sin theta cos phi (R - h))^2
//!                  + (cos theta y + sin theta sin phi (R - h))^2),
//!
//! i.e. a rotation about an in-plane point (R - h) tan theta away from the spot centre.
//! "Four-step" precession averages the footprint over phi = 0, 90, 180, 270 deg.
//!
//! How the shape depends on the parameters (each trend is tested below):
//! - **Offset h**: the spot radius grows as sqrt(2 R h - h^2), so the footprint widens
//!   (FWHM grows roughly as sqrt(h)); at fixed peak rate the volume rate grows as a^2.
//! - **Pressure profile**: `Hertz` (sqrt(1 - r^2/a^2), elastic sphere contact) gives a rounded
//!   top; `Parabolic` (1 - r^2/a^2) is more peaked; `Uniform` (membrane dominated by the inner
//!   pressure) is flat-topped with a sharp edge.
//! - **Precession angle theta**: at theta = 0 the speed is Omega r, zero at the centre, so the TIF
//!   is a ring (W-shaped section) with no removal at the centre. As theta grows the (R - h) sin
//!   theta term dominates the speed, which becomes nearly uniform across the spot, and the TIF
//!   approaches the pressure profile (centre-peaked, Gaussian-like): the centre-to-peak ratio
//!   rises towards 1.
//! - **Precession averaging**: one azimuth leaves a speed gradient across the spot, so the
//!   footprint is lopsided (centroid off the spot centre); four steps make it symmetric.
//! - **Spindle speed** only scales the rate (absorbed by the peak / volume scaling).

use serde::{Deserialize, Serialize};

use super::RateField;
use crate::error::ProcessError;

/// Contact-pressure profile across the spot, normalised to 1 at the centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PressureProfile {
    /// sqrt(1 - r^2 / a^2): Hertzian contact of an elastic sphere.
    #[default]
    Hertz,
    /// 1 - r^2 / a^2.
    Parabolic,
    /// Constant over the disc.
    Uniform,
}

impl PressureProfile {
    pub fn parse(s: &str) -> Option<PressureProfile> {
        match s.to_ascii_lowercase().as_str() {
            "hertz" => Some(PressureProfile::Hertz),
            "parabolic" => Some(PressureProfile::Parabolic),
            "uniform" => Some(PressureProfile::Uniform),
            _ => None,
        }
    }

    /// Relative pressure at normalised radius rho = r / a (0 outside).
    pub fn at(&self, rho: f64) -> f64 {
        if rho > 1.0 {
            return 0.0;
        }
        let q = 1.0 - rho * rho;
        match self {
            PressureProfile::Hertz => q.max(0.0).sqrt(),
            PressureProfile::Parabolic => q.max(0.0),
            PressureProfile::Uniform => 1.0,
        }
    }
}

/// How the footprint's absolute rate is fixed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum RateScale {
    /// Peak rate in nm/s.
    PeakNmPerS(f64),
    /// Integral of the rate over the plane in nm mm^2 / s.
    VolumeNmMm2PerS(f64),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BonnetTifParams {
    pub radius_mm: f64,
    pub offset_mm: f64,
    pub precession_deg: f64,
    pub spindle_rpm: f64,
    pub pressure: PressureProfile,
    pub scale: RateScale,
    /// Number of equally spaced precession azimuths (4 = four-step; 1 = a single tilt at 0 deg).
    pub precession_steps: usize,
}

impl BonnetTifParams {
    /// The paper's defaults with a given peak rate: R 20 mm, h 0.6 mm, 20 deg, 1000 rpm, Hertz.
    pub fn paper(peak_rate_nm_per_s: f64) -> BonnetTifParams {
        BonnetTifParams {
            radius_mm: 20.0,
            offset_mm: 0.6,
            precession_deg: 20.0,
            spindle_rpm: 1000.0,
            pressure: PressureProfile::Hertz,
            scale: RateScale::PeakNmPerS(peak_rate_nm_per_s),
            precession_steps: 4,
        }
    }

    /// Contact radius sqrt(2 R h - h^2) in mm.
    pub fn contact_radius_mm(&self) -> f64 {
        (2.0 * self.radius_mm * self.offset_mm - self.offset_mm * self.offset_mm)
            .max(0.0)
            .sqrt()
    }
}

/// The evaluated model (scale factor computed once).
#[derive(Debug, Clone)]
pub struct BonnetTif {
    p: BonnetTifParams,
    a_mm: f64,
    lever_mm: f64,
    omega_rad_s: f64,
    cos_t: f64,
    sin_t: f64,
    azimuths: Vec<(f64, f64)>,
    factor: f64,
    volume: f64,
}

impl BonnetTif {
    pub fn new(p: &BonnetTifParams) -> Result<BonnetTif, ProcessError> {
        let pos = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(ProcessError::invalid(format!(
                    "bonnet {name} must be positive, got {v}"
                )))
            }
        };
        pos("radius_mm", p.radius_mm)?;
        pos("offset_mm", p.offset_mm)?;
        pos("spindle_rpm", p.spindle_rpm)?;
        if p.offset_mm >= p.radius_mm {
            return Err(ProcessError::invalid(
                "bonnet offset_mm must be smaller than radius_mm",
            ));
        }
        if !(p.precession_deg.is_finite() && (0.0..90.0).contains(&p.precession_deg)) {
            return Err(ProcessError::invalid(
                "bonnet precession_deg must be in [0, 90)",
            ));
        }
        if p.precession_steps == 0 || p.precession_steps > 360 {
            return Err(ProcessError::invalid(
                "bonnet precession_steps must be 1..=360",
            ));
        }
        let theta = p.precession_deg.to_radians();
        let azimuths = (0..p.precession_steps)
            .map(|k| {
                let phi = 2.0 * std::f64::consts::PI * k as f64 / p.precession_steps as f64;
                (phi.cos(), phi.sin())
            })
            .collect();
        let mut m = BonnetTif {
            p: p.clone(),
            a_mm: p.contact_radius_mm(),
            lever_mm: p.radius_mm - p.offset_mm,
            omega_rad_s: p.spindle_rpm * 2.0 * std::f64::consts::PI / 60.0,
            cos_t: theta.cos(),
            sin_t: theta.sin(),
            azimuths,
            factor: 1.0,
            volume: 0.0,
        };
        // Fix the scale numerically on a fine midpoint grid over the contact disc.
        let n = 400;
        let h = 2.0 * m.a_mm / n as f64;
        let (mut peak, mut vol) = (0.0f64, 0.0);
        for i in 0..n {
            let y = -m.a_mm + (i as f64 + 0.5) * h;
            for j in 0..n {
                let x = -m.a_mm + (j as f64 + 0.5) * h;
                let v = m.raw(x, y);
                peak = peak.max(v);
                vol += v * h * h;
            }
        }
        peak = peak.max(m.raw(0.0, 0.0));
        m.factor = match p.scale {
            RateScale::PeakNmPerS(r) if r.is_finite() && r >= 0.0 && peak > 0.0 => r / peak,
            RateScale::VolumeNmMm2PerS(v) if v.is_finite() && v >= 0.0 && vol > 0.0 => v / vol,
            _ => {
                return Err(ProcessError::invalid(
                    "bonnet rate scale must be finite and >= 0",
                ))
            }
        };
        m.volume = m.factor * vol;
        Ok(m)
    }

    pub fn params(&self) -> &BonnetTifParams {
        &self.p
    }

    /// Contact radius in mm.
    pub fn contact_radius_mm(&self) -> f64 {
        self.a_mm
    }

    /// Unscaled p(r) * mean over azimuths of the in-plane speed (mm/s).
    fn raw(&self, x: f64, y: f64) -> f64 {
        let r2 = x * x + y * y;
        if r2 > self.a_mm * self.a_mm {
            return 0.0;
        }
        let p = self.p.pressure.at(r2.sqrt() / self.a_mm);
        if p == 0.0 {
            return 0.0;
        }
        let l = self.sin_t * self.lever_mm;
        p * self.omega_rad_s * self.cos_t * mean_speed(x, y, l / self.cos_t, &self.azimuths)
    }
}

/// Mean over the precession azimuths `(cos phi, sin phi)` of |(x, y) + b (cos phi, sin phi)|:
/// the in-plane speed per unit of Omega cos theta at (x, y), with b = (R - h) tan theta the
/// distance from the spot centre to where the spin axis pierces the surface.
fn mean_speed(x: f64, y: f64, b: f64, azimuths: &[(f64, f64)]) -> f64 {
    let mut s = 0.0;
    for &(c, sn) in azimuths {
        // Millimetre-sized terms: no overflow or underflow for `hypot` to guard against, and
        // the plain root is several times faster (this is the inner loop of the spot fit).
        let (u, v) = (x + b * c, y + b * sn);
        s += (u * u + v * v).sqrt();
    }
    s / azimuths.len() as f64
}

/// The shape of a precessing-bonnet footprint as a fit sees it: the same Preston product as
/// [`BonnetTif`] (pressure times the mean sliding speed over equally spaced precession
/// azimuths), with a continuous pressure exponent (`(1 - r^2/a^2)^gamma`: 0.5 Hertz,
/// 1 parabolic, 0 uniform) and the azimuths turned by `psi` from the X axis.
/// `peak` is the rate at the centre (nm/s): the speed is normalised by its value there.
#[derive(Debug, Clone, PartialEq)]
pub struct BonnetShape {
    /// Rate at the centre, nm/s.
    pub peak: f64,
    /// Contact radius a, mm.
    pub a_mm: f64,
    /// Pressure exponent gamma.
    pub gamma: f64,
    /// Lever b = (R - h) tan theta, mm.
    pub lever_mm: f64,
    /// Azimuth of the first precession step, rad.
    pub psi_rad: f64,
    /// Number of precession steps.
    pub steps: usize,
}

impl BonnetShape {
    /// The shape of a [`BonnetTif`] (exactly: `rate_at_mm` agrees with the model's).
    pub fn of(m: &BonnetTif) -> BonnetShape {
        let gamma = match m.p.pressure {
            PressureProfile::Hertz => 0.5,
            PressureProfile::Parabolic => 1.0,
            PressureProfile::Uniform => 0.0,
        };
        BonnetShape {
            peak: m.rate_at_mm(0.0, 0.0),
            a_mm: m.a_mm,
            gamma,
            lever_mm: m.sin_t * m.lever_mm / m.cos_t,
            psi_rad: 0.0,
            steps: m.p.precession_steps,
        }
    }

    /// The precession azimuths (cos, sin).
    pub fn azimuths(&self) -> Vec<(f64, f64)> {
        (0..self.steps)
            .map(|k| {
                let phi = self.psi_rad + 2.0 * std::f64::consts::PI * k as f64 / self.steps as f64;
                (phi.cos(), phi.sin())
            })
            .collect()
    }

    /// Rate (nm/s) at (x, y) mm from the centre, given the azimuths of [`Self::azimuths`].
    pub fn rate_with(&self, x: f64, y: f64, azimuths: &[(f64, f64)]) -> f64 {
        let rho2 = (x * x + y * y) / (self.a_mm * self.a_mm);
        if rho2 >= 1.0 {
            return if rho2 == 1.0 && self.gamma == 0.0 {
                self.peak * mean_speed(x, y, self.lever_mm, azimuths) / self.lever_mm
            } else {
                0.0
            };
        }
        let p = if self.gamma == 0.0 {
            1.0
        } else {
            (1.0 - rho2).powf(self.gamma)
        };
        let centre = mean_speed(0.0, 0.0, self.lever_mm, azimuths);
        self.peak * p * mean_speed(x, y, self.lever_mm, azimuths) / centre
    }

    /// Rate (nm/s) at (x, y) mm from the centre and its partial derivatives, in this order:
    /// d/dx, d/dy (nm/s per mm), d/d(ln a), d/d(ln gamma), d/d(ln lever), d/d(psi) (nm/s per
    /// unit), given the azimuths of [`Self::azimuths`]. For a fit's Jacobian (see
    /// `spotfit`): one pass instead of one evaluation per parameter.
    ///
    /// With `rho^2 = r^2 / a^2`, `P = (1 - rho^2)^gamma` and the mean speed
    /// `S = mean_k |(x, y) + b u_k|` (`u_k` the azimuths, `S(0, 0) = b`), the rate is
    /// `peak P S / b`; each `|.|` differentiates to the unit vector along it. Outside the
    /// contact (rho >= 1) everything is 0; the pressure derivatives are those of the open
    /// disc (they grow like `(1 - rho^2)^(gamma - 1)` towards the rim when gamma < 1).
    pub fn rate_partials(&self, x: f64, y: f64, azimuths: &[(f64, f64)]) -> (f64, [f64; 6]) {
        let a2 = self.a_mm * self.a_mm;
        let rho2 = (x * x + y * y) / a2;
        if rho2 >= 1.0 || azimuths.is_empty() {
            return (self.rate_with(x, y, azimuths), [0.0; 6]);
        }
        let b = self.lever_mm;
        let (mut s, mut sx, mut sy, mut sb, mut spsi) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut s0 = 0.0;
        for &(c, sn) in azimuths {
            let (u, v) = (x + b * c, y + b * sn);
            let h = (u * u + v * v).sqrt();
            s += h;
            let (u0, v0) = (b * c, b * sn);
            s0 += (u0 * u0 + v0 * v0).sqrt();
            if h > 0.0 {
                sx += u / h;
                sy += v / h;
                sb += (c * u + sn * v) / h;
                spsi += b * (c * v - sn * u) / h;
            }
        }
        let n = azimuths.len() as f64;
        let (s, sx, sy, sb, spsi, s0) = (s / n, sx / n, sy / n, sb / n, spsi / n, s0 / n);
        let g = self.gamma;
        let q = 1.0 - rho2;
        // As `rate_with` evaluates it; q > 0 inside the contact.
        let (p, dp_drho2) = if g == 0.0 {
            (1.0, 0.0)
        } else {
            let p = q.powf(g);
            (p, -g * p / q)
        };
        let k = self.peak / s0;
        // As `rate_with` rounds it.
        let rate = self.peak * p * s / s0;
        let dx = k * (dp_drho2 * 2.0 * x / a2 * s + p * sx);
        let dy = k * (dp_drho2 * 2.0 * y / a2 * s + p * sy);
        let d_ln_a = k * s * dp_drho2 * (-2.0 * rho2);
        let d_ln_gamma = if g == 0.0 { 0.0 } else { g * rate * q.ln() };
        // d/d(ln b) of peak P S / b with S0 = b: peak P (S_b - S / b) = k P (b S_b - S).
        let d_ln_b = k * p * (b * sb - s);
        let d_psi = k * p * spsi;
        (rate, [dx, dy, d_ln_a, d_ln_gamma, d_ln_b, d_psi])
    }
}

impl RateField for BonnetTif {
    fn rate_at_mm(&self, dx_mm: f64, dy_mm: f64) -> f64 {
        self.factor * self.raw(dx_mm, dy_mm)
    }

    fn half_extent_mm(&self) -> (f64, f64) {
        (self.a_mm, self.a_mm)
    }

    fn volume_rate_nm_mm2_per_s(&self) -> Option<f64> {
        Some(self.volume)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tif::Tif;

    fn tif(f: impl Fn(&mut BonnetTifParams)) -> Tif {
        let mut p = BonnetTifParams::paper(10.0);
        f(&mut p);
        Tif::bonnet(&p, 0.05, 0.05).unwrap()
    }

    fn centre_over_peak(t: &Tif) -> f64 {
        let (h0, h1) = t.half_widths();
        t.rate_nm_per_s[(h0, h1)] / t.peak_rate_nm_per_s()
    }

    #[test]
    fn contact_radius_and_support() {
        let p = BonnetTifParams::paper(10.0);
        let a = (2.0f64 * 20.0 * 0.6 - 0.36).sqrt();
        assert!((p.contact_radius_mm() - a).abs() < 1e-12);
        let m = BonnetTif::new(&p).unwrap();
        assert_eq!(m.rate_at_mm(a * 1.001, 0.0), 0.0);
        assert!(m.rate_at_mm(a * 0.99, 0.0) > 0.0);
        assert!((tif(|_| {}).peak_rate_nm_per_s() - 10.0).abs() < 0.05);
    }

    #[test]
    fn speed_matches_rigid_rotation_cross_product() {
        // Single azimuth, uniform pressure: rate ~ |omega x (x, y, -(R - h))| in the plane.
        let mut p = BonnetTifParams::paper(1.0);
        p.pressure = PressureProfile::Uniform;
        p.precession_steps = 1;
        let m = BonnetTif::new(&p).unwrap();
        let th = 20f64.to_radians();
        let w = [th.sin(), 0.0, th.cos()];
        let speed = |x: f64, y: f64| {
            let r = [x, y, -(20.0 - 0.6)];
            let v = [w[1] * r[2] - w[2] * r[1], w[2] * r[0] - w[0] * r[2]];
            (v[0] * v[0] + v[1] * v[1]).sqrt()
        };
        let ratio = m.rate_at_mm(2.0, -1.0) / m.rate_at_mm(-3.0, 0.5);
        assert!((ratio - speed(2.0, -1.0) / speed(-3.0, 0.5)).abs() < 1e-12);
    }

    #[test]
    fn wider_with_offset() {
        let w = [0.2, 0.6, 1.0].map(|h| tif(|p| p.offset_mm = h).fwhm_x_mm());
        assert!(w[0] < w[1] && w[1] < w[2], "{w:?}");
    }

    #[test]
    fn pressure_profile_sets_flatness() {
        let at_half = |pr: PressureProfile| {
            let t = tif(|p| p.pressure = pr);
            let a = BonnetTifParams::paper(1.0).contact_radius_mm();
            t.value_at_mm(a / 2.0, 0.0) / t.value_at_mm(0.0, 0.0)
        };
        let (u, h, q) = (
            at_half(PressureProfile::Uniform),
            at_half(PressureProfile::Hertz),
            at_half(PressureProfile::Parabolic),
        );
        assert!(u > h && h > q, "{u} {h} {q}");
    }

    #[test]
    fn precession_fills_the_centre() {
        let c =
            [0.0, 5.0, 10.0, 20.0, 30.0].map(|d| centre_over_peak(&tif(|p| p.precession_deg = d)));
        assert!(
            c[0] < 1e-9,
            "no speed at the centre without precession: {c:?}"
        );
        assert!(c.windows(2).all(|w| w[1] >= w[0]), "{c:?}");
        assert!(c[3] > 0.95, "{c:?}");
    }

    #[test]
    fn four_step_precession_is_symmetric() {
        let one = tif(|p| p.precession_steps = 1);
        let four = tif(|_| {});
        let (cx1, _) = one.centroid_mm();
        let (cx4, cy4) = four.centroid_mm();
        assert!(cx1.abs() > 0.02, "single azimuth is lopsided: {cx1}");
        assert!(cx4.abs() < 1e-9 && cy4.abs() < 1e-9);
        let t = &four.rate_nm_per_s;
        let tt = t.t();
        let asym = t
            .iter()
            .zip(tt.iter())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(asym < 1e-9 * four.peak_rate_nm_per_s());
    }

    #[test]
    fn shape_reproduces_the_model() {
        for pr in [PressureProfile::Hertz, PressureProfile::Parabolic] {
            let mut p = BonnetTifParams::paper(7.0);
            p.pressure = pr;
            let m = BonnetTif::new(&p).unwrap();
            let s = BonnetShape::of(&m);
            let az = s.azimuths();
            for (x, y) in [(0.0, 0.0), (1.3, -0.4), (-3.9, 2.2), (4.8, 0.1), (6.0, 0.0)] {
                let (a, b) = (m.rate_at_mm(x, y), s.rate_with(x, y, &az));
                assert!((a - b).abs() < 1e-12 * 7.0, "{pr:?} ({x}, {y}): {a} vs {b}");
            }
        }
    }

    #[test]
    fn partials_match_central_differences() {
        let s = BonnetShape {
            peak: 8.0,
            a_mm: 4.5,
            gamma: 0.7,
            lever_mm: 2.3,
            psi_rad: 0.4,
            steps: 4,
        };
        let rate = |s: &BonnetShape, x: f64, y: f64| s.rate_with(x, y, &s.azimuths());
        let h = 1e-6;
        for (x, y) in [
            (0.0, 0.0),
            (1.3, -0.4),
            (-3.1, 2.2),
            (2.0, 3.5),
            (0.2, -4.1),
        ] {
            let (r, d) = s.rate_partials(x, y, &s.azimuths());
            assert_eq!(r, rate(&s, x, y));
            let step = |f: &dyn Fn(f64) -> BonnetShape, dx: f64, dy: f64| {
                (rate(&f(h), x + dx * h, y + dy * h) - rate(&f(-h), x - dx * h, y - dy * h))
                    / (2.0 * h)
            };
            let num = [
                step(&|_| s.clone(), 1.0, 0.0),
                step(&|_| s.clone(), 0.0, 1.0),
                step(
                    &|e| BonnetShape {
                        a_mm: s.a_mm * e.exp(),
                        ..s.clone()
                    },
                    0.0,
                    0.0,
                ),
                step(
                    &|e| BonnetShape {
                        gamma: s.gamma * e.exp(),
                        ..s.clone()
                    },
                    0.0,
                    0.0,
                ),
                step(
                    &|e| BonnetShape {
                        lever_mm: s.lever_mm * e.exp(),
                        ..s.clone()
                    },
                    0.0,
                    0.0,
                ),
                step(
                    &|e| BonnetShape {
                        psi_rad: s.psi_rad + e,
                        ..s.clone()
                    },
                    0.0,
                    0.0,
                ),
            ];
            for (k, (a, b)) in d.iter().zip(num).enumerate() {
                assert!(
                    (a - b).abs() < 1e-6 * s.peak,
                    "({x}, {y}) partial {k}: {a} vs {b}"
                );
            }
        }
        // Outside the contact: the rate and every partial are 0.
        assert_eq!(s.rate_partials(4.0, 3.0, &s.azimuths()), (0.0, [0.0; 6]));
    }

    #[test]
    fn volume_scaling() {
        let t = tif(|p| p.scale = RateScale::VolumeNmMm2PerS(500.0));
        assert!((t.volume_rate_nm_mm2_per_s() / 500.0 - 1.0).abs() < 0.01);
    }
}
