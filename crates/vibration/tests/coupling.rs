//! The fast coupling (second-order expansion, FFT convolutions of weighted dwell maps) against
//! direct time-domain deposition of the instantaneous TIF, on a realistic raster run with
//! vibration on (issue 6: agreement within 1 % of the predicted MSF band RMS).

use bonnetlab_process::path::{RasterSpec, ScanAxis};
use bonnetlab_process::recipe::TifSource;
use bonnetlab_process::simulate::ToolModel;
use bonnetlab_process::tif::GaussianTif;
use bonnetlab_process::{Grid, PathLog};
use bonnetlab_vibration::coupling::predict::msf_band_rms_y;
use bonnetlab_vibration::coupling::{
    direct_removal, direct_removal_with, fast_maps, predict, CouplingInput, CouplingOptions,
    Mechanisms,
};
use bonnetlab_vibration::params::{Bonnet, LateralAxis, VibrationParams};
use ndarray::Array2;

struct Run {
    grid: Grid,
    tool: ToolModel,
    path: PathLog,
    pitch_mm: f64,
}

/// A 24 x 24 mm part at 0.25 mm, Gaussian spot (σ 1 mm, 8 mm footprint), bidirectional
/// raster at the paper's 3 mm pitch and 1.6 mm/s feed, 4 mm overtravel.
fn run() -> Run {
    run_lines(27.0)
}

/// As [`run`] with the last raster line at or below `y_last_mm`.
fn run_lines(y_last_mm: f64) -> Run {
    raster(3.0, ScanAxis::X, y_last_mm)
}

/// A raster of `pitch_mm` scanned along `axis` over the 24 x 24 mm part, lines from −3 mm up
/// to `last_mm` across the scan.
fn raster(pitch_mm: f64, axis: ScanAxis, last_mm: f64) -> Run {
    let grid = Grid::new(97, 97, 0.25, 0.25, 0.0, 0.0).unwrap();
    let tif = GaussianTif::new(1.0, 8.0, 10.0).unwrap();
    let tool = ToolModel::from_source(&TifSource::Gaussian(tif), None, 0.25, 0.25).unwrap();
    let mut spec = RasterSpec::over_rect((0.0, 24.0), (-3.0, last_mm), pitch_mm, 1.6);
    spec.overtravel_mm = 4.0;
    spec.axis = axis;
    let path = spec.generate().unwrap();
    Run {
        grid,
        tool,
        path,
        pitch_mm,
    }
}

fn input<'a>(r: &'a Run, params: &'a VibrationParams) -> CouplingInput<'a> {
    CouplingInput {
        grid: r.grid,
        valid: None,
        tool: &r.tool,
        path: &r.path,
        params,
        pitch_mm: Some(r.pitch_mm),
    }
}

fn band_diff(input: &CouplingInput<'_>, a: &Array2<f64>, b: &Array2<f64>) -> f64 {
    msf_band_rms_y(input, &(a - b), CouplingOptions::default().msf_band_per_mm).unwrap()
}

