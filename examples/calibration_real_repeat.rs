//! Calibration on a real instrument's repeatability (issue #15: "and on real measurements").
//!
//! The repeatability series `01_801B` (`../shared/data/real`), `02_801B` and `04_801B`
//! (`../shared/data/external`) are three measurements of one flat, 0.2457 mm pixels, a 97 mm
//! aperture, taken a minute or so apart with the part left in place. A run is built from two of
//! them: the before map is one measurement as read, the after map another less a removal that
//! the independent generator deposits exactly (`bonnetlab_calibrate::synth`: exact time-domain
//! deposition of the paper's precessing bonnet at 0.06 mm sub-steps, a raster over the whole
//! camera field, never calibrate's FFT model) on the same grid. Nothing else is added: the
//! measurement error of the run is the instrument's own (its pixel-scale noise, its smooth
//! drift and air between the two measurements, its real pixels). With nothing injected, every
//! accepted effect is a false positive; with an effect injected into the deposited removal, the
//! calibration should find it through the instrument's error.
//!
//! Run: `cargo run --release --example calibration_real_repeat [-- --seeds 2 --kinds null,rate_drift]
//! [--repeatability declared|none]]`. With `declared` (the default) every run declares the
//! instrument's repeatability as a lab would from this series (`[measurement]
//! repeatability_nm`): the quadratic mean over its three pairs of their difference's RMS, plane
//! removed; `none` runs as a recipe without the key.
//! Prints one line per run and a markdown table (reports/calibration.md keeps the measured one).
//! The data are read from `$BONNETLAB_SHARED_DATA`, else `../shared/data`; a missing file is an
//! error naming it (exit 2).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use bonnetlab::calibrate::run::{calibrate, Options};
use bonnetlab::calibrate::synth::{on_measured_maps, Injected, SynthConfig};
use bonnetlab::surface::form::{remove_terms, Term};
use bonnetlab::surface::stats::height_stats;
use bonnetlab::surface::Surface;

/// The series, in the order of measurement.
const SERIES: [&str; 3] = [
    "real/pyxsurf_01_801B.dat",
    "external/pyxsurf_02_801B.dat",
    "external/pyxsurf_04_801B.dat",
];

struct Args {
    seeds: u64,
    kinds: Vec<String>,
    pitches: Vec<f64>,
    declare_repeatability: bool,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        seeds: 1,
        kinds: vec!["null".into()],
        pitches: vec![2.0, 3.0],
        declare_repeatability: true,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        let mut val = || it.next().ok_or(format!("{k}: a value is needed"));
        match k.as_str() {
            "--seeds" => a.seeds = val()?.parse().map_err(|e| format!("--seeds: {e}"))?,
            "--kinds" => a.kinds = val()?.split(',').map(String::from).collect(),
            "--pitches" => {
                a.pitches = val()?
                    .split(',')
                    .map(|s| s.parse::<f64>().map_err(|e| format!("--pitches: {e}")))
                    .collect::<Result<_, _>>()?
            }
            "--repeatability" => {
                a.declare_repeatability = match val()?.as_str() {
                    "declared" => true,
                    "none" => false,
                    v => {
                        return Err(format!(
                            "--repeatability: \"declared\" or \"none\", got {v}"
                        ))
                    }
                }
            }
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.seeds == 0 || a.pitches.is_empty() {
        return Err("--seeds must be >= 1 and --pitches not empty".into());
    }
    Ok(a)
}

/// The injected effect of a kind (in the generator's terms), or an error for an unknown kind.
fn injected(kind: &str) -> Result<Vec<Injected>, String> {
    Ok(match kind {
        "null" => Vec::new(),
        "rate_drift" => vec![Injected::RateDrift {
            fraction_per_run: -0.2,
        }],
        "tif_scale" => vec![Injected::TifScale { scale: 1.1 }],
        other => {
            return Err(format!(
                "unknown kind {other} (null, rate_drift, tif_scale)"
            ))
        }
    })
}

/// RMS (nm) of `b - a` over the pixels valid in both, less its least-squares plane (the
/// surface crate's form removal and height statistics).
fn difference_rms(a: &Surface, b: &Surface) -> Option<f64> {
    let d = b.difference(a).ok()?;
    let (flat, _) = remove_terms(&d, &[Term::Piston, Term::Tilt]).ok()?;
    height_stats(&flat).ok().map(|h| h.rms_nm)
}

fn main() -> ExitCode {
    let a = match args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("calibration_real_repeat: {e}");
            return ExitCode::from(2);
        }
    };
    // The tests' convention: `$BONNETLAB_SHARED_DATA`, else `../shared/data` (a plain clone).
    let shared = PathBuf::from(
        std::env::var_os("BONNETLAB_SHARED_DATA").unwrap_or_else(|| "../shared/data".into()),
    );
    let mut maps = Vec::new();
    for name in SERIES {
        let p = shared.join(name);
        match bonnetlab::io::read_surface(&p) {
            Ok(s) => maps.push(s),
            Err(e) => {
                eprintln!("{}: {e}", p.display());
                return ExitCode::from(2);
            }
        }
    }
    let repeatability = if a.declare_repeatability {
        let pairs: Option<Vec<f64>> = [(0, 1), (0, 2), (1, 2)]
            .iter()
            .map(|&(i, j)| difference_rms(&maps[i], &maps[j]))
            .collect();
        let Some(pairs) = pairs else {
            eprintln!("calibration_real_repeat: the series' pair differences cannot be formed");
            return ExitCode::from(1);
        };
        let r = (pairs.iter().map(|v| v * v).sum::<f64>() / pairs.len() as f64).sqrt();
        println!("declared repeatability {r:.3} nm RMS (the series' three pairs: {pairs:.3?})");
        Some(r)
    } else {
        println!("no repeatability declared");
        None
    };
    let mut rows = Vec::new();
    for kind in &a.kinds {
        let effects = match injected(kind) {
            Ok(e) => e,
            Err(e) => {
                eprintln!("calibration_real_repeat: {e}");
                return ExitCode::from(2);
            }
        };
        for &pitch in &a.pitches {
            for seed in 1..=a.seeds {
                for (ib, ia) in [(0, 1), (1, 0), (0, 2), (2, 0), (1, 2), (2, 1)] {
                    match one_run(&maps, ib, ia, &effects, pitch, seed, repeatability) {
                        Ok(line) => {
                            println!("{kind} pitch {pitch} seed {seed}: {line}");
                            rows.push((kind.clone(), pitch, seed, line));
                        }
                        Err(e) => {
                            eprintln!("{kind} pitch {pitch} seed {seed} {ib}->{ia}: {e}");
                            return ExitCode::from(1);
                        }
                    }
                }
            }
        }
    }
    println!("\n| kind | pitch mm | seed | run |\n|---|---|---|---|");
    for (k, p, s, l) in rows {
        println!("| {k} | {p} | {s} | {l} |");
    }
    ExitCode::SUCCESS
}

