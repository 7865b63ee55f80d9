//! Output safety (issues 17 and 18), one test per defect, each failing on the old behaviour:
//! checked stdout (`/dev/full` is exit 1 with one line, a closed pipe ends quietly), `--json -`
//! is stdout in every command, an unwritable output is exit 2 in every command, the file is named
//! once, special files / symbolic links / inputs are never replaced, and a multi-file report is
//! published as a set under a lock (stale temporary files of killed runs removed).

use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

#[path = "common/shared_data.rs"]
mod shared_data;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A public dwell case from shared/data (tests using it are marked as needing the data).
fn dwell_case() -> PathBuf {
    shared_data::data_file("dwell", "rifta_case_a.toml")
}

fn sample_map() -> PathBuf {
    repo().join("samples/original/before_1.dat")
}

fn full() -> Stdio {
    Stdio::from(
        std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap(),
    )
}

/// A pipe whose reading end is already closed: any write gets EPIPE.
fn closed_pipe() -> Stdio {
    let (r, w) = std::io::pipe().unwrap();
    drop(r);
    Stdio::from(w)
}

fn run(mut c: Command, stdout: Stdio) -> Output {
    c.stdout(stdout).stderr(Stdio::piped()).output().unwrap()
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn one_line(o: &Output, needle: &str) {
    let e = err(o);
    assert_eq!(e.lines().count(), 1, "not one line: {e}");
    assert!(e.contains(needle), "'{needle}' not in: {e}");
    assert!(!e.contains("panicked"), "{e}");
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn full_stdout_is_exit_1_with_one_line_in_every_command() {
    let case = dwell_case();
    let mut cmds: Vec<(&str, Command)> = Vec::new();
    let mut c = bin();
    c.args(["psd", "--json"]).arg(sample_map());
    cmds.push(("psd --json", c));
    let mut c = bin();
    c.args(["stats", "--json"]).arg(sample_map());
    cmds.push(("stats --json", c));
    let mut c = bin();
    c.args(["vibration", "--json", "-"]);
    cmds.push(("vibration --json -", c));
    let mut c = bin();
    c.arg("vibration");
    cmds.push(("vibration", c));
    let mut c = bin();
    c.arg("batch").arg(sample_map());
    cmds.push(("batch", c));
    let mut c = bin();
    c.arg("dwell").arg(&case);
    cmds.push(("dwell", c));
    for (name, c) in cmds {
        let o = run(c, full());
        assert_eq!(o.status.code(), Some(1), "{name}: {}", err(&o));
        one_line(&o, "stdout: cannot write: No space left on device");
    }
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn closed_pipe_ends_quietly_without_a_panic() {
    let mut c = bin();
    c.arg("dwell").arg(dwell_case());
    let o = run(c, closed_pipe());
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    assert!(err(&o).is_empty(), "{}", err(&o));
    for args in [&["vibration", "--json", "-"][..], &["psd", "--json"][..]] {
        let mut c = bin();
        c.args(args);
        if args[0] == "psd" {
            c.arg(sample_map());
        }
        let o = run(c, closed_pipe());
        assert_eq!(o.status.code(), Some(0), "{args:?}: {}", err(&o));
        assert!(err(&o).is_empty(), "{args:?}: {}", err(&o));
    }
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn json_dash_is_stdout_in_dwell_and_vibration() {
    let d = tempfile::tempdir().unwrap();
    for args in [
        vec!["dwell".to_string(), dwell_case().display().to_string()],
        vec!["vibration".to_string()],
    ] {
        let o = bin()
            .args(&args)
            .args(["--json", "-"])
            .current_dir(d.path())
            .output()
            .unwrap();
        assert!(o.status.success(), "{args:?}: {}", err(&o));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON on stdout");
        assert!(v.is_object() || v.is_array());
        assert!(
            !d.path().join("-").exists(),
            "{args:?} created a file named -"
        );
    }
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn unwritable_output_is_exit_2_naming_the_file_once_everywhere() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("no/such/dir/out.csv");
    let o = bin()
        .arg("psd")
        .arg(sample_map())
        .arg("--csv")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "psd: {}", err(&o));
    one_line(&o, "out.csv: cannot write");
    assert_eq!(err(&o).matches("out.csv").count(), 1, "{}", err(&o));
    let json = d.path().join("no/such/dir/out.json");
    for args in [
        vec!["vibration".to_string()],
        vec!["dwell".to_string(), dwell_case().display().to_string()],
    ] {
        let o = bin().args(&args).arg("--json").arg(&json).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", err(&o));
        one_line(&o, "out.json: cannot write");
        assert_eq!(err(&o).matches("out.json").count(), 1, "{}", err(&o));
    }
}

#[test]
fn a_map_given_as_dwell_case_is_named_as_not_text() {
    let o = bin().arg("dwell").arg(sample_map()).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    one_line(&o, "before_1.dat: is not a text file");
    assert!(!err(&o).contains("stream did not contain valid UTF-8"));
}

#[test]
fn fifo_outputs_are_refused_and_kept() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("out.fifo");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let o = bin()
        .arg("psd")
        .arg(sample_map())
        .arg("--csv")
        .arg(&fifo)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "FIFO");
    let o = bin()
        .args(["vibration", "--json"])
        .arg(&fifo)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo());
}

