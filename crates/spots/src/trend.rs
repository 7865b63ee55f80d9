//! Trends across a single-factor sweep: metric against factor, one line per bonnet, with the
//! fitted model's prediction beside the measurement, and the optimisation degree between
//! bonnets.
//!
//! Sweep membership: a spot belongs to the sweep its manifest entry names (`sweep`), or, when it
//! names none, to the sweep of factor F if its other three factors equal the baseline (each
//! factor's most frequent value over all spots, ties to the median tied value), as in the paper's
//! Table 5. A sweep needs at least two levels of its factor.
//!
//! Optimisation degree (paper section 3.2, Figure 18). The paper prints, per sweep, one degree
//! for RMS and one for PV but not its formula; its values lie close to the relative reduction
//! of the sweep-mean, e.g. precession RMS from range midpoints (178.95 - 87.72) / 178.95 = 51.0 %
//! against the printed 50.1 % (the levels themselves are not printed, so it cannot be pinned
//! down further). This module reports `degree = (mean_ref - mean_other) / mean_ref` over the
//! levels both bonnets have, and beside it the mean of the per-level reductions
//! `(ref - other) / ref`; positive = the other bonnet leaves less error.

use serde::{Deserialize, Serialize};

use crate::model::{Factor, Factors};
use crate::sweep::SpotRecord;

/// A metric tabulated in trends: key (JSON/CSV), label with unit, and whether the paper's
/// optimisation degree applies to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrendMetric {
    PeakRateNmPerS,
    VolumeRateNmMm2PerS,
    FwhmXMm,
    FwhmYMm,
    RegionRmsNm,
    RegionPvNm,
}

impl TrendMetric {
    pub const ALL: [TrendMetric; 6] = [
        TrendMetric::RegionRmsNm,
        TrendMetric::RegionPvNm,
        TrendMetric::PeakRateNmPerS,
        TrendMetric::VolumeRateNmMm2PerS,
        TrendMetric::FwhmXMm,
        TrendMetric::FwhmYMm,
    ];

    pub fn key(&self) -> &'static str {
        match self {
            TrendMetric::PeakRateNmPerS => "peak_rate_nm_per_s",
            TrendMetric::VolumeRateNmMm2PerS => "volume_rate_nm_mm2_per_s",
            TrendMetric::FwhmXMm => "fwhm_x_mm",
            TrendMetric::FwhmYMm => "fwhm_y_mm",
            TrendMetric::RegionRmsNm => "region_rms_nm",
            TrendMetric::RegionPvNm => "region_pv_nm",
        }
    }

    pub fn label(&self) -> &'static str {
        match self {
            TrendMetric::PeakRateNmPerS => "peak removal rate (nm/s)",
            TrendMetric::VolumeRateNmMm2PerS => "volumetric rate (nm mm^2/s = 1e-6 mm^3/s)",
            TrendMetric::FwhmXMm => "FWHM X (mm)",
            TrendMetric::FwhmYMm => "FWHM Y (mm)",
            TrendMetric::RegionRmsNm => "RMS of the polished region (nm)",
            TrendMetric::RegionPvNm => "PV of the polished region (nm)",
        }
    }

    /// The measured value and the model's prediction for a spot.
    pub fn values(&self, r: &SpotRecord) -> (f64, Option<f64>) {
        let m = &r.metrics;
        let p = r.predicted.as_ref();
        match self {
            TrendMetric::PeakRateNmPerS => (m.peak_rate_nm_per_s, p.map(|p| p.peak_rate_nm_per_s)),
            TrendMetric::VolumeRateNmMm2PerS => (
                m.volume_rate_nm_mm2_per_s,
                p.map(|p| p.volume_rate_nm_mm2_per_s),
            ),
            TrendMetric::FwhmXMm => (m.fwhm_x_mm, p.map(|p| p.fwhm_x_mm)),
            TrendMetric::FwhmYMm => (m.fwhm_y_mm, p.map(|p| p.fwhm_y_mm)),
            TrendMetric::RegionRmsNm => (m.region_rms_nm, p.map(|p| p.region_rms_nm)),
            TrendMetric::RegionPvNm => (m.region_pv_nm, p.map(|p| p.region_pv_nm)),
        }
    }
}

/// One point of a trend line: the mean over the spots at this level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrendPoint {
    pub level: f64,
    pub n: usize,
    pub measured: f64,
    pub predicted: Option<f64>,
}

/// One bonnet's line in a trend.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrendLine {
    pub bonnet: String,
    pub points: Vec<TrendPoint>,
}

/// Metric against factor, one line per bonnet.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Trend {
    pub factor: Factor,
    pub metric: TrendMetric,
    pub lines: Vec<TrendLine>,
}

