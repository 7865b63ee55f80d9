//! Issue #17, re-audited (reports/first_hour.md): what a new user sees of the outputs of every
//! command. `--json -` is stdout wherever `--json` takes a path; an unwritable output is one
//! line, exit 2, `FILE: cannot write: WHY` naming the file once, in every command that writes;
//! a command whose JSON goes to a file says in one line what it wrote; `stats` prints the pixel
//! size to the precision the file stores it; the ripple lists each harmonic once, below Nyquist.
//! Only the bundled samples are used (no shared data needed).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn samples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples")
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ok(o: &Output) -> String {
    assert!(o.status.success(), "exit {:?}: {}", o.status.code(), err(o));
    String::from_utf8(o.stdout.clone()).unwrap()
}

/// The docs' dwell case (docs/formats.md) on the bundled sample map, as an absolute path.
fn dwell_case(dir: &Path) -> PathBuf {
    let case = dir.join("case.toml");
    let map = samples().join("original/before.dat");
    std::fs::write(
        &case,
        format!(
            "surface = {:?}\npixel_mm = 0.25\n[tif]\nkind = \"gaussian\"\nsigma_mm = 1.5\n\
             diameter_mm = 12.0\npeak_rate_nm_per_s = 10.0\n[clear_aperture]\n\
             rows = [40, 160]\ncols = [40, 160]\n",
            map.display().to_string()
        ),
    )
    .unwrap();
    case
}

/// `--json -` writes the JSON to stdout and creates no file named `-`, in every command whose
/// `--json` takes a path (calibrate and dwell created a file named `-` before).
#[test]
fn json_dash_is_stdout_in_every_command() {
    let d = tempfile::tempdir().unwrap();
    let case = dwell_case(d.path());
    let recipe = samples().join("original/recipe.toml");
    let cmds: Vec<Vec<std::ffi::OsString>> = vec![
        vec!["calibrate".into(), recipe.into()],
        vec![
            "dwell".into(),
            case.into(),
            "--method".into(),
            "rifta".into(),
        ],
        vec!["vibration".into(), "--bonnet".into(), "both".into()],
    ];
    for args in cmds {
        let o = bin()
            .args(&args)
            .args(["--json", "-"])
            .current_dir(d.path())
            .output()
            .unwrap();
        let out = ok(&o);
        let v: serde_json::Value =
            serde_json::from_str(&out).unwrap_or_else(|e| panic!("{args:?}: {e}: {out:.300}"));
        assert!(v.is_object() || v.is_array(), "{args:?}");
        assert!(
            !d.path().join("-").exists(),
            "{args:?} created a file named -"
        );
    }
}

