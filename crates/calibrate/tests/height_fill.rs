//! A height covariate rests on the height under the tool where the before map has no data (the
//! corners a round aperture leaves, the overrun past the part): `fill_error` draws what the
//! model's fill may miss there from surrogate surfaces with the map's own spectrum. Checked
//! against the true surface of the generator (a square twin of the same run measures the
//! corners), not against the surrogates' own construction. And the generator's reference
//! plane: `SynthRun::valid_plane_offset_nm` against the calibration's own plane fit.

use bonnetlab_calibrate::fill_error::{height_fill_errors, height_resolution_errors};
use bonnetlab_calibrate::grid::{sample, smooth_masked};
use bonnetlab_calibrate::model::{plane_fit, plane_removed, Problem};
use bonnetlab_calibrate::synth::{generate, InitialSurface, SynthConfig};
use bonnetlab_surface::rng::Rng;
use ndarray::Array2;

fn round_and_square(seed: u64, noise: f64) -> (SynthConfig, SynthConfig) {
    twin_configs(seed, 160, 2.2, noise, 80.0)
}

/// A run on a round aperture of `aperture_mm` and its square twin (the same surface, path and
/// noise, measured over the whole 100 mm part): `n`^2 maps, a power-law surface of 1-D exponent
/// `beta`.
fn twin_configs(
    seed: u64,
    n: usize,
    beta: f64,
    noise: f64,
    aperture_mm: f64,
) -> (SynthConfig, SynthConfig) {
    let square = SynthConfig::realistic(seed, n, 100.0, InitialSurface::realistic_texture(beta))
        .with_noise_nm(noise, noise);
    let round = square.clone().with_round_aperture(true, aperture_mm);
    (round, square)
}

/// The twins' problems (round first).
fn twin_problems((round, square): (SynthConfig, SynthConfig)) -> (Problem, Problem) {
    let pr = generate(&round).expect("round").problem().expect("problem");
    let ps = generate(&square)
        .expect("square")
        .problem()
        .expect("problem");
    (pr, ps)
}

/// The true local height over `sigma_mm` about the plane the round run's model takes (over its
/// aperture's pixels), from the square twin's map: the model's smoothing over a map with no
/// holes.
fn true_local_height(pr: &Problem, ps: &Problem, sigma_mm: f64) -> Array2<f64> {
    let g = &pr.grid;
    let [pz, px, py] = plane_fit(g, &ps.before, &pr.before_valid);
    let (cx, cy) = g.centre_mm();
    let flat = Array2::from_shape_fn(ps.before.dim(), |(i, j)| {
        ps.before[(i, j)] - pz - px * (g.x_mm(j) - cx) - py * (g.y_mm(i) - cy)
    });
    let all = Array2::from_elem(flat.dim(), true);
    smooth_masked(&flat, &all, sigma_mm / g.dx_mm)
}

#[test]
fn the_valid_plane_offset_is_the_calibrations_plane_over_the_aperture_less_over_the_map() {
    let (round, square) = round_and_square(11, 0.0);
    // Measured whole (no isolated dropouts either): the same plane.
    let whole = SynthConfig {
        dropout_fraction: 0.0,
        ..square
    };
    let sq = generate(&whole).expect("square run");
    assert_eq!(sq.valid_plane_offset_nm, (0.0, 0.0, 0.0));
    let run = generate(&round).expect("round run");
    let p = run.problem().expect("problem");
    let g = &p.grid;
    // The noise-free square twin's before map is the true surface at every pixel (the round
    // run's map holds no data outside its aperture).
    let truth = sq.before.heights_nm();
    let all = Array2::from_elem(p.before_valid.dim(), true);
    let over_valid = plane_fit(g, truth, &p.before_valid);
    let over_all = plane_fit(g, truth, &all);
    let (cx, cy) = g.centre_mm();
    let (p0, a, b) = run.valid_plane_offset_nm;
    let mut largest = 0.0f64;
    for (x, y) in [(cx, cy), (0.0, 0.0), (100.0, 20.0), (30.0, 90.0)] {
        let calib = (over_valid[0] - over_all[0])
            + (over_valid[1] - over_all[1]) * (x - cx)
            + (over_valid[2] - over_all[2]) * (y - cy);
        let synth = p0 + a * x + b * y;
        eprintln!("offset at ({x}, {y}) mm: calibration {calib:.6} nm, generator {synth:.6} nm");
        assert!((calib - synth).abs() < 1e-6, "{calib} vs {synth}");
        largest = largest.max(synth.abs());
    }
    // A case where the reference matters: tens of nm on this 140 nm surface.
    assert!(largest > 5.0, "offset {largest} nm");
}

