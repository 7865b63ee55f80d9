//! Wall-clock timing of one spectral workload on the synthetic map of benches/spectrum.rs (the
//! criterion bench is the reference; this is the Rust side of benches/peers/interleave.py,
//! which alternates it with the NumPy peer so both see the same machine load). Run:
//! `cargo run --release -p bonnetlab-spectrum --example time_psd -- 4096 3 metrology`
//! (N, repetitions, workload `psd_xy_ripple` or `metrology`). Prints one JSON line.

use std::f64::consts::PI;
use std::time::Instant;

use bonnetlab_spectrum::{psd_xy, ripple_from_psds, stats_psd_xy, PsdOptions, RippleOptions};
use bonnetlab_surface::{rng::Rng, Surface};
use ndarray::Array2;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(2048);
    let reps: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3).max(1);
    let workload = args.get(3).map_or("metrology", String::as_str);
    let d = 0.1;
    let mut rng = Rng::new(1);
    let z = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * d, i as f64 * d);
        10.0 * (2.0 * PI * y / 3.0).sin() + 0.3 * x - 0.2 * y + 2.0 * rng.normal()
    });
    let s = Surface::new(z, Some(d), Some(d)).expect("pixel size");
    let opts = PsdOptions::default();
    let ropts = RippleOptions::default();
    let mut runs = Vec::with_capacity(reps);
    let mut sigma1 = 0.0;
    for _ in 0..reps {
        let t = Instant::now();
        sigma1 = match workload {
            "psd_xy_ripple" => {
                let (x, y) = psd_xy(&s, &opts).expect("psd");
                ripple_from_psds(&x, &y, 3.0, &ropts)
                    .expect("ripple")
                    .sigma1_nm
            }
            "metrology" => {
                let (st, x, y) = stats_psd_xy(&s, &opts).expect("metrology");
                std::hint::black_box(st);
                ripple_from_psds(&x, &y, 3.0, &ropts)
                    .expect("ripple")
                    .sigma1_nm
            }
            other => {
                eprintln!("unknown workload '{other}' (psd_xy_ripple or metrology)");
                std::process::exit(2);
            }
        };
        runs.push(t.elapsed().as_secs_f64());
    }
    let list: Vec<String> = runs.iter().map(|t| format!("{t:.6}")).collect();
    println!(
        "{{\"name\": \"{workload}/{n}\", \"backend\": \"bonnetlab\", \"runs\": [{}], \"sigma1_nm\": {sigma1:.6}}}",
        list.join(", ")
    );
}