#[test]
fn an_input_map_is_not_overwritten_by_psd_csv() {
    let d = tempfile::tempdir().unwrap();
    let map = d.path().join("map.csv");
    let mut text = String::new();
    for i in 0..16 {
        let row: Vec<String> = (0..16)
            .map(|j| format!("{}", (i * j % 7) as f64 - 3.0))
            .collect();
        text.push_str(&row.join(","));
        text.push('\n');
    }
    std::fs::write(&map, &text).unwrap();
    let before = std::fs::read(&map).unwrap();
    let o = bin()
        .arg("psd")
        .arg(&map)
        .args(["--pixel-mm", "1"])
        .arg("--csv")
        .arg(&map)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "input of this command");
    assert_eq!(std::fs::read(&map).unwrap(), before);
}

#[test]
fn spots_does_not_overwrite_its_manifest_in_the_output_directory() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("sweep");
    std::fs::create_dir(&dir).unwrap();
    let src = repo().join("samples/spots");
    let mut csv = String::from(
        "file,bonnet,dwell_s,precession_deg,offset_mm,spindle_rpm,inner_pressure_mpa\n",
    );
    for (k, off) in ["0.2", "0.4", "0.6"].iter().enumerate() {
        let name = format!("original_offset_{off}.dat");
        std::fs::copy(src.join(&name), dir.join(&name)).unwrap();
        csv.push_str(&format!("{name},original,120,20,{off},500,0.25\n"));
        let _ = k;
    }
    let manifest = dir.join("spots.csv");
    std::fs::write(&manifest, &csv).unwrap();
    let o = bin()
        .arg("spots")
        .arg(&manifest)
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "input of this command");
    assert_eq!(std::fs::read_to_string(&manifest).unwrap(), csv);
    // Nothing else was published either (the set is all or nothing).
    assert!(!dir.join("report.json").exists());
    assert!(!dir.join("report.html").exists());
}

#[test]
fn a_symlinked_output_is_written_through_and_kept() {
    let d = tempfile::tempdir().unwrap();
    let target = d.path().join("real.csv");
    std::fs::write(&target, "old").unwrap();
    let link = d.path().join("link.csv");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let o = bin()
        .arg("psd")
        .arg(sample_map())
        .arg("--csv")
        .arg(&link)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", err(&o));
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(std::fs::read_to_string(&target)
        .unwrap()
        .starts_with("axis,"));
}

fn compare(dir: &Path, name: &str) -> Output {
    let s = repo().join("samples/original");
    bin()
        .arg("compare")
        .arg("--run")
        .arg(format!(
            "{name}={},{}",
            s.join("before_1.dat").display(),
            s.join("after_1.dat").display()
        ))
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap()
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn compare_failing_part_way_leaves_the_previous_report_whole() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("out");
    let o = compare(&dir, "first");
    assert!(o.status.success(), "{}", err(&o));
    let json = std::fs::read(dir.join("report.json")).unwrap();
    let html = std::fs::read(dir.join("report.html")).unwrap();
    let names = listing(&dir);
    // A 300-character run name makes a CSV name too long for the file system.
    let o = compare(&dir, &"r".repeat(300));
    assert_ne!(o.status.code(), Some(0), "{}", err(&o));
    assert_eq!(err(&o).lines().count(), 1, "{}", err(&o));
    assert_eq!(std::fs::read(dir.join("report.json")).unwrap(), json);
    assert_eq!(std::fs::read(dir.join("report.html")).unwrap(), html);
    assert_eq!(listing(&dir), names, "no staging or temporary file left");
}

