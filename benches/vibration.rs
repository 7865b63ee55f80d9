//! Benchmarks (criterion) for the vibration capability; numbers in
//! reports/performance_vibration.md.
//!
//! - `coupling_100mm_60min_1khz`: the fast coupling (all four mechanisms, one bonnet) on a
//!   100 x 100 mm map at 0.1 mm (1001 x 1001), a 60-minute bidirectional raster (3 mm pitch,
//!   10 mm overtravel, 1.16 mm/s), vibration sampled at 1 kHz (3.6 million samples).
//!   Target: <= 2 s.
//! - `forced_response` and `frf_spindle_band`: the closed form.
//!
//! Run: `cargo bench --bench vibration` (add `-- coupling` for the first only).

use bonnetlab_vibration::coupling::{fast_maps, CouplingCase, CouplingOptions};
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use bonnetlab_vibration::response::{forced_response, spindle_band_frf};
use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use std::time::Duration;

fn coupling(c: &mut Criterion) {
    let case = CouplingCase::bench_100mm().expect("bench case");
    let (path, input) = (&case.path, case.input());
    let opts = CouplingOptions::default();
    eprintln!(
        "path duration {:.1} min, {} log samples",
        path.duration_s() / 60.0,
        path.len()
    );
    let mut g = c.benchmark_group("vibration");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(20))
        .warm_up_time(Duration::from_secs(1));
    g.bench_function("coupling_100mm_60min_1khz", |b| {
        b.iter(|| black_box(fast_maps(&input, Bonnet::Original, &opts).expect("coupling")))
    });
    g.finish();
}

fn closed_form(c: &mut Criterion) {
    let p = VibrationParams::default();
    c.bench_function("forced_response", |b| {
        b.iter(|| black_box(forced_response(&p, Bonnet::Suppression, black_box(1000.0))))
    });
    c.bench_function("frf_spindle_band", |b| {
        b.iter(|| black_box(spindle_band_frf(&p, Bonnet::Original)))
    });
}

criterion_group!(benches, coupling, closed_form);
criterion_main!(benches);
