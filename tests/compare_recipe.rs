//! `compare --run NAME=RECIPE.toml` (issue 16): runs made by direct time-domain deposition of
//! the instantaneous TIF under the vibration model (`coupling::direct_removal`, no expansion),
//! on a power-law textured part with measurement noise on both maps, analysed by the library
//! pipeline (`bonnetlab::pipeline::bonnets`: calibrate, predict, infer the forcing, attribute
//! the difference) and through the CLI with real files (MetroPro .dat maps, path CSV, recipe).
//! The pipeline uses the fast expansion with its own vibration noise seed: it does not know the
//! truth's realisation.

use std::path::{Path, PathBuf};
use std::process::Command;

use bonnetlab::pipeline::bonnets::{compare_runs, BonnetsComparison, Options, RunInput};
use bonnetlab::process::path::log::path_to_csv;
use bonnetlab::process::path::RasterSpec;
use bonnetlab::process::recipe::TifSource;
use bonnetlab::process::simulate::ToolModel;
use bonnetlab::process::tif::GaussianTif;
use bonnetlab::process::{Grid, PathLog};
use bonnetlab::surface::Surface;
use bonnetlab::vibration::coupling::{direct_removal, CouplingInput, CouplingOptions};
use bonnetlab::vibration::infer::synth::measured_pair;
use bonnetlab::vibration::infer::Difference;
use bonnetlab::vibration::params::{Bonnet, VibrationParams};

const N: usize = 200;
const D: f64 = 0.25;
const PITCH: f64 = 3.0;
/// The x2 resonance and a feed whose spindle imprint along the scan (9.3 Hz / 30 mm/s =
/// 0.31 /mm) the 1 mm-sigma spot passes: the forcing can be constrained (at the paper's
/// 1.6 mm/s and 1000 rpm it cannot; see crates/vibration/tests/infer.rs).
const RPM: f64 = 558.0;
const FEED: f64 = 30.0;
const FN_TRUE: f64 = 5.0;
/// Robot damping ratio, and the same plus the suppression element's ζ_e = η / 2.
const ZETA: f64 = 0.05;
const ZETA_DAMPED: f64 = 0.05 + 0.115 / 2.0;

fn path() -> PathLog {
    let mut spec = RasterSpec::over_rect((0.0, 50.0), (-3.0, 53.0), PITCH, FEED);
    spec.overtravel_mm = 6.0;
    spec.sample_dt_s = 0.02;
    spec.generate().unwrap()
}

fn tif(scale: f64) -> GaussianTif {
    GaussianTif::new(1.0 * scale, 8.0 * scale, 1500.0 / (scale * scale)).unwrap()
}

fn params(zeta: f64) -> VibrationParams {
    VibrationParams {
        spindle_rpm: RPM,
        fn_n: FN_TRUE,
        noise_force_rms_n: 0.5,
        zeta1: zeta,
        zeta2: zeta,
        ..Default::default()
    }
}

fn coupling(seed: u64) -> CouplingOptions {
    CouplingOptions {
        sample_hz: 500.0,
        seed,
        ..Default::default()
    }
}

/// A measured run: truth removal by direct deposition with the true TIF (vibration seed 11),
/// before / after maps of the textured part with 1 nm RMS noise; the recipe names the nominal
/// TIF (`tif(1.0)`) and the true vibration parameters.
fn run(name: &str, truth: &VibrationParams, true_tif: &GaussianTif, noise_seed: u64) -> RunInput {
    let grid = Grid::new(N, N, D, D, 0.0, 0.0).unwrap();
    let p = path();
    let tool = ToolModel::from_source(&TifSource::Gaussian(*true_tif), None, D, D).unwrap();
    let input = CouplingInput {
        grid,
        valid: None,
        tool: &tool,
        path: &p,
        params: truth,
        pitch_mm: Some(PITCH),
    };
    let removal = direct_removal(&input, Bonnet::Original, &coupling(11)).unwrap();
    let (b, a) = measured_pair(&removal, D, 77, noise_seed, 1.0);
    RunInput {
        name: name.into(),
        recipe_file: PathBuf::from(format!("{name}.toml")),
        before: Surface::new(b, Some(D), Some(D)).unwrap(),
        after: Surface::new(a, Some(D), Some(D)).unwrap(),
        tif: TifSource::Gaussian(tif(1.0)),
        spot: None,
        pixels: bonnetlab::process::pixel::PixelSampling::Point,
        repeatability_nm: None,
        path: p,
        pitch_mm: PITCH,
        bonnet: Bonnet::Original,
        params: truth.clone(),
    }
}

