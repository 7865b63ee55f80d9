//! Benchmarks (criterion) for height metrics and form removal on synthetic maps of the two
//! sizes of issue 2 (a 640 x 480 camera frame and a 4096 x 4096 stitched map); see
//! reports/performance.md. Run: `cargo bench --bench metrics`.

use std::hint::black_box;

use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::{height_stats, pvr, remove_terms, Surface, Term};
use criterion::{criterion_group, criterion_main, Criterion};
use ndarray::Array2;

/// A tilted, curved map with white noise and 2 % dropouts, as a measured part would look.
fn synthetic(rows: usize, cols: usize) -> Surface {
    let mut rng = Rng::new(1);
    let z = Array2::from_shape_fn((rows, cols), |(i, j)| {
        if rng.uniform() < 0.02 {
            f64::NAN
        } else {
            let (x, y) = (j as f64 * 0.1, i as f64 * 0.1);
            50.0 + 0.3 * x - 0.2 * y + 1e-3 * (x * x + y * y) + 5.0 * rng.normal()
        }
    });
    Surface::new(z, Some(0.1), Some(0.1)).expect("finite pixel size")
}

fn bench(c: &mut Criterion) {
    for (rows, cols) in [(480, 640), (4096, 4096)] {
        let s = synthetic(rows, cols);
        let mut g = c.benchmark_group(format!("metrics_{cols}x{rows}"));
        if rows > 1000 {
            g.sample_size(10);
        }
        g.bench_function("height_stats", |b| b.iter(|| height_stats(black_box(&s))));
        g.bench_function("remove_piston_tilt+stats", |b| {
            b.iter(|| {
                let (r, _) = remove_terms(black_box(&s), &[Term::Piston, Term::Tilt]).unwrap();
                height_stats(&r).unwrap()
            })
        });
        g.bench_function("remove_zernike37", |b| {
            b.iter(|| remove_terms(black_box(&s), &[Term::Zernike(37)]).unwrap())
        });
        if rows < 1000 {
            g.bench_function("pvr", |b| b.iter(|| pvr(black_box(&s)).unwrap()));
        }
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
