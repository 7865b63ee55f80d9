//! Calibration speed (criterion): an 800 x 800 run (0.125 mm pixels, 100 mm part) with the
//! full candidate library and two undeclared effects (drift + misregistration), target
//! <= 20 s on 2 cores; and a 400 x 400 run. The run is generated once (exact deposition, not
//! timed); the timed part is `Problem::new` (path densification, covariates, FFT plans) plus
//! `calibrate`. Results: reports/performance_calibrate.md.
//!
//! `cargo bench --bench calibrate`
//!
//! One run without criterion (for profiling and side-by-side CPU comparisons):
//! `BONNETLAB_CALIBRATE_ONCE=800 target/release/deps/calibrate-<hash>` generates the 800 x 800
//! run, calibrates it once, prints the CPU time (all threads, s) and wall time of the timed part
//! and writes the calibration's JSON to the file named by `BONNETLAB_CALIBRATE_JSON` if set.
//! `BONNETLAB_CALIBRATE_PIXELS=area` reads the maps' and the spot's pixels as area means (the
//! recipe's `[measurement] pixels`); the criterion group times that too at 800 x 800, on the
//! same (point-sampled) run: a timing of the area reading, not a test of it.

use bonnetlab::calibrate::run::{calibrate, Options};
use bonnetlab::calibrate::synth::{generate, SynthConfig, SynthRun};
use bonnetlab::process::pixel::PixelSampling;
use criterion::{criterion_group, Criterion};

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
                let p = run.problem().expect("problem");
                let cal = calibrate(&p, &Options::default()).expect("calibration");
                assert_eq!(cal.effects.len(), 2);
                cal
            })
        });
        if n == 800 {
            g.bench_function(format!("{n}x{n}_full_library_area_pixels"), |b| {
                b.iter(|| {
                    let p = run.problem_seen(PixelSampling::Area).expect("problem");
                    calibrate(&p, &Options::default()).expect("calibration")
                })
            });
        }
    }
    g.finish();
}

/// CPU time of this process so far (user + system, all threads, s; NaN where unknown).
fn cpu_s() -> f64 {
    bonnetlab_process::usage::cpu_seconds().unwrap_or(f64::NAN)
}

fn once(n: usize) {
    let run = make(n);
    let pixels = std::env::var("BONNETLAB_CALIBRATE_PIXELS")
        .ok()
        .and_then(|v| PixelSampling::from_name(&v))
        .unwrap_or_default();
    let (c0, t0) = (cpu_s(), std::time::Instant::now());
    let p = run.problem_seen(pixels).expect("problem");
    let cal = calibrate(&p, &Options::default()).expect("calibration");
    let (cpu, wall) = (cpu_s() - c0, t0.elapsed().as_secs_f64());
    println!(
        "{n}x{n} ({} pixels): cpu {cpu:.2} s, wall {wall:.2} s, effects {:?}",
        pixels.name(),
        cal.effects
            .iter()
            .map(|e| e.kind.as_str())
            .collect::<Vec<_>>()
    );
    if let Ok(out) = std::env::var("BONNETLAB_CALIBRATE_JSON") {
        let json = serde_json::to_string_pretty(&cal).expect("json");
        std::fs::write(out, json).expect("write json");
    }
}

criterion_group!(benches, bench);

fn main() {
    // As the command line does (see bonnetlab_process::memory).
    bonnetlab_process::memory::retain_freed_memory();
    if let Some(n) = std::env::var("BONNETLAB_CALIBRATE_ONCE")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
    {
        once(n);
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}
