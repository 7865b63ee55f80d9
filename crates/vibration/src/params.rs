//! Parameters of the two-degree-of-freedom vibration model, read from a recipe's `[vibration]`
//! table (keys as in `shared/spec/interfaces.md`), with every default and its source.
//!
//! Frame conventions (used by every module of this crate):
//! - The polishing force lies in the robot's XZ plane. In-plane vectors are written `(t, n)`:
//!   `t` along the tangential (friction) direction, which is the map's scan axis X unless
//!   `lateral_axis = "y"`, and `n` along the normal reaction force on the tool, pointing away
//!   from the part.
//! - The principal stiffness axes are `e1 = (cos θ, sin θ)` (stiffest, k1) and
//!   `e2 = (-sin θ, cos θ)` (softest, k2); θ is the signed angle from the normal-force
//!   direction to the x2 axis (`cos θ = e2 · e_n`). With friction along +t (`mu > 0`) this gives
//!   the paper's projections F1 = Fn (sin θ + μ cos θ), F2 = Fn (cos θ − μ sin θ); the code
//!   always projects vectors, never those formulas.
//! - Stiffness in N/mm, force in N, mass in kg, displacement in mm, frequency in Hz.
//!
//! Defaults and their sources:
//!
//! | key | default | source |
//! |---|---|---|
//! | `k1_n_per_mm` | 1476.0 | paper, section 2.2.2 (eigenvalues of K_fd at the working pose) |
//! | `k2_n_per_mm` | 328.9 | paper, section 2.2.2 |
//! | `theta_deg` | 13.2 | paper, section 2.2.2 (k2 axis vs Z, the normal direction) |
//! | `natural_freq_hz` | 20.0 | paper's eq. (10) m = ‖K_fd‖_F / ω_n² with ω_n the measured mode 4 (20.00 Hz, best FEA agreement, 0.7 %); gives m = 95.8 kg and principal frequencies 19.8 / 9.3 Hz, next to the measured 20.00 and 8.75 Hz modes |
//! | `mass_kg` | derived | given instead of `natural_freq_hz` (not both) |
//! | `zeta1`, `zeta2` | 0.05 | assumed: "robot damping only, a few percent" (DOMAIN.md); modal tests of large industrial robots typically report 2–10 % |
//! | `fn_n` | 2.0 | assumed (the paper takes it from its ref. [19], not printed): mean normal force of an R20 bonnet at 0.25 MPa and 0.6 mm offset ≈ p·π(2Rh − h²) ≈ 19 N; a once-per-revolution fluctuation of ≈ 10 % (≈ 60 µm membrane run-out times the contact stiffness 2πp(R − h) ≈ 30 N/mm) |
//! | `mu` | 0.3 | assumed: order of the sliding friction of a polishing pad on a ceramic with slurry (measured pad/glass values 0.2–0.6) |
//! | `loss_factor` | 0.115 | paper, section 3.1 (hysteresis loop at 20 Hz, 4 mm); ζ_e = η / 2 = 0.0575 |
//! | `spindle_rpm` | `[process] spindle_rpm`, else 1000 | paper's whole-surface runs |
//! | `damping_split` | `"isotropic"` | ζ_e added to both principal directions: the rubber ring works in compression axially and in shear laterally with about the same loss factor. `"axial"`: a damper along the normal only, ζ_e,i = ζ_e (e_n · e_i)² |
//! | `harmonics` | [1.0, 0.25, 0.1] | assumed relative force amplitudes at 1x, 2x, 3x the spindle frequency (bonnet ovality, precession); `[1.0]` is the paper's model. The JSON response reports the fundamental |
//! | `noise_force_rms_n` | 0.5 | assumed broadband force noise (slurry, pad texture), RMS over 0..`noise_band_hz` |
//! | `noise_band_hz` | 200.0 | assumed; covers every robot mode (4.75–23.8 Hz) with margin |
//! | `accel_max_mm_per_s2` | 100.0 | assumed robot path acceleration in slow polishing moves (drives ring-down and dwell execution) |
//! | `element_stiffness_n_per_mm` | 50.0 | assumed wave-spring + rubber element rate (the paper gives none); must carry the ≈ 19 N working load within a few mm of stroke |
//! | `bonnet_radius_mm` | `[tif] model.radius_mm`, else 20.0 | spec example recipe |
//! | `offset_mm` | `[process] offset_mm`, else 0.6 | paper's whole-surface runs |
//! | `inner_pressure_mpa` | `[process] inner_pressure_mpa`, else 0.25 | paper |
//! | `pressure_exponent` | 0.5 | peak contact pressure ∝ (h / h0)^γ; 0.5 is Hertzian contact of a pad-covered sphere, 0 a pure membrane |
//! | `lateral_axis` | `"x"` | the paper's force plane XZ contains the scan direction X |
//!
//! Instead of k1, k2, θ the full in-plane matrix may be given, `kfd_n_per_mm = [[k_tt, k_tn],
//! [k_nt, k_nn]]` (symmetric, positive definite, t then n): its eigen-decomposition gives k1, k2
//! and θ, and ‖K_fd‖_F its Frobenius norm.

