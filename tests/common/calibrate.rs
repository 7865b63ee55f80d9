//! Shared set-up of the calibration tests: generate a synthetic run (exact time-domain
//! deposition, independent of the calibration's FFT model), write it as a run directory, load
//! and calibrate it through the pipeline the CLI calls (`bonnetlab::pipeline::calibrate`), and
//! describe the outcome for assertion messages.

// Each test file includes the whole module and uses only part of it.
#![allow(dead_code)]

use bonnetlab::calibrate::run::{Calibration, Options};
use bonnetlab::calibrate::synth::write::write_run;
use bonnetlab::calibrate::synth::{generate, Injected, SynthConfig};
use bonnetlab::pipeline::calibrate::{calibrate, load};

/// Calibrates a default-size run with these undeclared effects.
pub fn run(effects: Vec<Injected>, seed: u64) -> Calibration {
    run_cfg(&SynthConfig {
        effects,
        seed,
        ..SynthConfig::default()
    })
}

/// Calibrates a run generated from `cfg`.
pub fn run_cfg(cfg: &SynthConfig) -> Calibration {
    let run = generate(cfg).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_run(dir.path(), &run).unwrap();
    let p = load(&recipe).unwrap_or_else(|e| panic!("{}", e.message));
    calibrate(&recipe, &p, &Options::default()).unwrap_or_else(|e| panic!("{}", e.message))
}

/// A numeric parameter of the first accepted effect of `kind` (panics with the summary if
/// there is none).
pub fn param(c: &Calibration, kind: &str, name: &str) -> f64 {
    c.effects
        .iter()
        .find(|e| e.kind == kind)
        .unwrap_or_else(|| panic!("{kind} not found: {}", summary(c)))
        .params[name]
        .as_f64()
        .unwrap()
}

/// Effects, unexplained entries and residuals, for assertion messages.
pub fn summary(c: &Calibration) -> String {
    let k: Vec<String> = c
        .effects
        .iter()
        .map(|e| format!("{} {:?}", e.kind, e.params))
        .collect();
    let u: Vec<&str> = c
        .unexplained
        .iter()
        .map(|u| u.description.as_str())
        .collect();
    format!(
        "effects {k:?}, unexplained {u:?}, baseline {:.3} nm, final {:.3} nm, floor {:.3} nm",
        c.baseline.residual_rms_nm, c.final_.residual_rms_nm, c.noise_floor_rms_nm
    )
}
