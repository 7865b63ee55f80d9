//! Mutation fuzzer for every input reader (issue 8), run in-process.
//!
//! Seeds: the real Zygo files in shared/data/real, small maps generated here through our own
//! writers (.dat, CSV, EXR) and by hand (.asc), a generated path log and a recipe TOML.
//! Each input is a seed with 1-4 stacked mutations: bit flips, interesting bytes, truncation,
//! chunk deletion / insertion / duplication, header-field overwrites (MetroPro offsets, or any
//! aligned offset for HDF5 / EXR), numeric-token replacement and line edits for text formats,
//! and appended bytes. Every input is reproducible from (seed, reader, iteration).
//!
//! Per input it records: a panic (caught with catch_unwind), a time over 1 s, an error message
//! that is not one line, and allocation beyond the bound `ALLOC_PER_BYTE * len + ALLOC_SLACK`
//! (peak live bytes, from the counting global allocator below; a single request over
//! `HARD_CAP` is refused, which aborts after printing the input's coordinates). A watchdog
//! stops the run if one input takes more than 30 s. Findings are saved to `--out`.
//!
//! The structured readers (`recipe-x`, `path-x`, `manifest-x`, `dwell-x`) keep a valid input's
//! structure and change its content: extreme numbers (mutate::extreme_numbers), structural
//! edits (missing / duplicated keys and tables, values of another type, very long strings,
//! huge counts of rows or tables: mutate::structural_toml, mutate::structural_csv), and for
//! path logs generated rasters with extreme rows. `recipe-x` then runs the checks simulate and
//! calibrate make before allocating (plan.rs) and flags an accepted input predicted over 1 GB.
//!
//! Usage: fuzz_readers [--iterations N] [--seed S] [--reader NAME|all] [--out DIR]
//!        [--replay ITER]
//! Readers: dat asc xyz datx csv exr detect path recipe recipe-x path-x manifest-x dwell-x.

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use bonnetlab_io::{MapFormat, ParseError};
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;

mod mutate;
mod plan;
mod seeds;
use mutate::mutate;
use seeds::seeds;

/// Allowed peak live bytes per input byte, plus a fixed slack (parsers build f64 heights and a
/// mask: about 9 bytes per 4-byte pixel in .dat, far less per pixel in text).
const ALLOC_PER_BYTE: usize = 32;
const ALLOC_SLACK: usize = 64 << 20;
/// A single allocation request above this is refused (the process then aborts).
const HARD_CAP: usize = 4 << 30;
/// Peak-allocation bound of the structured readers (bytes): 320 MiB.
const STRUCTURED_ALLOC_BOUND: usize = 320 << 20;
const SLOW: Duration = Duration::from_secs(1);
const SLOW_STRUCTURED: Duration = Duration::from_secs(10);

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
static LARGEST: AtomicUsize = AtomicUsize::new(0);
/// (reader index << 48) | iteration of the input being parsed, for abort and watchdog messages.
static CURRENT: AtomicU64 = AtomicU64::new(u64::MAX);
static STARTED_MS: AtomicU64 = AtomicU64::new(0);

struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if l.size() > HARD_CAP {
            refuse(l.size());
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            note_alloc(l.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        if l.size() > HARD_CAP {
            refuse(l.size());
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc_zeroed(l) };
        if !p.is_null() {
            note_alloc(l.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        LIVE.fetch_sub(l.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        if new > HARD_CAP {
            refuse(new);
            return std::ptr::null_mut();
        }
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            LIVE.fetch_sub(l.size(), Ordering::Relaxed);
            note_alloc(new);
        }
        q
    }
}

fn note_alloc(size: usize) {
    let live = LIVE.fetch_add(size, Ordering::Relaxed) + size;
    PEAK.fetch_max(live, Ordering::Relaxed);
    LARGEST.fetch_max(size, Ordering::Relaxed);
}

/// Writes without allocating (we are inside the allocator).
fn refuse(size: usize) {
    use std::io::Write;
    let cur = CURRENT.load(Ordering::Relaxed);
    let mut buf = [0u8; 160];
    let mut w = &mut buf[..];
    let _ = writeln!(
        w,
        "FINDING alloc-refused: {size} bytes requested; reader {} iteration {}",
        cur >> 48,
        cur & 0xFFFF_FFFF_FFFF
    );
    let n = 160 - w.len();
    let _ = std::io::stderr().write_all(&buf[..n]);
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[derive(Clone, Copy, Debug, PartialEq)]
enum Reader {
    Dat,
    Asc,
    Xyz,
    Datx,
    Csv,
    Exr,
    Detect,
    Path,
    Recipe,
    /// Structured: a valid recipe with 1 to 4 numbers replaced by extreme values.
    RecipeX,
    /// Structured: a generated path log (2 to 400 rows) with extreme coordinates and times,
    /// read and then re-timed (`apply_limits`) and extent-checked.
    PathX,
    /// Structured: a spot manifest with extreme numbers.
    ManifestX,
    /// Structured: a dwell case with extreme numbers.
    DwellX,
}

const ALL: [Reader; 13] = [
    Reader::Dat,
    Reader::Asc,
    Reader::Xyz,
    Reader::Datx,
    Reader::Csv,
    Reader::Exr,
    Reader::Detect,
    Reader::Path,
    Reader::Recipe,
    Reader::RecipeX,
    Reader::PathX,
    Reader::ManifestX,
    Reader::DwellX,
];

impl Reader {
    fn name(self) -> &'static str {
        match self {
            Reader::Dat => "dat",
            Reader::Asc => "asc",
            Reader::Xyz => "xyz",
            Reader::Datx => "datx",
            Reader::Csv => "csv",
            Reader::Exr => "exr",
            Reader::Detect => "detect",
            Reader::Path => "path",
            Reader::Recipe => "recipe",
            Reader::RecipeX => "recipe-x",
            Reader::PathX => "path-x",
            Reader::ManifestX => "manifest-x",
            Reader::DwellX => "dwell-x",
        }
    }

    fn is_text(self) -> bool {
        matches!(
            self,
            Reader::Asc
                | Reader::Csv
                | Reader::Path
                | Reader::Recipe
                | Reader::RecipeX
                | Reader::PathX
                | Reader::ManifestX
                | Reader::DwellX
        )
    }

    /// Whether inputs are generated with extreme numbers rather than byte mutations.
    fn is_structured(self) -> bool {
        matches!(
            self,
            Reader::RecipeX | Reader::PathX | Reader::ManifestX | Reader::DwellX
        )
    }

    /// Runs the reader; Err carries the error message.
    fn run(self, bytes: &[u8]) -> Result<(), String> {
        // The CLI reads a recipe, case or manifest only up to this size (`input::read_text`).
        if matches!(self, Reader::RecipeX | Reader::ManifestX | Reader::DwellX)
            && bytes.len() as u64 > bonnetlab_io::input::TEXT_LIMIT
        {
            return Err(format!(
                "input of {} bytes: over the text limit",
                bytes.len()
            ));
        }
        let map = |r: Result<Surface, ParseError>| r.map(check_surface).map_err(|e| e.to_string());
        match self {
            Reader::Dat => map(bonnetlab_io::parse_bytes(bytes, MapFormat::MetroProDat))?,
            Reader::Asc => map(bonnetlab_io::parse_bytes(bytes, MapFormat::MetroProAsc))?,
            Reader::Xyz => map(bonnetlab_io::parse_bytes(bytes, MapFormat::ZygoXyz))?,
            Reader::Datx => map(bonnetlab_io::parse_bytes(bytes, MapFormat::Datx))?,
            Reader::Csv => map(bonnetlab_io::parse_bytes(bytes, MapFormat::Csv))?,
            Reader::Exr => map(bonnetlab_io::parse_bytes(bytes, MapFormat::Exr))?,
            Reader::Detect => {
                let f = bonnetlab_io::detect_format(bytes, Path::new("input.dat"))
                    .map_err(|e| e.to_string())?;
                map(bonnetlab_io::parse_bytes(bytes, f))?
            }
            Reader::Path => {
                let p = bonnetlab_process::path::log::read_path_from(bytes, Path::new("path.csv"))
                    .map_err(|e| e.to_string())?;
                let finite = p
                    .t_s
                    .iter()
                    .chain(&p.x_mm)
                    .chain(&p.y_mm)
                    .all(|v| v.is_finite());
                if !finite {
                    return Err("BUG: non-finite value accepted".into());
                }
            }
            Reader::Recipe => {
                let text = String::from_utf8_lossy(bytes);
                bonnetlab_process::Recipe::parse(&text, Path::new("/nonexistent/recipe.toml"))
                    .map_err(|e| e.to_string())?;
            }
            Reader::RecipeX => {
                let text = String::from_utf8_lossy(bytes);
                let name = Path::new("/nonexistent/recipe.toml");
                // `vibration RECIPE` reads the document and its [process] / [vibration] only.
                if let Ok(doc) = bonnetlab_process::recipe::RecipeDoc::parse(&text, name) {
                    let _ = bonnetlab_vibration::params::VibrationParams::from_recipe(&doc);
                }
                let recipe =
                    bonnetlab_process::Recipe::parse(&text, name).map_err(|e| e.to_string())?;
                plan::recipe(&recipe, bytes)?;
            }
            Reader::PathX => {
                use bonnetlab_process::path::kinematics::{apply_limits, Limits};
                let name = Path::new("path.csv");
                let p = bonnetlab_process::path::log::read_path_from(bytes, name)
                    .map_err(|e| e.to_string())?;
                bonnetlab_process::path::log::check_extent(
                    &p,
                    name,
                    (0.0, 100.0),
                    (0.0, 100.0),
                    10.0,
                )
                .map_err(|e| e.to_string())
                .and_then(|()| apply_limits(&p, &Limits::default(), 0.5).map_err(|e| e.to_string()))
                .map(|_| ())?;
            }
            Reader::ManifestX => {
                let text = String::from_utf8_lossy(bytes);
                bonnetlab_spots::manifest::parse_manifest(Path::new("/nonexistent/m.toml"), &text)
                    .map_err(|e| e.to_string())?;
            }
            Reader::DwellX => {
                let text = String::from_utf8_lossy(bytes);
                bonnetlab_process::dwell::case::DwellCase::parse(
                    &text,
                    Path::new("/nonexistent/case.toml"),
                )
                .map_err(|e| e.to_string())?;
            }
        }
        Ok(())
    }
}

/// Invariants a successfully read map must hold; a violation panics (and is recorded).
fn check_surface(s: Surface) {
    assert_eq!(s.heights_nm().dim(), s.valid().dim(), "mask shape");
    assert!(
        s.heights_nm().iter().all(|h| h.is_finite()),
        "non-finite height"
    );
    for d in [s.dx_mm, s.dy_mm].into_iter().flatten() {
        assert!(d.is_finite() && d > 0.0, "pixel size {d}");
    }
}

#[derive(Default)]
struct Tally {
    inputs: u64,
    ok: u64,
    errors: u64,
    panics: u64,
    slow: u64,
    multiline: u64,
    over_alloc: u64,
    /// Accepted inputs predicted to need more than the 1 GB (`BUDGET:`).
    over_budget: u64,
    max_time: Duration,
    max_ratio: f64,
    max_peak: usize,
    elapsed: Duration,
}

static LAST_PANIC: Mutex<String> = Mutex::new(String::new());

fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// Findings saved per (reader, kind); later ones are only counted.
const MAX_SAVED: usize = 20;
static SAVED: Mutex<Vec<(&'static str, String, usize)>> = Mutex::new(Vec::new());

fn save(out: &Path, r: Reader, iter: u64, kind: &str, bytes: &[u8], what: &str) {
    if let Ok(mut saved) = SAVED.lock() {
        let key = (r.name(), kind.to_string());
        match saved
            .iter_mut()
            .find(|(a, b, _)| (*a, b.as_str()) == (key.0, key.1.as_str()))
        {
            Some(e) if e.2 >= MAX_SAVED => return,
            Some(e) => e.2 += 1,
            None => saved.push((key.0, key.1, 1)),
        }
    }
    let _ = std::fs::create_dir_all(out);
    let base = out.join(format!("{}-{iter}-{kind}", r.name()));
    let _ = std::fs::write(base.with_extension("bin"), bytes);
    let _ = std::fs::write(base.with_extension("txt"), what);
    let shown: String = what
        .replace(['\n', '\r'], "\\n")
        .chars()
        .take(300)
        .collect();
    println!(
        "FINDING {kind}: reader {} iteration {iter}: {shown}",
        r.name()
    );
}

fn input_for(r: Reader, seeds: &[(Vec<u8>, u32)], total_w: u64, seed: u64, iter: u64) -> Vec<u8> {
    let ri = ALL.iter().position(|&x| x == r).unwrap_or(0) as u64;
    let mut rng = Rng::new(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (ri << 48) ^ iter);
    let mut pick = (rng.next_u64() % total_w) as i64;
    let mut data = Vec::new();
    for (b, w) in seeds {
        pick -= *w as i64;
        if pick < 0 {
            data = b.clone();
            break;
        }
    }
    match r {
        Reader::RecipeX | Reader::ManifestX | Reader::DwellX => {
            // Half extreme numbers only, a quarter structural edits only, a quarter both.
            let how = rng.below(4);
            if how != 1 {
                mutate::extreme_numbers(&mut data, &mut rng);
            }
            if how != 0 && how != 2 {
                if data.contains(&b'=') {
                    mutate::structural_toml(&mut data, &mut rng);
                } else {
                    mutate::structural_csv(&mut data, &mut rng);
                }
            }
        }
        Reader::PathX => {
            data = mutate::extreme_path_log(&mut rng);
            if rng.below(10) < 3 {
                mutate::structural_csv(&mut data, &mut rng);
            }
        }
        _ => mutate(r, &mut data, &mut rng),
    }
    data
}

fn fuzz(r: Reader, iterations: u64, seed: u64, out: &Path, replay: Option<u64>) -> Tally {
    let seeds = seeds(r);
    let total_w: u64 = seeds.iter().map(|(_, w)| *w as u64).sum::<u64>().max(1);
    let ri = ALL.iter().position(|&x| x == r).unwrap_or(0) as u64;
    let mut t = Tally::default();
    let range = match replay {
        Some(i) => i..i + 1,
        None => 0..iterations,
    };
    let report_every = (iterations / 10).max(1);
    let started = Instant::now();
    for iter in range {
        let data = input_for(r, &seeds, total_w, seed, iter);
        if replay.is_some() {
            // Saved before running, so an input that aborts the process is still kept.
            let _ = std::fs::create_dir_all(out);
            let _ = std::fs::write(out.join(format!("{}-{iter}-replay.bin", r.name())), &data);
        }
        CURRENT.store((ri << 48) | iter, Ordering::Relaxed);
        let base = LIVE.load(Ordering::Relaxed);
        PEAK.store(base, Ordering::Relaxed);
        STARTED_MS.store(now_ms(), Ordering::Relaxed);
        let t0 = Instant::now();
        let res = catch_unwind(AssertUnwindSafe(|| r.run(&data)));
        let dt = t0.elapsed();
        STARTED_MS.store(0, Ordering::Relaxed);
        let peak = PEAK.load(Ordering::Relaxed).saturating_sub(base);
        t.inputs += 1;
        t.max_time = t.max_time.max(dt);
        t.max_peak = t.max_peak.max(peak);
        if data.len() >= 4096 {
            // Below 4 KiB the fixed slack dominates and the ratio says nothing.
            t.max_ratio = t.max_ratio.max(peak as f64 / data.len() as f64);
        }
        match res {
            Ok(Ok(())) => t.ok += 1,
            Ok(Err(msg)) if msg.starts_with("BUDGET:") => {
                t.ok += 1;
                t.over_budget += 1;
                save(out, r, iter, "budget", &data, &msg);
            }
            Ok(Err(msg)) => {
                t.errors += 1;
                if msg.contains(['\n', '\r']) || msg.starts_with("BUG") {
                    t.multiline += 1;
                    save(out, r, iter, "error-message", &data, &msg);
                }
                if replay.is_some() {
                    println!("error: {msg}");
                }
            }
            Err(_) => {
                t.panics += 1;
                let msg = LAST_PANIC.lock().map(|m| m.clone()).unwrap_or_default();
                save(out, r, iter, "panic", &data, &msg);
            }
        }
        // Structured inputs are held to the bound (10 s); byte readers to 1 s.
        if dt
            > if r.is_structured() {
                SLOW_STRUCTURED
            } else {
                SLOW
            }
        {
            t.slow += 1;
            save(
                out,
                r,
                iter,
                "slow",
                &data,
                &format!("{dt:?} for {} bytes", data.len()),
            );
        }
        // A structured input's size does not bound its work: a 400-row path log may re-time to
        // the documented 4e6-point limit (about 220 MB). Their bound is that, plus the slack.
        // Text of up to 16 MiB costs the TOML parser about 32 bytes per input byte.
        let bound = if r.is_structured() {
            STRUCTURED_ALLOC_BOUND.max(ALLOC_PER_BYTE * data.len() + ALLOC_SLACK)
        } else {
            ALLOC_PER_BYTE * data.len() + ALLOC_SLACK
        };
        if peak > bound {
            t.over_alloc += 1;
            save(
                out,
                r,
                iter,
                "alloc",
                &data,
                &format!("peak {peak} bytes for {} bytes", data.len()),
            );
        }
        if replay.is_none() && (iter + 1) % report_every == 0 {
            eprintln!("{}: {} / {iterations}", r.name(), iter + 1);
        }
    }
    t.elapsed = started.elapsed();
    t
}

/// The process's peak resident set (`VmHWM` of /proc/self/status).
fn peak_rss() -> String {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .map(|l| l["VmHWM:".len()..].trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

fn main() {
    let mut iterations = 10_000u64;
    let mut seed = 1u64;
    let mut which = "all".to_string();
    let mut out = PathBuf::from("target/fuzz-findings");
    let mut replay = None;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut k = 0;
    while k < args.len() {
        let val = args.get(k + 1).cloned().unwrap_or_default();
        match args[k].as_str() {
            "--iterations" => iterations = val.parse().unwrap_or(iterations),
            "--seed" => seed = val.parse().unwrap_or(seed),
            "--reader" => which = val,
            "--out" => out = PathBuf::from(val),
            "--replay" => replay = val.parse().ok(),
            other => {
                eprintln!("fuzz_readers: unknown argument {other}");
                std::process::exit(2);
            }
        }
        k += 2;
    }
    std::panic::set_hook(Box::new(|info| {
        if let Ok(mut m) = LAST_PANIC.lock() {
            *m = info.to_string().replace('\n', " ");
        }
    }));
    std::thread::spawn(|| loop {
        std::thread::sleep(Duration::from_secs(1));
        let s = STARTED_MS.load(Ordering::Relaxed);
        if s != 0 && now_ms().saturating_sub(s) > 30_000 {
            let cur = CURRENT.load(Ordering::Relaxed);
            eprintln!(
                "FINDING hang: reader {} iteration {} ran over 30 s",
                cur >> 48,
                cur & 0xFFFF_FFFF_FFFF
            );
            std::process::exit(3);
        }
    });
    println!("| reader | inputs | ok | errors | panics | >1 s | multi-line errors | over alloc bound | max time | max peak alloc | max peak / input bytes (inputs >= 4 KiB) | wall time |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in ALL {
        if which != "all" && which != r.name() {
            continue;
        }
        let t = fuzz(r, iterations, seed, &out, replay);
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {:.1} ms | {:.1} MiB | {:.1} | {:.0} s |",
            r.name(),
            t.inputs,
            t.ok,
            t.errors,
            t.panics,
            t.slow,
            t.multiline,
            t.over_alloc,
            t.max_time.as_secs_f64() * 1e3,
            t.max_peak as f64 / (1 << 20) as f64,
            t.max_ratio,
            t.elapsed.as_secs_f64()
        );
        println!(
            "LARGEST single allocation so far: {} bytes; peak RSS so far (VmHWM): {}",
            LARGEST.load(Ordering::Relaxed),
            peak_rss()
        );
        if r.is_structured() {
            println!(
                "{}: accepted over the 1 GB budget: {}",
                r.name(),
                t.over_budget
            );
        }
        if r == Reader::RecipeX {
            println!(
                "recipe-x: passed every pre-allocation check: {}; footprints over 250k pixels \
                 size-checked but not sampled: {}",
                plan::ACCEPTED.load(Ordering::Relaxed),
                plan::LARGE_TIFS.load(Ordering::Relaxed)
            );
        }
    }
}