use crate::error::VibrationError;
use bonnetlab_process::config::from_table;
use bonnetlab_process::recipe::RecipeDoc;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

/// Which tool the robot carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Bonnet {
    /// Robot damping only.
    Original,
    /// Wave spring + rubber ring between spindle and bonnet: added damping ζ_e = η / 2 and a
    /// series compliance between robot and contact.
    Suppression,
}

impl Bonnet {
    pub const ALL: [Bonnet; 2] = [Bonnet::Original, Bonnet::Suppression];

    pub fn name(self) -> &'static str {
        match self {
            Bonnet::Original => "original",
            Bonnet::Suppression => "suppression",
        }
    }
}

impl fmt::Display for Bonnet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Bonnet {
    type Err = VibrationError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "original" => Ok(Bonnet::Original),
            "suppression" | "vibration_suppression" | "vibration-suppression" => {
                Ok(Bonnet::Suppression)
            }
            other => Err(VibrationError::InvalidArgument(format!(
                "unknown bonnet '{other}' (expected original or suppression)"
            ))),
        }
    }
}

/// How the element's ζ_e is split into the two principal directions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DampingSplit {
    /// ζ_e added to both directions.
    Isotropic,
    /// A damper along the normal only: ζ_e,i = ζ_e (e_n · e_i)².
    Axial,
}

/// The map axis the in-plane tangential direction `t` maps onto.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LateralAxis {
    X,
    Y,
}

/// Where the equivalent mass came from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MassSource {
    Given,
    /// m = ‖K_fd‖_F / ω_n² with this natural frequency.
    NaturalFreqHz(f64),
}

/// Every parameter of the vibration model, resolved (no option left open).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VibrationParams {
    pub k1_n_per_mm: f64,
    pub k2_n_per_mm: f64,
    pub theta_deg: f64,
    /// Frobenius norm of the in-plane K_fd (sqrt(k1² + k2²) when only k1, k2 are given).
    pub kfd_frobenius_n_per_mm: f64,
    pub mass_kg: f64,
    pub mass_source: MassSource,
    pub zeta1: f64,
    pub zeta2: f64,
    pub fn_n: f64,
    pub mu: f64,
    pub loss_factor: f64,
    pub spindle_rpm: f64,
    pub damping_split: DampingSplit,
    pub harmonics: Vec<f64>,
    pub noise_force_rms_n: f64,
    pub noise_band_hz: f64,
    pub accel_max_mm_per_s2: f64,
    pub element_stiffness_n_per_mm: f64,
    pub bonnet_radius_mm: f64,
    pub offset_mm: f64,
    pub inner_pressure_mpa: f64,
    pub pressure_exponent: f64,
    pub lateral_axis: LateralAxis,
}

/// Default natural frequency used to derive the equivalent mass (measured mode 4).
pub const DEFAULT_NATURAL_FREQ_HZ: f64 = 20.0;

/// Natural frequencies (Hz) a robot-and-bonnet model may have: the robot's measured modes are
/// 4.75 to 23.8 Hz; four decades either side is generous and still rejects unit slips.
pub const NATURAL_FREQ_RANGE_HZ: (f64, f64) = (0.01, 1.0e5);

