//! Truth suite for the removal forward model (issue: one removal model, proven against exact
//! deposition).
//!
//! The reference is written once, here, and shares nothing with the model's discretisation:
//! for a raster of straight lines travelled at constant speed v, the exact time-domain
//! deposition at a point p is `sum_l (1 / v) * integral T(s, d_l) ds`, with d_l the point's
//! distance across line l. Away from the line ends (the turnarounds lie outside the map by more
//! than the footprint) that is the whole removal. The line integral of the analytic TIF is done
//! by Simpson's rule in the angle phi of s = c sin(phi) over the footprint's chord |s| <= c, which
//! removes the square-root edge of a Hertz footprint, at a step count where halving it changes
//! the result by less than 1e-6 (checked below, far inside the 0.1 % the issue asks for).
//!
//! What is tested is the model as the CLI runs it: `ToolModel::from_source` (analytic models and
//! measured spots) and `simulate::removal` in fast mode; the calibration's forward model (the
//! same fast removal, reached through `channels::Channels` on the path densified to half a
//! pixel, as `bonnetlab_calibrate::model` evaluates every column); exact mode on a subset.
//!
//! Metrics: the removal RMS error relative to the reference removal RMS, and the ripple sigma_1
//! at 1/pitch across the lines (amplitude / sqrt 2 of the least-squares sinusoid at 1/pitch,
//! fitted with its harmonics below Nyquist and a mean, on the profile across the lines).

use std::sync::Arc;

use bonnetlab_process::channels::Channels;
use bonnetlab_process::path::PathLog;
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::removal::{deposit_exact, ExactOptions};
use bonnetlab_process::simulate::{removal, Mode, ToolModel, ToolShape};
use bonnetlab_process::tif::bonnet::BonnetTif;
use bonnetlab_process::tif::derived::Channel;
use bonnetlab_process::tif::measured::{MeasuredTif, Rim, SpotOptions as MeasuredSpotOptions};
use bonnetlab_process::tif::{
    BonnetTifParams, GaussianTif, PressureProfile, RateField, RateScale, Tif,
};
use bonnetlab_process::Grid;
use bonnetlab_surface::rng::Rng;
use bonnetlab_surface::Surface;
use ndarray::Array2;

/// Map side in mm.
const SIDE_MM: f64 = 20.0;
/// Feed along the lines, mm/s.
const SPEED: f64 = 10.0;

/// The precessing bonnet of the suite: R 20 mm, h 0.2 mm, 20 deg, four steps, Hertz pressure.
fn bonnet_params() -> BonnetTifParams {
    BonnetTifParams {
        radius_mm: 20.0,
        offset_mm: 0.2,
        precession_deg: 20.0,
        spindle_rpm: 1000.0,
        pressure: PressureProfile::Hertz,
        scale: RateScale::PeakNmPerS(10.0),
        precession_steps: 4,
    }
}

#[derive(Clone)]
enum Truth {
    Gaussian(GaussianTif),
    Bonnet(Box<BonnetTif>, f64),
}

impl Truth {
    fn gaussian() -> Truth {
        // 0.6 mm sigma truncated at 5 sigma: the truncation is part of the model, and exact.
        Truth::Gaussian(GaussianTif::new(0.6, 6.0, 10.0).unwrap())
    }

    fn bonnet() -> Truth {
        let p = bonnet_params();
        let a = p.contact_radius_mm();
        Truth::Bonnet(Box::new(BonnetTif::new(&p).unwrap()), a)
    }

