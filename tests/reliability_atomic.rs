//! Atomic outputs (issue 8): a write that fails or is killed part-way leaves the previous
//! output intact. Covers `bonnetlab_io::atomic`, which every writer and report goes through.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use bonnetlab_io::atomic::{write_atomic, write_atomic_with};

const CHILD_ENV: &str = "BONNETLAB_TEST_SLOW_WRITER";

fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-"))
        .collect()
}

#[test]
fn injected_failure_mid_write_keeps_the_previous_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report.json");
    write_atomic(&out, b"{\"previous\":true}\n").unwrap();
    // 8 MiB written, then the producer fails (as a serialiser or a full disk would).
    let err = write_atomic_with(&out, |w| {
        for _ in 0..8 * 1024 {
            w.write_all(&[b'x'; 1024])?;
        }
        Err(std::io::Error::other("injected failure"))
    })
    .unwrap_err();
    assert!(err.to_string().contains("injected failure"));
    assert_eq!(std::fs::read(&out).unwrap(), b"{\"previous\":true}\n");
    assert!(temp_files(dir.path()).is_empty(), "temporary file removed");
}

#[test]
fn killed_writer_leaves_the_previous_output_intact() {
    if let Some(target) = std::env::var_os(CHILD_ENV) {
        // Child: a slow writer (about 20 s) that the parent kills part-way.
        let _ = write_atomic_with(Path::new(&target), |w| {
            for _ in 0..2000 {
                w.write_all(&[b'y'; 4096])?;
                w.flush()?;
                std::thread::sleep(Duration::from_millis(10));
            }
            Ok(())
        });
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.csv");
    write_atomic(&out, b"1,2\n3,4\n").unwrap();
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "killed_writer_leaves_the_previous_output_intact",
            "--nocapture",
        ])
        .env(CHILD_ENV, &out)
        .spawn()
        .unwrap();
    // Wait until the child's temporary file holds data, then kill it mid-write.
    let t0 = Instant::now();
    let tmp = loop {
        let found = temp_files(dir.path()).into_iter().find_map(|n| {
            let p = dir.path().join(n);
            (std::fs::metadata(&p).map(|m| m.len()).unwrap_or(0) > 16 * 4096).then_some(p)
        });
        if let Some(p) = found {
            break p;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the child never started writing"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(
        std::fs::read(&out).unwrap(),
        b"1,2\n3,4\n",
        "previous output intact"
    );
    // The partial data only ever lived in the hidden temporary file.
    assert!(std::fs::metadata(&tmp).map(|m| m.len()).unwrap_or(0) > 0);
}
