//! What the measurements say about the vibration forcing, and which causes account for the
//! difference between two bonnets' runs (issue 16).
//!
//! - [`ForcingModel`]: the coupling's fast removal prediction as an exact polynomial in the
//!   unknown forcing. The fast expansion is quadratic in the displacements but for the
//!   spindle-harmonic offset, carried to fourth order, and the
//!   displacements are linear in the spindle-harmonic amplitude `fn_n` (N) and in the broadband
//!   force RMS `noise_force_rms_n` (N) (the ring-down after path velocity changes does not depend
//!   on either), so every mechanism map is `Σ_k w_k C_k` with monomials
//!   `w = [1, F, S, F², F S, S², F³, F⁴]` (F = fn_n, S = noise_force_rms_n). Eight coupling
//!   runs at (F, S) = (0,0), (1,0), (2,0), (0,1), (0,2), (1,1), (3,0), (4,0) N give the
//!   coefficient maps exactly; any
//!   forcing is then a weighted sum, no further coupling run.
//! - [`fit`]: the forcing fitted to a measured removal map through its one-sided X and Y PSDs
//!   (the PSD of a sum of fixed maps is a quadratic form in the weights), with a free removal-rate
//!   scale and a white measurement-noise floor; profile-likelihood intervals, upper bounds when
//!   the data cannot constrain it, and the joint (shared-forcing) test over several runs.
//! - [`attribute`]: the counterfactual attribution of the difference in σ1 and CR(RMS) between
//!   two runs to causes (coupling mechanisms at the fitted forcing, calibrated effects).

pub mod attribute;
pub mod fit;
pub mod synth;

pub use attribute::{
    attribute_difference, counterfactual_effect, vibration_effects, vibration_effects_with_noise,
    CauseEffect, Difference, DifferenceCause, NoiseDraws, RunEffects,
};
pub use fit::{
    end_amplitude_mm, infer_forcing, shared_forcing, ForcingFit, InferOptions, SharedForcing,
    SpectralModel, VibrationForcing,
};

use crate::coupling::predict::{msf_band_rms_y, MechanismResult};
use crate::coupling::{
    fast_maps_lagged, CouplingInput, CouplingOptions, MechanismMaps, Mechanisms,
};
use crate::error::VibrationError;
use crate::params::{Bonnet, VibrationParams};
use bonnetlab_process::Grid;
use bonnetlab_spectrum::{ripple, PsdOptions};
use bonnetlab_surface::Surface;
use ndarray::Array2;
use serde::Serialize;

/// Number of monomials of the forcing polynomial.
pub const N_MONO: usize = 8;

/// Monomials `[1, F, S, F², F S, S², F³, F⁴]` at spindle-harmonic amplitude F and broadband
/// RMS S (N).
pub fn monomials(fn_n: f64, noise_n: f64) -> [f64; N_MONO] {
    let f2 = fn_n * fn_n;
    [
        1.0,
        fn_n,
        noise_n,
        f2,
        fn_n * noise_n,
        noise_n * noise_n,
        f2 * fn_n,
        f2 * f2,
    ]
}

/// The forcings (F, S) of the coupling runs that give the coefficient maps.
const NODES: [(f64, f64); N_MONO] = [
    (0.0, 0.0),
    (1.0, 0.0),
    (2.0, 0.0),
    (0.0, 1.0),
    (0.0, 2.0),
    (1.0, 1.0),
    (3.0, 0.0),
    (4.0, 0.0),
];

/// Inverse of the monomials' matrix at [`NODES`] (row i: the monomials at node i), by
/// Gauss-Jordan elimination with partial pivoting: coefficient k is Σ_i inv[k][i] · run_i.
fn node_inverse() -> [[f64; N_MONO]; N_MONO] {
    let mut a = [[0.0; 2 * N_MONO]; N_MONO];
    for (i, &(f, s)) in NODES.iter().enumerate() {
        a[i][..N_MONO].copy_from_slice(&monomials(f, s));
        a[i][N_MONO + i] = 1.0;
    }
    for c in 0..N_MONO {
        let p = (c..N_MONO)
            .max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))
            .unwrap_or(c);
        a.swap(c, p);
        let d = a[c][c];
        for v in a[c].iter_mut() {
            *v /= d;
        }
        for r in 0..N_MONO {
            if r != c {
                let m = a[r][c];
                if m != 0.0 {
                    let pivot = a[c];
                    for (v, p) in a[r].iter_mut().zip(pivot) {
                        *v -= m * p;
                    }
                }
            }
        }
    }
    let mut inv = [[0.0; N_MONO]; N_MONO];
    for (k, row) in inv.iter_mut().enumerate() {
        row.copy_from_slice(&a[k][N_MONO..]);
    }
    inv
}