    fn name(&self) -> &'static str {
        match self {
            Truth::Gaussian(_) => "gaussian",
            Truth::Bonnet(..) => "bonnet",
        }
    }

    fn field(&self) -> &dyn RateField {
        match self {
            Truth::Gaussian(g) => g,
            Truth::Bonnet(b, _) => b.as_ref(),
        }
    }

    /// Radius of the disc outside which the rate is zero.
    fn support_mm(&self) -> f64 {
        match self {
            Truth::Gaussian(g) => g.diameter_mm / 2.0,
            Truth::Bonnet(_, a) => *a,
        }
    }

    /// Rate at an offset from the tool centre, nm/s.
    fn rate(&self, x: f64, y: f64) -> f64 {
        self.field().rate_at_mm(x, y)
    }

    /// integral T(s, d) ds along a line at distance d, along X (`along_x`) or along Y,
    /// Simpson in phi with `n` intervals (n even).
    fn line_integral(&self, d: f64, along_x: bool, n: usize) -> f64 {
        let r = self.support_mm();
        if d.abs() >= r {
            return 0.0;
        }
        let c = (r * r - d * d).sqrt();
        let h = std::f64::consts::PI / n as f64;
        let mut s = 0.0;
        for k in 0..=n {
            let phi = -std::f64::consts::FRAC_PI_2 + k as f64 * h;
            let w = if k == 0 || k == n {
                1.0
            } else if k % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let t = c * phi.sin();
            let f = if along_x {
                self.rate(t, d)
            } else {
                self.rate(d, t)
            };
            s += w * f * c * phi.cos();
        }
        s * h / 3.0
    }
}

/// Line positions across the lines (mm) of a raster whose first line is `phase` pixels past a
/// pixel centre, covering the map and the footprint on either side.
fn line_positions(pitch: f64, px: f64, phase: f64, support: f64) -> Vec<f64> {
    let first = phase * px - (((support + pitch) / pitch).ceil()) * pitch;
    let last = SIDE_MM + support + pitch;
    let mut v = Vec::new();
    let mut k = 0;
    loop {
        let y = first + k as f64 * pitch;
        if y > last {
            break;
        }
        v.push(y);
        k += 1;
    }
    v
}

/// A serpentine raster along X (`along_x`) or Y at constant speed, turning outside the map.
fn raster(lines: &[f64], along_x: bool, support: f64) -> PathLog {
    let (a, b) = (-support - 2.0, SIDE_MM + support + 2.0);
    let (mut u, mut w) = (Vec::new(), Vec::new());
    for (k, &l) in lines.iter().enumerate() {
        let (s0, s1) = if k % 2 == 0 { (a, b) } else { (b, a) };
        u.extend([s0, s1]);
        w.extend([l, l]);
    }
    let mut times = vec![0.0];
    for k in 1..u.len() {
        let d: f64 = (u[k] - u[k - 1]).hypot(w[k] - w[k - 1]);
        times.push(times[k - 1] + d / SPEED);
    }
    if along_x {
        PathLog::new(times, u, w).unwrap()
    } else {
        PathLog::new(times, w, u).unwrap()
    }
}

/// The reference removal profile across the lines at the pixel positions `pos` (mm).
fn reference_profile(
    truth: &Truth,
    lines: &[f64],
    pos: &[f64],
    along_x: bool,
    n: usize,
) -> Vec<f64> {
    pos.iter()
        .map(|&p| {
            lines
                .iter()
                .map(|&l| truth.line_integral(p - l, along_x, n) / SPEED)
                .sum()
        })
        .collect()
}

/// sigma_1: RMS of the least-squares sinusoid at 1/pitch (harmonics and mean fitted too).
fn sigma1(profile: &[f64], pos: &[f64], pitch: f64, px: f64) -> f64 {
    let kmax = ((pitch / (2.0 * px)) - 1e-9).floor().max(1.0) as usize;
    let kmax = kmax.min(6);
    let ncol = 1 + 2 * kmax;
    let mut ata = vec![vec![0.0; ncol]; ncol];
    let mut atb = vec![0.0; ncol];
    for (&p, &z) in pos.iter().zip(profile) {
        let mut b = vec![1.0];
        for k in 1..=kmax {
            let a = 2.0 * std::f64::consts::PI * k as f64 * p / pitch;
            b.push(a.cos());
            b.push(a.sin());
        }
        for i in 0..ncol {
            for j in 0..ncol {
                ata[i][j] += b[i] * b[j];
            }
            atb[i] += b[i] * z;
        }
    }
    let c = gauss_solve(ata, atb);
    (c[1] * c[1] + c[2] * c[2]).sqrt() / 2f64.sqrt()
}

