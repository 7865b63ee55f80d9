//! Issues #19 and #17: on a micron-scale map (70 x 70 pixels of 1 um: a 0.07 mm field), every
//! number `stats --bands`, `psd` and `compare` show is right or absent with a reason. Before the
//! fix, `compare --pitch-mm 3` on such a map printed ripple band edges "-75.68 to 77.68 1/mm",
//! a "NaN %" CR, "prominence 11.8 dB, detected: no" without a reason, counted one harmonic
//! band five times, and `msf.rms_nm` was 0.0 for an MSF band outside the measured range.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use bonnetlab_io::{write_surface, MapFormat};
use bonnetlab_surface::{rng::Rng, Surface};
use ndarray::Array2;
use serde_json::Value;

fn bonnetlab(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .args(args)
        .output()
        .expect("the binary runs")
}

fn json(out: &Output) -> Value {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("stdout is one JSON object")
}

/// A 70 x 70 map of 1 um pixels: roughness with power to the pixel scale, a few dropouts.
fn micron_map(dir: &Path, name: &str, seed: u64) -> PathBuf {
    let mut r = Rng::new(seed);
    let z = Array2::from_shape_fn((70, 70), |(i, j)| {
        let (x, y) = (j as f64 * 0.001, i as f64 * 0.001);
        3.0 * (2.0 * std::f64::consts::PI * x / 0.02).sin()
            + 2.0 * (2.0 * std::f64::consts::PI * y / 0.013).cos()
            + r.normal()
    });
    let mut s = Surface::new(z, Some(0.001), Some(0.001)).unwrap();
    let mut v = s.valid().clone();
    for k in 0..40 {
        v[((k * 37) % 70, (k * 11) % 70)] = false;
    }
    s = s.with_valid(v).unwrap();
    let p = dir.join(name);
    write_surface(&p, &s, MapFormat::Csv).unwrap();
    p
}

/// Every number in a JSON document is finite (serde writes NaN / infinity as null, so this
/// and the null checks below together exclude them), and every null among the keys of `keys`
/// has a string `*reason*` sibling.
fn check_absent_have_reasons(v: &Value, keys: &[&str], path: &str) {
    match v {
        Value::Object(m) => {
            let has_reason = m
                .iter()
                .any(|(k, v)| k.contains("reason") && v.as_str().is_some_and(|s| !s.is_empty()));
            for (k, x) in m {
                if x.is_null() && keys.contains(&k.as_str()) {
                    assert!(has_reason, "{path}.{k} is null without a reason: {v}");
                }
                check_absent_have_reasons(x, keys, &format!("{path}.{k}"));
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                check_absent_have_reasons(x, keys, &format!("{path}[{i}]"));
            }
        }
        Value::Number(n) => assert!(n.as_f64().is_some_and(f64::is_finite), "{path}"),
        _ => {}
    }
}

const BAND_KEYS: [&str; 9] = [
    "figure_rms_nm",
    "msf_rms_nm",
    "fine_rms_nm",
    "rms_nm",
    "rms_before_nm",
    "rms_after_nm",
    "cr",
    "rms_unbiased_nm",
    "f1_used_per_mm",
];