impl Default for VibrationParams {
    fn default() -> Self {
        let (k1, k2): (f64, f64) = (1476.0, 328.9);
        let norm = (k1 * k1 + k2 * k2).sqrt();
        VibrationParams {
            k1_n_per_mm: k1,
            k2_n_per_mm: k2,
            theta_deg: 13.2,
            kfd_frobenius_n_per_mm: norm,
            mass_kg: mass_from_natural_freq(norm, DEFAULT_NATURAL_FREQ_HZ),
            mass_source: MassSource::NaturalFreqHz(DEFAULT_NATURAL_FREQ_HZ),
            zeta1: 0.05,
            zeta2: 0.05,
            fn_n: 2.0,
            mu: 0.3,
            loss_factor: 0.115,
            spindle_rpm: 1000.0,
            damping_split: DampingSplit::Isotropic,
            harmonics: vec![1.0, 0.25, 0.1],
            noise_force_rms_n: 0.5,
            noise_band_hz: 200.0,
            accel_max_mm_per_s2: 100.0,
            element_stiffness_n_per_mm: 50.0,
            bonnet_radius_mm: 20.0,
            offset_mm: 0.6,
            inner_pressure_mpa: 0.25,
            pressure_exponent: 0.5,
            lateral_axis: LateralAxis::X,
        }
    }
}

/// m = ‖K_fd‖_F / ω_n² (paper eq. 10), stiffness in N/mm, result in kg.
pub fn mass_from_natural_freq(kfd_frobenius_n_per_mm: f64, natural_freq_hz: f64) -> f64 {
    let omega = 2.0 * PI * natural_freq_hz;
    kfd_frobenius_n_per_mm * 1e3 / (omega * omega)
}

/// Principal stiffnesses and angle of a symmetric positive-definite 2x2 K_fd in the (t, n)
/// frame: returns (k1, k2, θ in degrees, ‖K‖_F) with k1 ≥ k2 and θ the signed angle from e_n to
/// the k2 eigenvector (chosen with e2 · e_n ≥ 0), in (−90, 90].
pub fn principal_axes(kfd: [[f64; 2]; 2]) -> Result<(f64, f64, f64, f64), VibrationError> {
    let [[a, b1], [b2, c]] = kfd;
    if !(a.is_finite() && b1.is_finite() && b2.is_finite() && c.is_finite()) {
        return Err(VibrationError::param(
            "kfd_n_per_mm",
            "entries must be finite numbers",
        ));
    }
    let scale = a.abs().max(c.abs()).max(b1.abs()).max(f64::MIN_POSITIVE);
    if (b1 - b2).abs() > 1e-9 * scale {
        return Err(VibrationError::param(
            "kfd_n_per_mm",
            "matrix must be symmetric",
        ));
    }
    let b = 0.5 * (b1 + b2);
    let mean = 0.5 * (a + c);
    let radius = (0.25 * (a - c) * (a - c) + b * b).sqrt();
    let (k1, k2) = (mean + radius, mean - radius);
    if k2 <= 0.0 {
        return Err(VibrationError::param(
            "kfd_n_per_mm",
            "matrix must be positive definite",
        ));
    }
    // e1 = (cos φ, sin φ) with tan 2φ = 2b / (a − c); e2 = (−sin φ, cos φ) so θ = φ.
    let theta = 0.5 * (2.0 * b).atan2(a - c);
    let norm = (a * a + c * c + b1 * b1 + b2 * b2).sqrt();
    Ok((k1, k2, theta.to_degrees(), norm))
}

/// The `[vibration]` table as written: every key optional, unknown keys an error (read with
/// bonnetlab_process::config, which names the nearest valid key). Defaults and domains: the
/// table in the module doc.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VibrationTable {
    pub k1_n_per_mm: Option<f64>,
    pub k2_n_per_mm: Option<f64>,
    pub theta_deg: Option<f64>,
    pub kfd_n_per_mm: Option<[[f64; 2]; 2]>,
    pub mass_kg: Option<f64>,
    pub natural_freq_hz: Option<f64>,
    pub zeta1: Option<f64>,
    pub zeta2: Option<f64>,
    pub fn_n: Option<f64>,
    pub mu: Option<f64>,
    pub loss_factor: Option<f64>,
    pub spindle_rpm: Option<f64>,
    pub damping_split: Option<String>,
    pub harmonics: Option<Vec<f64>>,
    pub noise_force_rms_n: Option<f64>,
    pub noise_band_hz: Option<f64>,
    pub accel_max_mm_per_s2: Option<f64>,
    pub element_stiffness_n_per_mm: Option<f64>,
    pub bonnet_radius_mm: Option<f64>,
    pub offset_mm: Option<f64>,
    pub inner_pressure_mpa: Option<f64>,
    pub pressure_exponent: Option<f64>,
    pub lateral_axis: Option<String>,
}

