//! Developer probe: generate a run with one injected effect (by name) and calibrate it.
//! `cargo run --release -p bonnetlab-calibrate --example try_effect -- drift [N]`
//! N: an N x N map of a 100 mm part (default: the 160 x 180 test run). Environment: SEED,
//! REALISTIC (with N: `SynthConfig::realistic`, power-law texture 2.2), PITCH (mm), LAG (mm),
//! CLEAN (no map or spot noise, no dropouts, a centred spot), NOISE (nm), APERTURE (disc diameter, mm), SAMPLE_HZ (path log rate), WRITE (also write the run
//! directory there, for the CLI), BONNETLAB_TRACE (timings per round). Prints the
//! effects found, each round's best candidates and the timings to stderr, the JSON to stdout.
use bonnetlab_calibrate::run::{calibrate, Options};
use bonnetlab_calibrate::synth::{generate, Injected, SynthConfig, Waveform, WiggleCoord};

fn main() {
    let which = std::env::args().nth(1).unwrap_or_else(|| "none".into());
    let eff = match which.as_str() {
        "none" => vec![],
        "reg" => vec![Injected::Registration {
            dx_mm: 0.35,
            dy_mm: -0.2,
            rotation_deg: 0.15,
        }],
        "drift" => vec![Injected::RateDrift {
            fraction_per_run: -0.25,
        }],
        "scale" => vec![Injected::TifScale { scale: 1.12 }],
        "lag" => vec![Injected::DirectionLag {
            lag_mm: std::env::var("LAG")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(0.4),
        }],
        "wiggle" => vec![Injected::reference_wiggle()],
        "cov" => vec![Injected::RateCovariate {
            covariate: "height".into(),
            coefficient: 0.004,
        }],
        "osc" => vec![Injected::RateOscillation {
            amplitude_fraction: 0.15,
            period_s: 300.0,
        }],
        "noise" => vec![],
        "three" => vec![
            Injected::RateDrift {
                fraction_per_run: -0.15,
            },
            Injected::DirectionLag { lag_mm: 0.3 },
            Injected::Registration {
                dx_mm: 0.25,
                dy_mm: 0.1,
                rotation_deg: -0.08,
            },
        ],
        "bigreg" => vec![Injected::Registration {
            dx_mm: 1.3,
            dy_mm: -0.9,
            rotation_deg: 0.4,
        }],
        "bench" => SynthConfig::reference_large_run(800).effects,
        "step" => vec![Injected::RateStep {
            at_tau: 0.4,
            fraction: 0.2,
        }],
        "defect" => vec![Injected::LocalDefect {
            x_mm: 30.0,
            y_mm: 50.0,
            radius_mm: 2.0,
            depth_nm: 6.0,
        }],
        "tri" => vec![Injected::PeriodicPathError {
            axis_x: true,
            amplitude_mm: 0.3,
            period_mm: 15.0,
            phase_rad: 0.0,
            coord: WiggleCoord::Arc,
            waveform: Waveform::Triangle,
        }],
        "two" => vec![
            Injected::RateDrift {
                fraction_per_run: 0.2,
            },
            Injected::Registration {
                dx_mm: -0.3,
                dy_mm: 0.25,
                rotation_deg: 0.0,
            },
        ],
        _ => panic!("unknown"),
    };
    let seed = std::env::var("SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(11);
    let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f64>().ok());
    let n_arg = std::env::args()
        .nth(2)
        .and_then(|s| s.parse::<usize>().ok());
    let mut cfg = match (std::env::var("REALISTIC").is_ok(), n_arg) {
        (true, Some(n)) => SynthConfig::realistic(
            seed,
            n,
            100.0,
            bonnetlab_calibrate::synth::InitialSurface::realistic_texture(2.2),
        ),
        _ => SynthConfig::default(),
    };
    cfg.effects = eff;
    cfg.seed = seed;
    cfg.aperture_diameter_mm = env("APERTURE");
    if let Some(p) = env("PITCH") {
        cfg.pitch_mm = p;
    }
    if std::env::var("CLEAN").is_ok() {
        (cfg.noise_nm, cfg.noise_after_nm, cfg.spot_noise_nm) = (0.0, Some(0.0), 0.0);
        cfg.spot_offset_mm = (0.0, 0.0);
        (cfg.dropout_fraction, cfg.dropout_discs) = (0.0, 0);
    }
    if let Some(n) = env("NOISE") {
        cfg.noise_nm = n;
    }
    if let Some(hz) = env("SAMPLE_HZ") {
        cfg.sample_hz = hz;
    }
    if let Some(n) = n_arg.filter(|_| std::env::var("REALISTIC").is_err()) {
        (cfg.rows, cfg.cols, cfg.pixel_mm, cfg.deposit_step_mm) = (n, n, 100.0 / n as f64, 0.2);
    }
    let t = std::time::Instant::now();
    let run = generate(&cfg).unwrap();
    eprintln!(
        "generate {:?}, path {} samples, duration {:.0}s",
        t.elapsed(),
        run.path.len(),
        run.path.duration_s()
    );
    if let Ok(dir) = std::env::var("WRITE") {
        let recipe = bonnetlab_calibrate::synth::write::write_run(dir.as_ref(), &run).unwrap();
        eprintln!("wrote {}", recipe.display());
    }
    let t = std::time::Instant::now();
    let p = run.problem().unwrap();
    let c = calibrate(&p, &Options::default()).unwrap();
    eprintln!("calibrate {:?}", t.elapsed());
    eprintln!(
        "baseline {:.4} nm, final {:.4} nm, noise floor {:.4} nm",
        c.baseline.residual_rms_nm, c.final_.residual_rms_nm, c.noise_floor_rms_nm
    );
    for e in &c.effects {
        eprintln!(
            "{} {:?} +- {:?} z {:.1}",
            e.kind, e.params, e.uncertainties, e.significance
        );
    }
    for (k, r) in c.rounds.iter().enumerate() {
        let mut cands = r.candidates.clone();
        cands.sort_by(|a, b| b.z.total_cmp(&a.z));
        let top: Vec<String> = cands
            .iter()
            .take(5)
            .map(|c| {
                format!(
                    "{} z {:.1} f {:.3}",
                    c.key, c.z, c.heldout_reduction_fraction
                )
            })
            .collect();
        eprintln!("round {k} accepted {:?}: {}", r.accepted, top.join(" | "));
    }
    println!("{}", serde_json::to_string_pretty(&c).unwrap());
}
