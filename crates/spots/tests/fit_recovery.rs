//! The model fitted to synthetic spots (noise, tilt, off-centre) recovers the generating
//! parameters.

use bonnetlab_spots::{
    fit_model, generate_spot, measure_spot, BonnetModel, Factors, FitStart, Observation,
    SpotMetrics, SpotOptions, SpotSpec,
};

fn sweep(model: BonnetModel, factors: &[Factors], seed: u64) -> Vec<(Factors, SpotMetrics)> {
    factors
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let spec = SpotSpec {
                model,
                factors: *f,
                dwell_s: 120.0,
                rows: 131,
                cols: 141,
                dx_mm: 0.18,
                dy_mm: 0.18,
                centre_offset_mm: (0.3 - 0.1 * k as f64, 0.2),
                piston_nm: -25.0,
                tilt_nm_per_mm: (1.5, 2.5),
                noise_rms_nm: 2.0,
                seed: seed + k as u64,
            };
            let s = generate_spot(&spec).unwrap();
            (
                *f,
                measure_spot(&s, 120.0, &SpotOptions::default())
                    .unwrap()
                    .metrics,
            )
        })
        .collect()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b
}

#[test]
fn offset_sweep_recovers_radius_preston_and_modulus_within_five_percent() {
    let truth = BonnetModel::new(25.0, 0.035, 3.0);
    let base = Factors::PAPER_BASELINE;
    let levels: Vec<Factors> = [0.2, 0.4, 0.6, 0.8, 1.0]
        .iter()
        .map(|&h| Factors {
            offset_mm: h,
            ..base
        })
        .collect();
    let data = sweep(truth, &levels, 100);
    let obs: Vec<Observation> = data
        .iter()
        .map(|(f, m)| Observation {
            factors: *f,
            metrics: m,
        })
        .collect();
    let fit = fit_model(&obs, &FitStart::default()).unwrap();
    eprintln!("{fit:?}");
    assert_eq!(fit.fitted.len(), 3);
    assert!(
        rel(fit.model.radius_mm, 25.0) < 0.05,
        "R {}",
        fit.model.radius_mm
    );
    assert!(
        rel(fit.model.preston_nm_per_mpa_mm, 0.035) < 0.05,
        "k {}",
        fit.model.preston_nm_per_mpa_mm
    );
    assert!(
        rel(fit.model.modulus_mpa, 3.0) < 0.05,
        "E {}",
        fit.model.modulus_mpa
    );
    assert!(fit.rms_log_residual < 0.01);
}

#[test]
fn pressure_sweep_recovers_all_and_precession_sweep_holds_the_modulus() {
    let truth = BonnetModel::new(18.0, 0.05, 1.5);
    let base = Factors::PAPER_BASELINE;
    let levels: Vec<Factors> = [0.05, 0.10, 0.15, 0.20, 0.25]
        .iter()
        .map(|&p| Factors {
            inner_pressure_mpa: p,
            ..base
        })
        .collect();
    let data = sweep(truth, &levels, 200);
    let obs: Vec<Observation> = data
        .iter()
        .map(|(f, m)| Observation {
            factors: *f,
            metrics: m,
        })
        .collect();
    let fit = fit_model(&obs, &FitStart::default()).unwrap();
    eprintln!("{fit:?}");
    assert!(rel(fit.model.radius_mm, 18.0) < 0.05);
    assert!(rel(fit.model.preston_nm_per_mpa_mm, 0.05) < 0.05);
    assert!(
        rel(fit.model.modulus_mpa, 1.5) < 0.05,
        "E {}",
        fit.model.modulus_mpa
    );

    // Precession sweep: E is not identifiable; R is, and the rate is reproduced.
    let levels: Vec<Factors> = [10.0, 15.0, 20.0, 25.0, 30.0]
        .iter()
        .map(|&t| Factors {
            precession_deg: t,
            ..base
        })
        .collect();
    let data = sweep(truth, &levels, 300);
    let obs: Vec<Observation> = data
        .iter()
        .map(|(f, m)| Observation {
            factors: *f,
            metrics: m,
        })
        .collect();
    let fit = fit_model(&obs, &FitStart::default()).unwrap();
    eprintln!("{fit:?}");
    assert_eq!(fit.fitted, vec!["radius_mm", "preston_nm_per_mpa_mm"]);
    assert_eq!(fit.model.modulus_mpa, FitStart::default().modulus_mpa);
    assert!(
        rel(fit.model.radius_mm, 18.0) < 0.05,
        "R {}",
        fit.model.radius_mm
    );
    let want = truth.metrics(&base).unwrap().peak_rate_nm_per_s;
    let got = fit.model.metrics(&base).unwrap().peak_rate_nm_per_s;
    assert!(rel(got, want) < 0.02, "{got} vs {want}");
}
