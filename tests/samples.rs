//! The bundled recipe runs (samples/original, samples/suppression; issue 16): made by the
//! synthetic-run generator with the exact time-domain deposition under each bonnet's vibration
//! model (`bonnetlab::pipeline::recipe_samples`), they regenerate bit for bit, and the bonnet
//! comparison on them (the pipeline `compare --run NAME=RECIPE.toml` runs) finds each run's
//! built-in effects within 20 % and gives the difference in ripple between the bonnets to the
//! vibration: nothing else differs between the runs (same part, path, process and forcing; the
//! effects move the removal, they do not change its depth).

use std::path::PathBuf;

use bonnetlab::pipeline::bonnets::{compare_runs, BonnetsComparison, Options, RunInput};
use bonnetlab::pipeline::recipe_samples::{generate_run, recipe_runs, write_run, RECIPE_SEED};

const VIBRATION: [&str; 5] = [
    "normal_offset",
    "lateral_jitter",
    "envelope",
    "dwell_execution",
    "interaction",
];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn effect(c: &BonnetsComparison, run: &str, kind: &str, key: &str) -> f64 {
    let r = c.runs.iter().find(|r| r.name == run).unwrap();
    let e = r
        .calibration
        .effects
        .iter()
        .find(|e| e.kind == kind)
        .unwrap_or_else(|| {
            let kinds: Vec<&str> = r
                .calibration
                .effects
                .iter()
                .map(|e| e.kind.as_str())
                .collect();
            panic!("{run}: {kind} not found; found {kinds:?}")
        });
    e.params[key].as_f64().unwrap()
}

fn within(found: f64, truth: f64, rel: f64) -> bool {
    (found - truth).abs() <= rel * truth.abs()
}

#[test]
fn committed_recipe_samples_regenerate_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let mut total = 0;
    for spec in recipe_runs(RECIPE_SEED) {
        let run = generate_run(&spec).unwrap();
        let d = dir.path().join(spec.name);
        write_run(&d, &spec, &run).unwrap();
        for f in [
            "recipe.toml",
            "path.csv",
            "spot.dat",
            "before.dat",
            "after.dat",
        ] {
            let fresh = std::fs::read(d.join(f)).unwrap();
            let committed = std::fs::read(repo().join("samples").join(spec.name).join(f))
                .unwrap_or_else(|e| panic!("samples/{}/{f}: {e}", spec.name));
            assert!(
                fresh == committed,
                "samples/{}/{f} differs from what the generator writes \
                 (rerun `bonnetlab demo --generate-samples samples`)",
                spec.name
            );
            total += committed.len();
        }
    }
    assert!(total < 2_000_000, "recipe samples take {total} bytes");
}

/// Measured on the committed samples: see the report (`reports/demo/bonnets`) and the numbers
/// in the final assertion messages.
#[test]
fn sample_runs_built_in_effects_found_within_20_percent() {
    let runs: Vec<RunInput> = ["original", "suppression"]
        .iter()
        .map(|n| RunInput::load(n, &repo().join("samples").join(n).join("recipe.toml")).unwrap())
        .collect();
    let c = compare_runs(&runs, &Options::default()).unwrap();
    for r in &c.runs {
        let kinds: Vec<String> = r
            .calibration
            .effects
            .iter()
            .map(|e| format!("{} {:?}", e.kind, e.params))
            .collect();
        eprintln!(
            "{}: sigma1 measured {:.4} nm, predicted {:?} nm; forcing {:?}; effects {kinds:?}",
            r.name, r.measured.sigma1_nm, r.predicted.sigma1_nm, r.vibration_forcing
        );
    }
    // Built-in effects (truth: samples/README.md).
    let checks = [
        ("original", "direction_lag", "lag_mm", 0.3),
        ("suppression", "path_offset", "dx_mm", 0.3),
        ("suppression", "path_offset", "dy_mm", -0.25),
    ];
    for (run, kind, key, truth) in checks {
        let f = effect(&c, run, kind, key);
        assert!(
            within(f, truth, 0.2),
            "{run}: {kind} {key} {f} vs truth {truth}"
        );
    }
}

