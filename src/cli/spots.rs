//! `bonnetlab spots MANIFEST --out DIR`: fixed-point (spot) polishing sweeps.
//!
//! Reads the manifest (`bonnetlab_spots::manifest`: TOML or CSV), every spot map it lists
//! (any supported format), measures each spot, fits the bonnet model per bonnet, and writes into
//! DIR (created if missing; every file written whole or not at all):
//! - `report.html`: settings and conventions, per-spot table, removal maps, trend plots (metric
//!   against factor, one solid line per bonnet, the fitted model dashed), trend tables,
//!   optimisation degree, fitted models;
//! - `report.json`: the whole `SweepReport` plus the conventions (fractions, not percent);
//! - `spots.csv`: one row per spot, measured and predicted metrics;
//! - `trends.csv`: factor, metric, bonnet, level, n, measured, predicted;
//! - `model_<bonnet>.toml`: the fitted model as a recipe `[tif] model` table.
//!
//! `bonnetlab spots --make-sample DIR` writes the bundled synthetic sweep (two bonnets, offset
//! swept, MetroPro `.dat` maps and `manifest.toml`) from fixed seeds: the committed
//! `samples/spots/` is its output.
//!
//! Exit codes: 2 for a bad manifest or unreadable map (one line naming the file and the line /
//! key), 1 for a spot that cannot be analysed.

use crate::report::format::fixed;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::CliError;
use crate::report::html::{Page, Table};
use crate::report::maps::{false_colour_png_with, MapOptions};
use crate::report::plot::{LinePlot, Series, PALETTE};
use crate::report::write;
use bonnetlab_io::{read_surface, write_surface, MapFormat};
use bonnetlab_spots::export::model_toml;
use bonnetlab_spots::manifest::parse_manifest;
use bonnetlab_spots::sweep::{measure_entries, SpotRecord};
use bonnetlab_spots::{
    analyse_sweep, generate_spot, BonnetModel, Factor, Factors, FitStart, SpotAnalysis, SpotSpec,
    SweepReport, TrendMetric,
};
use bonnetlab_surface::rng::Rng;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The sweep manifest (TOML, or CSV by extension `.csv`); map paths are relative to it.
    #[arg(required_unless_present = "make_sample")]
    pub manifest: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long, required_unless_present = "make_sample")]
    pub out: Option<PathBuf>,
    /// Pressure profile of the fitted bonnet model: parabolic (default) or hertz.
    #[arg(long, default_value = "parabolic")]
    pub pressure: String,
    /// Starting bonnet radius of the fit, mm.
    #[arg(long, default_value_t = 20.0)]
    pub start_radius_mm: f64,
    /// Effective contact modulus (MPa) used as start, and held when the sweep cannot separate it
    /// from the Preston coefficient (no offset or pressure variation).
    #[arg(long, default_value_t = 2.0)]
    pub modulus_mpa: f64,
    /// Write the bundled synthetic sample sweep (maps + manifest.toml) into this directory
    /// and exit.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["manifest", "out"])]
    pub make_sample: Option<PathBuf>,
}

fn start_of(args: &Args) -> Result<FitStart, CliError> {
    let gamma = match args.pressure.to_ascii_lowercase().as_str() {
        "parabolic" => 1.0,
        "hertz" => 0.5,
        other => {
            return Err(CliError::usage(format!(
                "--pressure: '{other}' is not parabolic or hertz"
            )))
        }
    };
    for (name, v) in [
        ("--start-radius-mm", args.start_radius_mm),
        ("--modulus-mpa", args.modulus_mpa),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CliError::usage(format!(
                "{name}: {v} must be a positive number"
            )));
        }
    }
    Ok(FitStart {
        radius_mm: args.start_radius_mm,
        modulus_mpa: args.modulus_mpa,
        pressure_exponent: gamma,
        ..FitStart::default()
    })
}

pub fn run(args: &Args) -> Result<(), CliError> {
    if let Some(dir) = &args.make_sample {
        return make_sample(dir);
    }
    let (Some(manifest), Some(out)) = (&args.manifest, &args.out) else {
        return Err(CliError::usage("spots: give MANIFEST and --out DIR"));
    };
    let start = start_of(args)?;
    let text = super::read_text_input(manifest, "a spot manifest (TOML or CSV)")?;
    let m = parse_manifest(manifest, &text).map_err(|e| CliError::input(manifest, e))?;
    // Progress on stderr, drawn only on a terminal (reading, measuring, then the model fit,
    // which takes most of the time).
    let bar = indicatif::ProgressBar::with_draw_target(
        Some(m.spots.len() as u64),
        indicatif::ProgressDrawTarget::stderr(),
    );
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {msg} [{bar:30}] {pos}/{len}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_message("reading spot maps");
    let mut maps = Vec::with_capacity(m.spots.len());
    for e in &m.spots {
        let s = read_surface(&e.path).map_err(|err| CliError {
            code: err.exit_code(),
            message: format!("{err} (listed at {} line {})", manifest.display(), e.line),
        })?;
        maps.push(s);
        bar.inc(1);
    }
    bar.set_message("measuring spots and fitting the bonnet TIF models");
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    let measured = measure_entries(&m, &maps).map_err(|(k, err)| {
        let e = &m.spots[k];
        CliError::processing(
            &e.path,
            format!("{err} (listed at {} line {})", manifest.display(), e.line),
        )
    })?;
    let (records, analyses): (Vec<SpotRecord>, Vec<SpotAnalysis>) = measured.into_iter().unzip();
    let n_spots = records.len();
    let report = analyse_sweep(records, &start);
    bar.finish_and_clear();
    write_outputs(out, manifest, &report, &analyses).map_err(|e| CliError {
        code: 2,
        message: e,
    })?;
    println!(
        "spots: wrote {}: {n_spots} spots, {} sweeps, {} trend plots",
        out.join("report.html").display(),
        report.sweeps.len(),
        report.trends.len()
    );
    Ok(())
}

