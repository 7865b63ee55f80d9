//! `psd`: the ONE-SIDED 1-D PSDs of a map along X (rows) and Y (columns) in nm^2 mm with their
//! band RMS values, the ripple check at f0 = 1/pitch in the Y PSD, the limit-line check, the
//! radial forms of the 2-D PSD, and the band RMS of the map itself (areal split). A number that
//! cannot be computed (a band outside the PSD's range, a pitch the field cannot resolve) is
//! absent with its reason.

use std::path::Path;

use bonnetlab_spectrum::{
    band, band_split, check_limit, psd_x, psd_xy, psd_y, ripple_from_psds, to_gwyddion_w1,
    to_surfacetopography_c1d, ArealBands, BandRms, ConvertedPsd, Detrend, LimitCheck, LimitLine,
    Psd1d, PsdOptions, RadialPsd, Ripple, RippleOptions, SpectrumError, Window,
};
use bonnetlab_surface::{Surface, SurfaceError, Term};
use serde::Serialize;

use super::{read_map, Error};

/// Which 1-D PSDs are reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    X,
    Y,
    Both,
}

/// A peer tool's PSD convention.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Convention {
    /// Gwyddion: W1(K), K = 2 pi f rad/mm, W1 = P1 / (4 pi).
    Gwyddion,
    /// SurfaceTopography: C1D(q), q = 2 pi f rad/mm, C1D = P1 / 2.
    Surfacetopography,
}

/// What `psd` computes besides the PSDs (the `psd` flags, parsed).
#[derive(Debug, Clone)]
pub struct Options {
    /// Which 1-D PSDs to report.
    pub axis: Axis,
    /// Window, removed terms, detrend and gap rules of the PSDs.
    pub psd: PsdOptions,
    /// Raster pitch (mm): the ripple check at f0 = 1/pitch along Y.
    pub pitch_mm: Option<f64>,
    /// Highest ripple harmonic considered.
    pub harmonics: usize,
    /// Prominence (dB over the flanking median) at which the ripple counts as detected.
    pub prominence_threshold_db: f64,
    /// MSF band edges, mm^-1.
    pub msf_band: (f64, f64),
    /// Limit line checked against each PSD.
    pub limit: Option<LimitLine>,
    /// Also the radial forms of the 2-D PSD.
    pub radial: bool,
    /// Also the PSDs in a peer tool's convention.
    pub convention: Option<Convention>,
    /// Pixel size (X, Y) in mm for a map whose file does not give it.
    pub pixel_mm: Option<(f64, f64)>,
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
    /// Notes for the user (stderr, not the JSON): a `--pixel-mm` the file's own pixel size
    /// overrides.
    #[serde(skip)]
    pub notes: Vec<String>,
}

/// Reads a map and computes its PSD report.
pub fn psd(file: &Path, opts: &Options) -> Result<PsdReport, Error> {
    let mut surface = read_map(file)?;
    let note = super::fill_pixel_size(&mut surface, opts.pixel_mm, file);
    let mut report = analyse(&surface, file, opts)?;
    report.notes.extend(note);
    Ok(report)
}

fn spectrum_error(file: &Path, e: SpectrumError) -> Error {
    match e {
        SpectrumError::Surface(SurfaceError::NoValidPixel)
        | SpectrumError::Surface(SurfaceError::TooFewPixels { .. })
        | SpectrumError::Surface(SurfaceError::Singular(_))
        | SpectrumError::NoUsableLine { .. }
        | SpectrumError::TooSmall(_) => Error::processing(file, e),
        _ => Error::input(file, e),
    }
}

/// The PSD report of a map already read (`file` names it in errors and in the report).
pub fn analyse(s: &Surface, file: &Path, args: &Options) -> Result<PsdReport, Error> {
    let opts = &args.psd;
    let msf = args.msf_band;
    let limit = args.limit.as_ref();
    let (dx, dy) = s
        .pixel_mm("the PSD")
        .map_err(|e| Error::input(file, format!("{e} (use --pixel-mm)")))?;
    let err = |e| spectrum_error(file, e);
    let need_x = args.axis != Axis::Y || args.pitch_mm.is_some();
    let need_y = args.axis != Axis::X || args.pitch_mm.is_some();
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
    let axis_report = |p: &Psd1d| -> Result<AxisReport, Error> {
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
    let show_x = args.axis != Axis::Y;
    let show_y = args.axis != Axis::X;
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
        notes: Vec::new(),
    })
}
