//! `bonnetlab stats FILE [--remove TERMS] [--json] [--pvr] [--bands [F1,F2]]` (contract:
//! shared/spec/interfaces.md).
//!
//! Reads one map (format detected by content), removes the requested terms jointly, and prints
//! the height parameters of the residual over the valid pixels: a JSON object with `--json`
//! (stable field order, no time stamps), a small table otherwise. With `--bands`, also the
//! figure / MSF / fine band RMS of the same residual (`bonnetlab_spectrum::band_split`: areal
//! Gaussian filters, bands that add up to Sq exactly; a band the map cannot resolve is null
//! with a reason).

use std::path::{Path, PathBuf};

use bonnetlab_spectrum::{band_split, ArealBands, BAND_EDGES_DEFAULT_PER_MM};
use bonnetlab_surface::{
    height_stats, pvr, remove_terms, HeightStats, Surface, SurfaceError, Term, PVR_SET,
};
use serde::Serialize;

use super::CliError;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Map file (.dat, .asc, .xyz, .datx, .csv, .exr); the format is detected from the content.
    pub file: PathBuf,
    /// Comma list of form terms removed jointly before the statistics: piston, tilt, power,
    /// zernikeN (Fringe Z1..ZN, N <= 37, circular apertures), legendreD (total degree <= D,
    /// rectangles), or none.
    #[arg(long, default_value = "piston")]
    pub remove: String,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Also compute PVr (Evans 2008: PV of a 37-term Fringe Zernike fit + 3 x residual RMS).
    #[arg(long)]
    pub pvr: bool,
    /// Band RMS: figure below F1, MSF from F1 to F2, fine above F2 (cycles/mm; `1/33` style
    /// allowed). Without a value: 1/33,1/0.12 (periods 33 mm and 0.12 mm, the large-optics
    /// MSF convention of shared/spec/metrology.md).
    #[arg(long, value_name = "F1,F2", num_args = 0..=1, default_missing_value = "default")]
    pub bands: Option<String>,
}

/// The JSON object printed by `stats --json` (field names are the CLI contract).
#[derive(Debug, Clone, Serialize)]
pub struct StatsReport {
    pub file: String,
    pub format: String,
    pub rows: usize,
    pub cols: usize,
    pub dx_mm: Option<f64>,
    pub dy_mm: Option<f64>,
    pub valid: usize,
    pub removed: Vec<Term>,
    pub pv_nm: f64,
    pub rms_nm: f64,
    pub sa_nm: f64,
    pub sp_nm: f64,
    pub sv_nm: f64,
    pub sz_nm: f64,
    pub ssk: f64,
    pub sku: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pvr_nm: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pvr_set: Option<&'static str>,
    /// With `--bands`: the band RMS object of shared/spec/interfaces.md.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bands: Option<ArealBands>,
}

/// Maps a library error on a readable map to the CLI's exit codes: a map with too few valid
/// pixels is valid but unusable (1); anything else about the request is bad input (2).
fn surface_error(file: &Path, e: SurfaceError) -> CliError {
    match e {
        SurfaceError::NoValidPixel | SurfaceError::TooFewPixels { .. } => {
            CliError::processing(file, e)
        }
        _ => CliError::input(file, e),
    }
}

