//! Registration of textured maps (issue #15): power-law textures down to and above the pixel
//! scale (the truth grid twice as fine as the map, so the two maps alias the texture at
//! different sub-pixel phases), square and round apertures, dropouts, unequal white noise, the
//! after map made by exact time-domain deposition (`synth`, never calibrate's forward model).
//! Truth is the generator's misregistration.
//!
//! The 1 px-smoothed estimating equation is biased by texture that does not resample
//! identically; the estimate is extrapolated to no smoothing (`uncertainty::
//! registration_texture_step`). Without it the shift errors below are 2.5 times larger and the
//! rotation's 1.4 times, and the intervals, which then carried the bias as a systematic term,
//! covered every parameter of every case.

mod common;

use bonnetlab_calibrate::synth::{InitialSurface, Injected, SynthConfig};
use common::{alternate, run};

struct Case {
    r: u64,
    exponent: f64,
    reg: [f64; 3],
}

const CASES: [Case; 6] = [
    Case {
        r: 1,
        exponent: 1.8,
        reg: [0.2, -0.12, 0.05],
    },
    Case {
        r: 2,
        exponent: 2.2,
        reg: [-0.25, 0.07, -0.08],
    },
    Case {
        r: 3,
        exponent: 2.6,
        reg: [0.11, 0.28, 0.1],
    },
    Case {
        r: 4,
        exponent: 2.0,
        reg: [-0.3, -0.2, 0.03],
    },
    Case {
        r: 5,
        exponent: 2.4,
        reg: [0.05, -0.3, -0.1],
    },
    Case {
        r: 6,
        exponent: 1.9,
        reg: [0.27, 0.15, 0.07],
    },
];

/// Per case and parameter (dx mm, dy mm, rotation deg): estimate - truth, and the reported
/// 1-sigma.
fn errors() -> Vec<[(f64, f64); 3]> {
    CASES
        .iter()
        .map(|c| {
            let base = SynthConfig::realistic(
                90 + c.r,
                300,
                100.0,
                InitialSurface::realistic_texture(c.exponent),
            )
            .with_noise_nm(0.6 + 0.2 * c.r as f64, 1.5);
            let cfg = SynthConfig {
                truth_oversample: 2,
                effects: vec![Injected::Registration {
                    dx_mm: c.reg[0],
                    dy_mm: c.reg[1],
                    rotation_deg: c.reg[2],
                }],
                ..alternate(base, c.r, 90.0)
            };
            let (cal, _) = run(&cfg);
            let e = cal
                .effects
                .iter()
                .find(|e| e.kind == "registration")
                .unwrap_or_else(|| panic!("case {}: no registration accepted", c.r));
            let names = ["dx_mm", "dy_mm", "rotation_deg"];
            let out = [0, 1, 2].map(|i| {
                let est = e.params[names[i]].as_f64().expect("numeric parameter");
                let sig = e.uncertainties[names[i]].as_f64().expect("numeric sigma");
                (est - c.reg[i], sig)
            });
            eprintln!(
                "case {} (exponent {}): errors {:+.5} mm, {:+.5} mm, {:+.5} deg; sigma {:.5}, {:.5}, {:.5}",
                c.r, c.exponent, out[0].0, out[1].0, out[2].0, out[0].1, out[1].1, out[2].1
            );
            out
        })
        .collect()
}

#[test]
fn textured_registration_is_unbiased_and_its_intervals_are_honest() {
    let errs = errors();
    let n = errs.len() as f64;
    let rms = |i: usize| (errs.iter().map(|e| e[i].0.powi(2)).sum::<f64>() / n).sqrt();
    let (rx, ry, rr) = (rms(0), rms(1), rms(2));
    eprintln!("rms errors: {rx:.5} mm, {ry:.5} mm, {rr:.5} deg");
    // Issue 15 asks 0.05 mm and 0.03 deg; these bounds are what the bias correction reaches.
    // Measured: 0.00188 / 0.00058 mm and 0.00189 deg; without it 0.00359 / 0.00353 mm and
    // 0.00271 deg, with every one of the 18 intervals covering (a pixel is 0.333 mm).
    assert!(
        rx.hypot(ry) < BOUND_SHIFT_MM,
        "shift rms {rx:.5}, {ry:.5} mm"
    );
    assert!(rr < BOUND_ROT_DEG, "rotation rms {rr:.5} deg");
    // The intervals are neither blind to the error nor a bound on it: no parameter off by more
    // than 4 sigma, and not every one inside 1 sigma.
    let z: Vec<f64> = errs
        .iter()
        .flat_map(|e| e.iter().map(|(d, s)| d / s))
        .collect();
    let covered = z.iter().filter(|v| v.abs() <= 1.0).count();
    eprintln!("z: {z:.2?}; covered {covered} of {}", z.len());
    assert!(z.iter().all(|v| v.abs() < 4.0), "z {z:.2?}");
    assert!(covered < z.len(), "every interval covers: {z:.2?}");
}

const BOUND_SHIFT_MM: f64 = 3.0e-3;
const BOUND_ROT_DEG: f64 = 2.3e-3;