#[test]
fn fill_errors_vanish_inside_the_data_and_match_the_true_corners_outside() {
    // Three power-law surfaces; the truth of the corners from each run's square twin.
    for seed in [3u64, 8, 21] {
        let (pr, ps) = twin_problems(round_and_square(seed, 1.0));
        let g = &pr.grid;
        let sigma_mm = 2.0 * g.dx_mm;
        let draws = height_fill_errors(&pr, sigma_mm, 16);
        assert_eq!(draws.len(), 16);
        let truth = true_local_height(&pr, &ps, sigma_mm);
        let (cx, cy) = g.centre_mm();
        let model = pr.local_height(sigma_mm);
        let s = &pr.samples;
        let r_ap = 40.0;
        let dist = |k: usize| (s.x_mm[k] - cx).hypot(s.y_mm[k] - cy) - r_ap;
        let on_map = |k: usize| {
            (0.0..=g.x_mm(g.cols - 1)).contains(&s.x_mm[k])
                && (0.0..=g.y_mm(g.rows - 1)).contains(&s.y_mm[k])
        };
        // Corners: on the map, over 3 mm outside the aperture.
        let corners: Vec<usize> = (0..s.len())
            .filter(|&k| on_map(k) && dist(k) > 3.0)
            .collect();
        // Deep inside: the smoothing window (4 sigma) and a pixel clear of the rim.
        let inside: Vec<usize> = (0..s.len())
            .filter(|&k| dist(k) < -(4.0 * sigma_mm + 2.0 * g.dx_mm))
            .collect();
        assert!(corners.len() > 1000 && inside.len() > 1000);
        let rms = |f: &dyn Fn(usize) -> f64, set: &[usize]| {
            (set.iter().map(|&k| f(k).powi(2)).sum::<f64>() / set.len() as f64).sqrt()
        };
        let actual = rms(
            &|k| sample(g, &truth, s.x_mm[k], s.y_mm[k]) - model[k],
            &corners,
        );
        let drawn = |set: &[usize]| {
            (draws
                .iter()
                .map(|d| rms(&|k| d[k], set).powi(2))
                .sum::<f64>()
                / draws.len() as f64)
                .sqrt()
        };
        let (corner_draws, inside_draws) = (drawn(&corners), drawn(&inside));
        eprintln!(
            "seed {seed}: corners: true fill error {actual:.1} nm RMS, drawn {corner_draws:.1} nm; \
             inside: drawn {inside_draws:.3} nm"
        );
        assert!(
            corner_draws > actual / 1.5 && corner_draws < 1.5 * actual,
            "drawn {corner_draws} nm against the true {actual} nm"
        );
        // Inside, only the before map's isolated dropouts (0.1 % of the pixels) leave a fill.
        assert!(
            inside_draws < 0.03 * corner_draws,
            "inside {inside_draws} nm"
        );
    }
}

#[test]
fn the_fill_continues_the_surface_past_a_round_rim() {
    // Power-law surfaces (1-D exponents 1.8-2.6) behind a 90 mm aperture on a 100 mm part;
    // the truth of the unmeasured corners from each run's square twin, about the plane the
    // model takes. The model's fill against the one that stops at the smoothing's reach
    // (the masked smoothing alone, 0 beyond 4 sigma), 1-6 mm past the rim, where the tool's
    // footprint carries the fill into the measured removal; and far out, where neither knows.
    let mut pooled = [(0.0f64, 0.0f64); 2];
    for (seed, beta) in [(3u64, 1.8), (8, 2.2), (21, 2.6), (13, 2.2)] {
        let (pr, ps) = twin_problems(twin_configs(seed, 200, beta, 1.0, 90.0));
        let g = &pr.grid;
        let sigma_mm = 2.0 * g.dx_mm;
        let truth = true_local_height(&pr, &ps, sigma_mm);
        let flat = plane_removed(g, &pr.before, &pr.before_valid);
        let stopping = smooth_masked(&flat, &pr.before_valid, sigma_mm / g.dx_mm);
        let (cx, cy) = g.centre_mm();
        let model = pr.local_height(sigma_mm);
        let s = &pr.samples;
        let on_map = |k: usize| {
            (0.0..=g.x_mm(g.cols - 1)).contains(&s.x_mm[k])
                && (0.0..=g.y_mm(g.rows - 1)).contains(&s.y_mm[k])
        };
        let dist = |k: usize| (s.x_mm[k] - cx).hypot(s.y_mm[k] - cy) - 45.0;
        for (b, (lo, hi)) in [(1.0, 6.0), (10.0, 100.0)].into_iter().enumerate() {
            let set: Vec<usize> = (0..s.len())
                .filter(|&k| on_map(k) && dist(k) > lo && dist(k) <= hi)
                .collect();
            assert!(set.len() > 1000, "{}", set.len());
            let ms = |f: &dyn Fn(usize) -> f64| set.iter().map(|&k| f(k).powi(2)).sum::<f64>();
            let at = |m: &Array2<f64>, k: usize| sample(g, m, s.x_mm[k], s.y_mm[k]);
            let new = ms(&|k| at(&truth, k) - model[k]);
            let old = ms(&|k| at(&truth, k) - at(&stopping, k));
            let n = set.len() as f64;
            eprintln!(
                "seed {seed} (exponent {beta}), {lo}-{hi} mm past the rim: fill error {:.1} nm RMS, \
                 stopping at the smoothing's reach {:.1} nm, the true height {:.1} nm",
                (new / n).sqrt(),
                (old / n).sqrt(),
                (ms(&|k| at(&truth, k)) / n).sqrt()
            );
            pooled[b].0 += new;
            pooled[b].1 += old;
            if b == 0 {
                // RMS against RMS.
                assert!(
                    new.sqrt() < 0.95 * old.sqrt(),
                    "seed {seed}: {new} against {old}"
                );
            }
        }
    }
    let ratio = |b: usize| (pooled[b].0 / pooled[b].1).sqrt();
    eprintln!(
        "pooled: 1-6 mm {:.3} of the stopping fill's error, past 10 mm {:.3}",
        ratio(0),
        ratio(1)
    );
    assert!(ratio(0) < 0.85, "{}", ratio(0));
    // Far out, no worse than not knowing (the stopping fill is the plane there).
    assert!(ratio(1) < 1.1, "{}", ratio(1));
}