/// Reads a map through `bonnetlab_io`, keeping the reader's exit code and one-line message.
pub fn read_map(file: &Path) -> Result<Surface, CliError> {
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

/// Computes the report for a map already read.
pub fn stats_report(
    file: &Path,
    s: &Surface,
    terms: &[Term],
    with_pvr: bool,
) -> Result<StatsReport, CliError> {
    stats_report_with_bands(file, s, terms, with_pvr, None)
}

/// [`stats_report`] with, when `bands` gives edges (mm^-1), the band RMS object.
pub fn stats_report_with_bands(
    file: &Path,
    s: &Surface,
    terms: &[Term],
    with_pvr: bool,
    bands: Option<(f64, f64)>,
) -> Result<StatsReport, CliError> {
    if s.valid_count() == 0 {
        return Err(CliError::processing(file, SurfaceError::NoValidPixel));
    }
    let (r, _) = remove_terms(s, terms).map_err(|e| surface_error(file, e))?;
    let st: HeightStats = height_stats(&r).map_err(|e| surface_error(file, e))?;
    let p = if with_pvr {
        Some(pvr(&r).map_err(|e| surface_error(file, e))?)
    } else {
        None
    };
    // The split removes the same terms from the original map (one joint fit, as above).
    let bands = bands
        .map(|edges| band_split(s, terms, edges))
        .transpose()
        .map_err(|e| CliError::processing(file, e))?;
    Ok(StatsReport {
        file: file.display().to_string(),
        format: s.provenance.format.clone(),
        rows: s.rows(),
        cols: s.cols(),
        dx_mm: s.dx_mm,
        dy_mm: s.dy_mm,
        valid: st.valid,
        removed: r.removed.clone(),
        pv_nm: st.pv_nm,
        rms_nm: st.rms_nm,
        sa_nm: st.sa_nm,
        sp_nm: st.sp_nm,
        sv_nm: st.sv_nm,
        sz_nm: st.sz_nm,
        ssk: st.ssk,
        sku: st.sku,
        pvr_nm: p.map(|p| p.pvr_nm),
        pvr_set: p.map(|_| PVR_SET),
        bands,
    })
}

fn table(r: &StatsReport) -> String {
    let mm = |v: Option<f64>| v.map_or("unknown".to_string(), |v| format!("{v:.6e} mm"));
    let removed: Vec<&str> = r.removed.iter().map(Term::name).collect();
    let removed = if removed.is_empty() {
        "none".to_string()
    } else {
        removed.join(", ")
    };
    let mut t = String::new();
    t += &format!("file      {}\n", r.file);
    t += &format!("format    {}\n", r.format);
    t += &format!(
        "grid      {} rows x {} cols, dx {}, dy {}\n",
        r.rows,
        r.cols,
        mm(r.dx_mm),
        mm(r.dy_mm)
    );
    t += &format!("valid     {} pixels\n", r.valid);
    t += &format!("removed   {removed}\n");
    t += &format!("PV (Sz)   {:>12.4} nm\n", r.pv_nm);
    t += &format!("RMS (Sq)  {:>12.4} nm\n", r.rms_nm);
    t += &format!("Sa        {:>12.4} nm\n", r.sa_nm);
    t += &format!("Sp        {:>12.4} nm\n", r.sp_nm);
    t += &format!("Sv        {:>12.4} nm\n", r.sv_nm);
    t += &format!("Ssk       {:>12.4}\n", r.ssk);
    t += &format!("Sku       {:>12.4}   (not minus 3)\n", r.sku);
    if let (Some(p), Some(set)) = (r.pvr_nm, r.pvr_set) {
        t += &format!("PVr       {p:>12.4} nm   ({set})\n");
    }
    if let Some(b) = &r.bands {
        t += &bands_table(b);
    }
    t
}

/// The band lines of the table: edges, each band's RMS or why it is absent, and the method.
pub fn bands_table(b: &ArealBands) -> String {
    let [f1, f2] = b.edges_per_mm;
    let sig = bonnetlab_spectrum::fmt_sig;
    let mut t = format!(
        "bands     edges {} and {} 1/mm (periods {} mm and {} mm)\n",
        sig(f1),
        sig(f2),
        if f1 > 0.0 {
            sig(1.0 / f1)
        } else {
            "inf".into()
        },
        if f2 > 0.0 {
            sig(1.0 / f2)
        } else {
            "inf".into()
        }
    );
    for (name, v, why) in b.bands() {
        let label = match name {
            "figure" => format!("  figure  (f < {} 1/mm)", sig(f1)),
            "msf" => format!("  MSF     ({} to {} 1/mm)", sig(f1), sig(f2)),
            _ => format!("  fine    (f > {} 1/mm)", sig(f2)),
        };
        match (v, why) {
            (Some(v), _) => t += &format!("{label:<34} {v:>12.4} nm\n"),
            (None, Some(why)) => t += &format!("{label:<34} absent: {why}\n"),
            (None, None) => t += &format!("{label:<34} absent\n"),
        }
    }
    t += &format!(
        "  total (Sq, quadrature sum)       {:>12.4} nm\n  method: {}\n",
        b.total_rms_nm, b.method
    );
    t
}

pub fn run(args: &Args) -> Result<(), CliError> {
    let terms =
        Term::parse_list(&args.remove).map_err(|e| CliError::usage(format!("--remove: {e}")))?;
    let bands = match args.bands.as_deref() {
        None => None,
        Some("default") => Some(BAND_EDGES_DEFAULT_PER_MM),
        Some(v) => super::psd::parse_pair(Some(v), "--bands")?,
    };
    let s = read_map(&args.file)?;
    let report = stats_report_with_bands(&args.file, &s, &terms, args.pvr, bands)?;
    let text = if args.json {
        let mut j = serde_json::to_string(&report)
            .map_err(|e| CliError::processing(&args.file, format!("cannot encode JSON: {e}")))?;
        j.push('\n');
        j
    } else {
        table(&report)
    };
    super::write_stdout(text.as_bytes())
}