fn gauss_solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Vec<f64> {
    let n = b.len();
    for k in 0..n {
        let p = (k..n)
            .max_by(|&i, &j| a[i][k].abs().total_cmp(&a[j][k].abs()))
            .unwrap();
        a.swap(k, p);
        b.swap(k, p);
        for i in k + 1..n {
            let f = a[i][k] / a[k][k];
            let pivot = a[k].clone();
            for (x, p) in a[i][k..].iter_mut().zip(&pivot[k..]) {
                *x -= f * p;
            }
            b[i] -= f * b[k];
        }
    }
    let mut x = vec![0.0; n];
    for k in (0..n).rev() {
        let s: f64 = (k + 1..n).map(|j| a[k][j] * x[j]).sum();
        x[k] = (b[k] - s) / a[k][k];
    }
    x
}

/// A measured spot of the truth TIF: piston, tilt, `dwell_s` of removal, white noise; the spot
/// centre `offset_mm` (x, y) from the spot map's centre; point samples at pixel `spx`.
fn spot_map(truth: &Truth, spx: f64, offset: (f64, f64), noise_nm: f64, dwell_s: f64) -> Surface {
    let half = truth.support_mm() + 3.0;
    let n = (2.0 * half / spx).round() as usize + 1;
    let c = (n - 1) as f64 / 2.0 * spx;
    let (xc, yc) = (c + offset.0, c + offset.1);
    let mut rng = Rng::new(42);
    let h = Array2::from_shape_fn((n, n), |(i, j)| {
        let (x, y) = (j as f64 * spx, i as f64 * spx);
        30.0 + 0.01 * x - 0.02 * y - dwell_s * truth.rate(x - xc, y - yc) + noise_nm * rng.normal()
    });
    Surface::new(h, Some(spx), Some(spx)).unwrap()
}

#[derive(Clone, Copy)]
struct Spot {
    /// spot pixel = map pixel / `fineness` (not necessarily an integer: the spot is then on a
    /// different pixel from the map's)
    fineness: f64,
    /// the spot's centre is (offset, -0.6 offset) mm from its map's centre
    offset_mm: f64,
    noise_nm: f64,
}

struct Outcome {
    rms_err: f64,
    s1_err: f64,
    s1_ref: f64,
}

/// Which code computes the removal.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Engine {
    /// `simulate::removal` in a mode.
    Simulate(Mode),
    /// The calibration's route: the value channel on the densified path.
    Calibration,
}

/// Dwell of the measured spots, s.
const SPOT_DWELL_S: f64 = 20.0;

/// The tool as the CLI builds it: `ToolModel::from_source` on the analytic model, or on a
/// measured spot of the truth TIF (default spot options).
fn tool_for(truth: &Truth, px: f64, spot: Option<Spot>) -> ToolModel {
    match spot {
        None => match truth {
            Truth::Gaussian(g) => ToolModel::from_source(&TifSource::Gaussian(*g), None, px, px),
            Truth::Bonnet(..) => {
                ToolModel::from_source(&TifSource::Bonnet(bonnet_params()), None, px, px)
            }
        },
        Some(s) => {
            let map = measured_spot(truth, px, s);
            let src = TifSource::Spot {
                path: "spot.dat".into(),
                dwell_s: SPOT_DWELL_S,
            };
            ToolModel::from_source(&src, Some(&map), px, px)
        }
    }
    .unwrap()
}

fn measured_spot(truth: &Truth, px: f64, s: Spot) -> Surface {
    let off = (s.offset_mm, -0.6 * s.offset_mm);
    spot_map(truth, px / s.fineness, off, s.noise_nm, SPOT_DWELL_S)
}

