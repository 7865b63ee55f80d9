//! A new user's first hour (issue #17): `demo` with no arguments, one-line summaries on
//! stdout, `--pixel-mm` where a map may lack its pixel size, and numbers printed to their
//! precision.

use std::path::Path;
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "exit {:?}: {}",
        o.status.code(),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8(o.stdout.clone()).unwrap()
}

/// A 64 x 64 CSV map with no pixel size (CSV without a `# dx_mm=` header carries none).
fn csv_without_pixel_size(path: &Path, phase: f64) {
    let mut t = String::new();
    for i in 0..64 {
        let row: Vec<String> = (0..64)
            .map(|j| {
                let v = 20.0 * ((i as f64) * 0.7 + phase).sin() + 5.0 * ((j as f64) * 0.3).cos();
                format!("{v:.4}")
            })
            .collect();
        t.push_str(&row.join(","));
        t.push('\n');
    }
    std::fs::write(path, t).unwrap();
}

#[test]
fn demo_with_no_arguments_writes_the_report_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let o = bin().arg("demo").current_dir(dir.path()).output().unwrap();
    let out = ok(&o);
    // Stage messages go to a terminal only: a captured stderr stays empty on success.
    assert!(
        o.stderr.is_empty(),
        "stderr: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let report = dir.path().join("reports/demo/report.html");
    assert!(report.is_file(), "no report at {}", report.display());
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 1, "stdout: {out}");
    assert!(
        lines[0].starts_with("demo: wrote reports/demo/report.html"),
        "{out}"
    );
}

