//! The noise floor and the null behaviour of the calibration on realistic measurements (issue
//! #15): initial surfaces with a power-law PSD down to the pixel scale (140 nm RMS, so each map
//! alone shows tens of nm of pixel-scale texture), round apertures, circular dropouts in the
//! after map, different white noise in each map, an off-centre measured spot, the after map
//! made by exact time-domain deposition (`synth`, never calibrate's FFT model). The truth of the
//! floor is the two maps' white noise in quadrature.

use bonnetlab_calibrate::pipeline::problem_with_spot;
use bonnetlab_calibrate::run::{calibrate, Calibration, Options};
use bonnetlab_calibrate::synth::true_tif::TrueTif;
use bonnetlab_calibrate::synth::{generate, InitialSurface, Injected, SynthConfig};

/// A 70 mm part on a 200 x 200 map (0.35 mm pixels): power-law surface, round aperture on odd
/// `r`, 3-4 circular dropouts, noise `nb` / `na` nm.
fn scenario(r: u64, exponent: f64, nb: f64, na: f64, effects: Vec<Injected>) -> SynthConfig {
    let n = 200;
    let d = 70.0 / n as f64;
    SynthConfig {
        seed: 40 + r,
        rows: n,
        cols: n,
        pixel_mm: d,
        surface: InitialSurface::PowerLaw {
            exponent,
            rms_nm: 140.0,
        },
        truth_oversample: 2,
        tif: TrueTif::bonnet(800.0),
        pitch_mm: if r.is_multiple_of(2) { 2.0 } else { 3.0 },
        feed_min_mm_per_s: 2.0,
        feed_max_mm_per_s: 12.0,
        sample_hz: 10.0,
        deposit_step_mm: 0.08,
        spot_dwell_s: 20.0,
        spot_noise_nm: 0.5,
        spot_pixel_mm: None,
        spot_offset_mm: (0.15, -0.2),
        noise_nm: nb,
        noise_after_nm: Some(na),
        dropout_fraction: 0.001,
        dropout_discs: 3 + r as usize % 2,
        dropout_disc_radius_mm: (0.5, 2.0),
        setup_tilt_nm: 15.0,
        setup_piston_nm: 7.0,
        aperture_diameter_mm: (!r.is_multiple_of(2)).then_some(63.0),
        effects,
    }
}

fn run(cfg: &SynthConfig) -> (Calibration, f64) {
    let run = generate(cfg).expect("generate");
    let p = problem_with_spot(
        &run.before,
        &run.after,
        &run.spot,
        run.spot_dwell_s,
        &run.path,
    )
    .expect("problem");
    (
        calibrate(&p, &Options::default()).expect("calibrate"),
        run.true_noise_floor_nm,
    )
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