/// A measured spot's tool with explicit spot options (to compare rim reconstructions).
fn tool_with_rim(truth: &Truth, px: f64, spot: Spot, rim: Rim) -> ToolModel {
    let map = measured_spot(truth, px, spot);
    let o = MeasuredSpotOptions {
        rim,
        ..Default::default()
    };
    let m = MeasuredTif::from_spot(&map, SPOT_DWELL_S, &o).unwrap();
    ToolModel::from(ToolShape::Measured(
        Tif::sample(&m, px, px).unwrap(),
        Box::new(m),
    ))
}

fn run_case(
    truth: &Truth,
    pitch: f64,
    px: f64,
    phase: f64,
    along_x: bool,
    spot: Option<Spot>,
    engine: Engine,
) -> Outcome {
    let tool = Arc::new(tool_for(truth, px, spot));
    run_with(&tool, truth, pitch, px, phase, along_x, engine)
}

fn run_with(
    tool: &Arc<ToolModel>,
    truth: &Truth,
    pitch: f64,
    px: f64,
    phase: f64,
    along_x: bool,
    engine: Engine,
) -> Outcome {
    let n = (SIDE_MM / px).round() as usize + 1;
    let grid = Grid::new(n, n, px, px, 0.0, 0.0).unwrap();
    let lines = line_positions(pitch, px, phase, truth.support_mm());
    let path = raster(&lines, along_x, truth.support_mm());
    let model = match engine {
        Engine::Simulate(mode) => removal(tool, &path, &grid, None, mode).unwrap(),
        Engine::Calibration => {
            Channels::new(Arc::clone(tool) as Arc<dyn RateField + Send>, &grid, 1.0)
                .unwrap()
                .removal(Channel::Value, &path.densified(0.5 * px), None)
                .unwrap()
        }
    };
    let pos: Vec<f64> = (0..n).map(|i| i as f64 * px).collect();
    let reference = reference_profile(truth, &lines, &pos, along_x, 400);
    // The model's profile across the lines (mean along them) and its full-map error.
    let mut prof = vec![0.0; n];
    let (mut e2, mut r2) = (0.0, 0.0);
    for ((i, j), &m) in model.indexed_iter() {
        let k = if along_x { i } else { j };
        prof[k] += m / n as f64;
        e2 += (m - reference[k]).powi(2);
        r2 += reference[k].powi(2);
    }
    let rms_err = (e2 / r2).sqrt();
    let s1_ref = sigma1(&reference, &pos, pitch, px);
    let s1 = sigma1(&prof, &pos, pitch, px);
    Outcome {
        rms_err,
        s1_err: s1 / s1_ref - 1.0,
        s1_ref,
    }
}

#[test]
fn reference_quadrature_is_converged() {
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        for d in [0.0, 0.37, 1.1, 0.9 * truth.support_mm()] {
            for along_x in [true, false] {
                let a = truth.line_integral(d, along_x, 400);
                let b = truth.line_integral(d, along_x, 800);
                assert!(
                    (a - b).abs() <= 1e-6 * b.abs().max(1e-300),
                    "{} d {d}: {a} vs {b}",
                    truth.name()
                );
            }
        }
    }
    // And the reference against the closed form of an untruncated Gaussian line integral,
    // peak * sqrt(2 pi) sigma exp(-d^2 / 2 sigma^2), which the 5-sigma truncation changes by
    // less than 1e-5 at d = 0.
    let g = Truth::gaussian();
    let closed = 10.0 * (2.0 * std::f64::consts::PI).sqrt() * 0.6;
    assert!((g.line_integral(0.0, true, 400) / closed - 1.0).abs() < 1e-5);
    // The metric itself: the reference sigma_1 at the smallest ripple of the suite (the Gaussian
    // at the 1.3 mm pitch, 0.04 nm) and on the bonnet, with the quadrature steps halved.
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        for (pitch, px) in [(1.3, 0.1), (1.7, 0.25)] {
            let n = (SIDE_MM / px).round() as usize + 1;
            let pos: Vec<f64> = (0..n).map(|i| i as f64 * px).collect();
            let lines = line_positions(pitch, px, 0.37, truth.support_mm());
            let s1 = |steps| {
                sigma1(
                    &reference_profile(&truth, &lines, &pos, true, steps),
                    &pos,
                    pitch,
                    px,
                )
            };
            let (a, b) = (s1(400), s1(800));
            println!(
                "{} pitch {pitch}: reference sigma1 {a:.6} nm, steps halved {b:.6} nm",
                truth.name()
            );
            assert!(
                (a / b - 1.0).abs() < 1e-3,
                "{} pitch {pitch}: {a} vs {b}",
                truth.name()
            );
        }
    }
}

