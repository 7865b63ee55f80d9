//! Benchmarks (criterion) for reading surface maps; see reports/performance.md.
//!
//! `read+stats` is what `bonnetlab stats FILE --remove piston,tilt` does after parsing the
//! arguments: read the file, remove piston and tilt jointly, compute the height parameters.
//! Inputs: the real 640 x 480 NewView file `surfalize_test_1.dat` (skipped when
//! `shared/data/real` is absent) and a generated 4096 x 4096 `.dat` written to a temp dir.

use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, Criterion};
use ndarray::Array2;

use bonnetlab::io::{read_surface, write_surface, MapFormat};
use bonnetlab::surface::{height_stats, remove_terms, Surface, Term};

fn real_dat() -> Option<PathBuf> {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    here.ancestors()
        .map(|a| a.join("shared/data/real/surfalize_test_1.dat"))
        .find(|p| p.is_file())
}

fn read_and_stats(path: &Path) -> f64 {
    let s = read_surface(path).expect("read");
    let (r, _) = remove_terms(&s, &[Term::Piston, Term::Tilt]).expect("fit");
    height_stats(&r).expect("stats").rms_nm
}

/// A 4096 x 4096 map with form, ripple and a masked border, written as a MetroPro .dat.
fn generated_dat(dir: &Path) -> PathBuf {
    let n = 4096;
    let h = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 / n as f64 - 0.5, i as f64 / n as f64 - 0.5);
        if x * x + y * y > 0.25 {
            return f64::NAN;
        }
        120.0 * (x * x + y * y) + 15.0 * x + 3.0 * (x * 40.0).sin() + 1.5 * (y * 300.0).cos()
    });
    let s = Surface::new(h, Some(0.025), Some(0.025)).expect("surface");
    let p = dir.join("generated_4096.dat");
    write_surface(&p, &s, MapFormat::MetroProDat).expect("write");
    p
}

fn bench_io(c: &mut Criterion) {
    if let Some(p) = real_dat() {
        let mut g = c.benchmark_group("dat_640x480_real");
        g.bench_function("read", |b| {
            b.iter(|| read_surface(&p).expect("read").valid_count())
        });
        g.bench_function("read+stats", |b| b.iter(|| read_and_stats(&p)));
        g.finish();
    } else {
        eprintln!("skipping the real 640 x 480 bench: shared/data/real not found");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let p = generated_dat(dir.path());
    let mut g = c.benchmark_group("dat_4096x4096_generated");
    g.sample_size(10);
    g.bench_function("read", |b| {
        b.iter(|| read_surface(&p).expect("read").valid_count())
    });
    g.bench_function("read+stats", |b| b.iter(|| read_and_stats(&p)));
    g.finish();
}

criterion_group!(benches, bench_io);
criterion_main!(benches);
