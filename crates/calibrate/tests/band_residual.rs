//! The band-aware residual (issue #15) on independent realistic runs: power-law textures down
//! to the pixel scale (140 nm RMS), square and round (90 mm) apertures, circular dropouts,
//! unequal white noise in the two maps, an off-centre measured spot, and the after map made by
//! exact time-domain deposition (`synth`, never calibrate's FFT model). The truth of the floor
//! is the generator's white noise (the two maps' in quadrature).
//!
//! The residual is split at the process band's cutoff (the TIF's |MTF| at 1e-2 of its value at
//! 0): the process band, what the process can make, and the fine band, whose excess above its
//! share of the floor is reported under `unexplained` with its band.

mod common;

use bonnetlab_calibrate::run::Calibration;
use bonnetlab_calibrate::synth::{InitialSurface, Injected, SynthConfig};
use common::{alternate, run};

/// A 100 mm part on a 300 x 300 map (0.333 mm pixels): power-law surface (1-D PSD exponent
/// `exponent`), a 90 mm round aperture on odd `r`, 3-4 circular dropouts, noise `nb` / `na`
/// nm, truth grid `os` times finer than the map (texture above the map's Nyquist when 2).
fn scenario(
    r: u64,
    exponent: f64,
    nb: f64,
    na: f64,
    os: usize,
    effects: Vec<Injected>,
) -> SynthConfig {
    let base = SynthConfig::realistic(
        70 + r,
        300,
        100.0,
        InitialSurface::realistic_texture(exponent),
    )
    .with_noise_nm(nb, na);
    SynthConfig {
        truth_oversample: os,
        effects,
        ..alternate(base, r, 90.0)
    }
}

/// A sub-pixel misregistration (0.6 and 0.36 pixel) with a small rotation.
fn misregistration() -> Injected {
    Injected::Registration {
        dx_mm: 0.2,
        dy_mm: -0.12,
        rotation_deg: 0.05,
    }
}

fn summary(c: &Calibration, truth: f64) -> String {
    let bands: Vec<String> = c
        .final_
        .bands
        .iter()
        .map(|b| {
            format!(
                "{} {:.3}-{:.3}/mm: {:.3} nm (floor {:.3})",
                b.band, b.band_per_mm[0], b.band_per_mm[1], b.rms_nm, b.floor_nm
            )
        })
        .collect();
    format!(
        "floor {:.3} nm (true {truth:.3}, ratio {:.2}) read at {:.3}-{:.3}/mm along {}; cutoff {:.3}/mm; \
         final {:.3} nm; bands [{}]; effects {:?}; unexplained {:?}",
        c.noise_floor_rms_nm,
        c.noise_floor_rms_nm / truth,
        c.noise_floor_band_per_mm[0],
        c.noise_floor_band_per_mm[1],
        c.noise_floor_axis,
        c.process_band.cutoff_per_mm,
        c.final_.residual_rms_nm,
        bands.join("; "),
        c.effects
            .iter()
            .map(|e| format!("{} {:?}", e.kind, e.params))
            .collect::<Vec<_>>(),
        c.unexplained
            .iter()
            .map(|u| (u.band_per_mm, u.rms_nm, u.description.clone()))
            .collect::<Vec<_>>()
    )
}

/// The two bands add up to the full-band residual in power, the process band ends at the
/// cutoff and the fine band at Nyquist, and each band's floor is its share of the floor.
fn check_bands(c: &Calibration, tag: &str) {
    let b = &c.final_.bands;
    assert_eq!(b.len(), 2, "{tag}: {b:?}");
    assert_eq!(
        (b[0].band.as_str(), b[1].band.as_str()),
        ("process", "fine")
    );
    let fc = c.process_band.cutoff_per_mm;
    assert!(fc > 0.0 && fc < 1.5, "{tag}: cutoff {fc}");
    assert_eq!(b[0].band_per_mm, [0.0, fc]);
    assert_eq!(b[1].band_per_mm, [fc, 1.5]);
    let sum = b[0].rms_nm.hypot(b[1].rms_nm);
    let full = c.final_.residual_rms_nm;
    assert!(
        (sum / full - 1.0).abs() < 0.02,
        "{tag}: bands {sum} vs full {full}"
    );
    let floor = b[0].floor_nm.hypot(b[1].floor_nm);
    assert!((floor / c.noise_floor_rms_nm - 1.0).abs() < 1e-9);
    // White noise below the cutoff: the disc's share of the frequency square.
    let share = (std::f64::consts::PI * fc * fc / 4.0) / (1.5 * 1.5);
    assert!(((b[0].floor_nm / c.noise_floor_rms_nm).powi(2) / share - 1.0).abs() < 0.02);
    // The floor is read above the process band.
    assert!(
        c.noise_floor_band_per_mm[0] >= fc,
        "{tag}: {:?}",
        c.noise_floor_band_per_mm
    );
}

/// Calibrates a misregistered run: its bands checked ([`check_bands`]) and the registration
/// the one effect accepted. Returns the calibration, the true floor and the run's summary.
fn registered(cfg: &SynthConfig, tag: &str) -> (Calibration, f64, String) {
    let (c, truth) = run(cfg);
    let s = summary(&c, truth);
    eprintln!("{tag}: {s}");
    check_bands(&c, &s);
    assert_eq!(
        c.effects
            .iter()
            .map(|e| e.kind.as_str())
            .collect::<Vec<_>>(),
        ["registration"],
        "{s}"
    );
    (c, truth, s)
}