/// Issue 16's criterion "attributes the measured sigma1 difference to the right mechanism
/// within 20 %" on the sample runs. The runs share one part, path, process and forcing; only the
/// bonnet (the suppression element's damping and series compliance) and each run's own path
/// effect differ, and neither effect changes the ripple depth, so the truth is: all of the σ1
/// difference is the vibration's. The setup makes it measurable (`recipe_samples`): a part with
/// little ripple of its own at 1/pitch (texture exponent 3) and a 1.35 mm-sigma spot that leaves
/// a raster ripple the vibration changes by a few per cent.
///
/// Measured on the committed samples: σ1 after polishing 4.463 nm (original) and 4.312 nm
/// (suppression), 2.21 / 2.20 nm before; difference −0.150 nm. The forcing model of the lagged
/// original run has the calibrated lag (0.293 mm, truth 0.3) at the run's clock
/// (`ForcingModel::build_lagged`), the coupling's clock from the log with the raster corners
/// restored and the spindle-harmonic offset to fourth order (tests/forcing_truth.rs, against
/// the exact deposition): forcing original 5.002 N, suppression 4.659 N (truth 5 N both) and the
/// shares normal_offset 1.074, dwell_execution 0.002, interaction −0.014 (vibration 1.061),
/// path_offset −0.052, removal_rate 0.035, direction_lag −0.011, unexplained −0.033.
/// Before those two coupling fixes it read 5.818 N and 4.709 N, share 1.451 (failing): the
/// log's chords re-timed to a clock 0.73 s longer than the run's, and a second-order expansion
/// that put the imprint's power 7-36 % low over 0.30-0.46 per mm (more at the original run's
/// larger offset swing than at the damped suppression run's); main passed (4.77 N, 4.44 N,
/// 1.000) only through its interpolated spot TIF, 12-15 % low, cancelling them.
#[test]
fn sample_runs_difference_given_to_vibration() {
    let runs: Vec<RunInput> = ["original", "suppression"]
        .iter()
        .map(|n| RunInput::load(n, &repo().join("samples").join(n).join("recipe.toml")).unwrap())
        .collect();
    let c = compare_runs(&runs, &Options::default()).unwrap();
    let d = &c.difference[0];
    let vib: f64 = d
        .causes
        .iter()
        .filter(|c| VIBRATION.contains(&c.cause.as_str()))
        .map(|c| c.share_of_sigma1_difference)
        .sum();
    eprintln!("{d:#?}\nvibration share {vib:.4}");
    assert!(
        (0.8..=1.2).contains(&vib),
        "vibration share of the sigma1 difference {vib:.3} (truth 1); {d:?}"
    );
    // Nothing else is given a material part of it: each other cause, and what is left
    // unexplained, under 20 %.
    for c in d
        .causes
        .iter()
        .filter(|c| !VIBRATION.contains(&c.cause.as_str()))
    {
        assert!(
            c.share_of_sigma1_difference.abs() < 0.2,
            "{} given {:.3} of the sigma1 difference; {d:?}",
            c.cause,
            c.share_of_sigma1_difference
        );
    }
    assert!(
        d.unexplained_share_of_sigma1_difference.abs() < 0.2,
        "unexplained {:.3}",
        d.unexplained_share_of_sigma1_difference
    );
    // How sure: the σ1 difference (−0.151 nm) stands beyond the maps' white noise (SD 0.006
    // nm). dwell_execution is the same in both runs (byte-identical path logs, the same
    // forcing-free model): its −0.9 % / −5.9 % shares are smaller than what the causes leave
    // unexplained (−3.3 % / 21 %) and were once reported significant; they are not.
    assert!(d.sigma1_difference_beyond_noise, "{d:?}");
    assert!(d.sigma1_difference_sd_nm > 0.0 && d.sigma1_difference_sd_nm < 0.02);
    let dwell = d
        .causes
        .iter()
        .find(|c| c.cause == "dwell_execution")
        .expect("dwell_execution cause");
    assert!(!dwell.significant, "{dwell:?}");
    let top = &d.causes[0];
    assert!(
        top.cause == "normal_offset" && top.significant_sigma1,
        "{top:?}"
    );
}

fn vibration_share(c: &BonnetsComparison) -> f64 {
    c.difference[0]
        .causes
        .iter()
        .filter(|c| VIBRATION.contains(&c.cause.as_str()))
        .map(|c| c.share_of_sigma1_difference)
        .sum()
}

/// Issue 14: the sample runs analysed with their measured spot (`spot.dat` through the TIF
/// front end) and with the generator's true TIF in its place (`recipe_samples::recipe_tif`, the
/// Gaussian the runs were deposited with) give the same forcings and vibration share: the
/// spot-derived TIF is not what decides the attribution.
///
/// Measured: measured spot (smooth model: sigma 1.3494 mm, beta 0.999) original 5.002 N,
/// suppression 4.659 N, vibration share 1.061; true TIF 4.990 N, 4.652 N, share 1.075. (Main's
/// interpolated spot TIF, whose transfer in the imprint band was 6-100 % high, read 4.77 N and
/// 4.44 N and a share of 1.000.)
#[test]
fn sample_runs_spot_tif_agrees_with_the_true_tif() {
    let load = |true_tif: bool| -> Vec<RunInput> {
        ["original", "suppression"]
            .iter()
            .map(|n| {
                let mut r =
                    RunInput::load(n, &repo().join("samples").join(n).join("recipe.toml")).unwrap();
                if true_tif {
                    r.tif = bonnetlab_process::recipe::TifSource::Gaussian(
                        bonnetlab::pipeline::recipe_samples::recipe_tif(),
                    );
                    r.spot = None;
                }
                r
            })
            .collect()
    };
    let spot = compare_runs(&load(false), &Options::default()).unwrap();
    let truth = compare_runs(&load(true), &Options::default()).unwrap();
    for (a, b) in spot.runs.iter().zip(&truth.runs) {
        let (fa, fb) = (
            a.vibration_forcing.fn_n.unwrap(),
            b.vibration_forcing.fn_n.unwrap(),
        );
        eprintln!(
            "{}: forcing {fa:.3} N with the spot, {fb:.3} N with the true TIF",
            a.name
        );
        assert!((fa / fb - 1.0).abs() < 0.01, "{}: {fa} N vs {fb} N", a.name);
    }
    let (vs, vt) = (vibration_share(&spot), vibration_share(&truth));
    eprintln!("vibration share {vs:.4} with the spot, {vt:.4} with the true TIF");
    assert!((vs - vt).abs() < 0.03, "vibration share {vs} vs {vt}");
}