impl VibrationParams {
    /// Reads a whole recipe document (typed, strict: bonnetlab_process::recipe::RecipeDoc):
    /// `[vibration]` (optional), with `[process]` and the bonnet `[tif] model` supplying spindle
    /// speed, offset, pressure and bonnet radius where `[vibration]` is silent.
    pub fn from_recipe(doc: &RecipeDoc) -> Result<Self, VibrationError> {
        let p = doc.process.clone().unwrap_or_default();
        Self::from_parts(
            doc.vibration.as_ref(),
            p.spindle_rpm,
            p.offset_mm,
            p.inner_pressure_mpa,
            doc.bonnet_radius_mm(),
        )
    }

    /// For callers holding an already-parsed recipe (bonnetlab_process::Recipe): the raw
    /// `[vibration]` table (read here into [`VibrationTable`], strictly) plus the `[process]`
    /// values and the bonnet TIF radius, each optional.
    pub fn from_parts(
        vib: Option<&toml::Table>,
        spindle_rpm: Option<f64>,
        offset_mm: Option<f64>,
        inner_pressure_mpa: Option<f64>,
        tif_radius_mm: Option<f64>,
    ) -> Result<Self, VibrationError> {
        let v: VibrationTable = match vib {
            None => VibrationTable::default(),
            Some(t) => {
                from_table(t, "vibration").map_err(|e| VibrationError::Table(e.to_string()))?
            }
        };
        Self::from_table(
            &v,
            spindle_rpm,
            offset_mm,
            inner_pressure_mpa,
            tif_radius_mm,
        )
    }

    /// The parameters from a typed `[vibration]` table with fall-backs from `[process]` and the
    /// TIF model radius.
    pub fn from_table(
        v: &VibrationTable,
        process_spindle_rpm: Option<f64>,
        process_offset_mm: Option<f64>,
        process_inner_pressure_mpa: Option<f64>,
        tif_radius_mm: Option<f64>,
    ) -> Result<Self, VibrationError> {
        let d = VibrationParams::default();
        // One spindle speed per run: a [vibration] value that differs from [process]'s would
        // silently model another run than the one the recipe describes.
        if let (Some(vr), Some(pr)) = (v.spindle_rpm, process_spindle_rpm) {
            if vr != pr {
                return Err(VibrationError::param(
                    "spindle_rpm",
                    format!(
                        "{} rpm differs from [process] spindle_rpm = {} rpm: give one of them, \
                         or the same value in both",
                        bonnetlab_surface::format::sig(vr, 6),
                        bonnetlab_surface::format::sig(pr, 6)
                    ),
                ));
            }
        }
        let (k1, k2, theta, norm) = match v.kfd_n_per_mm {
            Some(m) => {
                for (k, given) in [
                    ("k1_n_per_mm", v.k1_n_per_mm.is_some()),
                    ("k2_n_per_mm", v.k2_n_per_mm.is_some()),
                    ("theta_deg", v.theta_deg.is_some()),
                ] {
                    if given {
                        return Err(VibrationError::Conflict("kfd_n_per_mm".into(), k.into()));
                    }
                }
                principal_axes(m)?
            }
            None => {
                let k1 = v.k1_n_per_mm.unwrap_or(d.k1_n_per_mm);
                let k2 = v.k2_n_per_mm.unwrap_or(d.k2_n_per_mm);
                positive("k1_n_per_mm", k1)?;
                positive("k2_n_per_mm", k2)?;
                if k2 > k1 {
                    return Err(VibrationError::param(
                        "k2_n_per_mm",
                        "k2 is the softest principal stiffness: must not exceed k1",
                    ));
                }
                let theta = v.theta_deg.unwrap_or(d.theta_deg);
                finite_in("theta_deg", theta, -90.0, 90.0)?;
                (k1, k2, theta, (k1 * k1 + k2 * k2).sqrt())
            }
        };
        let (mass_kg, mass_source) = match (v.mass_kg, v.natural_freq_hz) {
            (Some(_), Some(_)) => {
                return Err(VibrationError::Conflict(
                    "mass_kg".into(),
                    "natural_freq_hz".into(),
                ))
            }
            (Some(m), None) => {
                positive("mass_kg", m)?;
                (m, MassSource::Given)
            }
            (None, f) => {
                let f = f.unwrap_or(DEFAULT_NATURAL_FREQ_HZ);
                positive("natural_freq_hz", f)?;
                (
                    mass_from_natural_freq(norm, f),
                    MassSource::NaturalFreqHz(f),
                )
            }
        };
        let p = VibrationParams {
            k1_n_per_mm: k1,
            k2_n_per_mm: k2,
            theta_deg: theta,
            kfd_frobenius_n_per_mm: norm,
            mass_kg,
            mass_source,
            zeta1: v.zeta1.unwrap_or(d.zeta1),
            zeta2: v.zeta2.unwrap_or(d.zeta2),
            fn_n: v.fn_n.unwrap_or(d.fn_n),
            mu: v.mu.unwrap_or(d.mu),
            loss_factor: v.loss_factor.unwrap_or(d.loss_factor),
            spindle_rpm: v
                .spindle_rpm
                .or(process_spindle_rpm)
                .unwrap_or(d.spindle_rpm),
            damping_split: match v.damping_split.as_deref() {
                None => d.damping_split,
                Some("isotropic") => DampingSplit::Isotropic,
                Some("axial") => DampingSplit::Axial,
                Some(s) => {
                    return Err(VibrationError::param(
                        "damping_split",
                        format!("expected \"isotropic\" or \"axial\", found \"{s}\""),
                    ))
                }
            },
            harmonics: v.harmonics.clone().unwrap_or_else(|| d.harmonics.clone()),
            noise_force_rms_n: v.noise_force_rms_n.unwrap_or(d.noise_force_rms_n),
            noise_band_hz: v.noise_band_hz.unwrap_or(d.noise_band_hz),
            accel_max_mm_per_s2: v.accel_max_mm_per_s2.unwrap_or(d.accel_max_mm_per_s2),
            element_stiffness_n_per_mm: v
                .element_stiffness_n_per_mm
                .unwrap_or(d.element_stiffness_n_per_mm),
            bonnet_radius_mm: v
                .bonnet_radius_mm
                .or(tif_radius_mm)
                .unwrap_or(d.bonnet_radius_mm),
            offset_mm: v.offset_mm.or(process_offset_mm).unwrap_or(d.offset_mm),
            inner_pressure_mpa: v
                .inner_pressure_mpa
                .or(process_inner_pressure_mpa)
                .unwrap_or(d.inner_pressure_mpa),
            pressure_exponent: v.pressure_exponent.unwrap_or(d.pressure_exponent),
            lateral_axis: match v.lateral_axis.as_deref() {
                None => d.lateral_axis,
                Some("x") | Some("X") => LateralAxis::X,
                Some("y") | Some("Y") => LateralAxis::Y,
                Some(s) => {
                    return Err(VibrationError::param(
                        "lateral_axis",
                        format!("expected \"x\" or \"y\", found \"{s}\""),
                    ))
                }
            },
        };
        p.validate()?;
        Ok(p)
    }

