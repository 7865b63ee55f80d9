//! Shared set-up of the calibrate crate's realistic-run tests: a series of realistic textured
//! runs ([`SynthConfig::realistic`]) that alternate pitch, aperture and dropouts, and the
//! calibration of a generated run against its true noise floor.

// Each test file includes the whole module and uses only part of it.
#![allow(dead_code)]

use bonnetlab_calibrate::run::{calibrate, Calibration, Options};
use bonnetlab_calibrate::synth::{generate, SynthConfig};

/// Run `r` of a series: `cfg` with a 2 mm pitch, the whole map and 3 circular dropouts on even
/// `r`; a 3 mm pitch, a round aperture `round_mm` across and 4 circular dropouts on odd `r`.
pub fn alternate(cfg: SynthConfig, r: u64, round_mm: f64) -> SynthConfig {
    SynthConfig {
        pitch_mm: if r.is_multiple_of(2) { 2.0 } else { 3.0 },
        dropout_discs: 3 + r as usize % 2,
        ..cfg.with_round_aperture(!r.is_multiple_of(2), round_mm)
    }
}

/// The calibration of the run generated from `cfg` (given the measured spot) and the true
/// white-noise floor of before - after (nm).
pub fn run(cfg: &SynthConfig) -> (Calibration, f64) {
    let run = generate(cfg).expect("generate");
    let p = run.problem().expect("problem");
    (
        calibrate(&p, &Options::default()).expect("calibrate"),
        run.true_noise_floor_nm,
    )
}