#[test]
fn compare_and_batch_take_the_pixel_size_when_the_file_lacks_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (b, a) = (d.join("b.csv"), d.join("a.csv"));
    csv_without_pixel_size(&b, 0.0);
    csv_without_pixel_size(&a, 0.5);
    let run = format!("r={},{}", b.display(), a.display());
    // Without it: exit 2, and the message names the flag.
    let o = bin()
        .args(["compare", "--run", &run, "--out"])
        .arg(d.join("no"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--pixel-mm"), "{err}");
    // With it: the report and a one-line summary naming it.
    let out = d.join("yes");
    let o = bin()
        .args(["compare", "--run", &run, "--pixel-mm", "0.5", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stdout = ok(&o);
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.starts_with("compare: wrote "), "{stdout}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let text = json.to_string();
    assert!(text.contains("0.5"), "pixel size not used: {text:.400}");
    // Rectangular pixels.
    let o = bin()
        .args([
            "compare",
            "--run",
            &run,
            "--pixel-mm",
            "0.5",
            "--pixel-mm-y",
            "0.25",
            "--out",
        ])
        .arg(d.join("rect"))
        .output()
        .unwrap();
    ok(&o);
    // A bad value is a usage error.
    let o = bin()
        .args(["compare", "--run", &run, "--pixel-mm", "-1", "--out"])
        .arg(d.join("bad"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));

    // batch: the ripple needs the pixel size; without it the line is an error naming the flag.
    let o = bin()
        .args(["batch", "--pitch-mm", "3"])
        .arg(&b)
        .output()
        .unwrap();
    let line = String::from_utf8_lossy(&o.stdout);
    assert!(line.contains("--pixel-mm"), "{line}");
    let o = bin()
        .args(["batch", "--pitch-mm", "3", "--pixel-mm", "0.5"])
        .arg(&b)
        .output()
        .unwrap();
    let line = ok(&o);
    let v: serde_json::Value = serde_json::from_str(line.lines().next().unwrap()).unwrap();
    assert!(v.get("error").is_none(), "{line}");
    assert!(v.get("ripple").is_some(), "{line}");
}

#[test]
fn spots_prints_one_line_on_success() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = bin()
        .args(["spots", "--make-sample"])
        .arg(d.join("in"))
        .output()
        .unwrap();
    assert_eq!(ok(&o).lines().count(), 1);
    let o = bin()
        .arg("spots")
        .arg(d.join("in/manifest.toml"))
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    let out = ok(&o);
    assert_eq!(out.lines().count(), 1, "{out}");
    assert!(out.starts_with("spots: wrote "), "{out}");
}

#[test]
fn psd_prints_the_pixel_size_to_its_precision() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("s");
    let o = bin()
        .args(["demo", "--repeats", "1", "--generate-samples"])
        .arg(&samples)
        .output()
        .unwrap();
    ok(&o);
    let o = bin()
        .arg("psd")
        .arg(samples.join("original/before_1.dat"))
        .output()
        .unwrap();
    let out = ok(&o);
    // The .dat stores the pixel size as f32: 0.4 mm, not 0.39999998989515007.
    assert!(out.contains("dx 0.4 mm, dy 0.4 mm"), "{out}");
    assert!(!out.contains("0.3999999"), "{out}");
}

/// A run directory: the bundled sample before/after maps, a 3 mm raster log over the part and
/// a recipe with a Gaussian TIF model.
fn run_dir(dir: &Path) -> std::path::PathBuf {
    let s = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/original");
    std::fs::copy(s.join("before_1.dat"), dir.join("before.dat")).unwrap();
    std::fs::copy(s.join("after_1.dat"), dir.join("after.dat")).unwrap();
    let mut log = String::from("t_s,x_mm,y_mm\n");
    let mut t = 0.0;
    for i in 0..30 {
        let y = 5.0 + 3.0 * i as f64;
        for k in 0..=90 {
            let x = if i % 2 == 0 { 5 + k } else { 95 - k } as f64;
            log.push_str(&format!("{t:.3},{x},{y}\n"));
            t += 0.1;
        }
    }
    std::fs::write(dir.join("path.csv"), log).unwrap();
    let recipe = dir.join("recipe.toml");
    std::fs::write(
        &recipe,
        "[measurement]\nbefore = \"before.dat\"\nafter = \"after.dat\"\n[tif]\n\
         model = { kind = \"gaussian\", sigma_mm = 1.0, peak_rate_nm_per_s = 10.0, diameter_mm = 8.0 }\n\
         [path]\nlog = \"path.csv\"\npitch_mm = 3.0\n",
    )
    .unwrap();
    recipe
}

/// Issue #17: `simulate` and `calibrate` printed nothing on success; now one line each, naming
/// what was written and the headline numbers (no float artefacts, no 300-digit numbers).
#[test]
fn simulate_and_calibrate_print_one_line_on_success() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = run_dir(dir.path());
    let out = ok(&bin()
        .arg("simulate")
        .arg(&recipe)
        .args(["--no-vibration", "--out"])
        .arg(dir.path().join("sim"))
        .output()
        .unwrap());
    assert_eq!(out.lines().count(), 1, "{out}");
    assert!(out.starts_with("simulate: wrote "), "{out}");
    assert!(
        out.contains("simulation.json") && out.contains(" nm"),
        "{out}"
    );
    assert!(
        out.contains("ripple sigma1") && out.contains("3 mm pitch"),
        "{out}"
    );
    let out = ok(&bin()
        .arg("calibrate")
        .arg(&recipe)
        .arg("--out")
        .arg(dir.path().join("cal"))
        .output()
        .unwrap());
    assert_eq!(out.lines().count(), 1, "{out}");
    assert!(out.starts_with("calibrate: wrote "), "{out}");
    assert!(
        out.contains("report.html") && out.contains("residual RMS"),
        "{out}"
    );
    assert!(dir.path().join("cal/calibration.json").is_file());
    // Without --json / --out the JSON itself goes to stdout (the contract), no summary.
    let out = ok(&bin().arg("calibrate").arg(&recipe).output().unwrap());
    let v: serde_json::Value = serde_json::from_str(&out).expect("stdout is the JSON");
    assert!(v["final"].is_object());
}

/// Issue #17: `psd --pixel-mm-y` gives a map without a pixel size rectangular pixels.
#[test]
fn psd_takes_a_rectangular_pixel_size() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("m.csv");
    csv_without_pixel_size(&m, 0.0);
    let out = ok(&bin()
        .arg("psd")
        .arg(&m)
        .args(["--pixel-mm", "0.5", "--pixel-mm-y", "0.25", "--json"])
        .output()
        .unwrap());
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["dx_mm"], 0.5);
    assert_eq!(v["dy_mm"], 0.25);
    let o = bin()
        .arg("psd")
        .arg(&m)
        .args(["--pixel-mm-y", "0.25"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "--pixel-mm-y needs --pixel-mm");
}

