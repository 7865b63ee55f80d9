//! `bonnetlab batch`: one JSON line per map in input order, stats equal to the library's,
//! ripple with `--pitch-mm`, an error line and exit 1 for a bad map, manifests and single maps.

use std::process::Command;

use bonnetlab::io::{write_surface, MapFormat};
use bonnetlab::spectrum::{ripple, PsdOptions};
use bonnetlab::surface::{height_stats, remove_terms, Term};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn lines(stdout: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8_lossy(stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn batch_over_a_directory_and_a_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let maps = bonnetlab::report::samples::generate(3, 1);
    let mut names = Vec::new();
    for (k, m) in maps.iter().enumerate() {
        let name = format!("m{k}_{}_{}.dat", m.bonnet, m.state);
        write_surface(&dir.path().join(&name), &m.surface, MapFormat::MetroProDat).unwrap();
        names.push(name);
    }
    names.sort();
    std::fs::write(dir.path().join("notes.txt"), "not a map").unwrap();
    let o = bin()
        .args(["batch", "--jobs", "2", "--pitch-mm", "3"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let got = lines(&o.stdout);
    assert_eq!(got.len(), 4, "notes.txt is not a map");
    for (v, name) in got.iter().zip(&names) {
        assert!(
            v["file"].as_str().unwrap().ends_with(name.as_str()),
            "order: {} vs {name}",
            v["file"]
        );
        let s = bonnetlab::io::read_surface(&dir.path().join(name)).unwrap();
        let st = height_stats(&remove_terms(&s, &[Term::Piston, Term::Tilt]).unwrap().0).unwrap();
        assert!((v["rms_nm"].as_f64().unwrap() - st.rms_nm).abs() < 1e-9);
        assert!((v["pv_nm"].as_f64().unwrap() - st.pv_nm).abs() < 1e-9);
        assert_eq!(v["format"], "metropro-dat");
        let r = ripple(&s, 3.0, &PsdOptions::default()).unwrap();
        assert!((v["ripple"]["sigma1_nm"].as_f64().unwrap() - r.sigma1_nm).abs() < 1e-9);
    }
    // Same result with one thread: the order and values do not depend on parallelism.
    let o1 = bin()
        .args(["batch", "--jobs", "1", "--pitch-mm", "3"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(o1.stdout, o.stdout);

    // A manifest with a comment, a relative path and a missing file.
    let manifest = dir.path().join("list.txt");
    std::fs::write(&manifest, format!("# maps\n{}\n\nmissing.dat\n", names[1])).unwrap();
    let o = bin().arg("batch").arg(&manifest).output().unwrap();
    // The one failure is bad input: exit 2, as `stats missing.dat` would.
    assert_eq!(o.status.code(), Some(2));
    let got = lines(&o.stdout);
    assert_eq!(got.len(), 2);
    assert!(got[0]["error"].is_null() && got[0]["rms_nm"].is_number());
    assert!(got[1]["error"].as_str().unwrap().contains("missing.dat"));
    assert_eq!(got[1]["exit_code"], 2);
    assert!(String::from_utf8_lossy(&o.stderr).contains("1 of 2 maps failed"));

    // A single map is a batch of one.
    let o = bin()
        .arg("batch")
        .arg(dir.path().join(&names[0]))
        .output()
        .unwrap();
    assert!(o.status.success());
    assert_eq!(lines(&o.stdout).len(), 1);

    // A map without a pixel size keeps its statistics under --pitch-mm; the ripple is absent
    // with its reason (it was a failed map before).
    let nopx = dir.path().join("nopx.csv");
    let grid: String = (0..12)
        .map(|i| {
            (0..12)
                .map(|j| format!("{}", ((i * 7 + j * 3) % 5) as f64))
                .collect::<Vec<_>>()
                .join(",")
                + "\n"
        })
        .collect();
    std::fs::write(&nopx, grid).unwrap();
    let o = bin()
        .args(["batch", "--pitch-mm", "3"])
        .arg(&nopx)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let got = lines(&o.stdout);
    assert!(
        got[0]["rms_nm"].as_f64().is_some_and(|v| v > 0.0),
        "{}",
        got[0]
    );
    assert!(
        got[0]["dx_mm"].is_null() && got[0]["ripple"].is_null(),
        "{}",
        got[0]
    );
    assert!(
        got[0]["ripple_reason"]
            .as_str()
            .is_some_and(|r| r.contains("pixel size is unknown")),
        "{}",
        got[0]
    );
}
