//! Calibration speed (criterion): an 800 x 800 run (0.125 mm pixels, 100 mm part) with the
//! full candidate library and two undeclared effects (drift + misregistration), target
//! <= 20 s on 2 cores; and a 400 x 400 run. The run is generated once (exact deposition, not
//! timed); the timed part is `Problem::new` (path densification, covariates, FFT plans) plus
//! `calibrate`. Results: reports/performance_calibrate.md.
//!
//! `cargo bench --bench calibrate`

use bonnetlab::calibrate::run::{calibrate, Options};
use bonnetlab::calibrate::synth::{generate, SynthConfig, SynthRun};
use criterion::{criterion_group, criterion_main, Criterion};

fn make(n: usize) -> SynthRun {
    generate(&SynthConfig::reference_large_run(n)).expect("synthetic run")
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("calibrate");
    g.sample_size(10);
    for n in [400usize, 800] {
        let run = make(n);
        g.bench_function(format!("{n}x{n}_full_library"), |b| {
            b.iter(|| {
                let p = bonnetlab::calibrate::pipeline::problem_with_spot(
                    &run.before,
                    &run.after,
                    &run.spot,
                    run.spot_dwell_s,
                    &run.path,
                )
                .expect("problem");
                let cal = calibrate(&p, &Options::default()).expect("calibration");
                assert_eq!(cal.effects.len(), 2);
                cal
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
