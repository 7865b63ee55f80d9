//! Hostile and broken inputs (issue 18): the command lines of `tests/corpus/hostile/commands.tsv`
//! replayed against the binary, each under a 1 GiB address-space limit and a 30 s deadline.
//! Each must exit with its expected code and one stderr line holding the expected text, never
//! panic or abort, and leave every input file byte for byte as it was (and the FIFO a FIFO).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use bonnetlab::io::{write_surface, MapFormat};
use bonnetlab::process::path::log::path_to_csv;
use bonnetlab::process::RasterSpec;
use bonnetlab::surface::Surface;

/// Address-space limit of every replayed command (KiB): 1 GiB.
const MEMORY_LIMIT_KIB: u64 = 1 << 20;
/// A command still running after this is a hang.
const DEADLINE: Duration = Duration::from_secs(30);

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/hostile")
}

/// Copies the corpus into a fresh directory and adds the generated fixtures.
fn workspace() -> tempfile::TempDir {
    let t = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(corpus()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), t.path().join(e.file_name())).unwrap();
    }
    let before = ndarray::Array2::from_shape_fn((48, 60), |(i, j)| {
        ((i as f64) * 0.3).sin() * 5.0 + (j as f64 * 0.2).cos() * 3.0
    });
    let s = Surface::new(before, Some(1.0), Some(1.0)).unwrap();
    write_surface(&t.path().join("before.dat"), &s, MapFormat::MetroProDat).unwrap();
    let mut spec = RasterSpec::over_rect((-4.0, 63.0), (-4.0, 51.0), 2.0, 10.0);
    spec.sample_dt_s = 0.2;
    let path = spec.generate().unwrap();
    std::fs::write(t.path().join("good.csv"), path_to_csv(&path)).unwrap();
    let st = Command::new("mkfifo")
        .arg(t.path().join("fifo.dat"))
        .status()
        .expect("mkfifo (coreutils) is needed by this test");
    assert!(st.success());
    // 3 GiB of holes: costs no disk, must be refused by its size, not read.
    let f = std::fs::File::create(t.path().join("sparse.dat")).unwrap();
    f.set_len(3 << 30).unwrap();
    t
}

/// Content of every regular file in `dir` (not descending into outputs), and the FIFO's kind.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    use std::os::unix::fs::FileTypeExt;
    let mut m = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let ft = std::fs::symlink_metadata(e.path()).unwrap().file_type();
        let name = e.file_name().to_string_lossy().into_owned();
        if ft.is_fifo() {
            m.insert(name, b"<fifo>".to_vec());
        } else if ft.is_file() && name != "sparse.dat" {
            m.insert(name, std::fs::read(e.path()).unwrap());
        } else if name == "sparse.dat" {
            m.insert(name, e.metadata().unwrap().len().to_le_bytes().to_vec());
        }
    }
    m
}

struct Outcome {
    code: Option<i32>,
    stderr: String,
    elapsed: Duration,
    timed_out: bool,
}

/// Runs the binary with `args` in `cwd` under the memory limit and the deadline.
fn run_limited(cwd: &Path, args: &[&str]) -> Outcome {
    let script = format!("ulimit -v {MEMORY_LIMIT_KIB} && exec \"$0\" \"$@\"");
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(script)
        .arg(env!("CARGO_BIN_EXE_bonnetlab"))
        .args(args)
        .current_dir(cwd)
        .env("MALLOC_ARENA_MAX", "2")
        .env("RAYON_NUM_THREADS", "2")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > DEADLINE {
            timed_out = true;
            let _ = child.kill();
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let elapsed = start.elapsed();
    let mut stderr = String::new();
    use std::io::Read;
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    Outcome {
        code: status.code(),
        stderr,
        elapsed,
        timed_out,
    }
}

#[test]
fn hostile_command_lines_fail_cleanly_within_limits() {
    let list = std::fs::read_to_string(corpus().join("commands.tsv")).unwrap();
    let t = workspace();
    let mut failures = Vec::new();
    let mut n = 0;
    for line in list
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
    {
        let cols: Vec<&str> = line.split('\t').collect();
        assert_eq!(cols.len(), 3, "malformed commands.tsv line: {line}");
        let want: i32 = cols[0].parse().unwrap();
        let args: Vec<&str> = cols[2].split(' ').collect();
        let before = snapshot(t.path());
        let o = run_limited(t.path(), &args);
        n += 1;
        let after = snapshot(t.path());
        let lines: Vec<&str> = o.stderr.lines().collect();
        let mut why = Vec::new();
        if o.timed_out {
            why.push(format!("still running after {DEADLINE:?}"));
        }
        if o.code != Some(want) {
            why.push(format!("exit {:?}, want {want}", o.code));
        }
        if lines.len() != 1 || !lines[0].contains(cols[1]) {
            why.push(format!("stderr is not one line with '{}'", cols[1]));
        }
        if o.stderr.contains("invalid argument") {
            why.push("the libraries' 'invalid argument' tag leaks into the message".into());
        }
        if o.stderr.contains("panicked") || o.stderr.contains("memory allocation") {
            why.push("panic or abort".into());
        }
        for (k, v) in &before {
            if after.get(k) != Some(v) {
                why.push(format!("input {k} was modified"));
            }
        }
        eprintln!(
            "{:>6.2} s exit {:?}: bonnetlab {}",
            o.elapsed.as_secs_f64(),
            o.code,
            cols[2]
        );
        if !why.is_empty() {
            failures.push(format!(
                "bonnetlab {}: {} -- stderr: {}",
                cols[2],
                why.join("; "),
                o.stderr.trim()
            ));
        }
    }
    assert!(n >= 20, "only {n} command lines in the corpus");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