/// One run: before = measurement `ib`, after = measurement `ia` less the deposited removal.
fn one_run(
    maps: &[Surface],
    ib: usize,
    ia: usize,
    effects: &[Injected],
    pitch: f64,
    seed: u64,
    repeatability_nm: Option<f64>,
) -> Result<String, String> {
    let (before, after) = (&maps[ib], &maps[ia]);
    let cfg = SynthConfig {
        effects: effects.to_vec(),
        ..SynthConfig::on_grid_of(before, seed, pitch).map_err(|e| e.to_string())?
    };
    let real = on_measured_maps(&cfg, before, after).map_err(|e| format!("generator: {e}"))?;
    let mut p = real.problem().map_err(|e| e.to_string())?;
    p.repeatability_nm = repeatability_nm;
    let t = Instant::now();
    let cal = calibrate(&p, &Options::default()).map_err(|e| e.to_string())?;
    let wall = t.elapsed().as_secs_f64();
    let nm = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.3}"));
    let pair = nm(difference_rms(before, after));
    let effects: Vec<String> = cal
        .effects
        .iter()
        .map(|e| {
            let nums: Vec<String> = e
                .params
                .iter()
                .filter_map(|(k, v)| v.as_f64().map(|x| format!("{k} {x:.4}")))
                .collect();
            format!("{} (z {:.1}; {})", e.kind, e.significance, nums.join(", "))
        })
        .collect();
    let process = nm(cal
        .final_
        .bands
        .iter()
        .find(|b| b.band == "process")
        .map(|b| b.rms_nm));
    // Rates the data find but the smooth check turns down (a rate or the instrument's drift).
    let rate_or_drift: Vec<String> = cal
        .unexplained
        .iter()
        .filter_map(|u| u.below_bar.as_ref())
        .filter_map(|b| {
            b.z_beyond_smooth
                .map(|zb| format!("{} (z {:.1}, {zb:.1} beyond)", b.key, b.heldout_z))
        })
        .collect();
    // The smooth checks of the rounds: the smooth structure against the drift bound.
    let checks: Vec<String> = cal
        .rounds
        .iter()
        .filter_map(|r| r.smooth_check)
        .map(|c| {
            format!(
                "{:.2} nm vs {} ({})",
                c.map_rms_nm,
                nm(c.drift_bound_nm),
                if c.applied { "applied" } else { "not applied" }
            )
        })
        .collect();
    Ok(format!(
        "{ib}->{ia}: pair differs by {pair} nm RMS (plane removed); floor {:.3} nm; baseline {:.3} -> final {:.3} nm (process band {process}); accepted [{}]; {} unexplained, rate or drift [{}]; smooth check [{}]; {wall:.1} s",
        cal.noise_floor_rms_nm,
        cal.baseline.residual_rms_nm,
        cal.final_.residual_rms_nm,
        effects.join(", "),
        cal.unexplained.len(),
        rate_or_drift.join(", "),
        checks.join(", ")
    ))
}
