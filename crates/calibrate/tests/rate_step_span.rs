//! A rate step that falls while the tool is off the measured aperture (the corners of a round
//! aperture on a square raster) cannot be timed within that span: the residual is flat across
//! it. `rate_step::unseen_span` measures the span by scanning the analysis pixels under the
//! tool; checked here against the span computed from the path geometry alone (distance of the
//! tool centre from the aperture circle), and the reported 1-sigma of `at_fraction` against it.

use bonnetlab_calibrate::effects::rate_step::unseen_span;
use bonnetlab_calibrate::run::{calibrate, Options};
use bonnetlab_calibrate::synth::{generate, InitialSurface, Injected, SynthConfig};

#[test]
fn step_time_off_the_aperture_is_uncertain_over_the_unseen_span() {
    let (part, round) = (100.0, 70.0);
    let base = SynthConfig::realistic(7, 160, part, InitialSurface::realistic_texture(2.2))
        .with_round_aperture(true, round);
    let run = generate(&base).expect("generate");
    let p = run.problem().expect("problem");
    let s = &p.samples;
    // Geometry: a sample is unseen when its centre is farther than half the TIF radius (plus
    // a pixel diagonal, the pixel scan's resolution) outside the aperture circle.
    let (c, r) = (0.5 * part, 0.5 * round);
    let margin = 0.5 * p.tif_radius_mm;
    let pix = p.grid.dx_mm.hypot(p.grid.dy_mm);
    let dist = |k: usize| (s.x_mm[k] - c).hypot(s.y_mm[k] - c) - r;
    // The first sample deep in a corner, and the sample at the part centre.
    let corner = (0..s.len())
        .find(|&k| dist(k) > margin + 2.0 * pix && s.tau(k) > 0.3)
        .expect("a corner sample");
    let centre = (0..s.len())
        .min_by(|&a, &b| dist(a).total_cmp(&dist(b)))
        .unwrap();
    assert_eq!(unseen_span(&p, s.tau(centre)), 0.0);
    let span = unseen_span(&p, s.tau(corner));
    // Geometric span: contiguous samples around `corner` beyond margin +- a pixel diagonal.
    let extent = |m: f64| {
        let (mut lo, mut hi) = (corner, corner);
        while lo > 0 && dist(lo - 1) > m {
            lo -= 1;
        }
        while hi + 1 < s.len() && dist(hi + 1) > m {
            hi += 1;
        }
        s.tau(hi) - s.tau(lo)
    };
    let (inner, outer) = (extent(margin + pix), extent(margin - pix));
    eprintln!("unseen span {span:.5}, geometric {inner:.5} - {outer:.5}");
    assert!(inner > 0.0, "the corner sample is unseen by geometry");
    assert!(
        span >= inner && span <= outer + 4.0 * (s.tau(1) - s.tau(0)).abs() + 1e-12,
        "unseen span {span} outside the geometric [{inner}, {outer}]"
    );

    // A 30 % step there: large enough that the data alone would time it to about 0.0023 of
    // the run (measured with the unseen-span term switched off), below the span's uniform
    // spread width/sqrt(12) = 0.0030, so the check below fails without the term. The reported
    // 1-sigma covers at least that spread, and the estimate is within 2 sigma of the truth.
    let at = s.tau(corner);
    let cfg = SynthConfig {
        effects: vec![Injected::RateStep {
            at_tau: at,
            fraction: 0.3,
        }],
        ..base
    };
    let run = generate(&cfg).expect("generate");
    let cal = calibrate(&run.problem().expect("problem"), &Options::default()).expect("calibrate");
    let step = cal
        .effects
        .iter()
        .find(|e| e.kind == "rate_step")
        .unwrap_or_else(|| panic!("rate_step not found: {:?}", cal.effects));
    let sigma = step.uncertainties["at_fraction"].as_f64().unwrap();
    let est = step.params["at_fraction"].as_f64().unwrap();
    eprintln!("at_fraction {est:.5} (true {at:.5}) sigma {sigma:.5}");
    assert!(
        (est - at).abs() <= 2.0 * sigma,
        "at_fraction {est} is {} sigma from the true {at}",
        (est - at).abs() / sigma
    );
    assert!(
        sigma >= 0.9 * inner / 12f64.sqrt(),
        "sigma {sigma} below the unseen span's {}",
        inner / 12f64.sqrt()
    );
}