    /// Checks every value's domain; the message names the key.
    pub fn validate(&self) -> Result<(), VibrationError> {
        positive("k1_n_per_mm", self.k1_n_per_mm)?;
        positive("k2_n_per_mm", self.k2_n_per_mm)?;
        finite_in("theta_deg", self.theta_deg, -90.0, 90.0)?;
        positive("mass_kg", self.mass_kg)?;
        self.check_natural_freqs()?;
        for (key, z) in [("zeta1", self.zeta1), ("zeta2", self.zeta2)] {
            if !(z.is_finite() && z > 0.0 && z <= 1.0) {
                return Err(VibrationError::param(
                    key,
                    "damping ratio must be in (0, 1]",
                ));
            }
        }
        finite_in("fn_n", self.fn_n, 0.0, 1e6)?;
        finite_in("mu", self.mu, -5.0, 5.0)?;
        finite_in("loss_factor", self.loss_factor, 0.0, 2.0)?;
        finite_in("spindle_rpm", self.spindle_rpm, 1e-6, 1e6)?;
        if self.harmonics.is_empty() || self.harmonics.len() > 64 {
            return Err(VibrationError::param(
                "harmonics",
                "give 1 to 64 relative amplitudes",
            ));
        }
        for &h in &self.harmonics {
            finite_in("harmonics", h, -1e3, 1e3)?;
        }
        finite_in("noise_force_rms_n", self.noise_force_rms_n, 0.0, 1e6)?;
        finite_in("noise_band_hz", self.noise_band_hz, 1e-3, 1e5)?;
        positive("accel_max_mm_per_s2", self.accel_max_mm_per_s2)?;
        positive(
            "element_stiffness_n_per_mm",
            self.element_stiffness_n_per_mm,
        )?;
        positive("bonnet_radius_mm", self.bonnet_radius_mm)?;
        positive("offset_mm", self.offset_mm)?;
        if self.offset_mm >= self.bonnet_radius_mm {
            return Err(VibrationError::param(
                "offset_mm",
                "must be smaller than the bonnet radius",
            ));
        }
        positive("inner_pressure_mpa", self.inner_pressure_mpa)?;
        finite_in("pressure_exponent", self.pressure_exponent, 0.0, 5.0)?;
        Ok(())
    }

