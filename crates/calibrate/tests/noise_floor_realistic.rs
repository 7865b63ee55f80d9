//! The noise floor and the null behaviour of the calibration on realistic measurements (issue
//! #15): initial surfaces with a power-law PSD down to the pixel scale (140 nm RMS, so each map
//! alone shows tens of nm of pixel-scale texture), round apertures, circular dropouts in the
//! after map, different white noise in each map, an off-centre measured spot, the after map
//! made by exact time-domain deposition (`synth`, never calibrate's FFT model). The truth of the
//! floor is the two maps' white noise in quadrature.

mod common;

use bonnetlab_calibrate::synth::{InitialSurface, Injected, SynthConfig};
use common::{alternate, run};

/// A 70 mm part on a 200 x 200 map (0.35 mm pixels): power-law surface, round aperture on odd
/// `r`, 3-4 circular dropouts, noise `nb` / `na` nm.
fn scenario(r: u64, exponent: f64, nb: f64, na: f64, effects: Vec<Injected>) -> SynthConfig {
    let base = SynthConfig::realistic(
        40 + r,
        200,
        70.0,
        InitialSurface::realistic_texture(exponent),
    )
    .with_noise_nm(nb, na);
    SynthConfig {
        deposit_step_mm: 0.08,
        effects,
        ..alternate(base, r, 63.0)
    }
}

/// Null runs (nothing injected): the reported floor is within 15 % of the truth (each map
/// alone would give several times it), no effect is accepted, and the final residual is at the
/// floor.
#[test]
fn null_runs_on_textured_surfaces_report_the_true_floor_and_accept_nothing() {
    let cases = [(0, 2.2, 1.0, 0.7), (1, 1.8, 0.5, 1.6), (2, 2.6, 1.8, 1.2)];
    for (r, beta, nb, na) in cases {
        let (c, truth) = run(&scenario(r, beta, nb, na, Vec::new()));
        let ratio = c.noise_floor_rms_nm / truth;
        assert!(
            (ratio - 1.0).abs() <= 0.15,
            "run {r}: floor {:.3} nm vs true {truth:.3} nm",
            c.noise_floor_rms_nm
        );
        assert!(
            c.effects.is_empty(),
            "run {r}: null run accepted {:?}",
            c.effects.iter().map(|e| &e.kind).collect::<Vec<_>>()
        );
        assert!(
            c.final_.residual_rms_nm <= 1.1 * truth,
            "run {r}: final {:.3} nm vs floor {truth:.3} nm",
            c.final_.residual_rms_nm
        );
    }
}