fn opts() -> Options {
    Options {
        coupling: coupling(2),
        ..Default::default()
    }
}

const VIBRATION: [&str; 5] = [
    "normal_offset",
    "lateral_jitter",
    "envelope",
    "dwell_execution",
    "interaction",
];

fn vibration_share(d: &Difference) -> f64 {
    d.causes
        .iter()
        .filter(|c| VIBRATION.contains(&c.cause.as_str()))
        .map(|c| c.share_of_sigma1_difference)
        .sum()
}

fn show(c: &BonnetsComparison) {
    for r in &c.runs {
        let kinds: Vec<String> = r
            .calibration
            .effects
            .iter()
            .map(|e| format!("{} {:?}", e.kind, e.params))
            .collect();
        eprintln!(
            "{}: measured sigma1 {:.4} nm, MSF {:.4} nm, CR {:.5}; predicted sigma1 {:?} nm, \
             MSF {:.4} nm; effects {kinds:?}; tif scale for the fit {:.4}\n  forcing {:?}",
            r.name,
            r.measured.sigma1_nm,
            r.measured.msf_rms_nm,
            r.measured.cr_rms,
            r.predicted.sigma1_nm,
            r.predicted.msf_rms_nm,
            r.fit_tif_scale,
            r.vibration_forcing
        );
        let cal = &r.calibration;
        let mut top: Vec<(String, f64)> = cal
            .rounds
            .first()
            .map(|r| r.candidates.iter().map(|c| (c.key.clone(), c.z)).collect())
            .unwrap_or_default();
        top.sort_by(|a, b| b.1.total_cmp(&a.1));
        top.truncate(4);
        eprintln!(
            "  calibration: baseline {:.4} nm (rate scale {:.4}), final {:.4} nm, noise floor \
             {:.4} nm, measured removal {:.4} nm; first round best {top:?}",
            cal.baseline.residual_rms_nm,
            cal.baseline.rate_scale,
            cal.final_.residual_rms_nm,
            cal.noise_floor_rms_nm,
            cal.baseline.measured_removal_rms_nm
        );
    }
    for d in &c.difference {
        eprintln!("{d:#?}\nvibration share {:.4}", vibration_share(d));
    }
    if let Some(s) = &c.shared_forcing {
        eprintln!("shared: {}", s.reason);
    }
}

fn within(x: f64, truth: f64, tol: f64) -> bool {
    (x - truth).abs() <= tol * truth
}

