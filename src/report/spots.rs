//! Rendering of a spot sweep (`pipeline::spots`): `report.html` (settings and conventions,
//! per-spot table, removal maps, trend plots, trend tables, optimisation degree, fitted models),
//! `report.json`, `spots.csv` and `trends.csv`.

use std::fmt::Write as _;
use std::path::Path;

use bonnetlab_spots::sweep::SpotRecord;
use bonnetlab_spots::{Factor, SpotAnalysis, SweepReport, TrendMetric};
use serde::Serialize;

use super::format::fixed;
use super::html::{Page, Table};
use super::maps::{false_colour_png_with, MapOptions};
use super::plot::{LinePlot, Series, PALETTE};

/// The conventions written beside the numbers (JSON and HTML).
pub fn conventions() -> Vec<(&'static str, &'static str)> {
    vec![
        ("removal", "removal = -(height - background) nm, positive = removed; background = piston + tilt fitted on the ring [1.4 R5, 1.9 R5] about the spot (manifest [defaults] ring_inner_mm / ring_outer_mm override); R5 = sqrt(area / pi) of pixels removed by more than 5 % of the peak"),
        ("centre", "vertex of a paraboloid fitted to the pixels above 85 % of the peak (centre_method = paraboloid), else the removal-weighted centroid"),
        ("peak_rate_nm_per_s", "paraboloid vertex removal / dwell"),
        ("volume_rate_nm_mm2_per_s", "sum of removal over the disc inside the ring's inner radius x dx dy / dwell; 1 nm mm^2 = 1e-6 mm^3 (volume_rate_mm3_per_s)"),
        ("fwhm", "half-maximum crossings of the bilinearly interpolated removal through the centre along X and Y"),
        ("asymmetry", "asymmetry_x = right / left half-width, asymmetry_y = up / down, aspect_yx = FWHM_y / FWHM_x, centroid_offset = removal-weighted centroid (pixels > 5 % of peak) minus the centre"),
        ("region_rms_nm / region_pv_nm", "heights after the ring's piston + tilt over the disc of radius R5 about the centre: RMS about their mean (Sq) and max - min; map_rms_nm / map_pv_nm: whole map after piston + tilt fitted on the whole map"),
        ("optimisation degree", "(mean_ref - mean_other) / mean_ref over the levels both bonnets have (paper's Figure 18 figure of merit reconstructed; its formula is not printed); mean_level_degree = mean of per-level (ref - other) / ref; fractions"),
        ("model", "bonnetlab_spots::model: contact radius sqrt(2Rh - h^2), pressure p0 (1 - r^2/a^2)^gamma with p0 = p_inner + 2/pi E a / R, in-plane speed of the tilted spin axis averaged over four precession steps, rate = k p |v|; fitted per bonnet by least squares on log peak rate, volume rate and FWHM X / Y"),
    ]
}

/// `report.json`: the whole `SweepReport` plus the conventions.
#[derive(Serialize)]
pub struct JsonOut<'a> {
    pub manifest: String,
    pub conventions: std::collections::BTreeMap<&'static str, &'static str>,
    #[serde(flatten)]
    pub report: &'a SweepReport,
}

fn g(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.4e}")
    } else if a >= 100.0 {
        fixed(v, 1)
    } else if a >= 1.0 {
        fixed(v, 3)
    } else {
        fixed(v, 4)
    }
}

pub fn stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

pub fn csv_bytes(header: &[&str], rows: &[Vec<String>]) -> Result<Vec<u8>, String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(header).map_err(|e| e.to_string())?;
    for r in rows {
        w.write_record(r).map_err(|e| e.to_string())?;
    }
    w.into_inner().map_err(|e| e.to_string())
}

pub const SPOT_COLUMNS: [&str; 24] = [
    "file",
    "bonnet",
    "dwell_s",
    "precession_deg",
    "offset_mm",
    "spindle_rpm",
    "inner_pressure_mpa",
    "centre_x_mm",
    "centre_y_mm",
    "centre_method",
    "peak_rate_nm_per_s",
    "volume_rate_nm_mm2_per_s",
    "fwhm_x_mm",
    "fwhm_y_mm",
    "asymmetry_x",
    "asymmetry_y",
    "centroid_offset_mm",
    "region_rms_nm",
    "region_pv_nm",
    "noise_rms_nm",
    "predicted_peak_rate_nm_per_s",
    "predicted_volume_rate_nm_mm2_per_s",
    "predicted_fwhm_x_mm",
    "predicted_region_rms_nm",
];

