//! The generated-run check: a run whose truth is generated here, independently of the
//! library's fast path, is predicted from its recipe (before map, measured spot, path log).
//!
//! The generator (all in this file): a before map (figure + mid-spatial waves + seeded noise),
//! a raster path log whose feed realises a smooth dwell map, a measured spot (a Gaussian TIF
//! deposited for `dwell_s` at a fixed point, on a tilted background, plus noise) and the true
//! after map by direct time-domain deposition of the analytic TIF along the path (own sub-steps,
//! midpoint rule), plus measurement noise. The prediction goes through the files: `Recipe::load`,
//! `read_surface`, `read_path_csv`, `ToolModel::from_source` (measured spot) and
//! `simulate::predict` (fast mode). Acceptance: RMS after (piston + tilt removed) within 2 %,
//! Y ripple band RMS at 1/pitch within 15 %.

use bonnetlab::io::{read_surface, write_surface, MapFormat};
use bonnetlab::process::path::log::path_to_csv;
use bonnetlab::process::simulate::{predict, Mode, ToolModel};
use bonnetlab::process::{read_path_csv, PathLog, Recipe};
use bonnetlab::spectrum::{ripple, PsdOptions};
use bonnetlab::surface::rng::Rng;
use bonnetlab::surface::{height_stats, remove_terms, Surface, Term};
use ndarray::Array2;

const DX_MM: f64 = 0.25;
const N_PX: usize = 160; // 40 x 40 mm
const SIGMA_MM: f64 = 1.2;
const CUT_MM: f64 = 4.5 * SIGMA_MM;
const PEAK_NM_PER_S: f64 = 5.0;
const PITCH_MM: f64 = 3.0;
const NOISE_NM: f64 = 0.3;

/// The analytic TIF (nm/s) at offset (ox, oy) mm from the tool centre.
fn tif_rate(ox: f64, oy: f64) -> f64 {
    let r2 = ox * ox + oy * oy;
    if r2 > CUT_MM * CUT_MM {
        0.0
    } else {
        PEAK_NM_PER_S * (-r2 / (2.0 * SIGMA_MM * SIGMA_MM)).exp()
    }
}

/// Planned dwell density (s/mm^2): uniform plus a bump, so the removal has a shape.
fn dwell_density(x: f64, y: f64) -> f64 {
    let (u, v) = (x - 24.0, y - 16.0);
    0.8 * (1.0 + 0.4 * (-(u * u + v * v) / 60.0).exp())
}

fn noise(rng: &mut Rng, rows: usize, cols: usize) -> Array2<f64> {
    Array2::from_shape_fn((rows, cols), |_| NOISE_NM * rng.normal())
}

/// Raster along X, lines every PITCH_MM in Y, bidirectional; feed 1 / (density x pitch) set per
/// 0.1 mm piece at its midpoint; each piece is one log row.
fn raster_log() -> PathLog {
    let (x_lo, x_hi) = (-7.0, 47.0);
    let piece = 0.1;
    let n_pieces = ((x_hi - x_lo) / piece) as usize;
    let (mut t, mut xs, mut ys) = (vec![0.0], vec![x_lo], vec![-6.0]);
    let mut y = -6.0;
    let mut forward = true;
    while y <= 46.0 + 1e-9 {
        if y > -6.0 {
            // Step over to the next line at 20 mm/s.
            let t0 = *t.last().unwrap();
            t.push(t0 + PITCH_MM / 20.0);
            xs.push(*xs.last().unwrap());
            ys.push(y);
        }
        for k in 1..=n_pieces {
            let f = |k: usize| {
                if forward {
                    x_lo + k as f64 * piece
                } else {
                    x_hi - k as f64 * piece
                }
            };
            let xm = 0.5 * (f(k - 1) + f(k));
            let v = 1.0 / (dwell_density(xm, y) * PITCH_MM);
            let t0 = *t.last().unwrap();
            t.push(t0 + piece / v);
            xs.push(f(k));
            ys.push(y);
        }
        forward = !forward;
        y += PITCH_MM;
    }
    PathLog::new(t, xs, ys).unwrap()
}

