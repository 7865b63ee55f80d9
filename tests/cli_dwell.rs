//! `bonnetlab dwell` end to end: the contract's JSON fields on the public case A, the output
//! directory, and one-line errors with exit code 2 on bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn case(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/dwell")
        .join(name)
}

#[test]
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
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rms = v["residual_rms_nm"].as_f64().unwrap();
    assert!(rms > 0.0 && rms <= 0.08, "{rms}");
    assert!(v["residual_pv_nm"].as_f64().unwrap() > rms);
    // Total dwell: hundreds of minutes on this case (reference scripts: 522 to 1047 min).
    let total_min = v["total_dwell_s"].as_f64().unwrap() / 60.0;
    assert!((300.0..5000.0).contains(&total_min), "{total_min}");
    assert!(v["wall_s"].as_f64().unwrap() > 0.0);
    assert_eq!(v["method"], "rifta");
    for f in [
        "dwell_s.csv",
        "residual.dat",
        "dwell_map.png",
        "residual.png",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // The residual map written is the one the JSON describes.
    let res = bonnetlab::io::read_surface(&out.join("residual.dat")).unwrap();
    let st = bonnetlab::surface::height_stats(&res).unwrap();
    assert!(
        (st.rms_nm - rms).abs() < 1e-3 * rms.max(1e-3) + 1e-4,
        "{} vs {rms}",
        st.rms_nm
    );
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
