//! CPU and wall time per fast coupling on the bench case (`benches/vibration.rs`, 1001^2 at
//! 0.1 mm, 60-min raster, 1 kHz), `n` calls (default 8) after one warm-up call:
//!
//!     cargo run --release -p bonnetlab-vibration --example coupling_cpu -- 8
//!
//! CPU is the process's user + system time (all threads, /proc/self/stat, 100 ticks per
//! second): on a shared machine it varies much less with the load than the wall time, and it
//! counts the work on every thread. Used for the before/after rows of reports/performance.md.

use bonnetlab_vibration::coupling::{fast_maps, CouplingCase, CouplingOptions};
use bonnetlab_vibration::params::Bonnet;
use std::time::Instant;

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(8);
    let case = CouplingCase::bench_100mm().expect("bench case");
    let input = case.input();
    let opts = CouplingOptions::default();
    let _ = fast_maps(&input, Bonnet::Original, &opts).expect("coupling");
    let (c0, t0) = (bonnetlab_process::usage::cpu_seconds(), Instant::now());
    for _ in 0..n {
        std::hint::black_box(fast_maps(&input, Bonnet::Original, &opts).expect("coupling"));
    }
    let wall = t0.elapsed().as_secs_f64() / n as f64;
    match (c0, bonnetlab_process::usage::cpu_seconds()) {
        (Some(a), Some(b)) => println!(
            "per call: cpu {:.3} s, wall {:.3} s ({n} calls)",
            (b - a) / n as f64,
            wall
        ),
        _ => println!("per call: wall {wall:.3} s ({n} calls)"),
    }
}
