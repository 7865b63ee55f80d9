//! `bonnetlab dwell` end to end: the contract's JSON fields on the public case A, the target
//! options, the trade-off and feed outputs, and one-line errors with exit code 2 on bad input
//! (unknown keys with the nearest valid one, TOML syntax with the parser's cause).

#[path = "common/shared_data.rs"]
mod shared_data;

use std::path::PathBuf;
use std::process::Command;

use shared_data::data_file;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

/// A public case file (panics with instructions when the shared data is missing).
fn case(name: &str) -> PathBuf {
    data_file("dwell", name)
}

/// The CLI's default settings (only the issue's dwell budget given) meet issue 20's targets on
/// both public cases: the coarse dwell grid is picked from the TIF's width (A: fine grid, its
/// TIF only 2.8 px RMS wide; B: nodes every 5 px), and `--coarsen 1` overrides it.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn default_settings_meet_issue_20_targets_on_both_cases() {
    for (name, budget_min, target_nm, coarsening) in [
        ("rifta_case_a.toml", "655", 0.08, 1),
        ("ibfest_case_b.toml", "66", 0.30, 5),
    ] {
        let o = bin()
            .arg("dwell")
            .arg(case(name))
            .args(["--max-dwell-min", budget_min])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let rms = v["residual_rms_nm"].as_f64().unwrap();
        let min = v["total_dwell_s"].as_f64().unwrap() / 60.0;
        let budget: f64 = budget_min.parse().unwrap();
        assert!(
            rms > 0.0 && rms <= target_nm && min <= budget,
            "{name}: {rms} nm with {min} min"
        );
        assert_eq!(v["target_met"], true);
        assert_eq!(v["coarsening"], serde_json::json!([coarsening, coarsening]));
    }
    // The override: the full grid on case B (fewer iterations to keep the test short).
    let o = bin()
        .arg("dwell")
        .arg(case("ibfest_case_b.toml"))
        .args([
            "--coarsen",
            "1",
            "--iterations",
            "5",
            "--max-dwell-min",
            "66",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["coarsening"], serde_json::json!([1, 1]));
    // A bad factor is a one-line usage error.
    let o = bin()
        .arg("dwell")
        .arg(case("ibfest_case_b.toml"))
        .args(["--coarsen", "zero"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--coarsen"));
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn case_a_json_and_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("dwell.json");
    let out = dir.path().join("out");
    let o = bin()
        .arg("dwell")
        .arg(case("rifta_case_a.toml"))
        .arg("--json")
        .arg(&json)
        .arg("--out")
        .arg(&out)
        .arg("--max-dwell-min")
        .arg("655")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rms = v["residual_rms_nm"].as_f64().unwrap();
    assert!(rms > 0.0 && rms <= 0.08, "{rms}");
    assert!(v["residual_pv_nm"].as_f64().unwrap() > rms);
    // The budget asked for, met: at most 655 min (Richardson-Lucy's total on this case).
    let total_min = v["total_dwell_s"].as_f64().unwrap() / 60.0;
    assert!((300.0..=655.0).contains(&total_min), "{total_min}");
    assert!(v["wall_s"].as_f64().unwrap() > 0.0);
    assert_eq!(v["method"], "min-dwell");
    assert_eq!(v["target"]["kind"], "max_dwell");
    assert_eq!(v["target_met"], true);
    let curve = v["trade_off"].as_array().unwrap();
    assert_eq!(curve.len(), 7);
    // The executed raster's residual is reported beside the planned one.
    let feed = &v["feed"];
    let realised = feed["realised_residual_rms_nm"].as_f64().unwrap();
    assert!(
        realised >= 0.9 * rms && realised < 10.0 * rms,
        "{realised} vs {rms}"
    );
    assert!(feed["realised_duration_s"].as_f64().unwrap() > 0.9 * total_min * 60.0);
    for f in [
        "dwell_s.csv",
        "residual.dat",
        "dwell_map.png",
        "residual.png",
        "trade_off.csv",
        "trade_off.png",
        "realised_residual.dat",
        "feed_binding.csv",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // The CSV grids say what they hold, and the dwell map reads back to the JSON's total.
    let head = std::fs::read_to_string(out.join("dwell_s.csv")).unwrap();
    assert!(
        head.starts_with("# bonnetlab dwell map: seconds per pixel;"),
        "{}",
        &head[..80]
    );
    let dwell = bonnetlab::io::read_surface(&out.join("dwell_s.csv")).unwrap();
    let sum: f64 = dwell.heights_nm().iter().filter(|v| v.is_finite()).sum();
    assert!(
        (sum - v["total_dwell_s"].as_f64().unwrap()).abs() < 1e-6 * sum,
        "{sum} s"
    );
    let binding = std::fs::read_to_string(out.join("feed_binding.csv")).unwrap();
    assert!(
        binding.starts_with("# bonnetlab feed limit"),
        "{}",
        &binding[..60]
    );
    // The residual map written is the one the JSON describes.
    let res = bonnetlab::io::read_surface(&out.join("residual.dat")).unwrap();
    let st = bonnetlab::surface::height_stats(&res).unwrap();
    assert!(
        (st.rms_nm - rms).abs() < 1e-3 * rms.max(1e-3) + 1e-4,
        "{} vs {rms}",
        st.rms_nm
    );
}

/// Issue #18: absurd finite numbers in a dwell case (1e300, 1e-300, negative, a huge clear
/// aperture) are one-line errors naming the file and the key, exit 2.
#[test]
fn absurd_case_numbers_are_one_line_errors_naming_file_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let good = "surface = \"s.dat\"\npixel_mm = 0.5\n[tif]\nkind = \"gaussian\"\nsigma_mm = 1.0\ndiameter_mm = 6.0\npeak_rate_nm_per_s = 1.0\n[clear_aperture]\nrows = [10, 20]\ncols = [10, 30]\n";
    for (i, (from, to, key)) in [
        (
            "peak_rate_nm_per_s = 1.0",
            "peak_rate_nm_per_s = 1e300",
            "peak_rate_nm_per_s",
        ),
        (
            "peak_rate_nm_per_s = 1.0",
            "peak_rate_nm_per_s = 1e-300",
            "peak_rate_nm_per_s",
        ),
        (
            "peak_rate_nm_per_s = 1.0",
            "peak_rate_nm_per_s = -1.0",
            "peak_rate_nm_per_s",
        ),
        ("sigma_mm = 1.0", "sigma_mm = 1e300", "sigma_mm"),
        ("cols = [10, 30]", "cols = [10, 4000000000000]", "cols"),
    ]
    .into_iter()
    .enumerate()
    {
        let p = dir.path().join(format!("absurd{i}.toml"));
        std::fs::write(&p, good.replace(from, to)).unwrap();
        let o = bin().arg("dwell").arg(&p).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{to}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(&format!("absurd{i}.toml")) && err.contains(key),
            "{to}: {err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{to}: {err}");
    }
}

#[test]
fn bad_case_is_a_one_line_error_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.toml");
    std::fs::write(&p, "surface = \"x.dat\"\npixel_mm = -1\n").unwrap();
    let o = bin().arg("dwell").arg(&p).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("bad.toml") && err.contains("pixel_mm"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1);
    let o = bin()
        .arg("dwell")
        .arg(dir.path().join("missing.toml"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn trade_off_csv_is_the_json_curve() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("d.json");
    let o = bin()
        .arg("dwell")
        .arg(case("rifta_case_a.toml"))
        .args(["--iterations", "20", "--target-rms-nm", "0.5", "--json"])
        .arg(&json)
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["target"]["kind"], "residual_rms");
    let csv = std::fs::read_to_string(dir.path().join("trade_off.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("offset_nm,total_dwell_min,residual_rms_nm")
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    let curve = v["trade_off"].as_array().unwrap();
    assert_eq!(rows.len(), curve.len());
    for (r, p) in rows.iter().zip(curve) {
        assert!((r[2] - p["residual_rms_nm"].as_f64().unwrap()).abs() < 1e-12);
        assert!((r[1] * 60.0 - p["total_dwell_s"].as_f64().unwrap()).abs() < 1e-6);
    }
    // The chosen point is the least dwell on the curve that meets the target.
    let chosen = v["total_dwell_s"].as_f64().unwrap();
    let best = curve
        .iter()
        .filter(|p| p["residual_rms_nm"].as_f64().unwrap() <= 0.5)
        .map(|p| p["total_dwell_s"].as_f64().unwrap())
        .fold(f64::INFINITY, f64::min);
    assert!((chosen - best).abs() < 1e-9, "{chosen} vs {best}");
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn unknown_keys_and_syntax_errors_name_file_key_and_cause() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read_to_string(case("rifta_case_a.toml")).unwrap();
    let p = dir.path().join("typo.toml");
    std::fs::write(&p, good.replace("sigma_mm", "sigma_nm")).unwrap();
    let o = bin().arg("dwell").arg(&p).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("typo.toml")
            && err.contains("sigma_nm")
            && err.contains("did you mean `sigma_mm`"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1);
    let p = dir.path().join("syntax.toml");
    std::fs::write(&p, "surface = \"a.dat\"\npixel_mm = = 1\n").unwrap();
    let o = bin().arg("dwell").arg(&p).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("syntax.toml") && err.contains("line 2") && err.contains("syntax error"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1);
}

/// Case A with its TIF far narrower than a pixel (sigma 0.05 mm on 0.36 mm pixels) once gave
/// 77 nm RMS of 147 nm with `target_met: true` and exit 0: min-dwell held a total dwell below
/// what any non-negative map needs. The near-delta TIF inverts to ~1e-4 nm (RIFTA); min-dwell
/// must come within 0.1 % of the desired removal (0.15 nm) and say it converged.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn narrow_tif_converges_on_case_a() {
    let dir = tempfile::tempdir().unwrap();
    let src = case("rifta_case_a.toml");
    let text = std::fs::read_to_string(&src).unwrap();
    let dat = src.with_file_name("rifta_case_a.dat");
    let narrow = text.replace("sigma_mm = 1.0", "sigma_mm = 0.05").replace(
        "surface = \"rifta_case_a.dat\"",
        &format!("surface = {:?}", dat.display().to_string()),
    );
    assert_ne!(narrow, text);
    let p = dir.path().join("narrow.toml");
    std::fs::write(&p, narrow).unwrap();
    let o = bin().arg("dwell").arg(&p).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rms = v["residual_rms_nm"].as_f64().unwrap();
    assert!(rms < 0.147, "{rms}");
    assert_eq!(v["target_met"], true);
    assert_eq!(v["convergence"]["converged"], true);
    assert!(v["note"].is_null());
}

/// A sweep that did not converge (one healing iteration per point on case A: its best point
/// stays above 2 x the unconstrained inverse filter's residual) is never a silent answer: the
/// JSON is written with `target_met: false` and a `note`, and the command ends with that note
/// on one stderr line and exit code 1.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn unconverged_sweep_exits_1_with_a_note() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("dwell.json");
    let o = bin()
        .arg("dwell")
        .arg(case("rifta_case_a.toml"))
        .args(["--iterations", "1", "--json"])
        .arg(&json)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("did not converge") && err.trim_end().lines().count() == 1,
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["target_met"], false);
    assert_eq!(v["convergence"]["converged"], false);
    assert!(v["note"].as_str().unwrap().contains("did not converge"));
}
