//! `bonnetlab psd FILE [--axis x|y|both] [--window ...] [--pitch-mm P] [--remove TERMS] [--json]
//! [--csv OUT] [--plot OUT.png|OUT.svg]` (contract: shared/spec/interfaces.md).
//!
//! Reads one map, removes the form terms jointly (default piston, tilt), and prints the
//! ONE-SIDED 1-D PSDs along X (rows) and Y (columns) in nm^2 mm with their band RMS values;
//! with `--pitch-mm`, the ripple check at f0 = 1/pitch in the Y PSD. Every printed number
//! carries its band, window and removed terms; a number that cannot be computed (a band outside
//! the PSD's range, a pitch the field cannot resolve) is absent (JSON null) with its reason.
//! The per-axis `msf` values integrate the windowed PSD (labelled `band_method`); the band RMS
//! of the map itself (areal split, adding up to Sq) is the top-level `bands` object.
//! `--json` prints one JSON object (stable field order, no time stamps); `--csv` writes the
//! spectra in long form; `--plot` draws both PSDs log-log with the grating frequency and its
//! harmonics marked.

use std::path::{Path, PathBuf};

use bonnetlab_spectrum::{Detrend, LimitLine, PsdOptions, Window, MSF_DEFAULT_PER_MM};
use bonnetlab_surface::Term;

use super::CliError;
use crate::pipeline::psd::{psd, Axis, Options};
use crate::report;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum AxisArg {
    X,
    Y,
    Both,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DetrendArg {
    Mean,
    Linear,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Convention {
    /// Gwyddion: W1(K), K = 2 pi f rad/mm, W1 = P1 / (4 pi).
    Gwyddion,
    /// SurfaceTopography: C1D(q), q = 2 pi f rad/mm, C1D = P1 / 2.
    Surfacetopography,
}

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Map file; the format is detected from the content.
    pub file: PathBuf,
    /// Which 1-D PSDs to report: along X (rows), along Y (columns, the raster feed), or both.
    #[arg(long, value_enum, default_value = "both")]
    pub axis: AxisArg,
    /// Data window: hann (periodic, default), none, tukey, blackman, welch.
    #[arg(long, default_value = "hann")]
    pub window: String,
    /// Taper fraction of the Tukey window (0 = none, 1 = Hann).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.5, value_parser = super::num::non_negative)]
    pub tukey_alpha: f64,
    /// Raster pitch (grating spacing) in mm: adds the ripple check at f0 = 1/pitch along Y.
    #[arg(long, allow_negative_numbers = true, value_parser = super::num::positive)]
    pub pitch_mm: Option<f64>,
    /// Comma list of form terms removed jointly from the whole map before the PSDs.
    #[arg(long, default_value = "piston,tilt")]
    pub remove: String,
    /// Per-segment detrend after the global form removal.
    #[arg(long, value_enum, default_value = "mean")]
    pub detrend: DetrendArg,
    /// Longest dropout (pixels) inside a line that is filled by linear interpolation.
    #[arg(long, allow_negative_numbers = true, default_value_t = 5, value_parser = super::num::pixels)]
    pub max_gap_px: usize,
    /// Shortest line segment analysed, pixels. Every segment at least this long is used, each
    /// from its own first unbiased bin (ceil(b N / m) for a segment of m of N samples) up. A
    /// value longer than the lines means whole lines only (it is taken as the line's length).
    #[arg(long, default_value_t = 8)]
    pub min_segment_px: usize,
    /// Also skip segments shorter than this fraction of the line (0 = use every segment; 0.5
    /// reproduces the segment choice before issue #19, for comparisons).
    #[arg(long, allow_negative_numbers = true, default_value_t = 0.0)]
    pub min_segment_fraction: f64,
    /// Also compute the 2-D PSD's radial forms (JSON `radial`: azimuthal average, two-sided
    /// nm^2 mm^2, and azimuthally integrated, nm^2 mm).
    #[arg(long)]
    pub radial: bool,
    /// Highest ripple harmonic considered (0 to 1000).
    #[arg(long, allow_negative_numbers = true, default_value_t = 5, value_parser = super::num::harmonics)]
    pub harmonics: usize,
    /// Prominence (dB over the flanking median) at which the ripple counts as detected.
    #[arg(long, allow_negative_numbers = true, default_value_t = bonnetlab_spectrum::PROMINENCE_THRESHOLD_DB, value_parser = super::num::finite)]
    pub prominence_threshold_db: f64,
    /// MSF band edges F1,F2 in mm^-1 (default 1/33,1/0.12 i.e. periods 33 mm to 0.12 mm).
    #[arg(long, value_name = "F1,F2")]
    pub msf_band: Option<String>,
    /// ISO 10110-8 style limit line A,B[,F1,F2]: PSD(f) <= A f^-B (f in mm^-1) over [F1, F2].
    #[arg(long, value_name = "A,B[,F1,F2]")]
    pub limit: Option<String>,
    /// The limit line's A refers to a two-sided PSD (default: one-sided, like our PSD).
    #[arg(long)]
    pub limit_two_sided: bool,
    /// Also give the PSDs in a peer tool's convention (JSON `converted`, extra CSV columns).
    #[arg(long, value_enum)]
    pub convention: Option<Convention>,
    /// Pixel size in mm for a map whose file says it is unknown (square pixels unless
    /// --pixel-mm-y is given).
    #[arg(long, allow_negative_numbers = true, value_name = "MM")]
    pub pixel_mm: Option<f64>,
    /// Pixel size along Y (rows) in mm when it differs from --pixel-mm.
    #[arg(
        long,
        allow_negative_numbers = true,
        value_name = "MM",
        requires = "pixel_mm"
    )]
    pub pixel_mm_y: Option<f64>,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    pub json: bool,
    /// Write the spectra as CSV (axis,freq_per_mm,psd_nm2_mm; with --convention also
    /// q_rad_per_mm and gwyddion_w1_nm2_mm or surfacetopography_c1d_nm2_mm).
    #[arg(long, value_name = "OUT")]
    pub csv: Option<PathBuf>,
    /// Draw the PSDs log-log (X and Y, grating frequency and harmonics marked): .png or .svg.
    #[arg(long, value_name = "OUT")]
    pub plot: Option<PathBuf>,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let file = args.file.as_path();
    let opts = options(args)?;
    let msf = parse_pair(args.msf_band.as_deref(), "--msf-band")?.unwrap_or(MSF_DEFAULT_PER_MM);
    let limit = parse_limit(args)?;
    if let Some(p) = &args.plot {
        plot_kind(p)?;
    }
    let opts = Options {
        axis: match args.axis {
            AxisArg::X => Axis::X,
            AxisArg::Y => Axis::Y,
            AxisArg::Both => Axis::Both,
        },
        psd: opts,
        pitch_mm: args.pitch_mm,
        harmonics: args.harmonics,
        prominence_threshold_db: args.prominence_threshold_db,
        msf_band: msf,
        limit,
        radial: args.radial,
        convention: args.convention.map(|c| match c {
            Convention::Gwyddion => crate::pipeline::psd::Convention::Gwyddion,
            Convention::Surfacetopography => crate::pipeline::psd::Convention::Surfacetopography,
        }),
        pixel_mm: super::compare::pixel_size(args.pixel_mm, args.pixel_mm_y)?,
    };
    let report = psd(file, &opts)?;
    for n in &report.notes {
        eprintln!("note: {n}");
    }
    // The CSV and the plot are published together or not at all.
    let mut outputs = super::Outputs::default();
    if let Some(out) = &args.csv {
        let text = report::psd::csv_text(&report);
        outputs.file(out, text.as_bytes())?;
    }
    if let Some(out) = &args.plot {
        let bytes = report::psd::plot_bytes(
            &report,
            args.pitch_mm,
            args.harmonics,
            plot_kind(out)? == "svg",
        )
        .map_err(|e| CliError::processing(out, e))?;
        outputs.file(out, &bytes)?;
    }
    outputs.publish()?;
    let text = if args.json {
        serde_json::to_string(&report)
            .map_err(|e| CliError::processing(file, format!("JSON: {e}")))?
    } else {
        report::psd::summary(&report)
    };
    super::println_stdout(&text)
}