/// Null runs: the floor (read above the process band) within 15 % of the truth, no effect
/// accepted, the final residual at the floor in both bands, nothing in `unexplained`.
#[test]
fn null_runs_floor_per_band_and_nothing_accepted() {
    for (r, beta, nb, na) in [(0, 2.2, 1.0, 0.7), (1, 1.8, 0.5, 1.6)] {
        let (c, truth) = run(&scenario(r, beta, nb, na, 2, Vec::new()));
        let s = summary(&c, truth);
        eprintln!("null run {r}: {s}");
        check_bands(&c, &s);
        assert!((c.noise_floor_rms_nm / truth - 1.0).abs() <= 0.15, "{s}");
        assert!(c.effects.is_empty(), "{s}");
        for b in &c.final_.bands {
            assert!(b.rms_nm <= 1.15 * b.floor_nm, "{s}");
        }
        assert!(c.unexplained.is_empty(), "{s}");
    }
}

/// A sub-pixel misregistration of a texture that does not resample identically: the
/// registration is found, the final residual is reported per band, and the fine band's excess
/// above its floor is under `unexplained` with the fine band's edges.
#[test]
fn misregistered_run_reports_the_fine_band_excess_as_unexplained() {
    let (c, _, s) = registered(
        &scenario(1, 1.8, 0.5, 1.6, 1, vec![misregistration()]),
        "misregistered run",
    );
    let fine = &c.final_.bands[1];
    let u = c
        .unexplained
        .iter()
        .find(|u| {
            u.description
                .starts_with("fine texture the process cannot make")
        })
        .unwrap_or_else(|| panic!("no fine-band entry: {s}"));
    assert_eq!(u.band_per_mm, fine.band_per_mm, "{s}");
    let excess = (fine.rms_nm.powi(2) - fine.floor_nm.powi(2)).sqrt();
    assert!((u.rms_nm / excess - 1.0).abs() < 1e-9, "{s}");
}

/// Issue #15's final-residual criterion on misregistered runs whose map pixels average the
/// surface over their area, as a camera's pixels do (`pixel_average`): texture above the map's
/// Nyquist is attenuated by the pixel's sinc instead of folding back in full, and what still
/// does not resample identically stays in the fine band. The process band's residual within
/// 1.3x of the true floor's share of that band, and, where the full band is above 1.3x the
/// floor, the fine band's excess under `unexplained` with the fine band's edges. Measured
/// (session 19, maps and spot averaged): process band 1.02, 1.16 and 1.14x its share on these
/// three runs (1.03, 1.16, 1.17x with the maps alone averaged); on the roughest texture
/// (exponent 1.8, `r` = 1) 1.295x with the maps alone averaged, at the criterion's edge, and
/// 8.5x with point samples. The harness (reports/calibration.md): 50 of 50 registration runs meet
/// the criterion with pixel means, 12 of 50 (the real-map runs) with point samples.
#[test]
fn misregistered_pixel_averaged_runs_leave_the_process_band_at_the_floor() {
    for (r, beta, nb, na) in [(2, 2.6, 1.8, 1.2), (3, 2.2, 1.0, 1.0), (4, 2.0, 0.7, 1.4)] {
        let cfg = SynthConfig {
            pixel_average: 4,
            ..scenario(r, beta, nb, na, 2, vec![misregistration()])
        };
        let (c, truth, s) = registered(&cfg, &format!("misregistered pixel-averaged run {r}"));
        let process = &c.final_.bands[0];
        let share = process.floor_nm * truth / c.noise_floor_rms_nm;
        assert!(
            process.rms_nm <= 1.3 * share,
            "process band {:.3} nm against {share:.3} nm: {s}",
            process.rms_nm
        );
        if c.final_.residual_rms_nm > 1.3 * truth {
            let fine = &c.final_.bands[1];
            assert!(
                c.unexplained
                    .iter()
                    .any(|u| u.band_per_mm == fine.band_per_mm),
                "no fine-band entry: {s}"
            );
        }
    }
}

/// Issue #15's target on misregistered runs: the floor within 15 % of the generator's white
/// noise. Not met (see reports/calibration.md, "Band-aware residual"): the registered
/// difference's PSD stands 1.4-200 times above the true white level at every frequency from 0
/// to Nyquist, so no band holds the noise alone.
#[test]
#[ignore = "issue #15: the floor on misregistered runs is 1.2-11x the truth (measured, not met)"]
fn misregistered_runs_floor_within_15_percent() {
    let mut worst: f64 = 1.0;
    let mut lines = Vec::new();
    for (r, beta, nb, na, os) in [
        (1, 1.8, 0.5, 1.6, 2),
        (2, 2.6, 1.8, 1.2, 2),
        (1, 1.8, 0.5, 1.6, 1),
        (2, 2.6, 1.8, 1.2, 1),
    ] {
        let (c, truth) = run(&scenario(r, beta, nb, na, os, vec![misregistration()]));
        let s = summary(&c, truth);
        eprintln!("misregistered run {r} (oversample {os}): {s}");
        let ratio = c.noise_floor_rms_nm / truth;
        if (ratio - 1.0).abs() > (worst - 1.0).abs() {
            worst = ratio;
        }
        lines.push(s);
    }
    assert!(
        (worst - 1.0).abs() <= 0.15,
        "worst ratio {worst:.2}: {lines:#?}"
    );
}
