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

use crate::report::format::fixed;
use std::path::{Path, PathBuf};

use bonnetlab_spectrum::{
    band, band_split, check_limit, psd_x, psd_xy, psd_y, ripple_from_psds, to_gwyddion_w1,
    to_surfacetopography_c1d, ArealBands, BandRms, ConvertedPsd, Detrend, LimitCheck, LimitLine,
    Psd1d, PsdOptions, RadialPsd, Ripple, RippleOptions, SpectrumError, Window, MSF_DEFAULT_PER_MM,
};
use bonnetlab_surface::{Surface, SurfaceError, Term};
use serde::Serialize;

use super::CliError;
use crate::report::plot::{LinePlot, Series};

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
    #[arg(long, default_value_t = 0.5, value_parser = super::num::non_negative)]
    pub tukey_alpha: f64,
    /// Raster pitch (grating spacing) in mm: adds the ripple check at f0 = 1/pitch along Y.
    #[arg(long, value_parser = super::num::positive)]
    pub pitch_mm: Option<f64>,
    /// Comma list of form terms removed jointly from the whole map before the PSDs.
    #[arg(long, default_value = "piston,tilt")]
    pub remove: String,
    /// Per-segment detrend after the global form removal.
    #[arg(long, value_enum, default_value = "mean")]
    pub detrend: DetrendArg,
    /// Longest dropout (pixels) inside a line that is filled by linear interpolation.
    #[arg(long, default_value_t = 5, value_parser = super::num::pixels)]
    pub max_gap_px: usize,
    /// Shortest line segment analysed, pixels. Every segment at least this long is used, each
    /// from its own first unbiased bin (ceil(b N / m) for a segment of m of N samples) up.
    #[arg(long, default_value_t = 8)]
    pub min_segment_px: usize,
    /// Also skip segments shorter than this fraction of the line (0 = use every segment; 0.5
    /// reproduces the segment choice before issue #19, for comparisons).
    #[arg(long, default_value_t = 0.0)]
    pub min_segment_fraction: f64,
    /// Also compute the 2-D PSD's radial forms (JSON `radial`: azimuthal average, two-sided
    /// nm^2 mm^2, and azimuthally integrated, nm^2 mm).
    #[arg(long)]
    pub radial: bool,
    /// Highest ripple harmonic considered (0 to 1000).
    #[arg(long, default_value_t = 5, value_parser = super::num::harmonics)]
    pub harmonics: usize,
    /// Prominence (dB over the flanking median) at which the ripple counts as detected.
    #[arg(long, default_value_t = bonnetlab_spectrum::PROMINENCE_THRESHOLD_DB, value_parser = super::num::finite)]
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
    #[arg(long, value_name = "MM")]
    pub pixel_mm: Option<f64>,
    /// Pixel size along Y (rows) in mm when it differs from --pixel-mm.
    #[arg(long, value_name = "MM", requires = "pixel_mm")]
    pub pixel_mm_y: Option<f64>,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    pub json: bool,
    /// Write the spectra as CSV (axis,freq_per_mm,psd_nm2_mm[,q_rad_per_mm,converted_nm2_mm]).
    #[arg(long, value_name = "OUT")]
    pub csv: Option<PathBuf>,
    /// Draw the PSDs log-log (X and Y, grating frequency and harmonics marked): .png or .svg.
    #[arg(long, value_name = "OUT")]
    pub plot: Option<PathBuf>,
}

/// One axis in the JSON output (`freq_per_mm`, `psd_nm2_mm` are the contract).
#[derive(Debug, Clone, Serialize)]
pub struct AxisReport {
    pub freq_per_mm: Vec<f64>,
    /// ONE-SIDED, nm^2 mm.
    pub psd_nm2_mm: Vec<f64>,
    pub df_per_mm: f64,
    pub sidedness: &'static str,
    pub window: Window,
    pub enbw_bins: f64,
    pub removed: Vec<Term>,
    pub n_lines: usize,
    pub n_segments: usize,
    /// Bins below this index are biased by detrending.
    pub biased_bins: usize,
    /// RMS over all unbiased bins up to Nyquist, nm (null with `msf.reason`-style text in
    /// `rms_unbiased_reason` when the PSD has no unbiased bin).
    pub rms_unbiased_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rms_unbiased_reason: Option<String>,
    /// PSD-integrated MSF band RMS (bin sums of this windowed PSD; not the map's band RMS).
    pub msf: BandRms,
    pub band_method: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub limit: Option<LimitCheck>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub converted: Option<ConvertedPsd>,
}