#[test]
fn a_second_writer_to_one_out_directory_is_refused_and_stale_temps_removed() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("out");
    std::fs::create_dir(&dir).unwrap();
    // A live run (this test process) holds the lock.
    let lock = dir.join(".bonnetlab.lock");
    std::fs::write(&lock, format!("{}\n", std::process::id())).unwrap();
    let o = compare(&dir, "a");
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "another bonnetlab run");
    assert!(!dir.join("report.json").exists());
    // A killed run's lock and temporary files (pid above Linux's pid range) are stale.
    std::fs::write(&lock, "4194305\n").unwrap();
    let stale = dir.join(".report.json.tmp-4194305-3");
    std::fs::write(&stale, "half").unwrap();
    let staging = dir.join(".bonnetlab-staging-4194305-0");
    std::fs::create_dir(&staging).unwrap();
    let o = compare(&dir, "a");
    assert!(o.status.success(), "{}", err(&o));
    assert!(!stale.exists() && !staging.exists() && !lock.exists());
    assert!(dir.join("report.json").exists() && dir.join("report.html").exists());
}

#[test]
fn usage_errors_are_one_line() {
    let o = bin().args(["psd", "--no-such-flag", "x"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    one_line(&o, "--no-such-flag");
    let o = bin()
        .args(["psd", "--harmonics", "18446744073709551615", "x"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    one_line(&o, "between 0 and 1000");
    // A missing argument is named (clap lists it below the sentence; it was cut off).
    let o = bin().args(["stats"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    one_line(&o, "were not provided: <FILE>");
    let o = bin()
        .args(["psd", "x.dat", "--pixel-mm-y", "0.1"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    one_line(&o, "--pixel-mm");
}

/// Issue #18: `simulate --out` and `calibrate --out` are published as a set under the
/// directory's lock, like `compare`: a second writer is refused and nothing is written.
#[test]
fn simulate_and_calibrate_outputs_are_published_as_a_set_under_the_lock() {
    let d = tempfile::tempdir().unwrap();
    let s = repo().join("samples/original");
    let mut log = String::from("t_s,x_mm,y_mm\n");
    for k in 0..=80 {
        log.push_str(&format!("{},{},50\n", 0.1 * k as f64, 10 + k));
    }
    std::fs::write(d.path().join("path.csv"), log).unwrap();
    let recipe = d.path().join("r.toml");
    std::fs::write(
        &recipe,
        format!(
            "[measurement]\nbefore = \"{}\"\nafter = \"{}\"\n[tif]\n\
             model = {{ kind = \"gaussian\", sigma_mm = 1.0, peak_rate_nm_per_s = 10.0, diameter_mm = 8.0 }}\n\
             [path]\nlog = \"path.csv\"\n",
            s.join("before_1.dat").display(),
            s.join("after_1.dat").display()
        ),
    )
    .unwrap();
    for cmd in ["simulate", "calibrate"] {
        let dir = d.path().join(cmd);
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(
            dir.join(".bonnetlab.lock"),
            format!("{}\n", std::process::id()),
        )
        .unwrap();
        let mut c = bin();
        c.arg(cmd).arg(&recipe);
        if cmd == "simulate" {
            c.arg("--no-vibration");
        }
        c.arg("--out").arg(&dir);
        let o = run(c, Stdio::null());
        assert_eq!(o.status.code(), Some(2), "{cmd}: {}", err(&o));
        one_line(&o, "another bonnetlab run");
        assert_eq!(listing(&dir), vec![".bonnetlab.lock".to_string()], "{cmd}");
    }
}

/// With a live lock in `dir` (this test process's), the command `c` writing there is refused
/// with one line, exit 2, and nothing in the directory changes.
fn held_lock_refuses(dir: &Path, c: Command) {
    std::fs::write(
        dir.join(".bonnetlab.lock"),
        format!("{}\n", std::process::id()),
    )
    .unwrap();
    let before = snapshot(dir);
    let o = run(c, Stdio::null());
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "another bonnetlab run");
    assert_eq!(snapshot(dir), before);
}

/// A run into `dir` that fails part-way publishes nothing: with a directory standing where
/// its file `last` goes, `second` exits 2 with one line naming `last`, emits nothing on
/// stdout, leaves the previous run's files (`names`) as they were (same bytes, same inodes) and
/// no staging file; with `last` free again, a live lock (this test process) refuses `third`
/// before anything is written.
fn fails_part_way_as_a_set(
    dir: &Path,
    names: &[String],
    last: &str,
    mut second: Command,
    third: Command,
) {
    std::fs::remove_file(dir.join(last)).unwrap();
    std::fs::create_dir(dir.join(last)).unwrap();
    let before = snapshot(dir);
    let o = second
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, last);
    assert!(o.stdout.is_empty(), "nothing emitted on a failed run");
    assert_eq!(
        snapshot(dir),
        before,
        "the previous run's files were replaced"
    );
    assert_eq!(listing(dir), names, "no staging or temporary file left");
    std::fs::remove_dir(dir.join(last)).unwrap();
    held_lock_refuses(dir, third);
}

/// A file's bytes and inode: an output set that is not published leaves both as they were
/// (the old file-by-file writes replaced each file by rename, a new inode).
fn snapshot(dir: &Path) -> Vec<(String, u64, Vec<u8>)> {
    use std::os::unix::fs::MetadataExt;
    listing(dir)
        .into_iter()
        .filter(|n| dir.join(n).is_file())
        .map(|n| {
            let p = dir.join(&n);
            (
                n,
                std::fs::metadata(&p).unwrap().ino(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect()
}

/// Issue #18: `vibration --out` is one output set. A run that fails part-way (its last file,
/// timeseries.csv, cannot be written: a directory stands in its place) publishes none of its
/// files, so the previous run's plots stay whole (same bytes, same inode) instead of a mix of
/// two runs; nothing is emitted on stdout and no staging file is left; a live lock refuses a
/// second writer before anything is written.
#[test]
fn vibration_out_is_published_as_a_set() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("out");
    let recipe = |rpm: u32| {
        let p = d.path().join(format!("r{rpm}.toml"));
        std::fs::write(&p, format!("[process]\nspindle_rpm = {rpm}\n")).unwrap();
        p
    };
    let (r1, r2) = (recipe(900), recipe(1400));
    let o = run(
        {
            let mut c = bin();
            c.arg("vibration").arg(&r1).arg("--out").arg(&dir);
            c
        },
        Stdio::null(),
    );
    assert!(o.status.success(), "{}", err(&o));
    let names = listing(&dir);
    for f in [
        "frf_x1.svg",
        "frf_x1.png",
        "frf_x2.svg",
        "frf_x2.png",
        "timeseries.csv",
    ] {
        assert!(names.contains(&f.to_string()), "{f} missing: {names:?}");
    }
    // The second run (another spindle speed: different plots) fails on its last file.
    let second = || {
        let mut c = bin();
        c.arg("vibration").arg(&r2).arg("--out").arg(&dir);
        c
    };
    fails_part_way_as_a_set(&dir, &names, "timeseries.csv", second(), second());
}

/// Issue #18: `dwell --out` is one output set, as `vibration_out_is_published_as_a_set`.
/// The second run uses another method (different dwell map) and fails on its last file
/// (residual.png): the first run's maps stay whole.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn dwell_out_is_published_as_a_set() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("out");
    let mut c = bin();
    c.arg("dwell")
        .arg(dwell_case())
        .args(["--method", "rifta", "--out"])
        .arg(&dir);
    let o = run(c, Stdio::null());
    assert!(o.status.success(), "{}", err(&o));
    let names = listing(&dir);
    for f in [
        "dwell_s.csv",
        "residual.dat",
        "realised_residual.dat",
        "feed_binding.csv",
        "dwell_map.png",
        "trade_off.csv",
        "trade_off.png",
        "residual.png",
    ] {
        assert!(names.contains(&f.to_string()), "{f} missing: {names:?}");
    }
    let mut second = bin();
    second
        .arg("dwell")
        .arg(dwell_case())
        .args(["--method", "min-dwell", "--out"])
        .arg(&dir);
    let mut third = bin();
    third.arg("dwell").arg(dwell_case()).arg("--out").arg(&dir);
    fails_part_way_as_a_set(&dir, &names, "residual.png", second, third);
}

/// `spots --make-sample DIR` and `demo --generate-samples DIR` publish their maps and manifest
/// (README) as one output set: a run that fails part-way (a directory standing where one map
/// goes) leaves the previous files as they were, with no staging left, and a held lock refuses
/// a second run. Before, both wrote file by file: a failure left a mix of two runs' maps.
#[test]
fn sample_generators_publish_as_a_set() {
    let d = tempfile::tempdir().unwrap();
    // spots --make-sample
    let dir = d.path().join("spots");
    let mut c = bin();
    c.args(["spots", "--make-sample"]).arg(&dir);
    let o = run(c, Stdio::null());
    assert!(o.status.success(), "{}", err(&o));
    let names = listing(&dir);
    assert!(names.contains(&"manifest.toml".to_string()), "{names:?}");
    let again = || {
        let mut c = bin();
        c.args(["spots", "--make-sample"]).arg(&dir);
        c
    };
    fails_part_way_as_a_set(&dir, &names, "suppression_offset_1.0.dat", again(), again());

    // demo --generate-samples: maps in sub-directories, the recipe runs and the README.
    let dir = d.path().join("samples");
    let mut c = bin();
    c.args(["demo", "--generate-samples"]).arg(&dir);
    let o = run(c, Stdio::null());
    assert!(o.status.success(), "{}", err(&o));
    let top = listing(&dir);
    let orig = listing(&dir.join("original"));
    assert!(
        orig.contains(&"recipe.toml".to_string()) && orig.contains(&"before_1.dat".to_string()),
        "{orig:?}"
    );
    std::fs::remove_file(dir.join("suppression/after.dat")).unwrap();
    std::fs::create_dir(dir.join("suppression/after.dat")).unwrap();
    let (b_top, b_orig) = (snapshot(&dir), snapshot(&dir.join("original")));
    let mut c = bin();
    c.args(["demo", "--generate-samples"]).arg(&dir);
    let o = run(c, Stdio::null());
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    let last = err(&o).lines().last().unwrap_or_default().to_string();
    assert!(last.contains("after.dat"), "{last}");
    assert_eq!(snapshot(&dir), b_top, "the previous README was replaced");
    assert_eq!(
        snapshot(&dir.join("original")),
        b_orig,
        "the previous maps were replaced"
    );
    assert_eq!(listing(&dir), top, "no staging or temporary file left");
}

/// A command with several outputs publishes none of them when one cannot be written (before,
/// the `--out` directory or the first file was published, then the next failed): `dwell` and
/// `vibration` with `--out DIR --json` into a directory that does not exist, and `psd` with a
/// CSV and a plot there. Exit 2 naming the unwritable file, and nothing created or changed.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs shared/data: set BONNETLAB_SHARED_DATA (README, Tests)"
)]
fn one_unwritable_output_publishes_none_of_the_others() {
    let d = tempfile::tempdir().unwrap();
    let missing = d.path().join("no_such_dir").join("x.json");
    let out = d.path().join("nested").join("out");
    let mut cmds: Vec<(&str, Command)> = Vec::new();
    let mut c = bin();
    c.arg("dwell").arg(dwell_case()).arg("--out").arg(&out);
    c.arg("--json").arg(&missing);
    cmds.push(("dwell", c));
    let mut c = bin();
    c.args(["vibration", "--out"]).arg(&out);
    c.arg("--json").arg(&missing);
    cmds.push(("vibration", c));
    let csv = d.path().join("psd.csv");
    let mut c = bin();
    c.arg("psd").arg(sample_map()).arg("--csv").arg(&csv);
    c.arg("--plot")
        .arg(d.path().join("no_such_dir").join("p.svg"));
    cmds.push(("psd", c));
    for (name, c) in cmds {
        let o = run(c, Stdio::piped());
        assert_eq!(o.status.code(), Some(2), "{name}: {}", err(&o));
        one_line(&o, "no_such_dir");
        assert!(o.stdout.is_empty(), "{name} printed: {:?}", o.stdout);
        let left = listing(d.path());
        assert!(left.is_empty(), "{name} left {left:?}");
    }
    // An existing --out directory keeps what it had, and nothing is added.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep.txt"), b"old").unwrap();
    let mut c = bin();
    c.arg("dwell").arg(dwell_case()).arg("--out").arg(&out);
    c.arg("--json").arg(&missing);
    let o = run(c, Stdio::piped());
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert_eq!(listing(&out), vec!["keep.txt".to_string()]);
    assert_eq!(std::fs::read(out.join("keep.txt")).unwrap(), b"old");
}

/// `--json` may go inside the `--out` directory the command creates; two outputs naming one
/// file are refused before anything is published (one silently replaced the other before).
#[test]
fn outputs_inside_the_out_directory_and_outputs_naming_one_file() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("vd");
    let mut c = bin();
    c.args(["vibration", "--out"]).arg(&out);
    c.arg("--json").arg(out.join("summary.json"));
    let o = run(c, Stdio::piped());
    assert_eq!(o.status.code(), Some(0), "{}", err(&o));
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert!(v["natural_freq1_hz"].is_number(), "{v}");
    assert!(out.join("timeseries.csv").is_file());

    let twice = d.path().join("ve");
    let mut c = bin();
    c.args(["vibration", "--out"]).arg(&twice);
    c.arg("--json").arg(twice.join("timeseries.csv"));
    let o = run(c, Stdio::piped());
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "two outputs of this command name the same file");
    assert!(!twice.exists(), "{:?}", listing(&twice));

    let same = d.path().join("same.svg");
    let mut c = bin();
    c.arg("psd").arg(sample_map()).arg("--csv").arg(&same);
    c.arg("--plot").arg(&same);
    let o = run(c, Stdio::piped());
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    one_line(&o, "same.svg: two outputs");
    assert_eq!(listing(d.path()), vec!["vd".to_string()]);
}

/// A run into a directory a former run of the same command wrote removes the former run's
/// files it does not write itself (here the PSD tables of a run no longer compared), but
/// never a file the user put there or changed since.
#[test]
fn a_rerun_leaves_no_former_runs_file_beside_its_own() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("out");
    let s = repo().join("samples/original");
    let pair = format!(
        "{},{}",
        s.join("before_1.dat").display(),
        s.join("after_1.dat").display()
    );
    let compare_runs = |names: &[&str]| {
        let mut c = bin();
        c.arg("compare");
        for n in names {
            c.arg("--run").arg(format!("{n}={pair}"));
        }
        let o = c.arg("--out").arg(&dir).output().unwrap();
        assert!(o.status.success(), "{}", err(&o));
    };
    compare_runs(&["keep", "gone", "edited"]);
    for axis in ["x", "y"] {
        assert!(dir.join(format!("psd_{axis}_gone.csv")).exists());
    }
    std::fs::write(dir.join("notes.txt"), "the user's").unwrap();
    std::fs::write(dir.join("psd_y_edited.csv"), "changed by the user").unwrap();
    compare_runs(&["keep"]);
    let names = listing(&dir);
    for gone in ["psd_x_gone.csv", "psd_y_gone.csv", "psd_x_edited.csv"] {
        assert!(!names.contains(&gone.to_string()), "{gone}: {names:?}");
    }
    for kept in [
        "psd_x_keep.csv",
        "psd_y_keep.csv",
        "report.json",
        "report.html",
        "notes.txt",
        "psd_y_edited.csv",
    ] {
        assert!(names.contains(&kept.to_string()), "{kept}: {names:?}");
    }
    let json = std::fs::read_to_string(dir.join("report.json")).unwrap();
    assert!(!json.contains("\"gone\""), "the report is the second run's");
}