/// True removal (nm) on pixel centres (j DX, i DX): each log segment cut into sub-steps of at
/// most 0.05 mm, the TIF deposited at each sub-step's midpoint for its duration.
fn true_removal(p: &PathLog) -> Array2<f64> {
    let mut r = Array2::<f64>::zeros((N_PX, N_PX));
    let reach = (CUT_MM / DX_MM).ceil() as isize + 1;
    for k in 0..p.t_s.len() - 1 {
        let (x0, y0) = (p.x_mm[k], p.y_mm[k]);
        let (ddx, ddy) = (p.x_mm[k + 1] - x0, p.y_mm[k + 1] - y0);
        let dt = p.t_s[k + 1] - p.t_s[k];
        let m = ((ddx.hypot(ddy) / 0.05).ceil() as usize).max(1);
        for s in 0..m {
            let f = (s as f64 + 0.5) / m as f64;
            let (x, y) = (x0 + f * ddx, y0 + f * ddy);
            let (jc, ic) = ((x / DX_MM).round() as isize, (y / DX_MM).round() as isize);
            for i in (ic - reach).max(0)..(ic + reach + 1).min(N_PX as isize) {
                for j in (jc - reach).max(0)..(jc + reach + 1).min(N_PX as isize) {
                    let w = tif_rate(j as f64 * DX_MM - x, i as f64 * DX_MM - y);
                    r[(i as usize, j as usize)] += w * dt / m as f64;
                }
            }
        }
    }
    r
}

/// Before map: power + astigmatism-like figure, two mid-spatial waves (seeded phases).
fn true_before(rng: &mut Rng) -> Array2<f64> {
    let (p1, p2) = (
        rng.uniform() * std::f64::consts::TAU,
        rng.uniform() * std::f64::consts::TAU,
    );
    Array2::from_shape_fn((N_PX, N_PX), |(i, j)| {
        let (x, y) = (j as f64 * DX_MM - 20.0, i as f64 * DX_MM - 20.0);
        25.0 * (x * x + y * y) / 400.0
            + 8.0 * (x * x - y * y) / 400.0
            + 3.0 * (x / 6.0 + p1).sin()
            + 2.0 * (y / 4.5 + x / 9.0 + p2).cos()
    })
}

/// Spot map: 16 x 16 mm at 0.1 mm, the TIF deposited for `dwell_s` at (8.03, 7.96) mm, on a
/// tilted, offset background, plus noise.
fn spot_map(rng: &mut Rng, dwell_s: f64) -> Surface {
    let n = 161;
    let h = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * 0.1, i as f64 * 0.1);
        12.0 + 0.4 * x - 0.25 * y - dwell_s * tif_rate(x - 8.03, y - 7.96) + NOISE_NM * rng.normal()
    });
    Surface::new(h, Some(0.1), Some(0.1)).unwrap()
}

fn rms_pt(s: &Surface) -> f64 {
    let (r, _) = remove_terms(s, &[Term::Piston, Term::Tilt]).unwrap();
    height_stats(&r).unwrap().rms_nm
}