/// Fast coupling (process's fast removal + derivative-kernel expansion) against the direct
/// deposition (exact time-domain deposition of the instantaneous TIF, 2 sub-steps per
/// 500 Hz sample), every mechanism on, 24 x 24 mm at 0.25 mm, Gaussian σ 1 mm, lines from
/// −3 to 15 mm. Criterion (issue 14): the MSF band RMS across the raster lines (one-sided PSD
/// along Y for an X scan, along X for a Y scan; band 0.1 to 1 per mm) of the fast − direct
/// difference map within 1 % of the direct removal's. The vibration-induced part (all on − all
/// off) is checked against the same total, and its own band RMS within 5 %.
///
/// Measured (MSF band RMS across the lines, nm; diff = band RMS of the difference map):
///
/// | case | scan | pitch mm | rpm | vibration | fast | direct | diff | induced fast / direct / diff |
/// |---|---|---|---|---|---|---|---|---|
/// | a | X | 3.0 | 558 (x2 resonance) | default | 4.19589 | 4.19581 | 0.013 % | 0.00591 / 0.00605 / 0.00054 |
/// | b | X | 1.7 | 1500 | default | 6.35715 | 6.35715 | 0.002 % | 0.00113 / 0.00114 / 0.00010 |
/// | c | X | 3.0 | 558 | 1.5x force, 3x noise | 4.19577 | 4.19564 | 0.013 % | 0.01338 / 0.01361 / 0.00055 |
/// | d | Y (lateral Y) | 3.0 | 558 | default | 4.19589 | 4.19581 | 0.013 % | 0.00591 / 0.00605 / 0.00054 |
/// | e | Y (lateral Y) | 1.7 | 900 | 1.5x force, 3x noise | 6.35641 | 6.35641 | 0.003 % | 0.00337 / 0.00339 / 0.00018 |
///
/// (d is a transposed: the same numbers to every digit, so both scan axes run the same model.)
///
/// Most of the induced difference is the `normal_offset` ring-down after velocity changes,
/// whose offset swings are large enough for the second-order expansion's remainder to show
/// (about 9 % of that mechanism's own imprint, 1e-4 of the removal's MSF band RMS).
#[test]
fn fast_coupling_agrees_with_direct_deposition_within_1_percent_over_cases() {
    struct Case {
        name: &'static str,
        axis: ScanAxis,
        pitch: f64,
        params: VibrationParams,
    }
    let strong = |rpm: f64, lateral: LateralAxis| VibrationParams {
        spindle_rpm: rpm,
        fn_n: 3.0,
        noise_force_rms_n: 1.5,
        lateral_axis: lateral,
        ..Default::default()
    };
    let plain = |rpm: f64, lateral: LateralAxis| VibrationParams {
        spindle_rpm: rpm,
        lateral_axis: lateral,
        ..Default::default()
    };
    let cases = [
        Case {
            name: "a: X scan, 3 mm, 558 rpm",
            axis: ScanAxis::X,
            pitch: 3.0,
            params: plain(558.0, LateralAxis::X),
        },
        Case {
            name: "b: X scan, 1.7 mm, 1500 rpm",
            axis: ScanAxis::X,
            pitch: 1.7,
            params: plain(1500.0, LateralAxis::X),
        },
        Case {
            name: "c: X scan, 3 mm, 558 rpm, strong",
            axis: ScanAxis::X,
            pitch: 3.0,
            params: strong(558.0, LateralAxis::X),
        },
        Case {
            name: "d: Y scan, 3 mm, 558 rpm",
            axis: ScanAxis::Y,
            pitch: 3.0,
            params: plain(558.0, LateralAxis::Y),
        },
        Case {
            name: "e: Y scan, 1.7 mm, 900 rpm, strong",
            axis: ScanAxis::Y,
            pitch: 1.7,
            params: strong(900.0, LateralAxis::Y),
        },
    ];
    let opts = CouplingOptions {
        sample_hz: 500.0,
        ..Default::default()
    };
    let none = CouplingOptions {
        mechanisms: Mechanisms::NONE,
        ..opts
    };
    let band = opts.msf_band_per_mm;
    let mut failures = Vec::new();
    for c in &cases {
        let r = raster(c.pitch, c.axis, 15.0);
        let input = input(&r, &c.params);
        // Across the lines: a Y scan's maps are transposed (square pixels).
        let across = |m: &Array2<f64>| match c.axis {
            ScanAxis::X => m.clone(),
            ScanAxis::Y => m.t().to_owned(),
        };
        let fast = fast_maps(&input, Bonnet::Original, &opts).unwrap();
        let direct = across(&direct_removal(&input, Bonnet::Original, &opts).unwrap());
        let direct0 = across(&direct_removal(&input, Bonnet::Original, &none).unwrap());
        let total = across(&fast.total());
        let induced_fast = across(&fast.induced());
        let msf_fast = msf_band_rms_y(&input, &total, band).unwrap();
        let msf_direct = msf_band_rms_y(&input, &direct, band).unwrap();
        let diff = band_diff(&input, &total, &direct);
        let induced_direct = &direct - &direct0;
        let i_fast = msf_band_rms_y(&input, &induced_fast, band).unwrap();
        let i_direct = msf_band_rms_y(&input, &induced_direct, band).unwrap();
        let i_diff = band_diff(&input, &induced_fast, &induced_direct);
        eprintln!(
            "{}: MSF band RMS fast {msf_fast:.5} nm, direct {msf_direct:.5} nm, difference \
             {diff:.6} nm ({:.3} %); induced fast {i_fast:.5} nm, direct {i_direct:.5} nm, \
             difference {i_diff:.6} nm",
            c.name,
            100.0 * diff / msf_direct
        );
        if !(msf_direct > 0.0 && i_direct > 0.0) {
            failures.push(format!("{}: no MSF structure", c.name));
        }
        if diff > 0.01 * msf_direct || (msf_fast - msf_direct).abs() > 0.01 * msf_direct {
            failures.push(format!("{}: {diff} vs {msf_direct}", c.name));
        }
        // The vibration-induced part alone (all on minus all off) agrees too.
        if i_diff > 0.01 * msf_direct || (i_fast - i_direct).abs() > 0.05 * i_direct {
            failures.push(format!("{}: induced {i_fast} vs {i_direct}", c.name));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The reference is converged: halving the direct deposition's sub-step (2 -> 4 per 500 Hz
/// sample) changes its removal's MSF band RMS by less than 0.1 % (measured: 0.0 % on the
/// X-scan 558 rpm run, the difference map's band RMS 1e-6 of the removal's), and the MSF band RMS
/// of the induced part by less than 0.1 % of itself.
#[test]
fn direct_deposition_is_converged_in_its_sub_step() {
    let r = raster(3.0, ScanAxis::X, 9.0);
    let params = VibrationParams {
        spindle_rpm: 558.0,
        fn_n: 3.0,
        noise_force_rms_n: 1.5,
        ..Default::default()
    };
    let input = input(&r, &params);
    let opts = CouplingOptions {
        sample_hz: 500.0,
        ..Default::default()
    };
    let band = opts.msf_band_per_mm;
    let none = CouplingOptions {
        mechanisms: Mechanisms::NONE,
        ..opts
    };
    let d2 = direct_removal_with(&input, Bonnet::Original, &opts, 2).unwrap();
    let d4 = direct_removal_with(&input, Bonnet::Original, &opts, 4).unwrap();
    let b0 = direct_removal_with(&input, Bonnet::Original, &none, 4).unwrap();
    let total = msf_band_rms_y(&input, &d4, band).unwrap();
    let change = band_diff(&input, &d2, &d4);
    let induced = msf_band_rms_y(&input, &(&d4 - &b0), band).unwrap();
    eprintln!(
        "direct 2 vs 4 sub-steps: MSF band RMS {total:.5} nm, change {change:.3e} nm; induced \
         {induced:.5} nm"
    );
    assert!(total > 1.0 && induced > 0.0);
    assert!(change < 1e-3 * induced, "{change} vs induced {induced}");
}

#[test]
fn each_vibration_mechanism_matches_direct_deposition_when_exaggerated() {
    // A strongly vibrating robot (1.5x the default force, 3x the noise, at the x2 resonance:
    // offset swings of about 14 % of h0) so every vibration mechanism leaves a clear imprint;
    // each alone, fast vs direct. The expansion's third-order remainder is O(δ/h0) of the
    // second-order term, hence the looser tolerance than on the realistic run. Lateral jitter
    // of ~0.01 mm is far below the pixel and its imprint (~1e-4 nm) sits at the methods' common
    // discretisation floor, so each comparison also allows 1e-4 of the total MSF band RMS.
    let r = run_lines(15.0);
    let params = VibrationParams {
        spindle_rpm: 558.0,
        fn_n: 3.0,
        noise_force_rms_n: 1.5,
        ..Default::default()
    };
    let input = CouplingInput {
        grid: r.grid,
        valid: None,
        tool: &r.tool,
        path: &r.path,
        params: &params,
        pitch_mm: Some(3.0),
    };
    let band = CouplingOptions::default().msf_band_per_mm;
    let none = CouplingOptions {
        mechanisms: Mechanisms::NONE,
        sample_hz: 500.0,
        ..Default::default()
    };
    let base = direct_removal(&input, Bonnet::Original, &none).unwrap();
    let mut results = Vec::new();
    for name in ["normal_offset", "lateral_jitter", "envelope"] {
        let opts = CouplingOptions {
            mechanisms: Mechanisms::only(name),
            ..none
        };
        let fast = fast_maps(&input, Bonnet::Original, &opts).unwrap();
        let direct = direct_removal(&input, Bonnet::Original, &opts).unwrap();
        let mf = fast.by_name(name).unwrap();
        let md = &direct - &base;
        let rf = msf_band_rms_y(&input, mf, band).unwrap();
        let rd = msf_band_rms_y(&input, &md, band).unwrap();
        let dd = band_diff(&input, mf, &md);
        eprintln!("{name}: fast {rf:.6} nm, direct {rd:.6} nm, difference {dd:.6} nm");
        results.push((name, rd, dd));
    }
    let total = msf_band_rms_y(&input, &base, band).unwrap();
    for (name, rd, dd) in results {
        assert!(rd > 1e-5, "{name} leaves no imprint: {rd}");
        assert!(
            dd <= 0.15 * rd + 1e-4 * total,
            "{name}: difference {dd} vs {rd} (total {total})"
        );
    }
}

#[test]
fn suppression_bonnet_predicts_less_vibration_induced_msf_at_resonance() {
    let r = run();
    let params = VibrationParams {
        spindle_rpm: 558.0,
        fn_n: 3.0,
        ..Default::default()
    };
    let input = CouplingInput {
        grid: r.grid,
        valid: None,
        tool: &r.tool,
        path: &r.path,
        params: &params,
        pitch_mm: Some(3.0),
    };
    let opts = CouplingOptions {
        mechanisms: Mechanisms {
            dwell_execution: false,
            ..Mechanisms::ALL
        },
        sample_hz: 500.0,
        ..Default::default()
    };
    let o = predict(&input, Bonnet::Original, &opts).unwrap();
    let s = predict(&input, Bonnet::Suppression, &opts).unwrap();
    eprintln!(
        "induced MSF: original {:.5} nm, suppression {:.5} nm; sigma1 {:?} / {:?}",
        o.induced_msf_band_rms_nm,
        s.induced_msf_band_rms_nm,
        o.ripple_sigma1_nm,
        s.ripple_sigma1_nm
    );
    assert!(s.induced_msf_band_rms_nm < o.induced_msf_band_rms_nm);
    let share: f64 = o.mechanisms.iter().map(|m| m.share).sum();
    assert!((share - 1.0).abs() < 1e-12);
    assert_eq!(
        o.mechanisms
            .iter()
            .find(|m| m.name == "dwell_execution")
            .unwrap()
            .msf_band_rms_nm,
        0.0
    );
    assert!(o.ripple_sigma1_nm.unwrap() > 0.0);
}

#[test]
fn spindle_sweep_shows_the_resonance() {
    // Fast method only; resonance of x2 at 558 rpm raises the vibration-induced MSF of the
    // original bonnet above its off-resonance value, and the suppression bonnet stays lower.
    let r = run_lines(9.0);
    let params = VibrationParams {
        fn_n: 3.0,
        ..Default::default()
    };
    let input = CouplingInput {
        grid: r.grid,
        valid: None,
        tool: &r.tool,
        path: &r.path,
        params: &params,
        pitch_mm: Some(3.0),
    };
    let opts = CouplingOptions {
        mechanisms: Mechanisms {
            dwell_execution: false,
            ..Mechanisms::ALL
        },
        sample_hz: 500.0,
        ..Default::default()
    };
    let rows =
        bonnetlab_vibration::coupling::spindle_sweep(&input, &opts, &[558.0, 1500.0]).unwrap();
    assert_eq!(rows.len(), 4);
    for r in &rows {
        eprintln!(
            "{:>6.0} rpm {:<11} x2 {:.4} mm, induced MSF {:.5} nm",
            r.spindle_rpm,
            r.bonnet.name(),
            r.x2_amplitude_mm,
            r.induced_msf_band_rms_nm
        );
    }
    let get = |rpm: f64, b: Bonnet| {
        rows.iter()
            .find(|r| r.spindle_rpm == rpm && r.bonnet == b)
            .unwrap()
            .induced_msf_band_rms_nm
    };
    assert!(get(558.0, Bonnet::Original) > get(1500.0, Bonnet::Original));
    assert!(get(558.0, Bonnet::Suppression) < get(558.0, Bonnet::Original));
}

/// The demo's run (the paper's bonnet, 100 mm part at 0.4 mm, 3 mm raster at 1.6 mm/s with no
/// overtravel): the raster turns on the part's edge, so its step-overs (3 % of the dwell) sit on
/// the map. The fast baseline removal against direct deposition in the MSF band. Measured
/// (2026-11-25): difference 0.0099 nm of 3.0760 nm (0.32 %) with box-averaged phase kernels for
/// the step-overs, 0.0117 nm (0.38 %) with point-sampled ones, 0.036-0.040 nm (1.2-1.3 %) with
/// the step-overs splatted cubically across their columns.
#[test]
fn raster_turning_on_the_part_edge_matches_direct_deposition_in_the_msf_band() {
    use bonnetlab_process::tif::BonnetTifParams;
    use bonnetlab_vibration::coupling::CouplingCase;
    let tp = BonnetTifParams::paper(10.0);
    let params = VibrationParams::from_parts(
        None,
        Some(tp.spindle_rpm),
        Some(tp.offset_mm),
        Some(0.25),
        None,
    )
    .unwrap();
    let case = CouplingCase::square_raster(
        &TifSource::Bonnet(tp),
        params,
        250,
        0.4,
        0.2,
        100.0,
        3.0,
        1.6,
        0.0,
    )
    .unwrap();
    let input = case.input();
    let band = CouplingOptions::default().msf_band_per_mm;
    let opts = CouplingOptions {
        mechanisms: Mechanisms::NONE,
        sample_hz: 100.0,
        ..Default::default()
    };
    let fast = fast_maps(&input, Bonnet::Original, &opts).unwrap();
    let direct = direct_removal(&input, Bonnet::Original, &opts).unwrap();
    let rf = msf_band_rms_y(&input, &fast.baseline, band).unwrap();
    let rd = msf_band_rms_y(&input, &direct, band).unwrap();
    let dd = band_diff(&input, &fast.baseline, &direct);
    eprintln!("MSF band RMS fast {rf:.6} nm, direct {rd:.6} nm, difference {dd:.6} nm");
    assert!(rd > 1.0);
    assert!(dd < 5e-3 * rd, "{dd} vs {rd}");
}

/// Area pixels (a camera's: each pixel the mean over its square). The fast coupling with the
/// tool seen by 0.25 mm area pixels ([`ToolModel::seen_by`]: the fast removal and the
/// derivative kernels built from pixel means) against the truth such pixels report: direct
/// time-domain deposition on a grid three times finer, averaged over each pixel's 3 x 3
/// sub-pixels (point samples of the instantaneous TIF; it shares neither the fast model nor
/// the box quadrature). The exaggerated robot of the test above so the normal-offset imprint
/// is large; MSF band RMS across the lines of the total removal and of the imprint.
///
/// Measured: total 4.158 nm, the area prediction off by 0.0016 nm, the point one by 0.0126
/// nm; imprint 0.0117 nm, off by 0.00017 (area) and 0.00014 nm (point).
#[test]
fn area_pixels_coupling_matches_the_pixel_means_of_finer_direct_deposition() {
    use bonnetlab_process::pixel::PixelResponse;
    let r = run_lines(9.0);
    let params = VibrationParams {
        spindle_rpm: 558.0,
        fn_n: 3.0,
        noise_force_rms_n: 1.5,
        ..Default::default()
    };
    let none = CouplingOptions {
        mechanisms: Mechanisms::NONE,
        sample_hz: 500.0,
        ..Default::default()
    };
    let on = CouplingOptions {
        mechanisms: Mechanisms::only("normal_offset"),
        ..none
    };
    let band = none.msf_band_per_mm;
    let k = 3usize;
    let g = r.grid;
    let fine_grid = Grid::new(
        g.rows * k,
        g.cols * k,
        g.dx_mm / k as f64,
        g.dy_mm / k as f64,
        g.x0_mm - 0.5 * g.dx_mm + 0.5 * g.dx_mm / k as f64,
        g.y0_mm - 0.5 * g.dy_mm + 0.5 * g.dy_mm / k as f64,
    )
    .unwrap();
    let fine_tool = ToolModel::from_source(
        &TifSource::Gaussian(GaussianTif::new(1.0, 8.0, 10.0).unwrap()),
        None,
        fine_grid.dx_mm,
        fine_grid.dy_mm,
    )
    .unwrap();
    let fine = CouplingInput {
        grid: fine_grid,
        valid: None,
        tool: &fine_tool,
        path: &r.path,
        params: &params,
        pitch_mm: Some(3.0),
    };
    let means = |m: Array2<f64>| {
        Array2::from_shape_fn((g.rows, g.cols), |(i, j)| {
            m.slice(ndarray::s![i * k..(i + 1) * k, j * k..(j + 1) * k])
                .mean()
                .unwrap()
        })
    };
    let truth = means(direct_removal(&fine, Bonnet::Original, &on).unwrap());
    let truth_base = means(direct_removal(&fine, Bonnet::Original, &none).unwrap());
    let truth_imprint = &truth - &truth_base;
    let point_input = input(&r, &params);
    let area_tool = ToolModel::from_source(
        &TifSource::Gaussian(GaussianTif::new(1.0, 8.0, 10.0).unwrap()),
        None,
        g.dx_mm,
        g.dy_mm,
    )
    .unwrap()
    .seen_by(PixelResponse::area(g.dx_mm, g.dy_mm));
    let area_input = CouplingInput {
        tool: &area_tool,
        ..input(&r, &params)
    };
    let rms = |m: &Array2<f64>| msf_band_rms_y(&point_input, m, band).unwrap();
    let imprint = rms(&truth_imprint);
    let total = rms(&truth);
    let mut errs = Vec::new();
    for (name, inp) in [("point", &point_input), ("area", &area_input)] {
        let f = fast_maps(inp, Bonnet::Original, &on).unwrap();
        let e_total = rms(&(&f.total() - &truth));
        let e_imprint = rms(&(f.by_name("normal_offset").unwrap() - &truth_imprint));
        eprintln!(
            "{name} pixels: total {total:.5} nm, fast off by {e_total:.6} nm; imprint \
             {imprint:.5} nm, fast off by {e_imprint:.6} nm"
        );
        errs.push((e_total, e_imprint));
    }
    let ((pt, pi), (at, ai)) = (errs[0], errs[1]);
    assert!(imprint > 1e-3, "no imprint: {imprint} nm");
    assert!(at < 0.2 * pt, "total: area {at} nm vs point {pt} nm off");
    // The imprint is smooth on this 1 mm spot (the spindle's 9.3 Hz is averaged over the
    // spot's 0.6 s passage): the box changes it by less than the methods' common floor, so
    // here the area kernels need only be as right as the point ones.
    assert!(
        ai < 0.03 * imprint && pi < 0.03 * imprint,
        "imprint {imprint} nm: area off {ai} nm, point off {pi} nm"
    );
}