fn table_row(label: &str, o: &Outcome) -> String {
    format!(
        "{label:<58} rms err {:>7.3} %  sigma1 ref {:>8.4} nm  err {:>+7.2} %",
        100.0 * o.rms_err,
        o.s1_ref,
        100.0 * o.s1_err
    )
}

#[test]
fn analytic_tifs_fast_mode_matches_exact_deposition() {
    let mut rows = Vec::new();
    let mut worst = (0.0f64, 0.0f64);
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        for pitch in [1.3, 1.7, 2.7, 3.0] {
            for px in [0.1, 0.25, 0.5] {
                for phase in [0.0, 0.37] {
                    for along_x in [true, false] {
                        for engine in [Engine::Simulate(Mode::Fast), Engine::Calibration] {
                            let o = run_case(&truth, pitch, px, phase, along_x, None, engine);
                            let label = format!(
                                "{} pitch {pitch} px {px} phase {phase} {} {}",
                                truth.name(),
                                if along_x { "X-scan" } else { "Y-scan" },
                                if engine == Engine::Calibration {
                                    "calib"
                                } else {
                                    "fast"
                                }
                            );
                            rows.push(table_row(&label, &o));
                            worst.0 = worst.0.max(o.rms_err);
                            worst.1 = worst.1.max(o.s1_err.abs());
                        }
                    }
                }
            }
        }
    }
    println!("{}", rows.join("\n"));
    println!(
        "worst: rms {:.3} %, sigma1 {:.2} %",
        100.0 * worst.0,
        100.0 * worst.1
    );
    assert!(
        worst.0 < 0.005,
        "removal RMS error {:.3} %",
        100.0 * worst.0
    );
    assert!(worst.1 < 0.01, "sigma1 error {:.2} %", 100.0 * worst.1);
}

/// The tolerances for a measured spot: sigma_1 within 1 % when the spot is measured at
/// a quarter of the map pixel or finer, within 2 % otherwise; removal RMS within 0.5 %.
fn spot_tolerances(fineness: f64) -> (f64, f64) {
    let s1: f64 = if fineness >= 4.0 { 0.01 } else { 0.02 };
    (0.005, s1)
}

#[test]
fn measured_spots_fast_mode_matches_exact_deposition() {
    let mut rows = Vec::new();
    let mut fails = Vec::new();
    let mut worst = [(0.0f64, 0.0f64); 2];
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        for (pitch, px) in [(1.7, 0.25), (2.7, 0.5), (3.0, 0.5), (1.3, 0.1), (3.0, 0.3)] {
            // At the map pixel, on a different pixel (0.6 and 1.3 map pixels: between the
            // spot's pixels and the map's there is no integer ratio), at a quarter of it.
            for fineness in [1.0, 1.0 / 0.6, 1.0 / 1.3, 4.0] {
                for offset_mm in [0.0, 0.25, 0.8] {
                    let spot = Spot {
                        fineness,
                        offset_mm,
                        noise_nm: 0.1,
                    };
                    let tool = Arc::new(tool_for(&truth, px, Some(spot)));
                    let mut runs = vec![
                        (0.37, true, Engine::Simulate(Mode::Fast)),
                        (0.0, false, Engine::Simulate(Mode::Fast)),
                    ];
                    if offset_mm == 0.8 {
                        runs.push((0.37, true, Engine::Calibration));
                    }
                    for (phase, along_x, engine) in runs {
                        let o = run_with(&tool, &truth, pitch, px, phase, along_x, engine);
                        let label = format!(
                            "{} spot px {:.3} off {offset_mm} pitch {pitch} px {px} {} phase {phase}{}",
                            truth.name(),
                            px / fineness,
                            if along_x { "X" } else { "Y" },
                            if engine == Engine::Calibration {
                                " calib"
                            } else {
                                ""
                            }
                        );
                        let (rms_tol, s1_tol) = spot_tolerances(fineness);
                        if o.rms_err > rms_tol || o.s1_err.abs() > s1_tol {
                            fails.push(label.clone());
                        }
                        let w = &mut worst[usize::from(fineness >= 4.0)];
                        w.0 = w.0.max(o.rms_err);
                        w.1 = w.1.max(o.s1_err.abs());
                        rows.push(table_row(&label, &o));
                    }
                }
            }
        }
    }
    println!("{}", rows.join("\n"));
    println!(
        "worst, spot coarser than a quarter pixel: rms {:.3} %, sigma1 {:.2} %; \
         a quarter pixel or finer: rms {:.3} %, sigma1 {:.2} %",
        100.0 * worst[0].0,
        100.0 * worst[0].1,
        100.0 * worst[1].0,
        100.0 * worst[1].1
    );
    assert!(fails.is_empty(), "outside tolerance: {fails:?}");
}