/// A surface with detail below the map's pixel: `n` plane waves, frequencies log-uniform from
/// 1/100 to 1.6 cycles per mm (twice the Nyquist of 0.625 mm pixels), directions and phases
/// uniform, amplitudes for an isotropic 2-D PSD falling as f^-beta2, scaled to 140 nm RMS. Built
/// from its own waves, not an FFT, so it is neither periodic on the map nor band-limited.
fn plane_waves(seed: u64, beta2: f64, n: usize) -> impl Fn(f64, f64) -> f64 {
    let mut rng = Rng::new(seed);
    let (lo, hi) = (0.01f64.ln(), 1.6f64.ln());
    let mut waves: Vec<(f64, f64, f64, f64)> = (0..n)
        .map(|_| {
            let f = (lo + (hi - lo) * rng.uniform()).exp();
            let th = 2.0 * std::f64::consts::PI * rng.uniform();
            let ph = 2.0 * std::f64::consts::PI * rng.uniform();
            // Log-uniform frequencies: each wave carries f^2 S(f) of the variance.
            let a = f.powf(1.0 - 0.5 * beta2);
            (
                2.0 * std::f64::consts::PI * f * th.cos(),
                2.0 * std::f64::consts::PI * f * th.sin(),
                ph,
                a,
            )
        })
        .collect();
    let var: f64 = waves.iter().map(|w| 0.5 * w.3 * w.3).sum();
    let k = 140.0 / var.sqrt();
    for w in &mut waves {
        w.3 *= k;
    }
    move |x: f64, y: f64| {
        waves
            .iter()
            .map(|w| w.3 * (w.0 * x + w.1 * y + w.2).cos())
            .sum()
    }
}