pub fn spot_row(r: &SpotRecord) -> Vec<String> {
    let m = &r.metrics;
    let f = &r.factors;
    let p = r.predicted.as_ref();
    let opt = |v: Option<f64>| v.map(|v| format!("{v}")).unwrap_or_default();
    vec![
        r.file.clone(),
        r.bonnet.clone(),
        format!("{}", m.dwell_s),
        format!("{}", f.precession_deg),
        format!("{}", f.offset_mm),
        format!("{}", f.spindle_rpm),
        format!("{}", f.inner_pressure_mpa),
        format!("{}", m.centre_x_mm),
        format!("{}", m.centre_y_mm),
        format!("{:?}", m.centre_method).to_lowercase(),
        format!("{}", m.peak_rate_nm_per_s),
        format!("{}", m.volume_rate_nm_mm2_per_s),
        format!("{}", m.fwhm_x_mm),
        format!("{}", m.fwhm_y_mm),
        format!("{}", m.asymmetry_x),
        format!("{}", m.asymmetry_y),
        format!("{}", m.centroid_offset_mm),
        format!("{}", m.region_rms_nm),
        format!("{}", m.region_pv_nm),
        format!("{}", m.noise_rms_nm),
        opt(p.map(|p| p.peak_rate_nm_per_s)),
        opt(p.map(|p| p.volume_rate_nm_mm2_per_s)),
        opt(p.map(|p| p.fwhm_x_mm)),
        opt(p.map(|p| p.region_rms_nm)),
    ]
}

/// `report.json` of a sweep read from `manifest`.
pub fn json_out<'a>(manifest: &Path, rep: &'a SweepReport) -> JsonOut<'a> {
    JsonOut {
        manifest: manifest.display().to_string(),
        conventions: conventions().into_iter().collect(),
        report: rep,
    }
}

/// `spots.csv`: one row per spot, measured and predicted metrics.
pub fn spots_csv(rep: &SweepReport) -> Result<Vec<u8>, String> {
    let rows: Vec<Vec<String>> = rep.spots.iter().map(spot_row).collect();
    csv_bytes(&SPOT_COLUMNS, &rows)
}

/// `trends.csv`: factor, metric, bonnet, level, n, measured, predicted.
pub fn trends_csv(rep: &SweepReport) -> Result<Vec<u8>, String> {
    let mut trows = Vec::new();
    for t in &rep.trends {
        for l in &t.lines {
            for p in &l.points {
                trows.push(vec![
                    t.factor.key().to_string(),
                    t.metric.key().to_string(),
                    l.bonnet.clone(),
                    format!("{}", p.level),
                    p.n.to_string(),
                    format!("{}", p.measured),
                    p.predicted.map(|v| format!("{v}")).unwrap_or_default(),
                ]);
            }
        }
    }
    let th = [
        "factor",
        "metric",
        "bonnet",
        "level",
        "n",
        "measured",
        "predicted",
    ];
    csv_bytes(&th, &trows)
}

