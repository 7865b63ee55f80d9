//! Developer probe: one timed calibration of an N x N run (default 800), with phase timings.
//! `cargo run --release -p bonnetlab-calibrate --example time_800 -- 800`
use bonnetlab_calibrate::model::Problem;
use bonnetlab_calibrate::run::{calibrate, Options};
use bonnetlab_calibrate::synth::{generate, Injected, SynthConfig};
use bonnetlab_calibrate::tif::TifMap;

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(800);
    let cfg = SynthConfig {
        rows: n,
        cols: n,
        pixel_mm: 100.0 / n as f64,
        deposit_step_mm: 0.2,
        seed: 5,
        effects: vec![
            Injected::RateDrift {
                fraction_per_run: -0.2,
            },
            Injected::Registration {
                dx_mm: 0.2,
                dy_mm: -0.15,
                rotation_deg: 0.05,
            },
        ],
        ..SynthConfig::default()
    };
    let t = std::time::Instant::now();
    let run = generate(&cfg).unwrap();
    eprintln!("generate {:?}", t.elapsed());
    let t = std::time::Instant::now();
    let tif = TifMap::from_spot(&run.spot, run.spot_dwell_s).unwrap();
    let p = Problem::new(&run.before, &run.after, &tif, &run.path).unwrap();
    eprintln!("problem {:?}", t.elapsed());
    let c = calibrate(&p, &Options::default()).unwrap();
    eprintln!("calibrate total {:?}", t.elapsed());
    for e in &c.effects {
        eprintln!(
            "{} {:?} {:.3}->{:.3}",
            e.kind, e.params, e.residual_rms_before_nm, e.residual_rms_after_nm
        );
    }
    eprintln!(
        "baseline {:.3} final {:.3} floor {:.3}",
        c.baseline.residual_rms_nm, c.final_.residual_rms_nm, c.noise_floor_rms_nm
    );
}