/// Optimisation degree of one bonnet over the reference, for one sweep and metric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Optimisation {
    pub factor: Factor,
    pub metric: TrendMetric,
    pub reference: String,
    pub bonnet: String,
    pub common_levels: Vec<f64>,
    pub reference_mean: f64,
    pub bonnet_mean: f64,
    pub reference_range: (f64, f64),
    pub bonnet_range: (f64, f64),
    /// (mean_ref - mean_bonnet) / mean_ref, a fraction.
    pub degree: f64,
    /// Mean over common levels of (ref - bonnet) / ref, a fraction.
    pub mean_level_degree: f64,
}

fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1e-12)
}

/// Each factor's most frequent value (ties: the lower median of the tied values, so a lone
/// sweep's baseline is its middle level).
pub fn baseline(records: &[SpotRecord]) -> Factors {
    let mode = |f: Factor| {
        let mut counts: Vec<(f64, usize)> = Vec::new();
        for r in records {
            let v = r.factors.get(f);
            match counts.iter_mut().find(|(u, _)| same(*u, v)) {
                Some(c) => c.1 += 1,
                None => counts.push((v, 1)),
            }
        }
        let top = counts.iter().map(|c| c.1).max().unwrap_or(0);
        let mut tied: Vec<f64> = counts.iter().filter(|c| c.1 == top).map(|c| c.0).collect();
        tied.sort_by(f64::total_cmp);
        tied.get(tied.len().saturating_sub(1) / 2)
            .copied()
            .unwrap_or(f64::NAN)
    };
    Factors {
        precession_deg: mode(Factor::PrecessionDeg),
        offset_mm: mode(Factor::OffsetMm),
        spindle_rpm: mode(Factor::SpindleRpm),
        inner_pressure_mpa: mode(Factor::InnerPressureMpa),
    }
}

/// The sweeps present: each factor with the indices of its member spots (>= 2 levels).
pub fn sweeps(records: &[SpotRecord]) -> Vec<(Factor, Vec<usize>)> {
    let base = baseline(records);
    let mut out = Vec::new();
    for f in Factor::ALL {
        let members: Vec<usize> = records
            .iter()
            .enumerate()
            .filter(|(_, r)| match r.sweep {
                Some(s) => s == f,
                None => Factor::ALL
                    .iter()
                    .filter(|&&g| g != f)
                    .all(|&g| same(r.factors.get(g), base.get(g))),
            })
            .map(|(i, _)| i)
            .collect();
        let mut levels: Vec<f64> = members.iter().map(|&i| records[i].factors.get(f)).collect();
        levels.sort_by(f64::total_cmp);
        levels.dedup_by(|a, b| same(*a, *b));
        if levels.len() >= 2 {
            out.push((f, members));
        }
    }
    out
}

/// Bonnet names in order: the reference first, then by first appearance.
pub fn bonnet_order(records: &[SpotRecord], reference: &str) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    if records.iter().any(|r| r.bonnet == reference) {
        names.push(reference.to_string());
    }
    for r in records {
        if !names.contains(&r.bonnet) {
            names.push(r.bonnet.clone());
        }
    }
    names
}

/// A measured value and the model's prediction of it.
type Measured = (f64, Option<f64>);

/// The trend of one metric over one sweep.
pub fn trend(
    records: &[SpotRecord],
    members: &[usize],
    factor: Factor,
    metric: TrendMetric,
    bonnets: &[String],
) -> Trend {
    let mut lines = Vec::new();
    for b in bonnets {
        let mut pts: Vec<(f64, Vec<Measured>)> = Vec::new();
        for &i in members {
            let r = &records[i];
            if &r.bonnet != b {
                continue;
            }
            let lv = r.factors.get(factor);
            let v = metric.values(r);
            match pts.iter_mut().find(|(l, _)| same(*l, lv)) {
                Some(p) => p.1.push(v),
                None => pts.push((lv, vec![v])),
            }
        }
        if pts.is_empty() {
            continue;
        }
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        let points = pts
            .into_iter()
            .map(|(level, vs)| {
                let n = vs.len();
                let measured = vs.iter().map(|v| v.0).sum::<f64>() / n as f64;
                let predicted = vs
                    .iter()
                    .map(|v| v.1)
                    .collect::<Option<Vec<f64>>>()
                    .map(|p| p.iter().sum::<f64>() / n as f64);
                TrendPoint {
                    level,
                    n,
                    measured,
                    predicted,
                }
            })
            .collect();
        lines.push(TrendLine {
            bonnet: b.clone(),
            points,
        });
    }
    Trend {
        factor,
        metric,
        lines,
    }
}

