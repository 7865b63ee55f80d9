//! The calibration on the project's own synthetic suite (the runs of tests/calibrate_*.rs): one
//! row per run with what was injected, what was accepted, the final residual over the noise
//! floor and the wall time, as a Markdown table on stdout.
//!
//!     cargo run --release -p bonnetlab-calibrate --example synthetic_suite
//!     cargo run --release -p bonnetlab-calibrate --example synthetic_suite -- "null"   (only the
//!     runs whose name contains "null")
//!
//! `cpu (s)` is the process's user + system time over the calibration (all threads, from
//! /proc/self/stat at 100 ticks per second; empty where it cannot be read): on a shared
//! machine it varies much less with the load than the wall time.
//!
//! Used for the before/after table of reports/calibration_model.md (the same command on two
//! commits).

use std::time::Instant;

use bonnetlab_calibrate::run::{calibrate, Options};
use bonnetlab_calibrate::synth::{generate, Injected, SynthConfig};

fn case(
    name: &str,
    seed: u64,
    effects: Vec<Injected>,
    f: impl Fn(&mut SynthConfig),
) -> (String, SynthConfig) {
    let mut c = SynthConfig {
        seed,
        effects,
        ..SynthConfig::default()
    };
    f(&mut c);
    (name.to_string(), c)
}

fn main() {
    // As the command line does (see bonnetlab_process::memory).
    bonnetlab_process::memory::retain_freed_memory();
    let none = |_: &mut SynthConfig| {};
    let cases = vec![
        case("null", 21, vec![], none),
        case("null", 22, vec![], none),
        case("null, spot 0.25 mm off", 23, vec![], |c| {
            c.spot_offset_mm = (0.25, -0.15)
        }),
        case("null, spot 0.8 mm off", 23, vec![], |c| {
            c.spot_offset_mm = (0.8, -0.48)
        }),
        case("null, noise-free", 24, vec![], |c| {
            c.noise_nm = 0.0;
            c.spot_noise_nm = 0.0
        }),
        case("null, noise-free, spot 0.8 mm off", 24, vec![], |c| {
            c.noise_nm = 0.0;
            c.spot_noise_nm = 0.0;
            c.spot_offset_mm = (0.8, -0.48)
        }),
        case(
            "registration (0.35, -0.2) mm 0.15 deg",
            11,
            vec![Injected::Registration {
                dx_mm: 0.35,
                dy_mm: -0.2,
                rotation_deg: 0.15,
            }],
            none,
        ),
        case(
            "rate drift -25 %",
            12,
            vec![Injected::RateDrift {
                fraction_per_run: -0.25,
            }],
            none,
        ),
        case(
            "tif scale 1.12",
            13,
            vec![Injected::TifScale { scale: 1.12 }],
            none,
        ),
        case(
            "direction lag 0.5 mm",
            14,
            vec![Injected::DirectionLag { lag_mm: 0.5 }],
            none,
        ),
        case(
            "periodic path error y 0.3 mm / 12 mm",
            15,
            vec![Injected::reference_wiggle()],
            none,
        ),
        case(
            "path offset (0.3, -0.2) mm",
            16,
            vec![Injected::PathOffset {
                dx_mm: 0.3,
                dy_mm: -0.2,
            }],
            none,
        ),
    ];
    println!("| run | seed | accepted | final residual (nm) | noise floor (nm) | residual / floor | wall (s) | cpu (s) |");
    println!("|---|---|---|---|---|---|---|---|");
    // An optional argument keeps only the runs whose name contains it (for profiling one run).
    let only = std::env::args().nth(1);
    for (name, cfg) in cases {
        if only.as_ref().is_some_and(|o| !name.contains(o.as_str())) {
            continue;
        }
        let run = match generate(&cfg) {
            Ok(r) => r,
            Err(e) => {
                println!(
                    "| {name} | {} | generation failed: {e} | | | | | |",
                    cfg.seed
                );
                continue;
            }
        };
        let c0 = bonnetlab_process::usage::cpu_seconds();
        let t = Instant::now();
        let out = run
            .problem()
            .and_then(|p| calibrate(&p, &Options::default()));
        let wall = t.elapsed().as_secs_f64();
        let cpu = match (c0, bonnetlab_process::usage::cpu_seconds()) {
            (Some(a), Some(b)) => format!("{:.2}", b - a),
            _ => String::new(),
        };
        match out {
            Ok(c) => {
                let acc: Vec<String> = c
                    .effects
                    .iter()
                    .map(|e| {
                        let ps: Vec<String> = e
                            .params
                            .iter()
                            .filter_map(|(k, v)| v.as_f64().map(|x| format!("{k} {x:.4}")))
                            .collect();
                        format!("{} ({})", e.kind, ps.join(", "))
                    })
                    .collect();
                println!(
                    "| {name} | {} | {} | {:.4} | {:.4} | {:.2} | {wall:.2} | {cpu} |",
                    cfg.seed,
                    if acc.is_empty() {
                        "none".to_string()
                    } else {
                        acc.join("; ")
                    },
                    c.final_.residual_rms_nm,
                    c.noise_floor_rms_nm,
                    c.final_.residual_rms_nm / c.noise_floor_rms_nm.max(1e-12)
                );
            }
            Err(e) => println!(
                "| {name} | {} | calibration failed: {e} | | | | {wall:.2} | {cpu} |",
                cfg.seed
            ),
        }
    }
}