/// The radial PSD in the JSON output.
#[derive(Debug, Clone, Serialize)]
pub struct RadialReport {
    pub window: Window,
    /// Invalid pixels enter the 2-D FFT as 0 after the mean is removed; the normalisation uses
    /// the window energy over valid pixels only.
    pub masking: &'static str,
    #[serde(flatten)]
    pub psd: RadialPsd,
}

/// The JSON object printed by `psd --json`.
#[derive(Debug, Clone, Serialize)]
pub struct PsdReport {
    pub file: String,
    pub format: String,
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: f64,
    pub dy_mm: f64,
    pub window: Window,
    pub enbw_bins: f64,
    pub removed: Vec<Term>,
    pub detrend: Detrend,
    pub max_gap_px: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub x: Option<AxisReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub y: Option<AxisReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple: Option<Ripple>,
    /// With `--pitch-mm` on a map that cannot resolve the pitch: why `ripple` is absent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ripple_reason: Option<String>,
    /// With `--radial`: the radial forms of the 2-D PSD (same window and removed terms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radial: Option<RadialReport>,
    /// Band RMS of the map itself over the MSF edges (figure / MSF / fine, areal split; they
    /// add up to the RMS after `removed`).
    pub bands: ArealBands,
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let file = args.file.as_path();
    let opts = options(args)?;
    let msf = parse_pair(args.msf_band.as_deref(), "--msf-band")?.unwrap_or(MSF_DEFAULT_PER_MM);
    let limit = parse_limit(args)?;
    if let Some(p) = &args.plot {
        plot_kind(p)?;
    }
    let mut surface = read_map(file)?;
    if let Some((px, py)) = super::compare::pixel_size(args.pixel_mm, args.pixel_mm_y)? {
        surface.dx_mm = Some(surface.dx_mm.unwrap_or(px));
        surface.dy_mm = Some(surface.dy_mm.unwrap_or(py));
    }
    let report = analyse(&surface, file, args, &opts, msf, limit.as_ref())?;
    if let Some(out) = &args.csv {
        write_csv(out, &report)?;
    }
    if let Some(out) = &args.plot {
        write_plot(out, &report, args.pitch_mm, args.harmonics)?;
    }
    let text = if args.json {
        serde_json::to_string(&report)
            .map_err(|e| CliError::processing(file, format!("JSON: {e}")))?
    } else {
        summary(&report)
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

/// Reads a map through `bonnetlab_io`, keeping the reader's exit code and one-line message.
fn read_map(file: &Path) -> Result<Surface, CliError> {
    bonnetlab_io::read_surface(file).map_err(|e| {
        let msg = e.to_string();
        let shown = file.display().to_string();
        let message = if msg.contains(&shown) {
            msg
        } else {
            format!("{shown}: {msg}")
        };
        CliError {
            code: e.exit_code(),
            message: message.replace(['\n', '\r'], " "),
        }
    })
}

fn spectrum_error(file: &Path, e: SpectrumError) -> CliError {
    match e {
        SpectrumError::Surface(SurfaceError::NoValidPixel)
        | SpectrumError::Surface(SurfaceError::TooFewPixels { .. })
        | SpectrumError::Surface(SurfaceError::Singular(_))
        | SpectrumError::NoUsableLine { .. }
        | SpectrumError::TooSmall(_) => CliError::processing(file, e),
        _ => CliError::input(file, e),
    }
}

fn analyse(
    s: &Surface,
    file: &Path,
    args: &Args,
    opts: &PsdOptions,
    msf: (f64, f64),
    limit: Option<&LimitLine>,
) -> Result<PsdReport, CliError> {
    let (dx, dy) = s
        .pixel_mm("the PSD")
        .map_err(|e| CliError::input(file, format!("{e} (use --pixel-mm)")))?;
    let err = |e| spectrum_error(file, e);
    let need_x = args.axis != AxisArg::Y || args.pitch_mm.is_some();
    let need_y = args.axis != AxisArg::X || args.pitch_mm.is_some();
    // One form fit for both axes.
    let (x, y) = match (need_x, need_y) {
        (true, true) => {
            let (x, y) = psd_xy(s, opts).map_err(err)?;
            (Some(x), Some(y))
        }
        (true, false) => (Some(psd_x(s, opts).map_err(err)?), None),
        _ => (None, Some(psd_y(s, opts).map_err(err)?)),
    };
    let removed = x
        .as_ref()
        .or(y.as_ref())
        .map(|p| p.removed.clone())
        .unwrap_or_default();
    let (ripple, ripple_reason) = match (args.pitch_mm, &x, &y) {
        (Some(p), Some(px), Some(py)) => {
            let ropts = RippleOptions {
                harmonics: args.harmonics,
                prominence_threshold_db: args.prominence_threshold_db,
            };
            match ripple_from_psds(px, py, p, &ropts) {
                Ok(r) => (Some(r), None),
                Err(e @ SpectrumError::NotResolvable(_)) => (None, Some(e.to_string())),
                Err(e) => return Err(err(e)),
            }
        }
        _ => (None, None),
    };
    let bands = band_split(s, &opts.remove, msf).map_err(err)?;
    let radial = if args.radial {
        Some(RadialReport {
            window: opts.window,
            masking: "invalid pixels are 0 after mean removal; normalised by the window \
                      energy over the valid pixels",
            psd: bonnetlab_spectrum::psd_2d(s, opts).map_err(err)?.radial(),
        })
    } else {
        None
    };
    let axis_report = |p: &Psd1d| -> Result<AxisReport, CliError> {
        let nyq = p.freq_per_mm.last().copied().unwrap_or(0.0);
        let all = band(p, 0.0, nyq).map_err(err)?;
        Ok(AxisReport {
            freq_per_mm: p.freq_per_mm.clone(),
            psd_nm2_mm: p.psd_nm2_mm.clone(),
            df_per_mm: p.df_per_mm,
            sidedness: "one-sided",
            window: p.window,
            enbw_bins: p.enbw_bins,
            removed: p.removed.clone(),
            n_lines: p.n_lines,
            n_segments: p.n_segments,
            biased_bins: p.biased_bins,
            rms_unbiased_nm: all.rms_nm,
            rms_unbiased_reason: all.reason,
            msf: band(p, msf.0, msf.1).map_err(err)?,
            band_method: "PSD-integrated: bin sums of this one-sided windowed PSD over the \
                          unbiased bins in the band (a PSD quantity, not the map's band RMS)",
            // An open upper edge means "up to Nyquist".
            limit: limit
                .map(|l| {
                    check_limit(
                        p,
                        &LimitLine {
                            f2_per_mm: l.f2_per_mm.min(nyq),
                            ..*l
                        },
                    )
                })
                .transpose()
                .map_err(err)?,
            converted: args.convention.map(|c| match c {
                Convention::Gwyddion => to_gwyddion_w1(p),
                Convention::Surfacetopography => to_surfacetopography_c1d(p),
            }),
        })
    };
    let show_x = args.axis != AxisArg::Y;
    let show_y = args.axis != AxisArg::X;
    let xr = match (&x, show_x) {
        (Some(p), true) => Some(axis_report(p)?),
        _ => None,
    };
    let yr = match (&y, show_y) {
        (Some(p), true) => Some(axis_report(p)?),
        _ => None,
    };
    // Lines of X when X is reported, else of Y (at least one axis is always computed).
    let enbw = xr
        .as_ref()
        .or(yr.as_ref())
        .map(|a| a.enbw_bins)
        .unwrap_or_else(|| opts.window.enbw_bins(s.cols()));
    Ok(PsdReport {
        file: file.display().to_string(),
        format: s.provenance.format.clone(),
        rows: s.rows(),
        cols: s.cols(),
        dx_mm: dx,
        dy_mm: dy,
        window: opts.window,
        enbw_bins: enbw,
        removed,
        detrend: opts.detrend,
        max_gap_px: opts.max_gap_px,
        x: xr,
        y: yr,
        ripple,
        ripple_reason,
        radial,
        bands,
    })
}

fn names(terms: &[Term]) -> String {
    if terms.is_empty() {
        return "none".into();
    }
    serde_json::to_value(terms)
        .ok()
        .and_then(|v| v.as_array().cloned())
        .map(|a| {
            a.iter()
                .filter_map(|t| t.as_str().map(String::from))
                .collect::<Vec<_>>()
                .join(", ")
        })
        .unwrap_or_default()
}

fn summary(r: &PsdReport) -> String {
    let mut o = String::new();
    let mut line = |s: String| {
        o.push_str(&s);
        o.push('\n');
    };
    line(format!(
        "{} ({}): {} x {} pixels, dx {} mm, dy {} mm",
        r.file,
        r.format,
        r.rows,
        r.cols,
        crate::report::format::f32_value(r.dx_mm),
        crate::report::format::f32_value(r.dy_mm)
    ));
    line(format!("removed: {}; per-segment detrend: {:?}; window: {} (ENBW {} bins); gaps <= {} px interpolated", names(&r.removed), r.detrend, r.window, fixed(r.enbw_bins, 3), r.max_gap_px));
    line("PSDs are one-sided, nm^2 mm; band RMS by bin sums".into());
    for (name, a) in [("X (rows)", &r.x), ("Y (columns)", &r.y)] {
        let Some(a) = a else { continue };
        line(format!(
            "{name}: {} lines, {} segments, df {} mm^-1, first unbiased bin {}",
            a.n_lines,
            a.n_segments,
            fixed(a.df_per_mm, 6),
            a.biased_bins
        ));
        match (a.rms_unbiased_nm, &a.rms_unbiased_reason) {
            (Some(v), _) => line(format!(
                "  PSD-integrated RMS over the unbiased bins: {v_s} nm",
                v_s = fixed(v, 4)
            )),
            (None, why) => line(format!(
                "  PSD-integrated RMS over the unbiased bins: absent ({})",
                why.as_deref().unwrap_or("no unbiased bin")
            )),
        }
        match (a.msf.rms_nm, a.msf.f1_used_per_mm, a.msf.f2_used_per_mm) {
            (Some(v), Some(lo), Some(hi)) => line(format!(
                "  PSD-integrated MSF band [{}, {}] mm^-1 (used [{lo_s}, {hi_s}]): {v_s} nm",
                fixed(a.msf.f1_per_mm, 6),
                fixed(a.msf.f2_per_mm, 6),
                lo_s = fixed(lo, 6),
                hi_s = fixed(hi, 6),
                v_s = fixed(v, 4)
            )),
            _ => line(format!(
                "  PSD-integrated MSF band [{}, {}] mm^-1: absent ({})",
                fixed(a.msf.f1_per_mm, 6),
                fixed(a.msf.f2_per_mm, 6),
                a.msf.reason.as_deref().unwrap_or("not computed")
            )),
        }
        if let Some(l) = &a.limit {
            line(format!(
                "  limit {} f^-{} ({}) over [{}, {}] mm^-1: worst ratio {} at {} mm^-1: {}",
                l.line.a,
                l.line.b,
                l.sidedness,
                crate::report::format::sig(l.line.f1_per_mm, 6),
                crate::report::format::sig(l.line.f2_per_mm, 6),
                fixed(l.worst_ratio, 3),
                fixed(l.worst_freq_per_mm, 4),
                if l.pass { "PASS" } else { "FAIL" }
            ));
        }
    }
    line("band RMS of the map (areal split, adds up to the RMS):".into());
    for l in super::stats::bands_table(&r.bands).lines() {
        line(format!("  {l}"));
    }
    if let Some(why) = &r.ripple_reason {
        line(format!("ripple along Y: absent ({why})"));
    }
    if let Some(rp) = &r.ripple {
        line(format!(
            "ripple along Y at pitch {} mm (f0 {} mm^-1, bands |f - k f0| <= {} mm^-1):",
            rp.pitch_mm,
            fixed(rp.f0_per_mm, 6),
            fixed(rp.band_halfwidth_per_mm, 6)
        ));
        line(format!(
            "  sigma_1 {} nm, sigma_total {} nm, A_eq {} nm, PV_eq {} nm",
            fixed(rp.sigma1_nm, 4),
            fixed(rp.sigma_total_nm, 4),
            fixed(rp.a_eq_nm, 4),
            fixed(rp.pv_eq_nm, 4)
        ));
        line(format!(
            "  {} (prominence over the flanking median)",
            rp.verdict
        ));
        line(format!(
            "  Y/X at f0: {}",
            rp.y_over_x
                .map_or("n/a (no X power in the band)".into(), |v| format!("{v:.3}"))
        ));
        let h: Vec<String> = rp
            .harmonics
            .iter()
            .map(|h| format!("{}f0 {} nm", h.k, fixed(h.sigma_nm, 4)))
            .collect();
        line(format!("  harmonics: {}", h.join(", ")));
    }
    o.trim_end().to_string()
}

fn axis_rows(r: &PsdReport) -> impl Iterator<Item = (&'static str, &AxisReport)> {
    [("x", r.x.as_ref()), ("y", r.y.as_ref())]
        .into_iter()
        .filter_map(|(n, a)| a.map(|a| (n, a)))
}

fn write_csv(out: &Path, r: &PsdReport) -> Result<(), CliError> {
    let mut text = String::new();
    let conv = axis_rows(r)
        .next()
        .and_then(|(_, a)| a.converted.as_ref())
        .map(|c| c.convention);
    match conv {
        Some(c) => text.push_str(&format!(
            "axis,freq_per_mm,psd_nm2_mm,q_rad_per_mm,{}_nm2_mm\n",
            c.replace('-', "_")
        )),
        None => text.push_str("axis,freq_per_mm,psd_nm2_mm\n"),
    }
    for (name, a) in axis_rows(r) {
        for (k, (f, p)) in a.freq_per_mm.iter().zip(&a.psd_nm2_mm).enumerate() {
            match &a.converted {
                Some(c) => text.push_str(&format!(
                    "{name},{f:e},{p:e},{:e},{:e}\n",
                    c.q_rad_per_mm[k], c.values_nm2_mm[k]
                )),
                None => text.push_str(&format!("{name},{f:e},{p:e}\n")),
            }
        }
    }
    bonnetlab_io::atomic::write_atomic(out, text.as_bytes()).map_err(|e| CliError::output(out, &e))
}

fn write_plot(
    out: &Path,
    r: &PsdReport,
    pitch: Option<f64>,
    harmonics: usize,
) -> Result<(), CliError> {
    let mut plot = LinePlot::new(
        format!("1-D PSD ({}, window {})", r.file, r.window),
        "spatial frequency f (mm^-1)",
        "one-sided PSD (nm^2 mm)",
    )
    .log_log();
    for (name, a) in axis_rows(r) {
        // Biased lowest bins are left out of the plot.
        let skip = a.biased_bins;
        plot = plot.series(Series::new(
            if name == "x" {
                "X (along rows)"
            } else {
                "Y (along columns, feed)"
            },
            a.freq_per_mm[skip.min(a.freq_per_mm.len())..].to_vec(),
            a.psd_nm2_mm[skip.min(a.psd_nm2_mm.len())..].to_vec(),
        ));
    }
    // The limit line as tested (on the one-sided PSD: a two-sided A counts twice).
    if let Some(l) = axis_rows(r).find_map(|(_, a)| a.limit.as_ref()) {
        let line = l.line;
        let scale = if line.two_sided { 2.0 } else { 1.0 };
        let mut f: Vec<f64> = axis_rows(r)
            .flat_map(|(_, a)| a.freq_per_mm[a.biased_bins.min(a.freq_per_mm.len())..].iter())
            .copied()
            .filter(|&f| f > 0.0 && f >= line.f1_per_mm && f <= line.f2_per_mm)
            .collect();
        f.sort_by(f64::total_cmp);
        f.dedup();
        let y = f
            .iter()
            .map(|&f| scale * line.a * f.powf(-line.b))
            .collect();
        plot = plot.series(
            Series::new(
                format!(
                    "limit {} f^-{} ({})",
                    crate::report::format::sig(line.a, 6),
                    crate::report::format::sig(line.b, 6),
                    l.sidedness
                ),
                f,
                y,
            )
            .colour((0, 0, 0))
            .dashed(),
        );
    }
    if let Some(p) = pitch {
        plot = plot.grating_markers(p, harmonics);
    }
    let bytes = match plot_kind(out)? {
        "svg" => plot.to_svg().map(String::into_bytes),
        _ => plot.to_png(),
    }
    .map_err(|e| CliError::processing(out, e))?;
    bonnetlab_io::atomic::write_atomic(out, &bytes).map_err(|e| CliError::output(out, &e))
}