/// The conventions written beside the numbers (JSON and HTML).
fn conventions() -> Vec<(&'static str, &'static str)> {
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

#[derive(Serialize)]
struct JsonOut<'a> {
    manifest: String,
    conventions: std::collections::BTreeMap<&'static str, &'static str>,
    #[serde(flatten)]
    report: &'a SweepReport,
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

fn stem(name: &str) -> String {
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

fn csv_bytes(header: &[&str], rows: &[Vec<String>]) -> Result<Vec<u8>, String> {
    let mut w = csv::Writer::from_writer(Vec::new());
    w.write_record(header).map_err(|e| e.to_string())?;
    for r in rows {
        w.write_record(r).map_err(|e| e.to_string())?;
    }
    w.into_inner().map_err(|e| e.to_string())
}

const SPOT_COLUMNS: [&str; 24] = [
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

fn spot_row(r: &SpotRecord) -> Vec<String> {
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

fn write_outputs(
    dir: &Path,
    manifest: &Path,
    rep: &SweepReport,
    analyses: &[SpotAnalysis],
) -> Result<(), String> {
    let w = |e: write::WriteError| e.to_string();
    let mut set = write::Set::begin(dir).map_err(w)?;
    let json = JsonOut {
        manifest: manifest.display().to_string(),
        conventions: conventions().into_iter().collect(),
        report: rep,
    };
    set.json("report.json", &json).map_err(w)?;
    let rows: Vec<Vec<String>> = rep.spots.iter().map(spot_row).collect();
    set.bytes("spots.csv", &csv_bytes(&SPOT_COLUMNS, &rows)?)
        .map_err(w)?;
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
    set.bytes("trends.csv", &csv_bytes(&th, &trows)?)
        .map_err(w)?;
    let mut models = Vec::new();
    for f in &rep.fits {
        if let Ok(text) = model_toml(f) {
            let name = format!("model_{}.toml", stem(&f.bonnet));
            set.bytes(&name, text.as_bytes()).map_err(w)?;
            models.push((f.bonnet.clone(), name, text));
        }
    }
    let html = render_html(manifest, rep, analyses, &models)?;
    set.bytes("report.html", html.as_bytes()).map_err(w)?;
    set.commit().map_err(w)
}

fn render_html(
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

/// The bundled sample: two bonnets, offset swept 0.2 .. 1.0 mm at the paper's Table 5 settings
/// otherwise, 2-minute spots, 97 x 97 maps at 0.25 mm, 1.5 nm noise, seeded tilt and centre
/// offsets. The suppression bonnet is given a lower Preston coefficient and a softer contact
/// (an assumption for the sample, not a measured fact).
fn make_sample(dir: &Path) -> Result<(), CliError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| CliError::input(dir, format!("cannot create the directory: {e}")))?;
    let bonnets = [
        ("original", BonnetModel::new(20.0, 0.020, 2.0)),
        ("suppression", BonnetModel::new(20.0, 0.015, 1.2)),
    ];
    let mut rng = Rng::new(2024);
    let mut manifest = String::from(
        "# Synthetic fixed-point sweep written by `bonnetlab spots --make-sample` (seeded):\n\
         # two bonnets, offset swept, the paper's Table 5 settings otherwise. Generating models:\n\
         # original R 20 mm, k 0.020 nm/(MPa mm), E 2.0 MPa; suppression R 20 mm, k 0.015, E 1.2;\n\
         # parabolic pressure; 1.5 nm white noise, random tilt and centre offset.\n\
         [defaults]\n\
         dwell_s = 120.0\nprecession_deg = 20.0\nspindle_rpm = 500.0\ninner_pressure_mpa = 0.25\n",
    );
    let mut seed = 100;
    for (name, model) in bonnets {
        for h in [0.2, 0.4, 0.6, 0.8, 1.0] {
            let spec = SpotSpec {
                model,
                factors: Factors {
                    offset_mm: h,
                    ..Factors::PAPER_BASELINE
                },
                dwell_s: 120.0,
                rows: 97,
                cols: 97,
                dx_mm: 0.25,
                dy_mm: 0.25,
                centre_offset_mm: (rng.uniform() - 0.5, rng.uniform() - 0.5),
                piston_nm: 100.0 * (rng.uniform() - 0.5),
                tilt_nm_per_mm: (4.0 * (rng.uniform() - 0.5), 4.0 * (rng.uniform() - 0.5)),
                noise_rms_nm: 1.5,
                seed,
            };
            seed += 1;
            let s = generate_spot(&spec).map_err(|e| CliError::processing(dir, e))?;
            let file = format!("{name}_offset_{h_s}.dat", h_s = fixed(h, 1));
            write_surface(&dir.join(&file), &s, MapFormat::MetroProDat).map_err(|e| CliError {
                code: e.exit_code(),
                message: e.to_string(),
            })?;
            let _ = write!(
                manifest,
                "\n[[spot]]\nfile = \"{file}\"\nbonnet = \"{name}\"\noffset_mm = {h}\n"
            );
        }
    }
    write::bytes(&dir.join("manifest.toml"), manifest.as_bytes()).map_err(|e| CliError {
        code: 2,
        message: e.to_string(),
    })?;
    println!(
        "spots: wrote a sample sweep to {} (manifest.toml and its spot maps)",
        dir.display()
    );
    Ok(())
}