/// The `predicted` object of `compare`'s JSON at a given forcing (shared/spec/interfaces.md).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Predicted {
    /// σ1 at 1/pitch along Y, nm: of the predicted after map (before − c · removal) when a
    /// before map is given, else of the predicted removal. None without a pitch.
    pub sigma1_nm: Option<f64>,
    /// MSF band RMS along Y (the coupling's band) of the same map, nm.
    pub msf_rms_nm: f64,
    /// Each mechanism's removal contribution: MSF band RMS along Y and band-power share.
    pub mechanisms: Vec<MechanismResult>,
    /// The forcing and rate scale the prediction is made at.
    pub fn_n: f64,
    pub noise_force_rms_n: f64,
    pub rate_scale: f64,
}

/// The coupling's removal prediction for one run and bonnet as a polynomial in the forcing.
#[derive(Debug, Clone)]
pub struct ForcingModel {
    pub grid: Grid,
    pub bonnet: Bonnet,
    /// The run's vibration parameters (their `fn_n` and `noise_force_rms_n` are not used).
    pub params: VibrationParams,
    pub pitch_mm: Option<f64>,
    /// The mechanism switches of the coupling runs.
    pub mechanisms: Mechanisms,
    /// Servo lag of the run the model is built for, mm (0: the tool on its path).
    pub lag_mm: f64,
    /// Coefficient maps (nm) of the monomials, per mechanism.
    coef: Vec<MechanismMaps>,
}

fn combine(maps: &[&MechanismMaps], w: &[f64]) -> MechanismMaps {
    let lin = |get: &dyn Fn(&MechanismMaps) -> &Array2<f64>| {
        let mut out = Array2::<f64>::zeros(get(maps[0]).dim());
        for (m, &wk) in maps.iter().zip(w) {
            if wk != 0.0 {
                out.scaled_add(wk, get(m));
            }
        }
        out
    };
    MechanismMaps {
        baseline: lin(&|m| &m.baseline),
        normal_offset: lin(&|m| &m.normal_offset),
        lateral_jitter: lin(&|m| &m.lateral_jitter),
        envelope: lin(&|m| &m.envelope),
        dwell_execution: lin(&|m| &m.dwell_execution),
        interaction: lin(&|m| &m.interaction),
    }
}

impl ForcingModel {
    /// Eight fast coupling runs of `input` for `bonnet` (the forcing values of `input.params` are
    /// replaced; every other parameter, the path, the TIF and the mechanism switches are the
    /// run's).
    pub fn build(
        input: &CouplingInput<'_>,
        bonnet: Bonnet,
        opts: &CouplingOptions,
    ) -> Result<ForcingModel, VibrationError> {
        ForcingModel::build_lagged(input, bonnet, opts, 0.0)
    }

    /// [`ForcingModel::build`] for a run whose tool trails its path by `lag_mm` along the
    /// direction of travel (a calibrated servo lag): the coupling runs are
    /// [`crate::coupling::fast_maps_lagged`]'s, the lag applied at the run's own clock.
    pub fn build_lagged(
        input: &CouplingInput<'_>,
        bonnet: Bonnet,
        opts: &CouplingOptions,
        lag_mm: f64,
    ) -> Result<ForcingModel, VibrationError> {
        let at = |f: f64, s: f64| -> Result<MechanismMaps, VibrationError> {
            let params = VibrationParams {
                fn_n: f,
                noise_force_rms_n: s,
                ..input.params.clone()
            };
            params.validate()?;
            let inp = CouplingInput {
                params: &params,
                ..*input
            };
            fast_maps_lagged(&inp, bonnet, opts, lag_mm)
        };
        let runs = NODES
            .iter()
            .map(|&(f, s)| at(f, s))
            .collect::<Result<Vec<_>, _>>()?;
        let all: Vec<&MechanismMaps> = runs.iter().collect();
        // Coefficients of the monomials from the runs at the nodes (exact: the expansion is a
        // polynomial of these degrees in the forcing).
        let rows = node_inverse();
        let coef = rows.iter().map(|w| combine(&all, w)).collect();
        Ok(ForcingModel {
            grid: input.grid,
            bonnet,
            params: input.params.clone(),
            pitch_mm: input.pitch_mm,
            mechanisms: opts.mechanisms,
            lag_mm,
            coef,
        })
    }

