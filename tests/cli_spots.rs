//! `bonnetlab spots` end to end: the bundled sample sweep (generated with known models) through
//! the binary, its outputs, the fitted models against the generating ones, the exported model in
//! a recipe, and bad manifests (exit 2, one line naming the file).

use std::path::Path;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b
}

#[test]
fn sample_sweep_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let sample = dir.path().join("sample");
    let st = bin()
        .args(["spots", "--make-sample"])
        .arg(&sample)
        .status()
        .unwrap();
    assert!(st.success());
    let out = dir.path().join("out");
    let o = bin()
        .arg("spots")
        .arg(sample.join("manifest.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in [
        "report.html",
        "report.json",
        "spots.csv",
        "trends.csv",
        "model_original.toml",
        "model_suppression.toml",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let v = json(&out.join("report.json"));
    assert_eq!(v["spots"].as_array().unwrap().len(), 10);
    assert_eq!(v["sweeps"], serde_json::json!(["offset_mm"]));
    assert_eq!(v["reference_bonnet"], "original");
    // The generating models of --make-sample (see src/cli/spots.rs).
    for (k, (kp, e)) in [(0.020, 2.0), (0.015, 1.2)].into_iter().enumerate() {
        let m = &v["fits"][k]["fit"]["model"];
        assert!(rel(m["radius_mm"].as_f64().unwrap(), 20.0) < 0.05, "{m}");
        assert!(
            rel(m["preston_nm_per_mpa_mm"].as_f64().unwrap(), kp) < 0.05,
            "{m}"
        );
        assert!(rel(m["modulus_mpa"].as_f64().unwrap(), e) < 0.05, "{m}");
    }
    // Optimisation degree recomputed from the per-spot table.
    let spots = v["spots"].as_array().unwrap();
    let mean = |b: &str| {
        let xs: Vec<f64> = spots
            .iter()
            .filter(|s| s["bonnet"] == b)
            .map(|s| s["metrics"]["region_rms_nm"].as_f64().unwrap())
            .collect();
        xs.iter().sum::<f64>() / xs.len() as f64
    };
    let want = (mean("original") - mean("suppression")) / mean("original");
    let opt = v["optimisation"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["metric"] == "region_rms_nm")
        .unwrap();
    assert!((opt["degree"].as_f64().unwrap() - want).abs() < 1e-9);
    let csv = std::fs::read_to_string(out.join("spots.csv")).unwrap();
    assert_eq!(csv.lines().count(), 11);
    assert!(csv.starts_with("file,bonnet,dwell_s,"));
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("Optimisation degree") && html.contains("<svg"));

    // The exported model is a valid recipe [tif] table.
    let model = std::fs::read_to_string(out.join("model_suppression.toml")).unwrap();
    let recipe = format!(
        "[measurement]\nbefore = \"before.dat\"\n\n[path]\nlog = \"path.csv\"\n\n{}",
        model.split("\n[spots_fit]\n").next().unwrap()
    );
    let r = bonnetlab::process::Recipe::parse(&recipe, Path::new("/runs/recipe.toml")).unwrap();
    match r.tif {
        bonnetlab::process::recipe::TifSource::Bonnet(p) => assert!(rel(p.radius_mm, 20.0) < 0.05),
        other => panic!("not a bonnet model: {other:?}"),
    }
    let whole = format!("[measurement]\nbefore = \"b.dat\"\n\n[path]\nlog = \"p.csv\"\n\n{model}");
    // The whole file, with its spots_fit table, is accepted by the recipe reader too.
    assert!(bonnetlab::process::Recipe::parse(&whole, Path::new("r.toml")).is_ok());
}

#[test]
fn bad_manifests_exit_2_with_one_line_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let cases = [
        ("bad_key.toml", "[[spot]]\nfile = \"a.dat\"\nbonnet = \"original\"\ndwel_s = 120\n", "dwel_s"),
        (
            "bad_value.toml",
            "[defaults]\ndwell_s = 120.0\nprecession_deg = 20.0\nspindle_rpm = 500.0\ninner_pressure_mpa = 0.25\n\n[[spot]]\nfile = \"a.dat\"\nbonnet = \"original\"\noffset_mm = \"deep\"\n",
            "line",
        ),
        (
            "bad.csv",
            "file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,inner_pressure_mpa\na.dat,original,120,20,0.2,-500,0.25\n",
            "spindle_rpm",
        ),
        (
            "missing_map.toml",
            "[defaults]\ndwell_s = 120.0\nprecession_deg = 20.0\noffset_mm = 0.8\nspindle_rpm = 500.0\ninner_pressure_mpa = 0.25\n\n[[spot]]\nfile = \"nowhere.dat\"\nbonnet = \"original\"\n",
            "nowhere.dat",
        ),
    ];
    for (name, text, needle) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        let o = bin()
            .arg("spots")
            .arg(&p)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{name}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.trim_end().lines().count(), 1, "{name}: {err}");
        assert!(err.contains(name), "{name}: {err}");
        assert!(err.contains(needle), "{name}: {err}");
    }
    assert!(!out.exists(), "nothing is written on bad input");
    let o = bin()
        .arg("spots")
        .arg(dir.path().join("absent.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}
