//! Benchmarks (criterion) for the spectral analyses; see reports/performance.md and the peer
//! harness benches/peers/run.sh, which runs the same work in NumPy / SciPy and prints medians
//! side by side (same map, same conventions).
//!
//! Workloads on an N x N fully valid synthetic map (dx = dy = 0.1 mm, a 10 nm ripple with a
//! 3 mm pitch along Y, a tilt and 2 nm white noise; seed 1):
//! - `psd_xy_ripple/N`: piston + tilt removed jointly, 1-D PSD along X and along Y (periodic
//!   Hann, per-line mean), ripple at 3 mm (5 harmonics, prominence);
//! - `metrology/N`: the full metrology of a map (issue 9): the same removal, height statistics
//!   of the residual, both 1-D PSDs and the ripple (`stats_psd_xy`, one fit, no residual map);
//! - `psd_2d_radial/N`: the same removal, 2-D two-sided PSD (separable Hann), radial PSD;
//!   N = 512, 1024, 2048, 4096 (scaling).
//!
//! Run: `cargo bench --bench spectrum` (a few minutes on 2 cores). Filter with a name, for
//! example `cargo bench --bench spectrum -- psd_xy_ripple/4096`.

use std::f64::consts::PI;
use std::hint::black_box;
use std::time::Duration;

use bonnetlab_spectrum::{
    psd_2d, psd_xy, ripple_from_psds, stats_psd_xy, PsdOptions, RippleOptions,
};
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use ndarray::Array2;

const DX_MM: f64 = 0.1;
const PITCH_MM: f64 = 3.0;

fn synthetic(n: usize) -> Surface {
    let mut rng = Rng::new(1);
    let z = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * DX_MM, i as f64 * DX_MM);
        10.0 * (2.0 * PI * y / PITCH_MM).sin() + 0.3 * x - 0.2 * y + 2.0 * rng.normal()
    });
    Surface::new(z, Some(DX_MM), Some(DX_MM)).expect("finite pixel size")
}

fn bench(c: &mut Criterion) {
    let opts = PsdOptions::default();
    let ropts = RippleOptions::default();
    let mut g = c.benchmark_group("spectrum");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(500));
    g.measurement_time(Duration::from_secs(3));
    for n in [512usize, 1024, 2048, 4096] {
        let s = synthetic(n);
        g.bench_with_input(BenchmarkId::new("psd_xy_ripple", n), &s, |b, s| {
            b.iter(|| {
                let (x, y) = psd_xy(black_box(s), &opts).expect("psd");
                ripple_from_psds(&x, &y, PITCH_MM, &ropts).expect("ripple")
            })
        });
        g.bench_with_input(BenchmarkId::new("metrology", n), &s, |b, s| {
            b.iter(|| {
                let (st, x, y) = stats_psd_xy(black_box(s), &opts).expect("metrology");
                let r = ripple_from_psds(&x, &y, PITCH_MM, &ropts).expect("ripple");
                (st, r)
            })
        });
        g.bench_with_input(BenchmarkId::new("psd_2d_radial", n), &s, |b, s| {
            b.iter(|| {
                let p = psd_2d(black_box(s), &opts).expect("psd2d");
                p.radial()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
