//! Replays the `.datx` inputs the fuzz harness saved (`tests/corpus/fuzz-findings/`) through
//! `read_surface`: each must give a clean one-line error naming the file, or a valid surface,
//! and the heap peak while reading must stay within the harness's bound
//! (32 x input bytes + 64 MiB). A counting global allocator measures the peak; it is this
//! test binary's own allocator, so the whole file is one test to keep other threads out.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

struct Counting;
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = System.alloc(l);
        if !p.is_null() {
            note(l.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        let p = System.alloc_zeroed(l);
        if !p.is_null() {
            note(l.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        System.dealloc(p, l);
        LIVE.fetch_sub(l.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        let q = System.realloc(p, l, new);
        if !q.is_null() {
            LIVE.fetch_sub(l.size(), Ordering::Relaxed);
            note(new);
        }
        q
    }
}

fn note(size: usize) {
    let live = LIVE.fetch_add(size, Ordering::Relaxed) + size;
    PEAK.fetch_max(live, Ordering::Relaxed);
    LARGEST.fetch_max(size, Ordering::Relaxed);
}

#[global_allocator]
static A: Counting = Counting;

fn findings_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/corpus/fuzz-findings")
}

#[test]
fn saved_datx_findings_fail_cleanly_within_the_allocation_bound() {
    let dir = findings_dir();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("fuzz-findings directory")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "datx"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 4,
        "expected the saved datx findings, got {files:?}"
    );
    let mut failures = Vec::new();
    for f in &files {
        let input_bytes = std::fs::metadata(f).unwrap().len() as usize;
        let bound = 32 * input_bytes + 64 * 1024 * 1024;
        let base = LIVE.load(Ordering::Relaxed);
        PEAK.store(base, Ordering::Relaxed);
        LARGEST.store(0, Ordering::Relaxed);
        let t = Instant::now();
        let r = bonnetlab_io::read_surface(f);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let peak = PEAK.load(Ordering::Relaxed) - base;
        let largest = LARGEST.load(Ordering::Relaxed);
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let outcome = match &r {
            Ok(s) => {
                let (ny, nx) = s.dim();
                assert!(
                    s.heights_nm().iter().all(|v| v.is_finite()),
                    "{name}: non-finite height"
                );
                assert_eq!(s.valid().dim(), (ny, nx), "{name}: mask shape");
                format!("ok {ny} x {nx}")
            }
            Err(e) => {
                let msg = e.to_string();
                assert!(!msg.contains('\n'), "{name}: multi-line error {msg:?}");
                assert!(
                    msg.contains(&name),
                    "{name}: error does not name the file: {msg}"
                );
                format!("error: {msg}")
            }
        };
        eprintln!(
            "{name}: {input_bytes} B, peak {:.1} MiB, largest alloc {:.1} MiB, {ms:.0} ms, {outcome}",
            peak as f64 / 1048576.0,
            largest as f64 / 1048576.0
        );
        if peak > bound {
            failures.push(format!("{name}: peak {peak} B > bound {bound} B"));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
