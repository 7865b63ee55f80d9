//! Quick wall-clock timing of the spectral workloads on one synthetic map (the criterion bench
//! in benches/spectrum.rs is the reference). Run:
//! `cargo run --release -p bonnetlab-spectrum --example time_psd -- 4096`.

use std::f64::consts::PI;
use std::time::Instant;

use bonnetlab_spectrum::{psd_2d, psd_xy, ripple_from_psds, PsdOptions, RippleOptions};
use bonnetlab_surface::{remove_terms, rng::Rng, Surface, Term};
use ndarray::Array2;

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(2048);
    let d = 0.1;
    let mut rng = Rng::new(1);
    let z = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * d, i as f64 * d);
        10.0 * (2.0 * PI * y / 3.0).sin() + 0.3 * x - 0.2 * y + 2.0 * rng.normal()
    });
    let s = Surface::new(z, Some(d), Some(d)).expect("pixel size");
    let opts = PsdOptions::default();
    for _ in 0..3 {
        let t = Instant::now();
        let fast = bonnetlab_spectrum::remove_form(&s, &[Term::Piston, Term::Tilt]).expect("fit");
        let t_fast = t.elapsed();
        let t = Instant::now();
        let _ = remove_terms(&s, &[Term::Piston, Term::Tilt]).expect("fit");
        let t_slow = t.elapsed();
        let none = PsdOptions {
            remove: vec![],
            ..opts.clone()
        };
        let t = Instant::now();
        let _ = bonnetlab_spectrum::psd_x(&s, &none).expect("psd");
        let t_x = t.elapsed();
        let t = Instant::now();
        let _ = bonnetlab_spectrum::psd_y(&s, &none).expect("psd");
        let t_y = t.elapsed();
        println!("lines only: x {t_x:?}, y {t_y:?}");
        let t = Instant::now();
        let (x, y) = psd_xy(&s, &opts).expect("psd");
        let rp = ripple_from_psds(&x, &y, 3.0, &RippleOptions::default()).expect("ripple");
        let t_xy = t.elapsed();
        let t = Instant::now();
        let p2 = psd_2d(&s, &opts).expect("2d");
        let rad = p2.radial();
        let t_2d = t.elapsed();
        println!(
            "n {n}: form removal {t_fast:?} (remove_terms {t_slow:?}), psd_xy+ripple {t_xy:?} (sigma1 {:.4}), 2-D+radial {t_2d:?} ({} bins, {} px)",
            rp.sigma1_nm,
            rad.counts.len(),
            fast.valid_count()
        );
    }
}
