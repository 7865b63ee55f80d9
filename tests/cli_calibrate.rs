//! `bonnetlab calibrate` end to end: a synthetic run directory written through the real file
//! formats (MetroPro .dat maps, path CSV, recipe TOML), the JSON contract of
//! spec/interfaces.md, the HTML report, and one-line errors with exit code 2 on bad input.

use std::process::Command;

use bonnetlab::calibrate::synth::write::write_run;
use bonnetlab::calibrate::synth::{generate, Injected, SynthConfig};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

#[test]
fn calibrate_writes_the_contract_json_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = SynthConfig {
        seed: 31,
        effects: vec![Injected::RateDrift {
            fraction_per_run: -0.2,
        }],
        ..SynthConfig::default()
    };
    let recipe = write_run(dir.path(), &generate(&cfg).unwrap()).unwrap();
    let json = dir.path().join("cal.json");
    let out = dir.path().join("report");
    let o = bin()
        .arg("calibrate")
        .arg(&recipe)
        .arg("--json")
        .arg(&json)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    for k in [
        "residual_rms_nm",
        "residual_pv_nm",
        "measured_removal_rms_nm",
    ] {
        assert!(v["baseline"][k].as_f64().unwrap() > 0.0, "baseline.{k}");
    }
    assert!(
        v["final"]["residual_rms_nm"].as_f64().unwrap()
            < v["baseline"]["residual_rms_nm"].as_f64().unwrap()
    );
    assert!(v["noise_floor_rms_nm"].as_f64().unwrap() > 0.0);
    assert!(v["unexplained"].is_array());
    let e = &v["effects"][0];
    assert_eq!(e["kind"], "rate_drift");
    let f = e["params"]["fraction_per_run"].as_f64().unwrap();
    assert!((f + 0.2).abs() < 0.04, "{f}");
    for k in [
        "residual_rms_before_nm",
        "residual_rms_after_nm",
        "significance",
    ] {
        assert!(e[k].as_f64().is_some(), "{k}");
    }
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        html.contains("rate_drift")
            && html.contains("<svg")
            && html.contains("data:image/png;base64")
    );
    assert!(out.join("calibration.json").exists());
}

#[test]
fn bad_input_is_one_line_with_exit_code_2() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = dir.path().join("recipe.toml");
    std::fs::write(&recipe, "[measurement]\nbefore = \"missing.dat\"\nafter = \"after.dat\"\n[tif]\nspot = \"s.dat\"\ndwell_s = 10.0\n[path]\nlog = \"p.csv\"\n").unwrap();
    let o = bin().arg("calibrate").arg(&recipe).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("missing.dat"), "{err}");
    let o = bin()
        .arg("calibrate")
        .arg(dir.path().join("nope.toml"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}

/// Unit slips were calibrated without a word (reports/reliability.md, section 11: a spot's
/// `dwell_s` in ms gave rate_scale 1011.7, exit 0). The sample run as shipped has no warning;
/// its recipe with `dwell_s` 200 (ms for 0.2 s) and with the two maps swapped each warn on
/// stderr, naming the recipe, and in the JSON's `warnings`, and the run still completes.
#[test]
fn a_unit_slip_or_swapped_maps_are_warned_about() {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/original");
    let dir = tempfile::tempdir().unwrap();
    for f in ["before.dat", "after.dat", "spot.dat", "path.csv"] {
        std::fs::copy(src.join(f), dir.path().join(f)).unwrap();
    }
    let recipe = std::fs::read_to_string(src.join("recipe.toml")).unwrap();
    assert!(recipe.contains("dwell_s = 0.2") && recipe.contains("before = \"before.dat\""));
    let cases = [
        ("shipped", recipe.clone(), None),
        (
            "ms",
            recipe.replace("dwell_s = 0.2", "dwell_s = 200"),
            Some("a unit slip is likely"),
        ),
        (
            "swapped",
            recipe
                .replace("before = \"before.dat\"", "before = \"X\"")
                .replace("after = \"after.dat\"", "after = \"before.dat\"")
                .replace("before = \"X\"", "before = \"after.dat\""),
            Some("not swapped"),
        ),
    ];
    for (name, text, warning) in cases {
        let r = dir.path().join(format!("{name}.toml"));
        std::fs::write(&r, text).unwrap();
        let o = bin().arg("calibrate").arg(&r).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{name}: {err}");
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let scale = v["baseline"]["rate_scale"].as_f64().unwrap();
        match warning {
            None => {
                assert!(v.get("warnings").is_none(), "{name}: {v:.300}");
                assert!(!err.contains("warning:"), "{name}: {err}");
                assert!((scale - 1.0).abs() < 0.1, "{name}: rate_scale {scale}");
            }
            Some(w) => {
                let ws = v["warnings"].as_array().expect("warnings");
                assert!(
                    ws.len() == 1 && ws[0].as_str().unwrap().contains(w),
                    "{ws:?}"
                );
                let line = err.lines().find(|l| l.starts_with("warning: ")).unwrap();
                assert!(
                    line.contains(r.to_str().unwrap()) && line.contains(w),
                    "{line}"
                );
            }
        }
        if name == "ms" {
            assert!((scale / 1000.0 - 1.0).abs() < 0.1, "rate_scale {scale}");
        }
        if name == "swapped" {
            assert!(scale < 0.0, "rate_scale {scale}");
        }
    }
}
