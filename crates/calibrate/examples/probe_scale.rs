//! Developer probe: residual RMS of the model at fixed TIF scales on a run made with scale 1.12.
use bonnetlab_calibrate::effects::tif_scale::TifScale;
use bonnetlab_calibrate::model::{evaluate, fit, Effect, Problem};
use bonnetlab_calibrate::synth::{generate, Injected, SynthConfig};
use bonnetlab_calibrate::tif::TifMap;

fn main() {
    let cfg = SynthConfig {
        effects: vec![Injected::TifScale { scale: 1.12 }],
        seed: 11,
        noise_nm: 0.0,
        spot_noise_nm: 0.0,
        ..SynthConfig::default()
    };
    let run = generate(&cfg).unwrap();
    let tif = TifMap::from_spot(&run.spot, run.spot_dwell_s).unwrap();
    let p = Problem::new(&run.before, &run.after, &tif, &run.path).unwrap();
    for s in [1.0, 1.08, 1.10, 1.12, 1.14, 1.16, 1.2] {
        let e: Vec<Box<dyn Effect>> = vec![Box::new(TifScale { scale: s })];
        let ev = evaluate(&p, &e, None);
        let f = fit(&ev, &[]).unwrap();
        println!("scale {s}: rms {:.4} coef0 {:.4}", f.rms(), f.coef[0]);
    }
}