#[test]
fn generated_run_is_predicted_from_its_recipe() {
    let mut rng = Rng::new(20261123);
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();

    // Truth.
    let before_true = true_before(&mut rng);
    let path = raster_log();
    let removal_true = true_removal(&path);
    let after_true = &before_true - &removal_true + noise(&mut rng, N_PX, N_PX);
    let before_meas = &before_true + noise(&mut rng, N_PX, N_PX);
    let dwell_s = 10.0;
    let spot = spot_map(&mut rng, dwell_s);

    // The recipe's files.
    let before_s = Surface::new(before_meas, Some(DX_MM), Some(DX_MM)).unwrap();
    write_surface(&d.join("before.dat"), &before_s, MapFormat::MetroProDat).unwrap();
    write_surface(&d.join("spot.dat"), &spot, MapFormat::MetroProDat).unwrap();
    std::fs::write(d.join("path.csv"), path_to_csv(&path)).unwrap();
    std::fs::write(
        d.join("recipe.toml"),
        format!(
            "[measurement]\nbefore = \"before.dat\"\n[tif]\nspot = \"spot.dat\"\ndwell_s = {dwell_s}\n\
             [path]\nlog = \"path.csv\"\npitch_mm = {PITCH_MM}\n[process]\nbonnet = \"original\"\n"
        ),
    )
    .unwrap();

    // Prediction from the files only.
    let recipe = Recipe::load(&d.join("recipe.toml")).unwrap();
    let before = read_surface(&recipe.before).unwrap();
    assert_eq!(
        before.origin_mm,
        (0.0, 0.0),
        "truth assumes pixel (0, 0) at 0 mm"
    );
    let spot_path = match &recipe.tif {
        bonnetlab::process::recipe::TifSource::Spot { path, .. } => path.clone(),
        other => panic!("expected a measured spot, got {other:?}"),
    };
    let spot_read = read_surface(&spot_path).unwrap();
    let (dx, dy) = (before.dx_mm.unwrap(), before.dy_mm.unwrap());
    let tool = ToolModel::from_source(&recipe.tif, Some(&spot_read), dx, dy).unwrap();
    let log = read_path_csv(&recipe.path_log).unwrap();
    let pred = predict(&before, &tool, &log, None, Mode::Fast).unwrap();

    // The truth's mean removal is the analytic volume rate x planned dwell density (sanity of
    // the generator itself, independent of the library): 2 pi sigma^2 peak (1 - e^-cut^2/2s^2).
    let vol = 2.0
        * std::f64::consts::PI
        * SIGMA_MM
        * SIGMA_MM
        * PEAK_NM_PER_S
        * (1.0 - (-(CUT_MM * CUT_MM) / (2.0 * SIGMA_MM * SIGMA_MM)).exp());
    // Averaged over one pitch (rows 4..16 = y 1..4 mm) so the ripple cancels.
    let corner = (4..16).map(|i| removal_true[(i, 8)]).sum::<f64>() / 12.0;
    let expect_corner = vol * dwell_density(2.0, 2.5);
    assert!(
        (corner / expect_corner - 1.0).abs() < 0.03,
        "generator: removal {corner} vs {expect_corner}"
    );

    let truth = Surface::new(after_true, Some(DX_MM), Some(DX_MM)).unwrap();
    let (rms_true, rms_pred) = (rms_pt(&truth), rms_pt(&pred.after));
    let rms_before = rms_pt(&before);
    let rel = (rms_pred / rms_true - 1.0).abs();
    eprintln!("RMS before {rms_before:.3} nm, after true {rms_true:.3} nm, predicted {rms_pred:.3} nm ({:.2} %)", 100.0 * rel);
    // The run must change the RMS by far more than the tolerance, or predicting "no removal"
    // would pass too.
    assert!(
        (rms_before / rms_true - 1.0).abs() > 0.1,
        "the run barely changes the RMS"
    );
    assert!(rel <= 0.02, "RMS after {rms_pred} vs truth {rms_true}");

    let opts = PsdOptions::default();
    let rip_true = ripple(&truth, PITCH_MM, &opts).unwrap();
    let rip_pred = ripple(&pred.after, PITCH_MM, &opts).unwrap();
    let rel_r = (rip_pred.sigma1_nm / rip_true.sigma1_nm - 1.0).abs();
    eprintln!(
        "ripple sigma1 true {:.4} nm, predicted {:.4} nm ({:.2} %)",
        rip_true.sigma1_nm,
        rip_pred.sigma1_nm,
        100.0 * rel_r
    );
    assert!(rip_true.detected, "the generated ripple must be visible");
    assert!(
        rel_r <= 0.15,
        "ripple {} vs {}",
        rip_pred.sigma1_nm,
        rip_true.sigma1_nm
    );
}
