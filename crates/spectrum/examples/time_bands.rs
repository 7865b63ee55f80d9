//! Wall-clock timing of the areal band split (`band_split`) on a synthetic N x N map: a raster
//! ripple, a figure term and pixel-scale noise, on the full rectangle (`full`) and on a round
//! aperture of 90 % of the side with 2 % random dropouts (`round`). Run:
//! `cargo run --release -p bonnetlab-spectrum --example time_bands -- 4096 3 round`
//! (N, repetitions, aperture). Prints one JSON line.

use std::f64::consts::PI;
use std::time::Instant;

use bonnetlab_spectrum::band_split;
use bonnetlab_surface::{rng::Rng, Surface, Term};
use ndarray::Array2;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(2048);
    let reps: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3).max(1);
    let aperture = args.get(3).map_or("round", String::as_str);
    let d = 0.025;
    let mut rng = Rng::new(1);
    let c = 0.5 * (n as f64 - 1.0);
    let z = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * d, i as f64 * d);
        let u = (j as f64 - c) / c;
        10.0 * (2.0 * PI * y / 3.0).sin() + 40.0 * u * u + 0.3 * x + 2.0 * rng.normal()
    });
    let valid = Array2::from_shape_fn((n, n), |(i, j)| {
        let inside = aperture != "round" || (i as f64 - c).hypot(j as f64 - c) <= 0.9 * c;
        inside && (aperture == "full" || rng.uniform() >= 0.02)
    });
    let s = Surface::with_mask(z, valid, Some(d), Some(d)).expect("pixel size");
    let mut runs = Vec::with_capacity(reps);
    let mut msf = 0.0;
    for _ in 0..reps {
        let t = Instant::now();
        let b =
            band_split(&s, &[Term::Piston, Term::Tilt], (1.0 / 33.0, 1.0 / 0.12)).expect("bands");
        msf = b.msf_rms_nm.unwrap_or(f64::NAN);
        runs.push(t.elapsed().as_secs_f64());
    }
    let list: Vec<String> = runs.iter().map(|t| format!("{t:.3}")).collect();
    println!(
        "{{\"name\": \"band_split/{aperture}/{n}\", \"runs\": [{}], \"msf_rms_nm\": {msf:.6}}}",
        list.join(", ")
    );
}