/// Two runs of the same bonnet, forcing (5 N at the x2 resonance) and path; the only
/// difference is the robot damping (ζ 0.05 vs 0.1075).
///
/// Measured (session 9, after the coupling's clock and 4th-order imprint were fixed against
/// exact deposition): calibration (vibration taken back) accepts no effect in either run;
/// fitted 5.08 N [4.82, 5.35] and 5.08 N [4.73, 5.44]; one shared forcing 5.09 N (p = 0.65);
/// σ1 B − A = +0.141 nm; normal_offset 1.156 (significant), all vibration mechanisms 1.159,
/// removal_rate −0.266 (not significant), unexplained 0.107. Before the fix: 5.04 and
/// 5.21 N, shared 5.13 N (p = 0.42), normal_offset 0.992, removal_rate −0.103.
#[test]
fn damping_pair_forcing_within_30_percent_and_difference_attributed_to_vibration() {
    let t = tif(1.0);
    let a = run("A", &params(ZETA), &t, 1050);
    let b = run("B", &params(ZETA_DAMPED), &t, 1051);
    let c = compare_runs(&[a, b], &opts()).unwrap();
    show(&c);
    for r in &c.runs {
        let v = &r.vibration_forcing;
        assert!(v.constrained, "{}: {v:?}", r.name);
        let f = v.fn_n.unwrap();
        assert!(within(f, FN_TRUE, 0.3), "{}: fitted {f} N vs 5 N", r.name);
        assert!(r.predicted.sigma1_nm.is_some() && r.predicted.msf_rms_nm > 0.0);
    }
    let sh = c.shared_forcing.as_ref().unwrap();
    assert!(sh.consistent && sh.plausible, "{}", sh.reason);
    let d = &c.difference[0];
    assert!(d.sigma1_difference_nm.abs() > 0.05, "{d:?}");
    let vib = vibration_share(d);
    assert!((0.7..=1.3).contains(&vib), "vibration share {vib}");
    assert!(
        VIBRATION.contains(&d.causes[0].cause.as_str()) && d.causes[0].significant,
        "{d:?}"
    );
}

/// Identical vibration, but run B's working spot is 15 % wider than the recipe's (same volume
/// rate): the vibration must get under 10 % of the σ1 difference. On this raster (the path
/// covers the whole map, piston removed) the wider spot's ripple at the pitch is the nominal
/// spot's at a lower rate (exp(−2π²σ²/p²): 0.49 of it), so no map can tell the two apart:
/// the calibration finds no `tif_scale` and the difference goes to `removal_rate` (the
/// calibration's baseline rate scale), which the report says stands for either.
///
/// Measured: B's calibrated baseline rate scale 0.489 (A 1.000); B accepts a 0.034 mm
/// periodic path error at the pitch (share 0.001); σ1 B − A = −8.04 nm; removal_rate 1.038
/// (significant), vibration mechanisms 0.008, unexplained −0.047. B's
/// forcing, fitted on the nominal spot, is 7.96 N (truth 5 N): the spot cannot be told from
/// the rate here, and the fit absorbs part of the mismatch.
#[test]
fn wider_spot_pair_gives_vibration_less_than_10_percent() {
    let a = run("A", &params(ZETA), &tif(1.0), 1050);
    let b = run("B", &params(ZETA), &tif(1.15), 1051);
    let c = compare_runs(&[a, b], &opts()).unwrap();
    show(&c);
    let d = &c.difference[0];
    let vib = vibration_share(d);
    assert!(d.sigma1_difference_nm < -1.0, "{d:?}");
    assert!(vib.abs() < 0.1, "vibration share {vib}");
    let top = &d.causes[0];
    assert!(
        ["removal_rate", "tif_scale"].contains(&top.cause.as_str()),
        "{d:?}"
    );
    assert!(top.significant, "{d:?}");
    assert!(
        (0.8..=1.2).contains(&top.share_of_sigma1_difference),
        "{d:?}"
    );
}

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

/// Writes a run as files: before/after MetroPro maps, the path CSV, and the recipe.
fn write_run(dir: &Path, r: &RunInput, zeta: f64, bonnet: &str) -> PathBuf {
    let w = |name: &str, s: &Surface| {
        bonnetlab::io::write_surface(&dir.join(name), s, bonnetlab::io::MapFormat::MetroProDat)
            .unwrap()
    };
    w(&format!("{}_before.dat", r.name), &r.before);
    w(&format!("{}_after.dat", r.name), &r.after);
    std::fs::write(
        dir.join(format!("{}_path.csv", r.name)),
        path_to_csv(&r.path),
    )
    .unwrap();
    let recipe = format!(
        "[measurement]\nbefore = \"{n}_before.dat\"\nafter = \"{n}_after.dat\"\n\n\
         [tif]\nmodel = {{ kind = \"gaussian\", sigma_mm = 1.0, diameter_mm = 8.0, \
         peak_rate_nm_per_s = 1500.0 }}\n\n[path]\nlog = \"{n}_path.csv\"\npitch_mm = {PITCH}\n\n\
         [process]\nbonnet = \"{bonnet}\"\nspindle_rpm = {RPM}\n\n\
         [vibration]\nfn_n = {FN_TRUE}\nnoise_force_rms_n = 0.5\nzeta1 = {zeta}\nzeta2 = {zeta}\n",
        n = r.name
    );
    let p = dir.join(format!("{}.toml", r.name));
    std::fs::write(&p, recipe).unwrap();
    p
}

