//! A two-bonnet offset sweep through the whole pipeline: sweep detection, per-bonnet fits,
//! trends with predictions, optimisation degree (checked by brute force), model export.

use bonnetlab_spots::export::model_toml;
use bonnetlab_spots::sweep::SpotRecord;
use bonnetlab_spots::{
    analyse_sweep, generate_spot, measure_spot, BonnetModel, Factor, Factors, FitStart,
    SpotOptions, SpotSpec, TrendMetric,
};

fn records() -> Vec<SpotRecord> {
    let mut out = Vec::new();
    let bonnets = [
        ("original", BonnetModel::new(20.0, 0.05, 2.0)),
        ("suppression", BonnetModel::new(20.0, 0.03, 1.2)),
    ];
    let mut seed = 1;
    for (name, model) in bonnets {
        for h in [0.2, 0.4, 0.6, 0.8, 1.0] {
            let factors = Factors {
                offset_mm: h,
                ..Factors::PAPER_BASELINE
            };
            let spec = SpotSpec {
                model,
                factors,
                dwell_s: 120.0,
                rows: 101,
                cols: 101,
                dx_mm: 0.2,
                dy_mm: 0.2,
                centre_offset_mm: (0.1, -0.2),
                piston_nm: 10.0,
                tilt_nm_per_mm: (1.0, -1.0),
                noise_rms_nm: 1.0,
                seed,
            };
            seed += 1;
            let s = generate_spot(&spec).unwrap();
            let m = measure_spot(&s, 120.0, &SpotOptions::default())
                .unwrap()
                .metrics;
            out.push(SpotRecord {
                file: format!("{name}_{h}.dat"),
                line: seed as usize,
                bonnet: name.into(),
                factors,
                sweep: None,
                metrics: m,
                predicted: None,
                pixel_mm: (0.2, 0.2),
            });
        }
    }
    out
}

#[test]
fn offset_sweep_of_two_bonnets_end_to_end() {
    let recs = records();
    let rep = analyse_sweep(recs.clone(), &FitStart::default());
    assert_eq!(rep.sweeps, vec![Factor::OffsetMm]);
    assert_eq!(rep.reference_bonnet, "original");
    assert_eq!(rep.baseline.precession_deg, 20.0);
    for (f, r) in rep.fits.iter().zip([0.05, 0.03]) {
        let m = f.fit.as_ref().unwrap().model;
        assert!((m.radius_mm - 20.0).abs() < 0.5, "{m:?}");
        assert!((m.preston_nm_per_mpa_mm - r).abs() < 0.05 * r, "{m:?}");
        let text = model_toml(f).unwrap();
        let v: toml::Table = toml::from_str(&text).unwrap();
        assert_eq!(v["tif"]["model"]["kind"].as_str(), Some("bonnet"));
        assert_eq!(v["tif"]["model"]["pressure"].as_str(), Some("parabolic"));
    }
    let rms = rep
        .trends
        .iter()
        .find(|t| t.metric == TrendMetric::RegionRmsNm)
        .unwrap();
    assert_eq!(rms.lines.len(), 2);
    assert_eq!(rms.lines[0].points.len(), 5);
    for p in &rms.lines[0].points {
        let pred = p.predicted.unwrap();
        assert!((pred - p.measured).abs() < 0.03 * p.measured, "{p:?}");
    }
    // Optimisation degree by brute force from the records.
    let mean = |b: &str| {
        let v: Vec<f64> = recs
            .iter()
            .filter(|r| r.bonnet == b)
            .map(|r| r.metrics.region_rms_nm)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let want = (mean("original") - mean("suppression")) / mean("original");
    let o = rep
        .optimisation
        .iter()
        .find(|o| o.metric == TrendMetric::RegionRmsNm)
        .unwrap();
    assert_eq!(o.bonnet, "suppression");
    assert!((o.degree - want).abs() < 1e-12, "{} vs {want}", o.degree);
    assert!(
        o.degree > 0.2,
        "the weaker bonnet removes less: {}",
        o.degree
    );
}