fn options(args: &Args) -> Result<PsdOptions, CliError> {
    let window = Window::parse(&args.window, args.tukey_alpha)
        .map_err(|e| CliError::usage(format!("--window: {e}")))?;
    let remove =
        Term::parse_list(&args.remove).map_err(|e| CliError::usage(format!("--remove: {e}")))?;
    Ok(PsdOptions {
        window,
        remove,
        detrend: match args.detrend {
            DetrendArg::Mean => Detrend::Mean,
            DetrendArg::Linear => Detrend::Linear,
        },
        max_gap_px: args.max_gap_px,
        min_segment_px: args.min_segment_px,
        min_segment_fraction: if (0.0..=1.0).contains(&args.min_segment_fraction) {
            args.min_segment_fraction
        } else {
            return Err(CliError::usage(format!(
                "--min-segment-fraction must lie in [0, 1], got {}",
                args.min_segment_fraction
            )));
        },
    })
}

fn parse_numbers(s: &str, flag: &str) -> Result<Vec<f64>, CliError> {
    s.split(',')
        .map(|t| {
            let t = t.trim();
            let v = if let Some(d) = t.strip_prefix("1/") {
                d.parse::<f64>().map(|d| 1.0 / d)
            } else {
                t.parse::<f64>()
            };
            v.ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| CliError::usage(format!("{flag}: '{t}' is not a number")))
        })
        .collect()
}

pub(crate) fn parse_pair(s: Option<&str>, flag: &str) -> Result<Option<(f64, f64)>, CliError> {
    let Some(s) = s else { return Ok(None) };
    let v = parse_numbers(s, flag)?;
    match v.as_slice() {
        [a, b] if *a >= 0.0 && b >= a => Ok(Some((*a, *b))),
        _ => Err(CliError::usage(format!(
            "{flag}: expected F1,F2 with 0 <= F1 <= F2, got '{s}'"
        ))),
    }
}

fn parse_limit(args: &Args) -> Result<Option<LimitLine>, CliError> {
    let Some(s) = args.limit.as_deref() else {
        return Ok(None);
    };
    let v = parse_numbers(s, "--limit")?;
    let (a, b, f1, f2) = match v.as_slice() {
        [a, b] => (*a, *b, 0.0, f64::INFINITY),
        [a, b, f1, f2] => (*a, *b, *f1, *f2),
        _ => {
            return Err(CliError::usage(format!(
                "--limit: expected A,B or A,B,F1,F2, got '{s}'"
            )))
        }
    };
    if a.is_nan() || a <= 0.0 || f1 < 0.0 || f2 < f1 {
        return Err(CliError::usage(format!(
            "--limit: need A > 0 and 0 <= F1 <= F2, got '{s}'"
        )));
    }
    Ok(Some(LimitLine {
        a,
        b,
        f1_per_mm: f1,
        f2_per_mm: f2,
        two_sided: args.limit_two_sided,
    }))
}

fn plot_kind(p: &Path) -> Result<&'static str, CliError> {
    match p
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => Ok("png"),
        Some("svg") => Ok("svg"),
        _ => Err(CliError::usage(format!(
            "--plot {}: the name must end in .png or .svg",
            p.display()
        ))),
    }
}