    /// The natural frequencies sqrt(k_i / m) / 2 pi must lie in [`NATURAL_FREQ_RANGE_HZ`]: a
    /// mass or stiffness outside that is a typo or a unit slip (1e-300 kg gives 1.9e152 Hz).
    /// Names the key that moved them: the mass (`mass_kg` or `natural_freq_hz`) when the
    /// stiffest direction is out, else the softest stiffness.
    fn check_natural_freqs(&self) -> Result<(), VibrationError> {
        let (lo, hi) = NATURAL_FREQ_RANGE_HZ;
        let f = self.natural_freq_hz();
        let inside = |v: f64| v.is_finite() && (lo..=hi).contains(&v);
        if inside(f[0]) && inside(f[1]) {
            return Ok(());
        }
        let key = if !inside(f[0]) {
            match self.mass_source {
                MassSource::Given => "mass_kg",
                MassSource::NaturalFreqHz(_) => "natural_freq_hz",
            }
        } else {
            "k2_n_per_mm"
        };
        let sig = |v: f64| bonnetlab_surface::format::sig(v, 4);
        Err(VibrationError::param(
            key,
            format!(
                "mass {} kg with k1 {} and k2 {} N/mm gives natural frequencies {} and {} Hz, \
                 outside {} Hz to {} Hz: not a polishing robot's",
                sig(self.mass_kg),
                sig(self.k1_n_per_mm),
                sig(self.k2_n_per_mm),
                sig(f[0]),
                sig(f[1]),
                sig(lo),
                sig(hi)
            ),
        ))
    }

    /// Principal axis unit vectors (e1, e2) in the (t, n) frame.
    pub fn axes(&self) -> ([f64; 2], [f64; 2]) {
        let th = self.theta_deg.to_radians();
        ([th.cos(), th.sin()], [-th.sin(), th.cos()])
    }

    /// Amplitude of the polishing force vector (F_t, F_n) = F_n (μ, 1) in the (t, n) frame, N.
    pub fn force_vector_n(&self) -> [f64; 2] {
        [self.mu * self.fn_n, self.fn_n]
    }

    /// Projections (F1, F2) of a (t, n) force vector on the principal axes, N.
    pub fn project(&self, f_tn: [f64; 2]) -> [f64; 2] {
        let (e1, e2) = self.axes();
        [dot(f_tn, e1), dot(f_tn, e2)]
    }

    /// (t, n) displacement of the tool holder from principal coordinates (x1, x2), mm.
    pub fn to_tn(&self, x: [f64; 2]) -> [f64; 2] {
        let (e1, e2) = self.axes();
        [x[0] * e1[0] + x[1] * e2[0], x[0] * e1[1] + x[1] * e2[1]]
    }

    /// Principal stiffnesses [k1, k2], N/mm.
    pub fn stiffness_n_per_mm(&self) -> [f64; 2] {
        [self.k1_n_per_mm, self.k2_n_per_mm]
    }

    /// Undamped natural angular frequencies sqrt(k_i / m), rad/s.
    pub fn omega_n_rad_per_s(&self) -> [f64; 2] {
        self.stiffness_n_per_mm()
            .map(|k| (k * 1e3 / self.mass_kg).sqrt())
    }

    /// Undamped natural frequencies of the two principal directions, Hz.
    pub fn natural_freq_hz(&self) -> [f64; 2] {
        self.omega_n_rad_per_s().map(|w| w / (2.0 * PI))
    }

    /// The element's equivalent damping ratio ζ_e = η / 2 (paper eq. 15).
    pub fn zeta_element(&self) -> f64 {
        self.loss_factor / 2.0
    }

    /// Effective damping ratios [ζ1e, ζ2e] for a bonnet (ζ_ie = ζ_i + ζ_e,i).
    pub fn zeta_effective(&self, bonnet: Bonnet) -> [f64; 2] {
        match bonnet {
            Bonnet::Original => [self.zeta1, self.zeta2],
            Bonnet::Suppression => {
                let ze = self.zeta_element();
                let split = match self.damping_split {
                    DampingSplit::Isotropic => [ze, ze],
                    DampingSplit::Axial => {
                        let (e1, e2) = self.axes();
                        [ze * e1[1] * e1[1], ze * e2[1] * e2[1]]
                    }
                };
                [self.zeta1 + split[0], self.zeta2 + split[1]]
            }
        }
    }

