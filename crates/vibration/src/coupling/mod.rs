//! Coupling of the robot's vibration into removal: the predicted MSF ripple each bonnet leaves,
//! mechanism by mechanism (DOMAIN.md section 3).
//!
//! Mechanisms (each switchable, each reported on its own):
//! - `normal_offset`: the normal holder displacement from the spindle harmonics and the
//!   ring-down after path velocity changes, scaled by the bonnet's series transfer, changes the
//!   offset h, hence contact size and pressure, hence the removal rate (non-linear in h:
//!   a first-order modulation plus a rectified second-order mean);
//! - `lateral_jitter`: the lateral displacement (all excitations) moves the spot;
//! - `envelope`: the normal response to broadband force noise, whose slowly varying envelope
//!   (through the rate's curvature in h) changes removal from line to line;
//! - `dwell_execution`: the acceleration-limited robot re-times the commanded path, so the
//!   realised dwell differs from the planned one.
//!
//! Cross terms between mechanisms are kept in `interaction`.
//!
//! [`fast`] takes the unperturbed removal from the process crate's fast removal model and the
//! vibration's part from an expansion, second order and the offset to fourth (FFT convolutions of weighted dwell maps with
//! derivative kernels, [`bonnetlab_process::perturb`]); [`direct`] deposits the instantaneous
//! TIF sub-step by sub-step with the process crate's one exact deposition (the reference,
//! independent of the expansion). [`predict`] turns
//! the maps into the numbers `simulate` reports (MSF band RMS along Y per mechanism, shares,
//! Y ripple σ1) and runs the spindle-speed sweep.

pub mod case;
pub mod direct;
pub mod fast;
pub mod predict;
pub mod stream;

use crate::params::VibrationParams;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::{Grid, PathLog};
use ndarray::Array2;
use serde::Serialize;

pub use case::CouplingCase;
pub use direct::{direct_removal, direct_removal_with, Vibrating};
pub use fast::{direction_lag_path, fast_maps, fast_maps_lagged};
pub use predict::{
    predict, predict_both, spindle_sweep, BonnetPrediction, MechanismResult, SweepRow,
};

/// Mechanism switches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Mechanisms {
    pub normal_offset: bool,
    pub lateral_jitter: bool,
    pub envelope: bool,
    pub dwell_execution: bool,
}

impl Mechanisms {
    pub const ALL: Mechanisms = Mechanisms {
        normal_offset: true,
        lateral_jitter: true,
        envelope: true,
        dwell_execution: true,
    };
    pub const NONE: Mechanisms = Mechanisms {
        normal_offset: false,
        lateral_jitter: false,
        envelope: false,
        dwell_execution: false,
    };

    /// The names used in reports (and in `simulate`'s `mechanisms` array).
    pub const NAMES: [&'static str; 4] = [
        "normal_offset",
        "lateral_jitter",
        "envelope",
        "dwell_execution",
    ];

    pub fn is_on(&self, name: &str) -> bool {
        match name {
            "normal_offset" => self.normal_offset,
            "lateral_jitter" => self.lateral_jitter,
            "envelope" => self.envelope,
            "dwell_execution" => self.dwell_execution,
            _ => false,
        }
    }

    /// Only the named mechanism on.
    pub fn only(name: &str) -> Mechanisms {
        Mechanisms {
            normal_offset: name == "normal_offset",
            lateral_jitter: name == "lateral_jitter",
            envelope: name == "envelope",
            dwell_execution: name == "dwell_execution",
        }
    }
}

/// What the coupling needs from a run.
#[derive(Clone, Copy)]
pub struct CouplingInput<'a> {
    /// The map grid (the before map's).
    pub grid: Grid,
    /// Valid pixels of the map for the statistics (all valid when `None`).
    pub valid: Option<&'a Array2<bool>>,
    /// The tool at the nominal offset (process's TIF front end: its fast removal model and its
    /// continuous field).
    pub tool: &'a ToolModel,
    /// Commanded tool-centre path.
    pub path: &'a PathLog,
    pub params: &'a VibrationParams,
    /// Raster pitch for the ripple σ1 (Y), mm.
    pub pitch_mm: Option<f64>,
}

/// Options of a coupling run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CouplingOptions {
    pub mechanisms: Mechanisms,
    /// Sampling rate of the vibration along the path, Hz (at least 1 kHz recommended).
    pub sample_hz: f64,
    pub seed: u64,
    /// MSF band along Y, cycles/mm (upper edge clipped to Nyquist).
    pub msf_band_per_mm: (f64, f64),
}

impl Default for CouplingOptions {
    fn default() -> Self {
        CouplingOptions {
            mechanisms: Mechanisms::ALL,
            sample_hz: 1000.0,
            seed: 1,
            msf_band_per_mm: bonnetlab_spectrum::MSF_DEFAULT_PER_MM,
        }
    }
}

/// Removal maps (nm, map grid): the baseline (commanded path, no vibration) and each
/// mechanism's contribution; their sum is the predicted removal.
#[derive(Debug, Clone, PartialEq)]
pub struct MechanismMaps {
    pub baseline: Array2<f64>,
    pub normal_offset: Array2<f64>,
    pub lateral_jitter: Array2<f64>,
    pub envelope: Array2<f64>,
    pub dwell_execution: Array2<f64>,
    pub interaction: Array2<f64>,
}

impl MechanismMaps {
    pub fn by_name(&self, name: &str) -> Option<&Array2<f64>> {
        match name {
            "normal_offset" => Some(&self.normal_offset),
            "lateral_jitter" => Some(&self.lateral_jitter),
            "envelope" => Some(&self.envelope),
            "dwell_execution" => Some(&self.dwell_execution),
            "interaction" => Some(&self.interaction),
            _ => None,
        }
    }

    /// The predicted removal: baseline plus every contribution.
    pub fn total(&self) -> Array2<f64> {
        &self.baseline
            + &self.normal_offset
            + &self.lateral_jitter
            + &self.envelope
            + &self.dwell_execution
            + &self.interaction
    }

    /// The vibration- and execution-induced change (total − baseline).
    pub fn induced(&self) -> Array2<f64> {
        &self.normal_offset
            + &self.lateral_jitter
            + &self.envelope
            + &self.dwell_execution
            + &self.interaction
    }
}
