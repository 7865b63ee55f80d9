//! Shared set-up of the calibration tests: generate a synthetic run (exact time-domain
//! deposition, independent of the calibration's FFT model), calibrate it, and describe the
//! outcome for assertion messages.

use bonnetlab::calibrate::run::{calibrate, Calibration, Options};
use bonnetlab::calibrate::synth::{generate, Injected, SynthConfig};

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
    let p = bonnetlab::calibrate::pipeline::problem_with_spot(
        &run.before,
        &run.after,
        &run.spot,
        run.spot_dwell_s,
        &run.path,
    )
    .unwrap();
    calibrate(&p, &Options::default()).unwrap()
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