    /// Contact stiffness of the inflated bonnet dF/dh, N/mm: F ≈ p π (2 R h − h²), so
    /// dF/dh = 2 π p (R − h) (p in MPa = N/mm²).
    pub fn contact_stiffness_n_per_mm(&self) -> f64 {
        2.0 * PI * self.inner_pressure_mpa * (self.bonnet_radius_mm - self.offset_mm)
    }

    /// Fraction of a normal holder displacement that reaches the contact as an offset change.
    /// Original bonnet: 1 (rigid spindle, the bonnet compression changes by the full motion).
    /// Suppression bonnet: the element k_e and the bonnet k_b are springs in series carrying the
    /// same force, so Δh = u_n k_e / (k_e + k_b). (The element's loss factor adds a phase of
    /// about η k_b / (k_e + k_b) rad to this transfer; it is neglected.)
    pub fn offset_transfer(&self, bonnet: Bonnet) -> f64 {
        match bonnet {
            Bonnet::Original => 1.0,
            Bonnet::Suppression => {
                let ke = self.element_stiffness_n_per_mm;
                ke / (ke + self.contact_stiffness_n_per_mm())
            }
        }
    }

    /// Contact radius sqrt(2 R h − h²) at offset h, mm.
    pub fn contact_radius_mm(&self, offset_mm: f64) -> f64 {
        (2.0 * self.bonnet_radius_mm * offset_mm - offset_mm * offset_mm)
            .max(0.0)
            .sqrt()
    }

    /// Spindle (once-per-revolution) excitation frequency n / 60, Hz.
    pub fn excitation_hz(&self) -> f64 {
        self.spindle_rpm / 60.0
    }
}

pub(crate) fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

fn positive(key: &str, v: f64) -> Result<(), VibrationError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(VibrationError::param(
            key,
            format!(
                "must be a positive finite number, found {}",
                bonnetlab_surface::format::sig(v, 6)
            ),
        ))
    }
}