/// The rim reconstructions compared on the Hertz bonnet (whose square-root rim pixels cannot
/// resolve): the model fit plus the interpolated residual (the default), the fit alone, and the
/// pixels interpolated. The default must be the best of the three at the map pixel.
#[test]
fn rim_reconstructions_compared() {
    let truth = Truth::bonnet();
    let mut worst = [(0.0f64, 0.0f64); 3];
    let rims = [Rim::ModelPlusResidual, Rim::ModelOnly, Rim::Interpolate];
    for (pitch, px) in [(1.7, 0.25), (2.7, 0.5), (3.0, 0.5)] {
        for fineness in [1.0, 4.0] {
            for offset_mm in [0.0, 0.8] {
                let spot = Spot {
                    fineness,
                    offset_mm,
                    noise_nm: 0.5,
                };
                for (k, rim) in rims.iter().enumerate() {
                    let tool = Arc::new(tool_with_rim(&truth, px, spot, *rim));
                    let o = run_with(
                        &tool,
                        &truth,
                        pitch,
                        px,
                        0.37,
                        true,
                        Engine::Simulate(Mode::Fast),
                    );
                    let label =
                        format!("{rim:?} spot px/{fineness} off {offset_mm} pitch {pitch} px {px}");
                    println!("{}", table_row(&label, &o));
                    if fineness == 1.0 {
                        worst[k].0 = worst[k].0.max(o.rms_err);
                        worst[k].1 = worst[k].1.max(o.s1_err.abs());
                    }
                }
            }
        }
    }
    for (rim, w) in rims.iter().zip(&worst) {
        println!(
            "{rim:?} at the map pixel: worst rms {:.3} %, sigma1 {:.2} %",
            100.0 * w.0,
            100.0 * w.1
        );
    }
    assert!(worst[0].1 <= worst[1].1 && worst[0].1 <= worst[2].1);
    assert!(worst[0].0 <= worst[1].0 && worst[0].0 <= worst[2].0);
}

/// The exact mode's own sub-steps: halving them changes the removal by less than 0.1 % of its
/// RMS (the condition on the exact reference), on both analytic TIFs.
#[test]
fn exact_mode_substeps_are_converged() {
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        let (pitch, px) = (1.7, 0.25);
        let tool = tool_for(&truth, px, None);
        let n = (SIDE_MM / px).round() as usize + 1;
        let grid = Grid::new(n, n, px, px, 0.0, 0.0).unwrap();
        let lines = line_positions(pitch, px, 0.37, truth.support_mm());
        let path = raster(&lines, true, truth.support_mm());
        let (ex, ey) = tool.field().half_extent_mm();
        let default_step = (0.25 * px).min(ex.min(ey) / 80.0);
        let run = |step: f64| {
            let o = ExactOptions {
                max_step_mm: Some(step),
                ..Default::default()
            };
            deposit_exact(&path, tool.field(), &grid, None, &o).unwrap()
        };
        let (a, b) = (run(default_step), run(0.5 * default_step));
        let d2: f64 = a.iter().zip(b.iter()).map(|(x, y)| (x - y).powi(2)).sum();
        let r2: f64 = b.iter().map(|y| y * y).sum();
        let rel = (d2 / r2).sqrt();
        println!(
            "{} exact sub-steps halved: {:.4} %",
            truth.name(),
            100.0 * rel
        );
        assert!(rel < 1e-3, "{}: {rel}", truth.name());
    }
}