/// The CLI on two recipe runs writes the contract fields; a bad recipe is one line naming the
/// file with exit code 2 and no report.
#[test]
fn cli_compare_recipe_runs_writes_the_contract_fields() {
    let dir = tempfile::tempdir().unwrap();
    let t = tif(1.0);
    let a = write_run(
        dir.path(),
        &run("A", &params(ZETA), &t, 1050),
        ZETA,
        "original",
    );
    let b = write_run(
        dir.path(),
        &run("B", &params(ZETA_DAMPED), &t, 1051),
        ZETA_DAMPED,
        "suppression",
    );
    let out = dir.path().join("report");
    let o = bin()
        .arg("compare")
        .arg("--run")
        .arg(format!("A={}", a.display()))
        .arg("--run")
        .arg(format!("B={}", b.display()))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let runs = j["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    for r in runs {
        let p = &r["predicted"];
        assert!(p["sigma1_nm"].as_f64().unwrap() > 0.0);
        assert!(p["msf_rms_nm"].as_f64().unwrap() > 0.0);
        let m = p["mechanisms"].as_array().unwrap();
        assert!(!m.is_empty());
        for k in ["name", "msf_band_rms_nm", "share"] {
            assert!(!m[0][k].is_null(), "mechanism {k}");
        }
        let cal = &r["calibration"];
        for k in [
            "baseline",
            "final",
            "noise_floor_rms_nm",
            "effects",
            "unexplained",
        ] {
            assert!(!cal[k].is_null(), "calibration {k}");
        }
        let f = &r["vibration_forcing"];
        for k in [
            "fn_n",
            "interval_n",
            "upper_bound_n",
            "end_amplitude_mm",
            "constrained",
            "reason",
        ] {
            assert!(f.get(k).is_some(), "vibration_forcing {k}");
        }
        assert!(f["reason"].as_str().is_some_and(|s| !s.is_empty()));
        // --pitch-mm defaults to the recipe's pitch.
        assert!(r["ripple_after"]["sigma1_nm"].as_f64().is_some());
    }
    assert_eq!(runs[1]["bonnet"], "suppression");
    let d = j["difference"].as_array().unwrap();
    assert_eq!(d.len(), 1);
    assert_eq!(d[0]["runs"], serde_json::json!(["A", "B"]));
    for k in [
        "sigma1_difference_nm",
        "sigma1_difference_sd_nm",
        "cr_rms_difference",
        "cr_rms_difference_sd",
        "unexplained_share_of_sigma1_difference",
        "unexplained_share_of_cr_rms_difference",
    ] {
        assert!(d[0][k].as_f64().is_some(), "difference {k}");
    }
    // The maps' white noise gives the differences a positive SD, and says whether each stands
    // beyond it.
    assert!(d[0]["sigma1_difference_sd_nm"].as_f64().unwrap() > 0.0);
    assert!(d[0]["cr_rms_difference_sd"].as_f64().unwrap() > 0.0);
    assert!(d[0]["sigma1_difference_beyond_noise"].is_boolean());
    assert!(d[0]["cr_rms_difference_beyond_noise"].is_boolean());
    let causes = d[0]["causes"].as_array().unwrap();
    let shares: Vec<f64> = causes
        .iter()
        .map(|c| c["share_of_sigma1_difference"].as_f64().unwrap().abs())
        .collect();
    assert!(shares.windows(2).all(|w| w[0] >= w[1]), "{shares:?}");
    for c in causes {
        assert!(c["cause"].is_string() && c["significant"].is_boolean());
        assert!(c["share_of_cr_rms_difference"].is_number());
        let (s1, cr) = (
            c["significant_sigma1"].as_bool().unwrap(),
            c["significant_cr_rms"].as_bool().unwrap(),
        );
        assert_eq!(c["significant"].as_bool().unwrap(), s1 || cr);
        // A share under 5 %, or of a difference within the maps' noise, is never significant.
        if s1 {
            assert!(c["share_of_sigma1_difference"].as_f64().unwrap().abs() >= 0.05);
            assert_eq!(d[0]["sigma1_difference_beyond_noise"], true);
        }
        if cr {
            assert!(c["share_of_cr_rms_difference"].as_f64().unwrap().abs() >= 0.05);
            assert_eq!(d[0]["cr_rms_difference_beyond_noise"], true);
        }
    }
    let html_table = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html_table.contains("significant for σ1 (95 %)"));
    assert!(html_table.contains("significant for CR (95 %)"));
    assert!(html_table.contains("run-to-run scatter"));
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("Bonnets: measured vs predicted ripple"));
    assert!(html.contains("Vibration forcing inferred from the measurements"));
    // Conclusions in words, with how sure and what would change them; the forcing next to the
    // paper's amplitude.
    assert!(html.contains("What would change this"));
    assert!(html.contains("95 % sure") || html.contains("not explained with confidence"));
    assert!(html.contains("end-of-robot amplitude") && html.contains("paper&#39;s ~1e-2 mm"));
    assert!(html.contains("unexplained"));

    // The same B read as a camera's pixels (`[measurement] pixels = "area"`): its calibration
    // and its prediction say so, and the prediction is each pixel's mean, which flattens the
    // raster's ripple at the pitch to sinc(pi D / PITCH) = 0.98862 of its amplitude (the
    // pixel's box along y; analytic) while A's stays as it was.
    let b_area = dir.path().join("B_area.toml");
    std::fs::write(
        &b_area,
        std::fs::read_to_string(&b).unwrap().replacen(
            "[measurement]\n",
            "[measurement]\npixels = \"area\"\n",
            1,
        ),
    )
    .unwrap();
    let out_area = dir.path().join("report_area");
    let o = bin()
        .arg("compare")
        .arg("--run")
        .arg(format!("A={}", a.display()))
        .arg("--run")
        .arg(format!("B={}", b_area.display()))
        .arg("--out")
        .arg(&out_area)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ja: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_area.join("report.json")).unwrap())
            .unwrap();
    let sigma1 = |j: &serde_json::Value, k: usize| j["runs"][k]["predicted"]["sigma1_nm"].as_f64();
    assert_eq!(ja["runs"][0]["calibration"]["pixels"], "point");
    assert_eq!(ja["runs"][1]["calibration"]["pixels"], "area");
    assert_eq!(sigma1(&ja, 0), sigma1(&j, 0));
    let (point, area) = (sigma1(&j, 1).unwrap(), sigma1(&ja, 1).unwrap());
    // Measured: 16.669 -> 16.481 nm, a ratio of 0.98872.
    let x = std::f64::consts::PI * D / PITCH;
    assert!(
        (area / point - x.sin() / x).abs() < 1e-3,
        "area {area} nm vs point {point} nm: ratio {} vs sinc {}",
        area / point,
        x.sin() / x
    );

    // A bad recipe: one line naming it, exit 2, nothing written.
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[measurement]\nbefore = 3\n").unwrap();
    let out2 = dir.path().join("report2");
    let o = bin()
        .arg("compare")
        .arg("--run")
        .arg(format!("A={}", a.display()))
        .arg("--run")
        .arg(format!("X={}", bad.display()))
        .arg("--out")
        .arg(&out2)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("bad.toml"), "{err}");
    assert!(!out2.exists());
}
