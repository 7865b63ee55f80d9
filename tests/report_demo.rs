//! The README's first command and the committed example: `bonnetlab demo` regenerates the
//! committed samples byte for byte from their seed, and its report on them equals the
//! committed `reports/demo` output (so the example cannot silently go stale).

use std::path::Path;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

#[test]
fn samples_regenerate_bit_for_bit_from_their_seed() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let o = bin()
        .args(["demo", "--generate-samples"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for bonnet in ["original", "suppression"] {
        for name in ["before_1.dat", "before_2.dat", "after_1.dat", "after_2.dat"] {
            let fresh = std::fs::read(dir.path().join(bonnet).join(name)).unwrap();
            let committed = std::fs::read(repo.join("samples").join(bonnet).join(name)).unwrap();
            assert!(
                fresh == committed,
                "samples/{bonnet}/{name} differs from what the generator writes"
            );
            assert!(committed.len() < 1_000_000);
        }
    }
    let readme = std::fs::read_to_string(dir.path().join("README.md")).unwrap();
    assert_eq!(
        readme,
        std::fs::read_to_string(repo.join("samples/README.md")).unwrap()
    );
}

#[test]
fn demo_report_equals_the_committed_example() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let o = bin()
        .current_dir(repo)
        .args(["demo", "--samples", "samples", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // Progress is visible even without a terminal.
    assert!(
        err.contains("analysed samples/original/before_1.dat"),
        "{err}"
    );
    assert!(err.contains("improvement CR(RMS)"), "{err}");
    // Numbers may differ in the last bits between debug and release builds (libm / powi),
    // so the JSON and CSVs are compared as numbers to 1e-9 relative; the HTML by presence.
    let read_json = |p: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
    };
    same_numbers(
        &read_json(&dir.path().join("report.json")),
        &read_json(&repo.join("reports/demo/report.json")),
        "report.json",
    );
    for f in [
        "psd_x_original.csv",
        "psd_y_original.csv",
        "psd_x_suppression.csv",
        "psd_y_suppression.csv",
    ] {
        let fresh = std::fs::read_to_string(dir.path().join(f)).unwrap();
        let committed = std::fs::read_to_string(repo.join("reports/demo").join(f)).unwrap();
        assert_eq!(fresh.lines().count(), committed.lines().count(), "{f}");
        for (a, b) in fresh.lines().zip(committed.lines()).skip(1) {
            for (x, y) in a.split(',').zip(b.split(',')) {
                let (x, y): (f64, f64) = (x.parse().unwrap(), y.parse().unwrap());
                assert!(
                    (x - y).abs() <= 1e-9 * x.abs().max(y.abs()),
                    "reports/demo/{f} is stale: {x} vs {y}"
                );
            }
        }
    }
    assert!(repo.join("reports/demo/report.html").is_file());
    // The example shows what the paper's table shows: the suppression bonnet converges better,
    // beyond the repeat noise.
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    let s = &j["runs"][1];
    assert_eq!(s["name"], "suppression");
    assert!(s["improvement_cr_rms"].as_f64().unwrap() > 0.2);
    assert_eq!(s["improvement"]["noise"]["rms_within_noise"], false);
    let rip_o = j["runs"][0]["ripple_after"]["sigma1_nm"].as_f64().unwrap();
    let rip_s = s["ripple_after"]["sigma1_nm"].as_f64().unwrap();
    assert!(
        rip_o > 1.5 * rip_s,
        "ripple original {rip_o} vs suppression {rip_s}"
    );
}

/// Recursive comparison: equal structure and strings, numbers to 1e-9 relative.
fn same_numbers(a: &serde_json::Value, b: &serde_json::Value, at: &str) {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!(
                (x - y).abs() <= 1e-9 * x.abs().max(y.abs()),
                "reports/demo/report.json is stale at {at}: {x} vs {y} (rerun `bonnetlab demo --out reports/demo`)"
            );
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{at}");
            for (k, (u, v)) in x.iter().zip(y).enumerate() {
                same_numbers(u, v, &format!("{at}[{k}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            assert_eq!(
                x.keys().collect::<Vec<_>>(),
                y.keys().collect::<Vec<_>>(),
                "{at}"
            );
            for (k, u) in x {
                same_numbers(u, &y[k], &format!("{at}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "reports/demo/report.json is stale at {at}"),
    }
}