pub fn render_html(
    manifest: &Path,
    rep: &SweepReport,
    analyses: &[SpotAnalysis],
    models: &[(String, String, String)],
) -> Result<String, String> {
    let mut page = Page::new("Fixed-point (spot) polishing sweep");
    page.paragraph(&format!(
        "Manifest {}: {} spots, bonnets {}; reference bonnet \"{}\". Sweeps found: {}. Baseline (most frequent value of each factor): precession {} deg, offset {} mm, spindle {} rpm, inner pressure {} MPa. bonnetlab {}.",
        manifest.display(),
        rep.spots.len(),
        rep.fits.iter().map(|f| f.bonnet.as_str()).collect::<Vec<_>>().join(", "),
        rep.reference_bonnet,
        if rep.sweeps.is_empty() { "none (no factor takes two levels)".to_string() } else { rep.sweeps.iter().map(|f| f.key()).collect::<Vec<_>>().join(", ") },
        rep.baseline.precession_deg, rep.baseline.offset_mm, rep.baseline.spindle_rpm, rep.baseline.inner_pressure_mpa,
        env!("CARGO_PKG_VERSION"),
    ));

    // Optimisation degree first: it is the paper's headline number.
    page.section("Optimisation degree between bonnets");
    let mut t = Table::new([
        "sweep",
        "metric",
        "bonnet vs reference",
        "reference range",
        "bonnet range",
        "reference mean",
        "bonnet mean",
        "degree",
        "mean of per-level degrees",
    ]);
    for o in &rep.optimisation {
        if !matches!(o.metric, TrendMetric::RegionRmsNm | TrendMetric::RegionPvNm) {
            continue;
        }
        t.row([
            o.factor.label().to_string(),
            o.metric.label().to_string(),
            format!("{} vs {}", o.bonnet, o.reference),
            format!("{}-{}", g(o.reference_range.0), g(o.reference_range.1)),
            format!("{}-{}", g(o.bonnet_range.0), g(o.bonnet_range.1)),
            g(o.reference_mean),
            g(o.bonnet_mean),
            format!("{} %", fixed(100.0 * o.degree, 2)),
            format!("{} %", fixed(100.0 * o.mean_level_degree, 2)),
        ]);
    }
    page.table(&t);
    page.note("Degree = (mean_ref - mean_bonnet) / mean_ref over the levels both bonnets have; positive = the bonnet leaves a lower value. The paper (Figure 18) prints the degree but not its formula; its numbers sit near this definition (precession RMS from range midpoints: 51.0 % against its 50.1 %). The RMS / PV of a spot is dominated by the spot's own depth, so a lower value also means less removal: read it with the removal rates below.");

    for f in &rep.sweeps {
        page.section(&format!("Sweep: {}", f.label()));
        for t in rep.trends.iter().filter(|t| t.factor == *f) {
            let mut plot = LinePlot::new(
                format!("{} vs {}", t.metric.label(), f.label()),
                f.label(),
                t.metric.label(),
            )
            .size(640, 380);
            for (k, l) in t.lines.iter().enumerate() {
                let c = PALETTE[k % PALETTE.len()];
                let x: Vec<f64> = l.points.iter().map(|p| p.level).collect();
                plot = plot.series(
                    Series::new(
                        format!("{} measured", l.bonnet),
                        x.clone(),
                        l.points.iter().map(|p| p.measured).collect(),
                    )
                    .colour(c),
                );
                if l.points.iter().all(|p| p.predicted.is_some()) {
                    plot = plot.series(
                        Series::new(
                            format!("{} model", l.bonnet),
                            x,
                            l.points
                                .iter()
                                .map(|p| p.predicted.unwrap_or(f64::NAN))
                                .collect(),
                        )
                        .colour(c)
                        .dashed(),
                    );
                }
            }
            let svg = plot.to_svg().map_err(|e| e.to_string())?;
            page.svg(
                &svg,
                &format!(
                    "{}: measured (solid) and fitted model (dashed), one line per bonnet.",
                    t.metric.label()
                ),
            );
        }
        let mut header = vec![f.label().to_string()];
        let metrics = rep
            .trends
            .iter()
            .filter(|t| t.factor == *f)
            .collect::<Vec<_>>();
        let bonnets: Vec<String> = metrics
            .first()
            .map(|t| t.lines.iter().map(|l| l.bonnet.clone()).collect())
            .unwrap_or_default();
        for b in &bonnets {
            for t in &metrics {
                header.push(format!("{b}: {} (model)", t.metric.key()));
            }
        }
        let mut table = Table::new(header).caption(format!(
            "Trend table, {} (mean over repeats; model in brackets)",
            f.label()
        ));
        let mut levels: Vec<f64> = metrics
            .iter()
            .flat_map(|t| {
                t.lines
                    .iter()
                    .flat_map(|l| l.points.iter().map(|p| p.level))
            })
            .collect();
        levels.sort_by(f64::total_cmp);
        levels.dedup();
        for lv in levels {
            let mut row = vec![g(lv)];
            for b in &bonnets {
                for t in &metrics {
                    let cell = t
                        .lines
                        .iter()
                        .find(|l| &l.bonnet == b)
                        .and_then(|l| l.points.iter().find(|p| p.level == lv))
                        .map(|p| match p.predicted {
                            Some(q) => format!("{} ({})", g(p.measured), g(q)),
                            None => g(p.measured),
                        })
                        .unwrap_or_else(|| "-".into());
                    row.push(cell);
                }
            }
            table.row(row);
        }
        page.table(&table);
    }

    page.section("Fitted bonnet models");
    let mut t = Table::new([
        "bonnet",
        "radius (mm)",
        "Preston k (nm/(MPa mm))",
        "k (m^2/N)",
        "effective modulus (MPa)",
        "pressure exponent",
        "fitted",
        "held",
        "rel. std. errors",
        "rms log residual",
        "baseline peak rate (nm/s)",
        "baseline FWHM (mm)",
    ]);
    for f in &rep.fits {
        match &f.fit {
            Some(fit) => {
                let bp = f.baseline_prediction.as_ref();
                t.row([
                    f.bonnet.clone(),
                    g(fit.model.radius_mm),
                    g(fit.model.preston_nm_per_mpa_mm),
                    g(fit.model.preston_nm_per_mpa_mm * 1e-12),
                    g(fit.model.modulus_mpa),
                    g(fit.model.pressure_exponent),
                    fit.fitted.join(", "),
                    fit.held.join("; "),
                    fit.rel_std_err
                        .iter()
                        .map(|v| format!("{} %", fixed(100.0 * v, 2)))
                        .collect::<Vec<_>>()
                        .join(", "),
                    g(fit.rms_log_residual),
                    bp.map(|p| g(p.peak_rate_nm_per_s)).unwrap_or_default(),
                    bp.map(|p| g(p.fwhm_x_mm)).unwrap_or_default(),
                ]);
            }
            None => {
                t.row([
                    f.bonnet.clone(),
                    format!("no fit: {}", f.error.clone().unwrap_or_default()),
                ]);
            }
        }
    }
    page.table(&t);
    for (b, name, text) in models {
        page.subsection(&format!("{name} (bonnet {b})"));
        page.preformatted(text);
    }

    page.section("Spots");
    let mut t = Table::new([
        "file",
        "bonnet",
        "prec. (deg)",
        "offset (mm)",
        "spindle (rpm)",
        "p (MPa)",
        "dwell (s)",
        "centre (mm)",
        "peak rate (nm/s)",
        "volume rate (nm mm^2/s)",
        "FWHM X / Y (mm)",
        "asym. X / Y",
        "centroid offset (mm)",
        "region RMS (nm)",
        "region PV (nm)",
        "noise (nm)",
    ]);
    for r in &rep.spots {
        let m = &r.metrics;
        t.row([
            r.file.clone(),
            r.bonnet.clone(),
            g(r.factors.precession_deg),
            g(r.factors.offset_mm),
            g(r.factors.spindle_rpm),
            g(r.factors.inner_pressure_mpa),
            g(m.dwell_s),
            format!("{}, {}", g(m.centre_x_mm), g(m.centre_y_mm)),
            g(m.peak_rate_nm_per_s),
            g(m.volume_rate_nm_mm2_per_s),
            format!("{} / {}", g(m.fwhm_x_mm), g(m.fwhm_y_mm)),
            format!("{} / {}", g(m.asymmetry_x), g(m.asymmetry_y)),
            g(m.centroid_offset_mm),
            g(m.region_rms_nm),
            g(m.region_pv_nm),
            g(m.noise_rms_nm),
        ]);
    }
    page.table(&t);
    page.subsection("Removal maps (background removed, positive = removed)");
    for (r, a) in rep.spots.iter().zip(analyses) {
        let opts = MapOptions {
            width: 300,
            height: 260,
            ..MapOptions::new(format!("{} ({})", r.file, r.bonnet), "nm")
        };
        let png = false_colour_png_with(&a.removal, &opts).map_err(|e| e.to_string())?;
        page.png(
            &png,
            &r.file,
            &format!(
                "{}: {} {} = {}",
                r.file,
                r.bonnet,
                sweep_label(r),
                sweep_value(r)
            ),
        );
    }

    page.section("Conventions");
    let mut conv = String::new();
    for (k, v) in conventions() {
        let _ = writeln!(conv, "{k}: {v}");
    }
    page.preformatted(&conv);
    Ok(page.render())
}

fn sweep_label(r: &SpotRecord) -> &'static str {
    r.sweep.map(|f| f.key()).unwrap_or("offset_mm")
}

fn sweep_value(r: &SpotRecord) -> String {
    g(r.factors.get(r.sweep.unwrap_or(Factor::OffsetMm)))
}