/// Issue #17: `psd` on a 1e-300 mm pixel printed df as a 300-digit number; every number of the
/// summary now has at most a few significant digits or an exponent.
#[test]
fn no_output_prints_a_number_hundreds_of_digits_long() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("m.csv");
    csv_without_pixel_size(&m, 0.0);
    for px in ["1e-300", "1e300"] {
        let out = ok(&bin()
            .arg("psd")
            .arg(&m)
            .args(["--pixel-mm", px])
            .output()
            .unwrap());
        let longest = out
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .map(str::len)
            .max()
            .unwrap_or(0);
        assert!(longest <= 20, "a {longest}-character number in: {out}");
        assert!(out.contains("dx 1e"), "{out}");
    }
}

/// Session 40 (reliability.md §11's review): `--pixel-mm` was ignored without a word when the
/// file gives its own pixel size. The file's is still used (a batch of mixed files takes the
/// flag for the maps without one); psd, batch and compare now say so on stderr, naming the
/// file and both sizes, and say nothing when the two agree or the file has none.
#[test]
fn a_pixel_size_the_file_overrides_is_named_on_stderr() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (own, own2, bare) = (d.join("own.csv"), d.join("own2.csv"), d.join("bare.csv"));
    for (p, phase) in [(&own, 0.0), (&own2, 0.5)] {
        csv_without_pixel_size(p, phase);
        let t = std::fs::read_to_string(p).unwrap();
        std::fs::write(p, format!("# dx_mm=0.1 dy_mm=0.1\n{t}")).unwrap();
    }
    csv_without_pixel_size(&bare, 0.0);
    let stderr = |o: &Output| String::from_utf8_lossy(&o.stderr).to_string();
    let named = |err: &str, file: &Path| {
        let note: Vec<&str> = err.lines().filter(|l| l.starts_with("note: ")).collect();
        assert_eq!(note.len(), 1, "{err}");
        for part in [
            file.display().to_string().as_str(),
            "0.1000000 x 0.1000000 mm",
            "--pixel-mm 0.5 x 0.5 mm",
        ] {
            assert!(note[0].contains(part), "{part} not in {}", note[0]);
        }
    };
    let psd = |m: &Path, px: &str| {
        bin()
            .arg("psd")
            .arg(m)
            .args(["--pixel-mm", px, "--json"])
            .output()
            .unwrap()
    };
    let o = psd(&own, "0.5");
    let v: serde_json::Value = serde_json::from_str(&ok(&o)).unwrap();
    assert_eq!(v["dx_mm"], 0.1, "the file's pixel size is used");
    named(&stderr(&o), &own);
    for (m, px) in [(&own, "0.1"), (&bare, "0.5")] {
        let o = psd(m, px);
        let v: serde_json::Value = serde_json::from_str(&ok(&o)).unwrap();
        assert_eq!(v["dx_mm"], px.parse::<f64>().unwrap());
        assert!(!stderr(&o).contains("note:"), "{}", stderr(&o));
    }
    let o = bin()
        .args(["batch", "--pixel-mm", "0.5"])
        .arg(&own)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_str(ok(&o).lines().next().unwrap()).unwrap();
    assert!(v.get("error").is_none() && v["dx_mm"] == 0.1, "{v}");
    named(&stderr(&o), &own);
    let run = format!("r={},{}", own.display(), own2.display());
    let o = bin()
        .args(["compare", "--run", &run, "--pixel-mm", "0.5", "--out"])
        .arg(d.join("cmp"))
        .output()
        .unwrap();
    ok(&o);
    let err = stderr(&o);
    assert_eq!(
        err.lines().filter(|l| l.starts_with("note: ")).count(),
        2,
        "{err}"
    );
    assert!(err.contains(own2.display().to_string().as_str()), "{err}");
}