fn finite_in(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), VibrationError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(VibrationError::param(
            key,
            format!(
                "must be within [{}, {}], found {}",
                bonnetlab_surface::format::sig(lo, 6),
                bonnetlab_surface::format::sig(hi, 6),
                bonnetlab_surface::format::sig(v, 6)
            ),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_follow_the_paper_and_eq10() {
        let p = VibrationParams::default();
        let norm = (1476.0f64.powi(2) + 328.9f64.powi(2)).sqrt();
        let w = 2.0 * PI * 20.0;
        assert!((p.mass_kg - norm * 1e3 / (w * w)).abs() < 1e-9);
        assert!((p.mass_kg - 95.75).abs() < 0.1, "mass {}", p.mass_kg);
        let f = p.natural_freq_hz();
        assert!(
            (f[0] - 19.76).abs() < 0.02 && (f[1] - 9.33).abs() < 0.02,
            "{f:?}"
        );
        p.validate().unwrap();
    }

    #[test]
    fn projection_matches_paper_formulas_for_friction_on_plus_t() {
        let p = VibrationParams {
            mu: 0.3,
            fn_n: 10.0,
            theta_deg: 13.2,
            ..Default::default()
        };
        let th = 13.2f64.to_radians();
        let f = p.project(p.force_vector_n());
        assert!((f[0] - 10.0 * (th.sin() + 0.3 * th.cos())).abs() < 1e-12);
        assert!((f[1] - 10.0 * (th.cos() - 0.3 * th.sin())).abs() < 1e-12);
        // Back to (t, n): the projection preserves the vector.
        let back = p.to_tn(f);
        assert!((back[0] - 3.0).abs() < 1e-12 && (back[1] - 10.0).abs() < 1e-12);
    }

    #[test]
    fn eigen_decomposition_recovers_principal_frame() {
        for &(k1, k2, th) in &[
            (1476.0, 328.9, 13.2),
            (900.0, 100.0, -40.0),
            (50.0, 49.0, 80.0),
        ] {
            let t = f64::to_radians(th);
            let (e1, e2) = ([t.cos(), t.sin()], [-t.sin(), t.cos()]);
            let mut k = [[0.0; 2]; 2];
            for i in 0..2 {
                for j in 0..2 {
                    k[i][j] = k1 * e1[i] * e1[j] + k2 * e2[i] * e2[j];
                }
            }
            let (a1, a2, ath, norm) = principal_axes(k).unwrap();
            assert!((a1 - k1).abs() < 1e-9 * k1 && (a2 - k2).abs() < 1e-9 * k1);
            assert!((ath - th).abs() < 1e-9, "{ath} vs {th}");
            assert!((norm - (k1 * k1 + k2 * k2).sqrt()).abs() < 1e-9 * k1);
        }
        assert!(principal_axes([[1.0, 2.0], [2.0, 1.0]]).is_err());
        assert!(principal_axes([[1.0, 0.1], [0.2, 1.0]]).is_err());
    }

    #[test]
    fn table_parsing_defaults_conflicts_and_typos() {
        let doc_of = |t: &str| RecipeDoc::parse(t, std::path::Path::new("r.toml"));
        let doc = doc_of(
            "[process]\nspindle_rpm = 750\noffset_mm = 0.8\n[vibration]\nmass_kg = 50.0\nzeta1 = 0.03\n",
        )
        .unwrap();
        let p = VibrationParams::from_recipe(&doc).unwrap();
        assert_eq!(p.spindle_rpm, 750.0);
        assert_eq!(p.offset_mm, 0.8);
        assert_eq!(p.mass_kg, 50.0);
        assert_eq!(p.zeta1, 0.03);
        assert_eq!(p.mass_source, MassSource::Given);
        let q = VibrationParams::from_parts(
            doc.vibration.as_ref(),
            Some(750.0),
            Some(0.8),
            None,
            Some(25.0),
        )
        .unwrap();
        assert_eq!(
            (q.spindle_rpm, q.offset_mm, q.bonnet_radius_mm, q.mass_kg),
            (750.0, 0.8, 25.0, 50.0)
        );
        let bad = doc_of("[vibration]\nk1 = 3.0\n").unwrap();
        assert_eq!(
            VibrationParams::from_recipe(&bad).unwrap_err().to_string(),
            "[vibration] k1: unknown key; did you mean `k1_n_per_mm`?"
        );
        let both = doc_of("[vibration]\nmass_kg = 3.0\nnatural_freq_hz = 9.0\n").unwrap();
        assert!(matches!(
            VibrationParams::from_recipe(&both),
            Err(VibrationError::Conflict(..))
        ));
        let neg = doc_of("[vibration]\nzeta2 = -0.1\n").unwrap();
        let e = VibrationParams::from_recipe(&neg).unwrap_err().to_string();
        assert!(e.contains("zeta2"), "{e}");
        let txt = doc_of("[vibration]\nmu = \"high\"\n").unwrap();
        assert!(VibrationParams::from_recipe(&txt)
            .unwrap_err()
            .to_string()
            .contains("mu"));
        let kfd =
            doc_of("[vibration]\nkfd_n_per_mm = [[1000.0, 200.0], [200.0, 500.0]]\n").unwrap();
        let p = VibrationParams::from_recipe(&kfd).unwrap();
        assert!(p.k1_n_per_mm > p.k2_n_per_mm);
        let m = 1e3 * (1000.0f64.powi(2) + 500.0f64.powi(2) + 2.0 * 200.0f64.powi(2)).sqrt()
            / (2.0 * PI * 20.0f64).powi(2);
        assert!((p.mass_kg - m).abs() < 1e-9 * m);
    }

    #[test]
    fn suppression_damping_and_series_transfer() {
        let p = VibrationParams::default();
        let z = p.zeta_effective(Bonnet::Suppression);
        assert!((z[0] - (0.05 + 0.0575)).abs() < 1e-15 && (z[1] - (0.05 + 0.0575)).abs() < 1e-15);
        let axial = VibrationParams {
            damping_split: DampingSplit::Axial,
            ..p.clone()
        };
        let za = axial.zeta_effective(Bonnet::Suppression);
        // The axial split conserves ζ_e: (e_n·e1)² + (e_n·e2)² = 1.
        assert!(((za[0] - 0.05) + (za[1] - 0.05) - 0.0575).abs() < 1e-15);
        let kb = 2.0 * PI * 0.25 * (20.0 - 0.6);
        assert!((p.contact_stiffness_n_per_mm() - kb).abs() < 1e-12);
        assert_eq!(p.offset_transfer(Bonnet::Original), 1.0);
        assert!((p.offset_transfer(Bonnet::Suppression) - 50.0 / (50.0 + kb)).abs() < 1e-15);
    }
}