/// Optimisation degree of every non-reference line of a trend over the reference line.
pub fn optimisation(t: &Trend) -> Vec<Optimisation> {
    let Some(reference) = t.lines.first() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for other in &t.lines[1..] {
        let pairs: Vec<(f64, f64, f64)> = reference
            .points
            .iter()
            .filter_map(|p| {
                other
                    .points
                    .iter()
                    .find(|q| same(q.level, p.level))
                    .map(|q| (p.level, p.measured, q.measured))
            })
            .collect();
        if pairs.is_empty() {
            continue;
        }
        let n = pairs.len() as f64;
        let mr = pairs.iter().map(|p| p.1).sum::<f64>() / n;
        let mb = pairs.iter().map(|p| p.2).sum::<f64>() / n;
        let range = |k: usize| {
            pairs
                .iter()
                .map(|p| if k == 1 { p.1 } else { p.2 })
                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, v| {
                    (a.0.min(v), a.1.max(v))
                })
        };
        out.push(Optimisation {
            factor: t.factor,
            metric: t.metric,
            reference: reference.bonnet.clone(),
            bonnet: other.bonnet.clone(),
            common_levels: pairs.iter().map(|p| p.0).collect(),
            reference_mean: mr,
            bonnet_mean: mb,
            reference_range: range(1),
            bonnet_range: range(2),
            degree: (mr - mb) / mr,
            mean_level_degree: pairs.iter().map(|p| (p.1 - p.2) / p.1).sum::<f64>() / n,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::SpotMetrics;

    fn rec(bonnet: &str, f: Factors, rms: f64) -> SpotRecord {
        SpotRecord {
            file: String::new(),
            line: 0,
            bonnet: bonnet.into(),
            factors: f,
            sweep: None,
            metrics: SpotMetrics {
                region_rms_nm: rms,
                ..SpotMetrics::default()
            },
            predicted: None,
            pixel_mm: (0.1, 0.1),
        }
    }

    /// The paper's Table 5: four single-factor groups around 20 deg, 0.8 mm, 500 rpm, 0.25 MPa.
    fn table5(bonnet: &str, scale: f64) -> Vec<SpotRecord> {
        let b = Factors::PAPER_BASELINE;
        let mut v = Vec::new();
        for t in [10.0, 15.0, 20.0, 25.0, 30.0] {
            v.push(rec(
                bonnet,
                Factors {
                    precession_deg: t,
                    ..b
                },
                scale * t,
            ));
        }
        for h in [0.2, 0.4, 0.6, 0.8, 1.0] {
            v.push(rec(
                bonnet,
                Factors { offset_mm: h, ..b },
                scale * 100.0 * h,
            ));
        }
        for n in [250.0, 500.0, 1000.0, 1500.0, 2000.0] {
            v.push(rec(
                bonnet,
                Factors {
                    spindle_rpm: n,
                    ..b
                },
                scale * n / 10.0,
            ));
        }
        for p in [0.05, 0.10, 0.15, 0.20, 0.25] {
            v.push(rec(
                bonnet,
                Factors {
                    inner_pressure_mpa: p,
                    ..b
                },
                scale * 400.0 * p,
            ));
        }
        v
    }

    #[test]
    fn table5_design_gives_four_sweeps_and_the_degree_by_hand() {
        let mut r = table5("original", 1.0);
        r.extend(table5("suppression", 0.7));
        assert_eq!(baseline(&r), Factors::PAPER_BASELINE);
        let s = sweeps(&r);
        assert_eq!(
            s.iter().map(|x| x.0).collect::<Vec<_>>(),
            Factor::ALL.to_vec()
        );
        // Each sweep holds its five levels per bonnet (the baseline spot counts in every sweep).
        for (_, m) in &s {
            assert_eq!(
                m.len(),
                10 + 2 * 3,
                "baseline spots of the other groups join"
            );
        }
        let names = bonnet_order(&r, "original");
        let (f, m) = &s[1];
        let t = trend(&r, m, *f, TrendMetric::RegionRmsNm, &names);
        assert_eq!(t.lines[0].points.len(), 5);
        // The 0.8 mm level pools the four baseline spots (one per group), averaged.
        let p08 = t.lines[0].points.iter().find(|p| p.level == 0.8).unwrap();
        assert_eq!(p08.n, 4);
        let o = optimisation(&t);
        assert_eq!(o.len(), 1);
        assert!((o[0].degree - 0.3).abs() < 1e-12, "{}", o[0].degree);
        assert!((o[0].mean_level_degree - 0.3).abs() < 1e-12);
        assert_eq!(o[0].reference_range, (20.0, 100.0));
    }

    #[test]
    fn baseline_ties_take_the_middle_level() {
        let b = Factors::PAPER_BASELINE;
        let r: Vec<SpotRecord> = [0.2, 0.4, 0.6]
            .iter()
            .map(|&h| rec("a", Factors { offset_mm: h, ..b }, 1.0))
            .collect();
        assert_eq!(baseline(&r).offset_mm, 0.4);
    }
}