#[test]
fn resolution_errors_match_the_detail_a_surface_has_below_its_pixels() {
    // The path and grid of a generated square run (160^2 at 0.625 mm, noise free); its before
    // map replaced by point samples of a surface with detail to twice the map's Nyquist. The
    // truth at every sub-step is that surface's own height there (about the plane the model
    // removes), against the model's covariate (the map smoothed over 2 px).
    for (seed, beta2) in [(5u64, 2.9), (6, 3.3), (7, 3.6)] {
        let cfg = SynthConfig {
            dropout_fraction: 0.0,
            ..SynthConfig::realistic(seed, 160, 100.0, InitialSurface::realistic_texture(2.2))
                .with_noise_nm(0.0, 0.0)
        };
        let mut run = generate(&cfg).expect("run");
        let h = plane_waves(seed, beta2, 12000);
        let g0 = bonnetlab_calibrate::grid::MapGrid::of(&run.before).expect("grid");
        let z = Array2::from_shape_fn(run.before.heights_nm().dim(), |(i, j)| {
            h(g0.x_mm(j), g0.y_mm(i))
        });
        run.before = run.before.with_heights(z).expect("before");
        let p = run.problem().expect("problem");
        let g = &p.grid;
        let sigma_mm = 2.0 * g.dx_mm;
        let model = p.local_height(sigma_mm);
        let [pz, px, py] = plane_fit(g, &p.before, &p.before_valid);
        let (cx, cy) = g.centre_mm();
        let s = &p.samples;
        // On the map, the smoothing window clear of its edges (the overrun is the fill's).
        let m = 4.0 * sigma_mm + 2.0 * g.dx_mm;
        let (xe, ye) = (g.x_mm(g.cols - 1), g.y_mm(g.rows - 1));
        let inside: Vec<usize> = (0..s.len())
            .filter(|&k| (m..=xe - m).contains(&s.x_mm[k]) && (m..=ye - m).contains(&s.y_mm[k]))
            .collect();
        assert!(inside.len() > 1000);
        let err = |k: usize| {
            let (x, y) = (s.x_mm[k], s.y_mm[k]);
            h(x, y) - pz - px * (x - cx) - py * (y - cy) - model[k]
        };
        let actual =
            (inside.iter().map(|&k| err(k).powi(2)).sum::<f64>() / inside.len() as f64).sqrt();
        let draws = height_resolution_errors(&p, sigma_mm, 16);
        assert_eq!(draws.len(), 16);
        let drawn = (draws
            .iter()
            .map(|d| inside.iter().map(|&k| d[k] * d[k]).sum::<f64>() / inside.len() as f64)
            .sum::<f64>()
            / draws.len() as f64)
            .sqrt();
        eprintln!("beta2 {beta2}: true resolution error {actual:.2} nm RMS, drawn {drawn:.2} nm");
        assert!(actual > 0.5, "{actual}");
        assert!(
            drawn > actual / 1.3 && drawn < 1.3 * actual,
            "drawn {drawn} nm against the true {actual} nm"
        );
    }
}

/// The coefficient a round part's calibration reports is the one about the plane of its
/// measured pixels (docs/formats.md): the generator's rate `1 + c (h - P_map)` is stated about
/// the true surface's plane over the whole map, which differs from the measured disc's by the
/// plane `A` (`valid_plane_offset_nm`, from the true surface), so the truth to compare with is
/// `c / (1 + c A)` at the path's dwell-weighted mean position. Two seeds where that differs
/// from `c` by 4-8 % (400^2, 80 mm aperture on a 100 mm part).
#[test]
fn a_round_parts_height_coefficient_is_the_one_about_its_measured_plane() {
    use bonnetlab_calibrate::run::{calibrate, Options};
    use bonnetlab_calibrate::synth::Injected;
    // 25 % per 140 nm of height about the true surface's plane over the whole map.
    let c = 0.25 / 140.0;
    for seed in [5u64, 7] {
        let round =
            SynthConfig::realistic(seed, 400, 100.0, InitialSurface::realistic_texture(2.2))
                .with_noise_nm(1.0, 1.0)
                .with_round_aperture(true, 80.0);
        let cfg = SynthConfig {
            effects: vec![Injected::RateCovariate {
                covariate: "height".into(),
                coefficient: c,
            }],
            ..round
        };
        let run = generate(&cfg).expect("round run");
        let p = run.problem().expect("problem");
        let s = &p.samples;
        let (p0, a, b) = run.valid_plane_offset_nm;
        let offset = p0 + a * s.dwell_mean(&s.x_mm) + b * s.dwell_mean(&s.y_mm);
        let about_measured = c / (1.0 + c * offset);
        let cal = calibrate(&p, &Options::default()).expect("calibrate");
        let e = cal
            .effects
            .iter()
            .find(|e| e.kind == "rate_covariate")
            .unwrap_or_else(|| panic!("seed {seed}: no rate covariate in {:?}", cal.effects));
        assert_eq!(e.params["covariate"].as_str(), Some("height"));
        let est = e.params["coefficient"].as_f64().unwrap();
        let sigma = e.uncertainties["coefficient"].as_f64().unwrap();
        let rel = |v: f64| (est - v) / v;
        eprintln!(
            "seed {seed}: plane offset {offset:.1} nm; coefficient {est:.4e} +- {sigma:.1e}: \
             {:+.2} % from c / (1 + c A) = {about_measured:.4e}, {:+.2} % from c = {c:.4e}",
            100.0 * rel(about_measured),
            100.0 * rel(c)
        );
        // The reference matters here ...
        assert!((about_measured - c).abs() > 0.04 * c, "offset {offset} nm");
        // ... and the estimate is the measured plane's coefficient, within its interval.
        assert!(
            (est - about_measured).abs() <= 2.0 * sigma,
            "{est} is {} sigma from {about_measured}",
            (est - about_measured).abs() / sigma
        );
        assert!(rel(about_measured).abs() < 0.5 * rel(c).abs());
    }
}