#[test]
fn stats_bands_on_a_micron_map_are_absent_with_reasons() {
    let dir = tempfile::tempdir().unwrap();
    let f = micron_map(dir.path(), "m.csv", 1);
    let v = json(&bonnetlab(&[
        "stats",
        f.to_str().unwrap(),
        "--bands",
        "--json",
    ]));
    let b = &v["bands"];
    assert!(
        b["figure_rms_nm"].is_null() && b["msf_rms_nm"].is_null(),
        "{b}"
    );
    assert!(
        b["msf_reason"]
            .as_str()
            .unwrap()
            .contains("lies below the lowest measured frequency"),
        "{b}"
    );
    // The whole RMS is in the fine band, which is what the map measures.
    let fine = b["fine_rms_nm"].as_f64().unwrap();
    let rms = v["rms_nm"].as_f64().unwrap();
    assert!((fine / rms - 1.0).abs() < 1e-9, "{fine} vs {rms}");
    assert_eq!(b["edges_per_mm"][0].as_f64().unwrap(), 1.0 / 33.0);
    check_absent_have_reasons(&v, &BAND_KEYS, "stats");
    // The table says "absent" with the reason.
    let out = bonnetlab(&["stats", f.to_str().unwrap(), "--bands"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("absent: not resolvable"), "{text}");
}

#[test]
fn psd_on_a_micron_map_with_a_3_mm_pitch() {
    let dir = tempfile::tempdir().unwrap();
    let f = micron_map(dir.path(), "m.csv", 2);
    let v = json(&bonnetlab(&[
        "psd",
        f.to_str().unwrap(),
        "--pitch-mm",
        "3",
        "--json",
    ]));
    assert!(v.get("ripple").is_none(), "{v}");
    assert_eq!(
        v["ripple_reason"].as_str().unwrap(),
        "not resolvable: the 3 mm pitch is longer than the 0.07 mm field (Y lines)"
    );
    for axis in ["x", "y"] {
        let msf = &v[axis]["msf"];
        assert!(
            msf["rms_nm"].is_null() && msf["reason"].is_string(),
            "{msf}"
        );
    }
    check_absent_have_reasons(&v, &BAND_KEYS, "psd");
    let out = bonnetlab(&["psd", f.to_str().unwrap(), "--pitch-mm", "3"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(!text.contains("NaN") && !text.contains("inf"), "{text}");
    assert!(text.contains("ripple along Y: absent (not resolvable: the 3 mm pitch is longer than the 0.07 mm field"), "{text}");
}

#[test]
fn compare_on_a_micron_map_with_a_3_mm_pitch() {
    let dir = tempfile::tempdir().unwrap();
    let b = micron_map(dir.path(), "b.csv", 3);
    let a = micron_map(dir.path(), "a.csv", 4);
    let out_dir = dir.path().join("out");
    let run = format!("small={},{}", b.display(), a.display());
    let out = bonnetlab(&[
        "compare",
        "--run",
        &run,
        "--pitch-mm",
        "3",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
            .unwrap();
    check_absent_have_reasons(&j, &BAND_KEYS, "report");
    let r = &j["runs"][0];
    assert!(r.get("ripple_before").is_none() && r.get("ripple_after").is_none());
    assert!(r["ripple_reason"]
        .as_str()
        .unwrap()
        .contains("the 3 mm pitch is longer than the 0.07 mm field"));
    for band in r["bands"].as_array().unwrap() {
        let f1 = band["f1_per_mm"].as_f64().unwrap();
        let f2 = band["f2_per_mm"].as_f64().unwrap();
        assert!(f1 >= 0.0 && f2 >= f1, "{band}");
        if band["band"] == "ripple" || band["band"] == "figure" || band["band"] == "msf" {
            assert!(
                band["rms_before_nm"].is_null() && band["cr"].is_null(),
                "{band}"
            );
            assert!(band["reason"].is_string(), "{band}");
        }
    }
    // The PSD-quantity table over the same edges is absent with the same reason: before the
    // fix it held MSF 0.000 / 0.000 and figure 36.902 / 36.439 nm (annulus sums of no bins, or
    // of the DC bin) under a map-RMS table saying "absent: not resolvable".
    let areal = r["bands"].as_array().unwrap();
    for band in r["bands_psd"].as_array().unwrap() {
        let name = band["band"].as_str().unwrap();
        let same = areal.iter().find(|b| b["band"] == name).unwrap();
        for key in ["rms_before_nm", "rms_after_nm", "cr"] {
            assert!(band[key].is_null(), "bands_psd {name}: {band}");
        }
        assert_eq!(band["reason"], same["reason"], "bands_psd {name}");
    }
    // The fine band holds the map's RMS: figure and MSF lie below 1 / 0.07 mm.
    let fine = &r["band_fine"];
    let rb = r["rms_before_nm"].as_f64().unwrap();
    assert!((fine["rms_before_nm"].as_f64().unwrap() / rb - 1.0).abs() < 1e-9);
    let html = std::fs::read_to_string(out_dir.join("report.html")).unwrap();
    for bad in ["NaN", "-75.68", "inf %", ">inf<"] {
        assert!(!html.contains(bad), "HTML contains {bad}");
    }
    assert!(html.contains(
        "ripple absent (not resolvable: the 3 mm pitch is longer than the 0.07 mm field"
    ));
    assert!(html.contains("absent"));
    let psd_table = &html[html.find("For reference, a PSD quantity").unwrap()..];
    let psd_table = &psd_table[..psd_table.find("</table>").unwrap()];
    assert!(
        !psd_table.contains("0.000") && psd_table.contains("absent"),
        "{psd_table}"
    );
}

/// `batch --pitch-mm 3` over a micron map and a map that resolves the pitch: the micron map's
/// line carries its statistics and `ripple_reason` (not an `error`, not a failed exit), the other
/// its `ripple` object. Before the fix the micron map's line was an error ("not resolvable",
/// exit_code 2) and the batch exited 1.
#[test]
fn batch_on_a_micron_map_with_a_3_mm_pitch() {
    let dir = tempfile::tempdir().unwrap();
    micron_map(dir.path(), "a_small.csv", 5);
    // 120 x 120 at 0.25 mm (a 30 mm field) with a 3 mm ripple along Y.
    let mut r = Rng::new(6);
    let z = Array2::from_shape_fn((120, 120), |(i, _)| {
        4.0 * (2.0 * std::f64::consts::PI * i as f64 * 0.25 / 3.0).sin() + 0.5 * r.normal()
    });
    let big = dir.path().join("b_field.csv");
    write_surface(
        &big,
        &Surface::new(z, Some(0.25), Some(0.25)).unwrap(),
        MapFormat::Csv,
    )
    .unwrap();
    let out = bonnetlab(&["batch", dir.path().to_str().unwrap(), "--pitch-mm", "3"]);
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2);
    let (s, b) = (&lines[0], &lines[1]);
    assert!(s.get("error").is_none() && s.get("ripple").is_none(), "{s}");
    assert_eq!(
        s["ripple_reason"].as_str().unwrap(),
        "not resolvable: the 3 mm pitch is longer than the 0.07 mm field (Y lines)"
    );
    assert!(s["rms_nm"].as_f64().unwrap() > 0.0, "{s}");
    check_absent_have_reasons(s, &BAND_KEYS, "batch[0]");
    assert!(b.get("ripple_reason").is_none(), "{b}");
    // A 4 nm sine has an RMS of 4 / sqrt(2) = 2.83 nm, all of it in the f0 band.
    let sigma1 = b["ripple"]["sigma1_nm"].as_f64().unwrap();
    assert!((sigma1 / (4.0 / 2f64.sqrt()) - 1.0).abs() < 0.1, "{b}");
}

/// A reference run without removal (its before map given as its after map): the improvement
/// over it is undefined, absent with a reason rather than a bare null (it was NaN, printed as
/// null). The other run's own figures stand.
#[test]
fn compare_against_a_reference_without_removal_says_why_there_is_no_improvement() {
    let dir = tempfile::tempdir().unwrap();
    let a = micron_map(dir.path(), "a.dat", 1);
    let b = micron_map(dir.path(), "b.dat", 2);
    let out = dir.path().join("o");
    let o = bonnetlab(&[
        "compare",
        "--run",
        &format!("z={},{}", a.display(), a.display()),
        "--run",
        &format!("b={},{}", a.display(), b.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let b = &v["runs"][1];
    assert_eq!(
        v["runs"][0]["cr_rms"].as_f64(),
        Some(0.0),
        "{}",
        v["runs"][0]
    );
    assert!(b["cr_rms"].as_f64().is_some_and(f64::is_finite), "{b}");
    assert!(
        b.get("improvement_cr_rms").is_none() && b.get("improvement").is_none(),
        "{b}"
    );
    let why = b["improvement_reason"].as_str().expect("a reason");
    assert!(why.contains("'z'") && why.contains("undefined"), "{why}");
}