    /// Mechanism maps (nm) at spindle-harmonic amplitude `fn_n` and broadband RMS `noise_n` (N).
    pub fn maps(&self, fn_n: f64, noise_n: f64) -> MechanismMaps {
        let refs: Vec<&MechanismMaps> = self.coef.iter().collect();
        combine(&refs, &monomials(fn_n, noise_n))
    }

    /// The coefficient maps of the total removal, one per monomial.
    pub fn total_coefficients(&self) -> Vec<Array2<f64>> {
        self.coef.iter().map(|m| m.total()).collect()
    }

    /// The vibration parameters with the given forcing.
    pub fn params_at(&self, fn_n: f64, noise_n: f64) -> VibrationParams {
        VibrationParams {
            fn_n,
            noise_force_rms_n: noise_n,
            ..self.params.clone()
        }
    }

    /// The prediction at forcing (`fn_n`, `noise_n`) N and removal-rate scale `rate_scale`
    /// (1 for the recipe's rate; a fit's `rate_scale` to compare with that run). `input` gives
    /// the mask (its `valid`) and grid; `band` is the MSF band along Y, cycles/mm.
    pub fn predicted(
        &self,
        input: &CouplingInput<'_>,
        fn_n: f64,
        noise_n: f64,
        rate_scale: f64,
        band: (f64, f64),
        before: Option<&Surface>,
    ) -> Result<Predicted, VibrationError> {
        let maps = self.maps(fn_n, noise_n);
        let removal = maps.total() * rate_scale;
        let map = match before {
            Some(b) => {
                if b.dim() != removal.dim() {
                    return Err(VibrationError::InvalidArgument(format!(
                        "before map is {:?}, the model grid {:?}",
                        b.dim(),
                        removal.dim()
                    )));
                }
                b.heights_nm() - &removal
            }
            None => removal,
        };
        let valid = match (before, input.valid) {
            (Some(b), _) => b.valid().clone(),
            (None, Some(v)) => v.clone(),
            (None, None) => Array2::from_elem(map.dim(), true),
        };
        let sigma1_nm = match self.pitch_mm {
            Some(p) => {
                let s = Surface::with_mask(
                    map.clone(),
                    valid.clone(),
                    Some(self.grid.dx_mm),
                    Some(self.grid.dy_mm),
                )
                .map_err(|e| VibrationError::InvalidArgument(e.to_string()))?;
                Some(
                    ripple(&s, p, &PsdOptions::default())
                        .map_err(|e| VibrationError::InvalidArgument(e.to_string()))?
                        .sigma1_nm,
                )
            }
            None => None,
        };
        let inp = CouplingInput {
            valid: Some(&valid),
            ..*input
        };
        let mut mechanisms = Vec::new();
        for name in Mechanisms::NAMES
            .iter()
            .chain(std::iter::once(&"interaction"))
        {
            let m = maps.by_name(name).unwrap_or(&maps.interaction) * rate_scale;
            mechanisms.push(MechanismResult {
                name: name.to_string(),
                enabled: *name == "interaction" || self.mechanisms.is_on(name),
                msf_band_rms_nm: msf_band_rms_y(&inp, &m, band)?,
                share: 0.0,
            });
        }
        let power: f64 = mechanisms.iter().map(|m| m.msf_band_rms_nm.powi(2)).sum();
        if power > 0.0 {
            for m in &mut mechanisms {
                m.share = m.msf_band_rms_nm.powi(2) / power;
            }
        }
        Ok(Predicted {
            sigma1_nm,
            msf_rms_nm: msf_band_rms_y(&inp, &map, band)?,
            mechanisms,
            fn_n,
            noise_force_rms_n: noise_n,
            rate_scale,
        })
    }
}
