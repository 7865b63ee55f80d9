//! Stage timings of the fast coupling on the bench case (100 x 100 mm at 0.1 mm, 60-min raster,
//! 1 kHz): `cargo run --release -p bonnetlab-vibration --example profile_coupling`.

use bonnetlab_process::perturb::{DerivativeKernels, WeightedDwell};
use bonnetlab_vibration::coupling::fast::{axis, executed_path, offset_tif};
use bonnetlab_vibration::coupling::stream::SampleStream;
use bonnetlab_vibration::coupling::{fast_maps, CouplingCase, CouplingOptions, Mechanisms};
use bonnetlab_vibration::params::Bonnet;
use std::time::Instant;

fn main() {
    let case = CouplingCase::bench_100mm().expect("bench case");
    let tif = CouplingCase::bench_tif().expect("tif");
    let (grid, params, input) = (case.grid, &case.params, case.input());
    let opts = CouplingOptions::default();
    let t = Instant::now();
    let inst = offset_tif(&tif, params);
    let k = DerivativeKernels::sample(&inst, 0.1, 0.1, axis(params.lateral_axis));
    eprintln!("kernels {:?} ({:?})", t.elapsed(), k.kh.dim());
    let t = Instant::now();
    let exec = executed_path(&input, &Mechanisms::ALL).expect("exec");
    eprintln!("executed path {:?} ({} nodes)", t.elapsed(), exec.len());
    let t = Instant::now();
    let mut n = 0usize;
    let mut acc = 0.0;
    for s in SampleStream::new(&exec, params, Bonnet::Original, &Mechanisms::ALL, 1000.0, 1)
        .expect("stream")
    {
        n += 1;
        acc += s.u_mm;
    }
    eprintln!("stream {:?} ({n} samples, {acc:.3e})", t.elapsed());
    let t = Instant::now();
    let ext = grid.grown(k.half.0, k.half.1);
    let mut c8 = WeightedDwell::<8>::new(ext);
    for s in SampleStream::new(&exec, params, Bonnet::Original, &Mechanisms::ALL, 1000.0, 1)
        .expect("stream")
    {
        c8.add(s.x_mm, s.y_mm, s.dt_s, &[s.u_mm; 8]);
    }
    c8.finish();
    eprintln!("stream + splat {:?}", t.elapsed());
    for _ in 0..2 {
        let t = Instant::now();
        let m = fast_maps(&input, Bonnet::Original, &opts).expect("fast");
        eprintln!("fast_maps total {:?} ({:?})", t.elapsed(), m.baseline.dim());
    }
}