#[test]
fn exact_mode_matches_the_reference() {
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        let o = run_case(
            &truth,
            1.7,
            0.25,
            0.37,
            true,
            None,
            Engine::Simulate(Mode::Exact),
        );
        println!("{}", table_row(&format!("{} exact", truth.name()), &o));
        assert!(o.rms_err < 0.005 && o.s1_err.abs() < 0.01);
    }
}

/// Sub-pixel recentring without bias: the centroid of the reconstructed rate field (both
/// truths are point-symmetric about the tool centre, so their centroid is the centre) for a
/// spot 0.8 mm off its map centre, at eight sub-pixel positions, each with its own noise
/// (0.1 nm, as in the suite). The mean over the positions is the bias; the scatter from the
/// noise is reported with it.
#[test]
fn recentring_has_no_bias() {
    for truth in [Truth::gaussian(), Truth::bonnet()] {
        for spx in [0.25, 0.1] {
            let mut err = Vec::new();
            for k in 0..8 {
                let f = k as f64 / 8.0;
                let off = (0.8 + f * spx, -0.48 + 0.37 * f * spx);
                let half = truth.support_mm() + 3.0;
                let n = (2.0 * half / spx).round() as usize + 1;
                let c = (n - 1) as f64 / 2.0 * spx;
                let (xc, yc) = (c + off.0, c + off.1);
                let mut rng = Rng::new(100 + k);
                let h = Array2::from_shape_fn((n, n), |(i, j)| {
                    let (x, y) = (j as f64 * spx, i as f64 * spx);
                    30.0 + 0.01 * x - 0.02 * y - SPOT_DWELL_S * truth.rate(x - xc, y - yc)
                        + 0.1 * rng.normal()
                });
                let map = Surface::new(h, Some(spx), Some(spx)).unwrap();
                let m = MeasuredTif::from_spot(&map, SPOT_DWELL_S, &MeasuredSpotOptions::default())
                    .unwrap();
                let r = m.half_extent_mm().0;
                let d = 0.01;
                let nn = (r / d).ceil() as i64;
                let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
                for i in -nn..=nn {
                    for j in -nn..=nn {
                        let (x, y) = (j as f64 * d, i as f64 * d);
                        let v = m.rate_at_mm(x, y);
                        s += v;
                        sx += v * x;
                        sy += v * y;
                    }
                }
                err.push((sx / s, sy / s));
            }
            let nk = err.len() as f64;
            let mean = (
                err.iter().map(|e| e.0).sum::<f64>() / nk,
                err.iter().map(|e| e.1).sum::<f64>() / nk,
            );
            let sd = (err
                .iter()
                .map(|e| (e.0 - mean.0).powi(2) + (e.1 - mean.1).powi(2))
                .sum::<f64>()
                / (2.0 * (nk - 1.0)))
                .sqrt();
            println!(
                "{} spot px {spx}: recentring bias ({:+.2}, {:+.2}) um, scatter {:.2} um per spot",
                truth.name(),
                1e3 * mean.0,
                1e3 * mean.1,
                1e3 * sd
            );
            // Bias within 1 um or three standard errors of the mean, whichever is larger.
            let tol = (1e-3f64).max(3.0 * sd / nk.sqrt());
            assert!(
                mean.0.abs() < tol && mean.1.abs() < tol,
                "{} spot px {spx}: bias {mean:?} mm",
                truth.name()
            );
        }
    }
}
