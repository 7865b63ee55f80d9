//! The fast coupling (second-order expansion: the one fast removal model run on the TIF's
//! derivative fields with weighted dwell) against direct time-domain deposition of the
//! instantaneous TIF, on raster runs with vibration on (issue 14: the vibration's own part, not
//! only the total, within 1 % of direct deposition).

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
    raster(3.0, ScanAxis::X, y_last_mm, 8.0)
}

/// Footprint diameter (mm) of a σ 1 mm Gaussian cut where its rate is 1.5e-8 of the peak (6 σ):
/// no rate step at the rim (see [`fast_coupling_vibration_part_agrees_with_direct_deposition`]).
const SMOOTH_MM: f64 = 12.0;

/// A raster of `pitch_mm` scanned along `axis` over the 24 x 24 mm part, lines from −3 mm up
/// to `last_mm` across the scan; Gaussian spot σ 1 mm cut at `diameter_mm`.
fn raster(pitch_mm: f64, axis: ScanAxis, last_mm: f64, diameter_mm: f64) -> Run {
    let grid = Grid::new(97, 97, 0.25, 0.25, 0.0, 0.0).unwrap();
    let tif = GaussianTif::new(1.0, diameter_mm, 10.0).unwrap();
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

/// Fast coupling against the direct deposition (exact time-domain deposition of the
/// instantaneous TIF through process's `deposit_exact_modulated`, sub-steps of at most 1 ms =
/// 2 per 500 Hz sample), every mechanism on, 24 x 24 mm at 0.25 mm, Gaussian σ 1 mm cut at 6 σ,
/// lines from −3 to 15 mm, forcing strong enough that the vibration's part of the MSF is
/// 5e-4 to 3e-3 of the removal's (far above the methods' common floor, ~2e-6). Criteria
/// (issue 14), MSF band RMS across the raster lines (one-sided PSD along Y for an X scan, along
/// X for a Y scan; band 0.1 to 1 per mm):
/// - the vibration-induced part (all on minus all off, each method with itself): the band RMS of
///   the fast − direct difference within 1 % of the direct part's band RMS;
/// - the total removal: the difference within 1 % of the direct removal's band RMS.
///
/// Measured (nm; diff = band RMS of the difference map, % of direct):
///
/// | case | scan | pitch mm | rpm | forcing fn / noise N | total diff | induced fast / direct | induced diff |
/// |---|---|---|---|---|---|---|---|
/// | a | X | 3.0 | 558 (x2 resonance) | 3 / 1.5 | 0.0028 % | 0.013516 / 0.013568 | 0.87 % |
/// | b | X | 3.0 | 558 | 2 / 0.5 | 0.0005 % | 0.005966 / 0.005967 | 0.31 % |
/// | c | X | 1.7 | 1500 | 6 / 3 | 0.0003 % | 0.006747 / 0.006756 | 0.26 % |
/// | d | Y (lateral Y) | 3.0 | 558 | 3 / 1.5 | 0.0028 % | 0.013516 / 0.013568 | 0.87 % |
/// | e | Y (lateral Y) | 1.7 | 900 | 3 / 1.5 | 0.0002 % | 0.003374 / 0.003379 | 0.26 % |
///
/// (d is a transposed: the same numbers, so both scan axes run the same model.) The largest
/// difference, at the resonance, is the expansion's remainder: offset swings of about 14 % of
/// h0 leave a third-order term of that order relative to the rectified second-order one
/// (halving the forcing takes `normal_offset` alone from 0.80 % to 0.25 %).
///
/// Why the previous model was 9 % off on the induced part (and this one is 29 % off there with
/// the footprint cut at 4 σ, while the total stays within 0.1 %): a Gaussian cut at 4 σ has a
/// rate step of 3.4e-4 of its peak at the rim, and the rim moves with the offset. The spindle's
/// offset oscillation (9.3 and 18.6 Hz, 0.17 and 0.086 mm along the path at 1.6 mm/s: below the
/// pixel) then writes sub-pixel structure at the rim, which the direct method samples at pixel
/// centres (aliasing it into the band) and the pixel kernels of any convolution model cannot
/// represent: with the rim moved out to 6 σ, fast and direct agree as above
/// ([`cut_footprint_rim_is_the_induced_part_difference`] keeps the 4 σ numbers).
#[test]
fn fast_coupling_vibration_part_agrees_with_direct_deposition() {
    struct Case {
        name: &'static str,
        axis: ScanAxis,
        pitch: f64,
        params: VibrationParams,
    }
    let forced = |rpm: f64, lateral: LateralAxis, fn_n: f64, noise: f64| VibrationParams {
        spindle_rpm: rpm,
        fn_n,
        noise_force_rms_n: noise,
        lateral_axis: lateral,
        ..Default::default()
    };
    let cases = [
        Case {
            name: "a: X scan, 3 mm, 558 rpm, fn 3 N, noise 1.5 N",
            axis: ScanAxis::X,
            pitch: 3.0,
            params: forced(558.0, LateralAxis::X, 3.0, 1.5),
        },
        Case {
            name: "b: X scan, 3 mm, 558 rpm, fn 2 N, noise 0.5 N",
            axis: ScanAxis::X,
            pitch: 3.0,
            params: forced(558.0, LateralAxis::X, 2.0, 0.5),
        },
        Case {
            name: "c: X scan, 1.7 mm, 1500 rpm, fn 6 N, noise 3 N",
            axis: ScanAxis::X,
            pitch: 1.7,
            params: forced(1500.0, LateralAxis::X, 6.0, 3.0),
        },
        Case {
            name: "d: Y scan, 3 mm, 558 rpm, fn 3 N, noise 1.5 N",
            axis: ScanAxis::Y,
            pitch: 3.0,
            params: forced(558.0, LateralAxis::Y, 3.0, 1.5),
        },
        Case {
            name: "e: Y scan, 1.7 mm, 900 rpm, fn 3 N, noise 1.5 N",
            axis: ScanAxis::Y,
            pitch: 1.7,
            params: forced(900.0, LateralAxis::Y, 3.0, 1.5),
        },
    ];
    let opts = CouplingOptions {
        sample_hz: 500.0,
        ..Default::default()
    };
    let mut failures = Vec::new();
    for c in &cases {
        let r = raster(c.pitch, c.axis, 15.0, SMOOTH_MM);
        let input = input(&r, &c.params);
        let m = compare(&input, c.axis, &opts);
        eprintln!("{}: {m}", c.name);
        if m.induced_direct.is_nan() || m.induced_direct <= 3e-4 * m.total_direct {
            failures.push(format!("{}: vibration part too small: {m}", c.name));
        }
        if m.total_diff > 0.01 * m.total_direct || m.induced_diff > 0.01 * m.induced_direct {
            failures.push(format!("{}: {m}", c.name));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Fast and direct MSF band RMS (nm) across the lines of a run: total, induced (all on minus
/// all off) and the band RMS of their differences.
struct Comparison {
    total_fast: f64,
    total_direct: f64,
    total_diff: f64,
    induced_fast: f64,
    induced_direct: f64,
    induced_diff: f64,
}

impl std::fmt::Display for Comparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "total fast {:.5} / direct {:.5} nm, diff {:.2e} nm ({:.4} %); induced fast {:.6} / \
             direct {:.6} nm, diff {:.2e} nm ({:.2} %)",
            self.total_fast,
            self.total_direct,
            self.total_diff,
            100.0 * self.total_diff / self.total_direct,
            self.induced_fast,
            self.induced_direct,
            self.induced_diff,
            100.0 * self.induced_diff / self.induced_direct
        )
    }
}

fn compare(input: &CouplingInput<'_>, axis: ScanAxis, opts: &CouplingOptions) -> Comparison {
    let band = opts.msf_band_per_mm;
    let none = CouplingOptions {
        mechanisms: Mechanisms::NONE,
        ..*opts
    };
    // Across the lines: a Y scan's maps are transposed (square pixels).
    let across = |m: &Array2<f64>| match axis {
        ScanAxis::X => m.clone(),
        ScanAxis::Y => m.t().to_owned(),
    };
    let fast = fast_maps(input, Bonnet::Original, opts).unwrap();
    let direct = across(&direct_removal(input, Bonnet::Original, opts).unwrap());
    let direct0 = across(&direct_removal(input, Bonnet::Original, &none).unwrap());
    let total = across(&fast.total());
    let induced_fast = across(&fast.induced());
    let induced_direct = &direct - &direct0;
    Comparison {
        total_fast: msf_band_rms_y(input, &total, band).unwrap(),
        total_direct: msf_band_rms_y(input, &direct, band).unwrap(),
        total_diff: band_diff(input, &total, &direct),
        induced_fast: msf_band_rms_y(input, &induced_fast, band).unwrap(),
        induced_direct: msf_band_rms_y(input, &induced_direct, band).unwrap(),
        induced_diff: band_diff(input, &induced_fast, &induced_direct),
    }
}

/// The footprint cut at 4 σ (a rate step of 3.4e-4 of the peak at the rim): the total removal
/// still agrees within 1 % (measured 0.09 % at 558 rpm, fn 3 N, noise 1.5 N), but the vibration's
/// part does not (measured: fast 0.0177 nm, direct 0.0136 nm, difference 64 % for the
/// `normal_offset` mechanism alone; 29 % with every mechanism on) because the rim moving with
/// the offset at the spindle frequency writes sub-pixel structure (see
/// [`fast_coupling_vibration_part_agrees_with_direct_deposition`]). Asserted so the cause stays
/// documented: the same run with the rim moved out to 6 σ agrees within 1 %.
#[test]
fn cut_footprint_rim_is_the_induced_part_difference() {
    let params = VibrationParams {
        spindle_rpm: 558.0,
        fn_n: 3.0,
        noise_force_rms_n: 1.5,
        ..Default::default()
    };
    let opts = CouplingOptions {
        sample_hz: 500.0,
        ..Default::default()
    };
    let cut = raster(3.0, ScanAxis::X, 15.0, 8.0);
    let m = compare(&input(&cut, &params), ScanAxis::X, &opts);
    eprintln!("cut at 4 sigma: {m}");
    assert!(m.total_diff < 0.01 * m.total_direct, "{m}");
    assert!(m.induced_diff > 0.1 * m.induced_direct, "{m}");
}

/// The reference is converged: halving the direct deposition's sub-step (2 -> 4 per 500 Hz
/// sample) changes its removal's MSF band RMS by less than 0.1 % (measured: 0.0 % on the
/// X-scan 558 rpm run, the difference map's band RMS 1e-6 of the removal's), and the MSF band RMS
/// of the induced part by less than 0.1 % of itself.
#[test]
fn direct_deposition_is_converged_in_its_sub_step() {
    let r = raster(3.0, ScanAxis::X, 9.0, SMOOTH_MM);
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
    // each alone, fast vs direct, footprint without a rim step (Gaussian cut at 6 σ). Measured
    // (MSF band RMS, nm): normal_offset 0.013579 / 0.013624, difference 0.80 % (the expansion's
    // third-order remainder); lateral_jitter 0.000132 / 0.000132, 0.60 %; envelope
    // 0.002527 / 0.002530, 0.25 %.
    let r = raster(3.0, ScanAxis::X, 15.0, SMOOTH_MM);
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
        assert!(rd > 1e-5 * total, "{name}: imprint {rd} vs total {total}");
        assert!(
            dd <= 0.01 * rd,
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