/// Every command that writes files, given an output under a regular file (so it cannot be
/// created): exit 2, one line on stderr, `FILE: cannot write: WHY`, the file named once, no
/// Rust "(os error N)" suffix, nothing on stdout. psd exited 1 before; calibrate, simulate and
/// dwell `--out` said "No such file or directory (os error 2)" without "cannot write".
#[test]
fn unwritable_output_is_exit_2_one_line_everywhere() {
    let d = tempfile::tempdir().unwrap();
    let blocker = d.path().join("plain_file");
    std::fs::write(&blocker, "not a directory").unwrap();
    let bad = |leaf: &str| blocker.join(leaf);
    let case = dwell_case(d.path());
    let s = samples();
    let recipe = s.join("original/recipe.toml");
    let map = s.join("original/before.dat");
    let run = format!(
        "o={},{}",
        s.join("original/before.dat").display(),
        s.join("original/after.dat").display()
    );
    let os = |x: &Path| x.as_os_str().to_owned();
    let cmds: Vec<(Vec<std::ffi::OsString>, PathBuf)> = vec![
        (
            vec!["psd".into(), os(&map), "--csv".into(), os(&bad("p.csv"))],
            bad("p.csv"),
        ),
        (
            vec!["psd".into(), os(&map), "--plot".into(), os(&bad("p.png"))],
            bad("p.png"),
        ),
        (
            vec![
                "compare".into(),
                "--run".into(),
                run.clone().into(),
                "--out".into(),
                os(&bad("cmp")),
            ],
            bad("cmp"),
        ),
        (
            vec![
                "spots".into(),
                os(&s.join("spots/manifest.toml")),
                "--out".into(),
                os(&bad("spots")),
            ],
            bad("spots"),
        ),
        (
            vec![
                "spots".into(),
                "--make-sample".into(),
                os(&bad("spot_sample")),
            ],
            bad("spot_sample"),
        ),
        (
            vec![
                "simulate".into(),
                os(&recipe),
                "--no-vibration".into(),
                "--out".into(),
                os(&bad("sim")),
            ],
            bad("sim"),
        ),
        (
            vec![
                "calibrate".into(),
                os(&recipe),
                "--out".into(),
                os(&bad("cal")),
            ],
            bad("cal"),
        ),
        (
            vec![
                "calibrate".into(),
                os(&recipe),
                "--json".into(),
                os(&bad("cal.json")),
            ],
            bad("cal.json"),
        ),
        (
            vec![
                "dwell".into(),
                os(&case),
                "--method".into(),
                "rifta".into(),
                "--out".into(),
                os(&bad("dw")),
            ],
            bad("dw"),
        ),
        (
            vec![
                "dwell".into(),
                os(&case),
                "--method".into(),
                "rifta".into(),
                "--json".into(),
                os(&bad("dw.json")),
            ],
            bad("dw.json"),
        ),
        (
            vec!["vibration".into(), "--out".into(), os(&bad("vib"))],
            bad("vib"),
        ),
        (
            vec!["vibration".into(), "--json".into(), os(&bad("vib.json"))],
            bad("vib.json"),
        ),
        (
            vec![
                "demo".into(),
                "--repeats".into(),
                "1".into(),
                "--generate-samples".into(),
                os(&bad("gen")),
            ],
            bad("gen"),
        ),
    ];
    for (args, target) in cmds {
        let o = bin().args(&args).current_dir(d.path()).output().unwrap();
        let all = err(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {all}");
        // Every command's stderr is the error line alone, `demo` included: its stage messages
        // go to a terminal only (before, they came first on a captured stderr).
        let e = all.clone();
        let lines: Vec<&str> = e.lines().collect();
        assert_eq!(lines.len(), 1, "{args:?}: {all}");
        let name = target.display().to_string();
        assert!(
            lines[0].starts_with(&format!("bonnetlab: {name}: cannot write: ")),
            "{args:?}: {e}"
        );
        assert_eq!(
            e.matches(&name).count(),
            1,
            "{args:?} names the file twice: {e}"
        );
        assert!(!e.contains("os error"), "{args:?}: {e}");
        assert!(o.stdout.is_empty(), "{args:?}: stdout {:?}", o.stdout);
    }
}

/// With its JSON sent to a file (or only `--out`), `dwell` and `vibration` print one line
/// saying what they wrote and the headline numbers; before, both printed nothing (and `dwell
/// --out` without `--json` printed the whole JSON).
#[test]
fn dwell_and_vibration_say_what_they_wrote() {
    let d = tempfile::tempdir().unwrap();
    let case = dwell_case(d.path());
    let one_line = |args: &[&std::ffi::OsStr], start: &str, has: &[&str]| {
        let o = bin().args(args).current_dir(d.path()).output().unwrap();
        let out = ok(&o);
        assert_eq!(out.lines().count(), 1, "{args:?}: {out}");
        assert!(out.starts_with(start), "{args:?}: {out}");
        for h in has {
            assert!(out.contains(h), "{args:?}: no {h:?} in {out}");
        }
        // Numbers to their precision: no 10-digit fractions.
        let longest = out
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .map(str::len)
            .max()
            .unwrap_or(0);
        assert!(longest <= 9, "{args:?}: {out}");
    };
    let c = case.as_os_str();
    one_line(
        &[
            "dwell".as_ref(),
            c,
            "--method".as_ref(),
            "rifta".as_ref(),
            "--json".as_ref(),
            "d.json".as_ref(),
        ],
        "dwell: wrote d.json: rifta, total dwell ",
        &[" min", "residual RMS ", " nm"],
    );
    assert!(d.path().join("d.json").is_file());
    one_line(
        &[
            "dwell".as_ref(),
            c,
            "--method".as_ref(),
            "rifta".as_ref(),
            "--out".as_ref(),
            "dw".as_ref(),
        ],
        "dwell: wrote dw/: rifta",
        &["residual RMS"],
    );
    assert!(d.path().join("dw/dwell_map.png").is_file());
    one_line(
        &[
            "vibration".as_ref(),
            "--bonnet".as_ref(),
            "both".as_ref(),
            "--json".as_ref(),
            "v.json".as_ref(),
            "--out".as_ref(),
            "vib".as_ref(),
        ],
        "vibration: wrote v.json and vib/: original offset amplitude ",
        &["suppression offset amplitude", " mm"],
    );
    assert!(d.path().join("vib/frf_x1.png").is_file());
    // Without --json the table stays, and --out adds where the plots went.
    let out = ok(&bin()
        .args(["vibration", "--out", "vib2"])
        .current_dir(d.path())
        .output()
        .unwrap());
    assert!(out.starts_with("principal frame: "), "{out}");
    assert!(
        out.trim_end()
            .ends_with("vibration: wrote vib2/ (FRF plots and the tool-tip time series)"),
        "{out}"
    );
    // Without --json and --out, dwell's JSON is stdout (the contract).
    let out = ok(&bin()
        .args(["dwell".as_ref(), c, "--method".as_ref(), "rifta".as_ref()])
        .output()
        .unwrap());
    let v: serde_json::Value = serde_json::from_str(&out).expect("JSON on stdout");
    assert_eq!(v["method"], "rifta");
}

/// `stats` printed the pixel size as "2.500000e-1 mm" (and "1.000000e0 mm"); now to the f32
/// precision files store it, as `psd` does.
#[test]
fn stats_prints_the_pixel_size_to_its_precision() {
    let out = ok(&bin()
        .arg("stats")
        .arg(samples().join("original/before.dat"))
        .output()
        .unwrap());
    assert!(
        out.contains("grid      200 rows x 200 cols, dx 0.25 mm, dy 0.25 mm"),
        "{out}"
    );
    assert!(!out.contains("e-1 mm") && !out.contains("e0 mm"), "{out}");
}

/// The ripple's harmonic bands: each listed once, every one below Nyquist (2 1/mm at 0.25 mm
/// pixels). At a 0.8 mm pitch only f0 = 1.25 1/mm fits; before the fix a clamped band was
/// counted once per harmonic.
#[test]
fn ripple_harmonics_are_distinct_and_below_nyquist() {
    let map = samples().join("original/before.dat");
    for (pitch, n) in [("0.8", 1usize), ("3", 5)] {
        let out = ok(&bin()
            .arg("psd")
            .arg(&map)
            .args(["--axis", "y", "--json", "--pitch-mm", pitch])
            .output()
            .unwrap());
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        let h = v["ripple"]["harmonics"].as_array().unwrap();
        assert_eq!(h.len(), n, "pitch {pitch}: {h:?}");
        let f: Vec<f64> = h
            .iter()
            .map(|x| x["freq_per_mm"].as_f64().unwrap())
            .collect();
        for w in f.windows(2) {
            assert!(w[1] > w[0], "pitch {pitch}: {f:?}");
        }
        assert!(f.iter().all(|&x| x <= 2.0), "pitch {pitch}: {f:?}");
        let text = ok(&bin()
            .arg("psd")
            .arg(&map)
            .args(["--axis", "y", "--pitch-mm", pitch])
            .output()
            .unwrap());
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with("harmonics:"))
            .unwrap();
        assert_eq!(line.matches("f0 ").count(), n, "{line}");
    }
}
