//! `bonnetlab vibration`: the JSON contract of spec/interfaces.md, recipe handling, errors,
//! and the plots / time series written with `--out`.

use std::path::Path;
use std::process::Command;

fn bonnetlab(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .args(args)
        .output()
        .expect("run bonnetlab")
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_string_lossy().into_owned()
}

const RECIPE: &str = r#"
[process]
bonnet = "suppression"
spindle_rpm = 1000.0

[vibration]
k1_n_per_mm = 1476.0
k2_n_per_mm = 328.9
theta_deg = 13.2
mass_kg = 50.0
zeta1 = 0.02
zeta2 = 0.02
fn_n = 40.0
mu = 0.3
loss_factor = 0.115
spindle_rpm = 1000.0
"#;

#[test]
fn json_has_the_contract_fields_and_the_closed_form_values() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write(dir.path(), "run.toml", RECIPE);
    let out = dir.path().join("vib.json");
    let o = bonnetlab(&["vibration", &recipe, "--json", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    for key in [
        "bonnet",
        "excitation_hz",
        "x1_amplitude_mm",
        "x2_amplitude_mm",
        "x1_phase_deg",
        "x2_phase_deg",
        "zeta1_effective",
        "zeta2_effective",
        "natural_freq1_hz",
        "natural_freq2_hz",
        "frf",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    assert_eq!(v["bonnet"], "suppression");
    // Independent closed form for this recipe (suppression: ζ = 0.02 + 0.0575).
    let th = 13.2f64.to_radians();
    let f2 = 40.0 * (th.cos() - 0.3 * th.sin());
    let w = 2.0 * std::f64::consts::PI * 1000.0 / 60.0;
    let wn2 = (328.9e3f64 / 50.0).sqrt();
    let l = w / wn2;
    let z = 0.02 + 0.0575;
    let x2 = (f2 / 328.9) / ((1.0 - l * l).powi(2) + (2.0 * z * l).powi(2)).sqrt();
    let got = v["x2_amplitude_mm"].as_f64().unwrap();
    assert!((got - x2).abs() < 1e-9 * x2, "{got} vs {x2}");
    assert!((v["zeta2_effective"].as_f64().unwrap() - z).abs() < 1e-12);
    assert!(
        (v["natural_freq2_hz"].as_f64().unwrap() - wn2 / (2.0 * std::f64::consts::PI)).abs() < 1e-9
    );
    let frf = v["frf"].as_array().unwrap();
    assert!(frf.len() > 100);
    let first = frf[0]["freq_hz"].as_f64().unwrap();
    let last = frf[frf.len() - 1]["freq_hz"].as_f64().unwrap();
    assert!((first - 250.0 / 60.0).abs() < 1e-9 && (last - 2000.0 / 60.0).abs() < 1e-9);
    for p in frf {
        assert!(
            p["x1_amplitude_mm"].as_f64().unwrap() > 0.0
                && p["x2_amplitude_mm"].as_f64().unwrap() > 0.0
        );
    }
}

#[test]
fn both_bonnets_give_an_array_and_suppression_damps_more() {
    let o = bonnetlab(&["vibration", "--bonnet", "both", "--json", "-"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let a = v.as_array().unwrap();
    assert_eq!(a.len(), 2);
    assert_eq!(a[0]["bonnet"], "original");
    assert_eq!(a[1]["bonnet"], "suppression");
    let z0 = a[0]["zeta1_effective"].as_f64().unwrap();
    let z1 = a[1]["zeta1_effective"].as_f64().unwrap();
    assert!((z1 - z0 - 0.0575).abs() < 1e-12);
    let peak = |x: &serde_json::Value| {
        x["frf"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["x2_amplitude_mm"].as_f64().unwrap())
            .fold(0.0, f64::max)
    };
    assert!(peak(&a[1]) < peak(&a[0]));
}

#[test]
fn bad_input_names_the_file_and_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write(dir.path(), "bad.toml", "[vibration]\nzeta1 = -0.5\n");
    let o = bonnetlab(&["vibration", &recipe, "--json", "-"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.toml") && err.contains("zeta1"), "{err}");
    assert_eq!(err.trim().lines().count(), 1);

    let typo = write(dir.path(), "typo.toml", "[vibration]\nk_1 = 3.0\n");
    let o = bonnetlab(&["vibration", &typo]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("k_1"));

    let o = bonnetlab(&["vibration", "--bonnet", "rubber"]);
    assert_eq!(o.status.code(), Some(2));
    let o = bonnetlab(&[
        "vibration",
        &dir.path().join("missing.toml").to_string_lossy(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.toml"));
}

#[test]
fn out_dir_gets_frf_plots_and_a_time_series() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("vib");
    let o = bonnetlab(&[
        "vibration",
        "--out",
        out.to_str().unwrap(),
        "--duration-s",
        "2",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["frf_x1.svg", "frf_x1.png", "frf_x2.svg", "frf_x2.png"] {
        let bytes = std::fs::read(out.join(f)).unwrap();
        assert!(bytes.len() > 1000, "{f}");
    }
    let csv = std::fs::read_to_string(out.join("timeseries.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0],
        "t_s,x1_mm,x2_mm,normal_mm,lateral_mm,offset_change_mm"
    );
    assert_eq!(lines.len(), 1 + 2001);
}