/// The refinement finds the step time's profile minimum from a start 0.008 of the run away
/// (the size of the candidate scan's misses on issue 15's harness). Beyond about a spot transit
/// the residual grows like |error| (the misassigned stretch of path), not quadratically, and the
/// forward-difference Gauss-Newton steps alone crawled there: on that harness they stopped
/// 0.003 of the run short, 17 sigma, with the process band 1.23x the floor. Checked against a
/// brute-force scan of the profiled residual (every eighth of the scan step over +-0.012 of the
/// run) and against the generator's step time (exact time-domain deposition, textured surface).
/// Without the scan (`RateStep::nl_scan` at 0) the start 0.558 refines to 0.55289, mean square
/// 3.008 against the minimum's 2.955 nm^2, and this fails; with it, 0.54997 from both starts.
#[test]
fn a_step_time_started_far_off_is_refined_to_the_profile_minimum() {
    use bonnetlab_calibrate::effects::rate_step::{scan_step, RateStep};
    use bonnetlab_calibrate::model::{evaluate, fit, Effect, Problem};
    use bonnetlab_calibrate::refine::refine;

    let at = 0.55;
    let cfg = SynthConfig {
        effects: vec![Injected::RateStep {
            at_tau: at,
            fraction: 0.1,
        }],
        ..SynthConfig::realistic(11, 160, 100.0, InitialSurface::realistic_texture(2.0))
    };
    let run = generate(&cfg).expect("generate");
    let p = run.problem().expect("problem");
    let d = scan_step(&p);
    assert!(d > 0.0 && d < 0.004, "scan step {d}");
    let step = |t: f64| -> Vec<Box<dyn Effect>> {
        vec![Box::new(RateStep {
            at_tau: t,
            h_tau: d,
        })]
    };
    let cost = |p: &Problem, t: f64| {
        let f = fit(&evaluate(p, &step(t), None).unwrap(), &[]).unwrap();
        f.rss / f.n
    };
    let n = (0.012 / (d / 8.0)).ceil() as i64;
    let (t_min, c_min) = (-n..=n)
        .map(|i| at + i as f64 * d / 8.0)
        .map(|t| (t, cost(&p, t)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    for start in [at + 0.008, at - 0.008] {
        let mut e = step(start);
        let (_, f) = refine(&p, &mut e, 6).expect("refine");
        let t = e[0].nl()[0];
        let c = f.rss / f.n;
        eprintln!(
            "start {start:.4}: refined {t:.5} (profile minimum {t_min:.5}, truth {at}), \
             mean square {c:.5} vs {c_min:.5}, scan step {d:.5}"
        );
        assert!(
            c <= c_min * (1.0 + 1e-6),
            "refined mean square {c} above the brute-force minimum {c_min}"
        );
        assert!(
            (t - at).abs() < d,
            "refined step time {t} more than a scan step ({d}) from the truth {at}"
        );
    }

    // The reported 1-sigma against the profile's curvature at the minimum (classical:
    // sigma^2 = s^2 / c2 for rss(t) ~ rss_min + c2 (t - t_min)^2, the profiled sum of squares'
    // second derivative being the inverse of the covariance's diagonal). Fitted over +-d/2,
    // inside the quadratic span. Measured: 1.035e-4 reported, 1.058e-4 from the curvature; the
    // refinement's secant of 0.004 of the run as the uncertainties' step reports 1.551e-4, and
    // this fails.
    let mut e = step(t_min);
    let (ev, f) = refine(&p, &mut e, 6).expect("refine");
    let t_hat = e[0].nl()[0];
    let rss = |t: f64| {
        fit(&evaluate(&p, &step(t), None).unwrap(), &[])
            .unwrap()
            .rss
    };
    let hs: Vec<f64> = (-4..=4).map(|j| j as f64 * d / 8.0).collect();
    let ys: Vec<f64> = hs.iter().map(|&h| rss(t_hat + h)).collect();
    // Least-squares parabola a + b h + c h^2 through the nine points (normal equations).
    let mut m = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for (&h, &y) in hs.iter().zip(&ys) {
        let v = [1.0, h, h * h];
        for i in 0..3 {
            r[i] += v[i] * y;
            for j in 0..3 {
                m[i][j] += v[i] * v[j];
            }
        }
    }
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let mut m2 = m;
    for i in 0..3 {
        m2[i][2] = r[i];
    }
    let c2 = det(&m2) / det(&m);
    let s2 = f.rss / (f.n - ev.cols.len() as f64 - 1.0);
    let sigma_profile = (s2 / c2).sqrt();
    let sp = bonnetlab_calibrate::selection::split(&p);
    let sig = bonnetlab_calibrate::uncertainty::uncertainties(&p, &e, &ev, &f, &sp).unwrap();
    eprintln!(
        "at_fraction sigma {:.3e}, from the profile's curvature {sigma_profile:.3e}",
        sig[0]
    );
    assert!(c2 > 0.0, "the profile is not convex at its minimum: {ys:?}");
    assert!(
        sig[0] >= 0.8 * sigma_profile && sig[0] <= 1.25 * sigma_profile,
        "reported sigma {} against the profile's {sigma_profile}",
        sig[0]
    );
}
