//! `compare`: the comparison of bonnet runs (the maps given by `--run`): per run PV / RMS before and after
//! on one aperture, convergence ratios (RMS, PV, per band), improvement over the first run,
//! ripple at the grating spacing, PSD curves, and the spread over repeat measurements.
//!
//! Conventions (shared/spec/metrology.md, DOMAIN.md section 4):
//! - the aperture of a run is the intersection of the valid masks of all its maps (every before
//!   and after repeat), so all numbers of a run use the same pixels;
//! - the stated form terms are removed from each map separately (a joint least-squares fit),
//!   then PV and RMS are taken on the valid pixels; CR = (Q_before - Q_after) / Q_before;
//! - improvement of a run over the first = (CR_run - CR_first) / CR_first;
//! - with repeats, Q is the mean over repeats and the spread of CR and improvement is
//!   propagated to first order from the standard errors of the means (bonnetlab_surface
//!   `repeat_cr` / `compare_runs`); a difference is "within noise" when smaller than twice its
//!   standard deviation;
//! - PSDs are one-sided 1-D PSDs in nm^2 mm (bonnetlab_spectrum), averaged over repeats; the
//!   ripple is computed from the averaged X and Y PSDs;
//! - band RMS values (figure below F1, MSF F1..F2, fine above F2) are the areal split of the
//!   map itself (`bonnetlab_spectrum::band_split`: brick-wall bands of the map's 2-D
//!   transform, projected over its valid pixels low band first, so they add up to the map RMS
//!   exactly and none is negative); a band the map cannot resolve is
//!   absent with a reason. The 2-D PSD annulus values (Hann window) stay as a labelled PSD
//!   quantity (`bands_psd`); the ripple band's CR uses the ripple's sigma_total (Y PSD,
//!   harmonic bands), absent with a reason when the pitch cannot be resolved.

use std::path::{Path, PathBuf};

use bonnetlab_surface::format::sig;
use ndarray::{Array2, Zip};
use rayon::prelude::*;

use bonnetlab_spectrum::{
    band_split, psd_2d, psd_xy, ripple_from_psds, ArealBands, Psd1d, PsdOptions, Ripple,
    RippleOptions, SpectrumError, Window,
};
use bonnetlab_surface::{
    compare_runs, height_stats, remove_terms, repeat_cr, RunComparison, Surface, Term,
};

/// Default MSF band edges, mm^-1 (periods 33 mm to 0.12 mm; clipped to Nyquist).
pub const MSF_BAND_PER_MM: (f64, f64) = bonnetlab_spectrum::MSF_DEFAULT_PER_MM;

pub use super::run_spec::RunSpec;

mod results;
pub use results::*;

/// Settings shared by every run of a comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub remove: Vec<Term>,
    pub window: Window,
    /// Grating spacing in mm; `None` skips the ripple check and the markers.
    pub pitch_mm: Option<f64>,
    /// MSF band edges in mm^-1; the figure band is [0, msf.0], the HSF rest is not reported.
    pub msf_band_per_mm: (f64, f64),
    pub harmonics: usize,
    /// Pixel size (dx, dy) in mm for maps whose file does not carry one (`--pixel-mm`).
    pub pixel_mm: Option<(f64, f64)>,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            remove: vec![Term::Piston, Term::Tilt],
            window: Window::Hann,
            pitch_mm: None,
            msf_band_per_mm: MSF_BAND_PER_MM,
            harmonics: 5,
            pixel_mm: None,
        }
    }
}

impl Settings {
    fn psd_options(&self) -> PsdOptions {
        PsdOptions {
            window: self.window,
            remove: self.remove.clone(),
            ..PsdOptions::default()
        }
    }
}

/// An error of the comparison: the file it concerns (if any), what went wrong, and whether it
/// is bad input (exit 2) or a processing failure on valid input (exit 1).
#[derive(Debug, Clone, PartialEq)]
pub struct CompareError {
    pub file: Option<PathBuf>,
    pub message: String,
    pub bad_input: bool,
}

impl std::fmt::Display for CompareError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.file {
            Some(p) => write!(f, "{}: {}", p.display(), self.message),
            None => f.write_str(&self.message),
        }
    }
}

impl CompareError {
    fn processing(file: &Path, what: impl std::fmt::Display) -> Self {
        CompareError {
            file: Some(file.to_path_buf()),
            message: what.to_string(),
            bad_input: false,
        }
    }
    fn input(file: &Path, what: impl std::fmt::Display) -> Self {
        CompareError {
            file: Some(file.to_path_buf()),
            message: what.to_string(),
            bad_input: true,
        }
    }
}

/// Per-map results before they are combined into a run.
struct MapResult {
    rms_nm: f64,
    pv_nm: f64,
    px: Psd1d,
    py: Psd1d,
    /// 2-D PSD annulus values (PSD quantity).
    figure_psd_nm: f64,
    msf_psd_nm: f64,
    bands: ArealBands,
    /// The map on the aperture with the terms removed (kept for the pictures).
    residual: Surface,
}

/// Reads, analyses and compares the runs. `progress(step)` is called after each map is
/// analysed (from worker threads) so a caller can show progress.
pub fn compare(
    runs: &[RunSpec],
    settings: &Settings,
    progress: &(dyn Fn(&Path) + Sync),
) -> Result<Comparison, CompareError> {
    if runs.is_empty() {
        return Err(CompareError {
            file: None,
            message: "no --run given".into(),
            bad_input: true,
        });
    }
    for (i, r) in runs.iter().enumerate() {
        if runs[..i].iter().any(|o| o.name == r.name) {
            return Err(CompareError {
                file: None,
                message: format!("run name '{}' is given twice", r.name),
                bad_input: true,
            });
        }
    }
    if let Some(p) = settings.pitch_mm {
        if !(p.is_finite() && p > 0.0) {
            return Err(CompareError {
                file: None,
                message: format!("--pitch-mm must be a positive number of mm, got {p}"),
                bad_input: true,
            });
        }
    }
    // Read every map in parallel, keeping the order of the command line.
    let files: Vec<&PathBuf> = runs
        .iter()
        .flat_map(|r| r.before.iter().chain(&r.after))
        .collect();
    let read: Vec<Result<(Surface, Option<String>), CompareError>> = files
        .par_iter()
        .map(|p| {
            let mut s = bonnetlab_io::read_surface(p).map_err(|e| CompareError {
                file: None,
                message: e.to_string(),
                bad_input: e.exit_code() == 2,
            })?;
            let note = crate::pipeline::fill_pixel_size(&mut s, settings.pixel_mm, p);
            Ok((s, note))
        })
        .collect();
    let mut notes = Vec::new();
    let mut read = read.into_iter().map(|r| {
        r.map(|(s, note)| {
            notes.extend(note);
            s
        })
    });
    let mut results = Vec::with_capacity(runs.len());
    for r in runs {
        let mut surfaces = Vec::with_capacity(r.before.len() + r.after.len());
        for _ in 0..r.before.len() + r.after.len() {
            surfaces.push(read.next().unwrap_or_else(|| {
                Err(CompareError {
                    file: None,
                    message: "internal: map count".into(),
                    bad_input: false,
                })
            })?);
        }
        results.push(analyse_run(r, surfaces, settings, progress)?);
    }
    add_improvements(&mut results)?;
    Ok(Comparison {
        tool: "bonnetlab".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        settings: settings_report(settings),
        runs: results,
        notes,
    })
}

fn settings_report(s: &Settings) -> SettingsReport {
    SettingsReport {
        removed: s.remove.iter().map(|t| t.name().to_string()).collect(),
        window: s.window.name(),
        pitch_mm: s.pitch_mm,
        psd: "one-sided 1-D PSD, nm^2 mm, averaged over lines and over repeat maps".into(),
        band_method: bonnetlab_spectrum::areal::AREAL_METHOD.into(),
        figure_band_per_mm: (0.0, s.msf_band_per_mm.0),
        msf_band_per_mm: s.msf_band_per_mm,
        harmonics: s.harmonics,
        aperture: "pixels valid in every map of the run (before and after, all repeats)".into(),
        noise_rule: "within noise when |difference| < 2 sd, sd propagated from the standard \
                     errors of the repeat means"
            .into(),
    }
}

/// Analyses one run's maps (before maps first, then after maps, as in the spec).
fn analyse_run(
    spec: &RunSpec,
    surfaces: Vec<Surface>,
    settings: &Settings,
    progress: &(dyn Fn(&Path) + Sync),
) -> Result<RunResult, CompareError> {
    let paths: Vec<&PathBuf> = spec.before.iter().chain(&spec.after).collect();
    let first = &surfaces[0];
    let (dx, dy) = first
        .pixel_mm("a run comparison (PSD, bands)")
        .map_err(|e| CompareError::input(paths[0], e))?;
    for (s, p) in surfaces.iter().zip(&paths).skip(1) {
        if s.dim() != first.dim() {
            return Err(CompareError::input(
                p,
                format!(
                    "grid {}x{} differs from {} ({}x{}); maps of a run must be registered on one grid",
                    s.rows(),
                    s.cols(),
                    paths[0].display(),
                    first.rows(),
                    first.cols()
                ),
            ));
        }
        let (sx, sy) = s
            .pixel_mm("a run comparison")
            .map_err(|e| CompareError::input(p, e))?;
        if (sx - dx).abs() > 1e-6 * dx || (sy - dy).abs() > 1e-6 * dy {
            return Err(CompareError::input(
                p,
                format!(
                    "pixel size {} x {} mm differs from {}'s {} x {} mm",
                    sig(sx, 7),
                    sig(sy, 7),
                    paths[0].display(),
                    sig(dx, 7),
                    sig(dy, 7),
                ),
            ));
        }
    }
    let mut common: Array2<bool> = first.valid().clone();
    for s in &surfaces[1..] {
        Zip::from(&mut common)
            .and(s.valid())
            .for_each(|c, &v| *c = *c && v);
    }
    let n_common = common.iter().filter(|&&v| v).count();
    if n_common == 0 {
        return Err(CompareError::processing(
            paths[0],
            format!(
                "run '{}': no pixel is valid in every map of the run",
                spec.name
            ),
        ));
    }
    let opts = settings.psd_options();
    let maps: Vec<MapResult> = surfaces
        .par_iter()
        .zip(paths.par_iter())
        .map(|(s, p)| {
            let r = analyse_map(s, &common, settings, &opts)
                .map_err(|e| CompareError::processing(p, e));
            progress(p);
            r
        })
        .collect::<Result<_, _>>()?;
    let nb = spec.before.len();
    let (mb, ma) = maps.split_at(nb);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let each = |m: &[MapResult], f: fn(&MapResult) -> f64| m.iter().map(f).collect::<Vec<f64>>();
    let (rb, ra) = (each(mb, |m| m.rms_nm), each(ma, |m| m.rms_nm));
    let (pb, pa) = (each(mb, |m| m.pv_nm), each(ma, |m| m.pv_nm));
    let (rms_b, rms_a, pv_b, pv_a) = (mean(&rb), mean(&ra), mean(&pb), mean(&pa));
    let cr = |b: f64, a: f64| (b - a) / b;
    // CR = (before - after) / before is undefined for a flat before map: bad input, named,
    // never a silent null in report.json.
    for (m, &p) in mb.iter().zip(&paths) {
        if let Some(why) = bonnetlab_surface::convergence::undefined_convergence_reason(
            m.rms_nm,
            m.pv_nm,
            &settings.remove,
        ) {
            return Err(CompareError::input(
                p,
                format!("run '{}': {why}", spec.name),
            ));
        }
    }

    let spread = if mb.len() >= 2 && ma.len() >= 2 {
        let err = |e| CompareError::processing(paths[0], e);
        let r = repeat_cr(&rb, &ra).map_err(err)?;
        let p = repeat_cr(&pb, &pa).map_err(err)?;
        Some(RunSpread {
            n_before: mb.len(),
            n_after: ma.len(),
            rms_before_sd_nm: r.before.sd,
            rms_after_sd_nm: r.after.sd,
            pv_before_sd_nm: p.before.sd,
            pv_after_sd_nm: p.after.sd,
            cr_rms_sd: r.cr_sd,
            cr_pv_sd: p.cr_sd,
        })
    } else {
        None
    };
    let spread_reason = spread.is_none().then(|| {
        format!(
            "{} before and {} after map(s): a spread over repeats needs at least two of each",
            mb.len(),
            ma.len()
        )
    });

    let psd = RunPsds {
        x_before: Some(mean_psd(mb.iter().map(|m| &m.px))),
        x_after: Some(mean_psd(ma.iter().map(|m| &m.px))),
        y_before: Some(mean_psd(mb.iter().map(|m| &m.py))),
        y_after: Some(mean_psd(ma.iter().map(|m| &m.py))),
    };
    let nyq = 0.5 / dx.max(dy);
    let msf_hi = settings.msf_band_per_mm.1.min(nyq);
    let (f1, f2) = settings.msf_band_per_mm;
    // Areal band RMS: mean over repeats, or absent with the first map's reason.
    let areal = |m: &[MapResult], k: usize| -> Result<f64, String> {
        let mut v = Vec::with_capacity(m.len());
        for r in m {
            let (_, val, why) = r.bands.bands()[k];
            match val {
                Some(x) => v.push(x),
                None => return Err(why.unwrap_or("not computed").to_string()),
            }
        }
        Ok(mean(&v))
    };
    let range = mb[0].bands.measured_range_per_mm.unwrap_or([0.0, nyq]);
    let method_areal = bonnetlab_spectrum::areal::AREAL_METHOD.to_string();
    let mut bands = vec![
        BandCr::new(
            "figure",
            (0.0, f1),
            method_areal.clone(),
            areal(mb, 0),
            areal(ma, 0),
        ),
        BandCr::new(
            "msf",
            (f1.max(range[0]).min(msf_hi), msf_hi),
            method_areal.clone(),
            areal(mb, 1),
            areal(ma, 1),
        ),
    ];
    let band_fine = BandCr::new(
        "fine",
        (f2.min(nyq), nyq),
        method_areal,
        areal(mb, 2),
        areal(ma, 2),
    );
    let method_2d = format!(
        "PSD-integrated: 2-D PSD annulus sums, {} window (a PSD quantity: its window loss \
         makes it disagree with the map RMS)",
        settings.window.name()
    );
    // The PSD quantity over the same edges: absent, with the areal band's reason, where the
    // maps cannot resolve the band (an annulus sum there would be of no bins, or of DC).
    let psd_band = |m: &[MapResult], k: usize, v: fn(&MapResult) -> f64| {
        areal(m, k).map(|_| mean(&each(m, v)))
    };
    let bands_psd = vec![
        BandCr::new(
            "figure",
            (0.0, f1),
            method_2d.clone(),
            psd_band(mb, 0, |m| m.figure_psd_nm),
            psd_band(ma, 0, |m| m.figure_psd_nm),
        ),
        BandCr::new(
            "msf",
            (f1, msf_hi),
            method_2d,
            psd_band(mb, 1, |m| m.msf_psd_nm),
            psd_band(ma, 1, |m| m.msf_psd_nm),
        ),
    ];
    let band_rms = RunBandRms {
        before: mb.iter().map(|m| m.bands.clone()).collect(),
        after: ma.iter().map(|m| m.bands.clone()).collect(),
    };

    let (mut ripple_before, mut ripple_after, mut ripple_reason) = (None, None, None);
    if let Some(pitch) = settings.pitch_mm {
        let ropts = RippleOptions {
            harmonics: settings.harmonics,
            ..RippleOptions::default()
        };
        let rip = |x: &Option<Psd1d>, y: &Option<Psd1d>| -> Result<Ripple, SpectrumError> {
            match (x, y) {
                (Some(x), Some(y)) => ripple_from_psds(x, y, pitch, &ropts),
                _ => Err(SpectrumError::TooSmall("no PSD".into())),
            }
        };
        let keep = |r: Result<Ripple, SpectrumError>, p: &Path| match r {
            Ok(r) => Ok(Ok(r)),
            Err(e @ SpectrumError::NotResolvable(_)) => Ok(Err(e.to_string())),
            Err(e) => Err(CompareError::input(p, e)),
        };
        let rbf = keep(rip(&psd.x_before, &psd.y_before), paths[0])?;
        let raf = keep(rip(&psd.x_after, &psd.y_after), paths[nb])?;
        let f0 = 1.0 / pitch;
        let (edges, method) = match &rbf {
            Ok(r) => {
                let h = r.band_halfwidth_per_mm;
                let last = r
                    .harmonics
                    .last()
                    .map(|m| m.freq_per_mm)
                    .unwrap_or(r.f0_per_mm);
                (
                    ((r.f0_per_mm - h).max(0.0), last + h),
                    format!(
                        "sigma_total of the Y PSD over the union of |f - k f0| <= {} mm^-1, k = 1..{}",
                        bonnetlab_spectrum::fmt_sig(h),
                        r.harmonics.len()
                    ),
                )
            }
            Err(_) => (
                (f0, f0),
                "sigma_total of the Y PSD over the harmonic bands".to_string(),
            ),
        };
        bands.push(BandCr::new(
            "ripple",
            edges,
            method,
            rbf.as_ref().map(|r| r.sigma_total_nm).map_err(Clone::clone),
            raf.as_ref().map(|r| r.sigma_total_nm).map_err(Clone::clone),
        ));
        ripple_reason = rbf.as_ref().err().or(raf.as_ref().err()).cloned();
        ripple_before = rbf.ok();
        ripple_after = raf.ok();
    }

    let maps_for_pictures = {
        let b = mb[0].residual.clone();
        let a = ma[0].residual.clone();
        let removal = b
            .difference(&a)
            .and_then(|d| remove_terms(&d, &settings.remove).map(|r| r.0))
            .map_err(|e| CompareError::processing(paths[0], e))?;
        Some(RunMaps {
            before: b,
            after: a,
            removal,
        })
    };

    Ok(RunResult {
        name: spec.name.clone(),
        before_files: spec
            .before
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        after_files: spec.after.iter().map(|p| p.display().to_string()).collect(),
        rows: first.rows(),
        cols: first.cols(),
        dx_mm: first.dx_mm,
        dy_mm: first.dy_mm,
        common_valid: n_common,
        removed: settings
            .remove
            .iter()
            .map(|t| t.name().to_string())
            .collect(),
        rms_before_nm: rms_b,
        rms_after_nm: rms_a,
        pv_before_nm: pv_b,
        pv_after_nm: pv_a,
        cr_rms: cr(rms_b, rms_a),
        cr_pv: cr(pv_b, pv_a),
        rms_before_each_nm: rb,
        rms_after_each_nm: ra,
        pv_before_each_nm: pb,
        pv_after_each_nm: pa,
        spread,
        spread_reason,
        bands,
        band_fine,
        band_rms,
        bands_psd,
        ripple_before,
        ripple_after,
        ripple_reason,
        improvement_cr_rms: None,
        improvement_cr_pv: None,
        improvement: None,
        improvement_reason: None,
        psd,
        maps: maps_for_pictures,
    })
}

fn analyse_map(
    s: &Surface,
    common: &Array2<bool>,
    settings: &Settings,
    opts: &PsdOptions,
) -> Result<MapResult, String> {
    let on_aperture = s.with_valid(common.clone()).map_err(|e| e.to_string())?;
    let (residual, _) = remove_terms(&on_aperture, &settings.remove).map_err(|e| e.to_string())?;
    let st = height_stats(&residual).map_err(|e| e.to_string())?;
    // The residual already has the terms removed; the PSD options remove them again, which is
    // a no-op up to rounding and keeps `removed` stated in the PSD.
    let (px, py) = psd_xy(&residual, opts).map_err(|e| e.to_string())?;
    let p2 = psd_2d(&residual, opts).map_err(|e| e.to_string())?;
    let (f1, f2) = settings.msf_band_per_mm;
    // The residual has the terms removed already: the split removes only its mean.
    let bands = band_split(&residual, &[], (f1, f2)).map_err(|e| e.to_string())?;
    Ok(MapResult {
        rms_nm: st.rms_nm,
        pv_nm: st.pv_nm,
        px,
        py,
        figure_psd_nm: p2.annulus_rms(0.0, f1),
        // Half-open at f1 so the figure and MSF bands do not share an annulus.
        msf_psd_nm: (p2.annulus_rms(0.0, f2).powi(2) - p2.annulus_rms(0.0, f1).powi(2))
            .max(0.0)
            .sqrt(),
        bands,
        residual,
    })
}

/// Mean of PSDs on one frequency grid (the maps of a run share their grid).
fn mean_psd<'a>(mut it: impl Iterator<Item = &'a Psd1d>) -> Psd1d {
    let Some(first) = it.next() else {
        return Psd1d {
            axis: bonnetlab_spectrum::Axis::X,
            freq_per_mm: vec![],
            psd_nm2_mm: vec![],
            df_per_mm: 1.0,
            spacing_mm: 1.0,
            window: Window::Hann,
            enbw_bins: 1.5,
            n_lines: 0,
            n_segments: 0,
            biased_bins: 0,
            removed: vec![],
        };
    };
    let mut out = first.clone();
    let mut n = 1.0;
    for p in it {
        for (o, v) in out.psd_nm2_mm.iter_mut().zip(&p.psd_nm2_mm) {
            *o += v;
        }
        out.n_lines += p.n_lines;
        out.n_segments += p.n_segments;
        n += 1.0;
    }
    for o in &mut out.psd_nm2_mm {
        *o /= n;
    }
    out
}

fn add_improvements(runs: &mut [RunResult]) -> Result<(), CompareError> {
    let Some((first, rest)) = runs.split_first_mut() else {
        return Ok(());
    };
    for r in rest {
        if first.cr_rms == 0.0 || first.cr_pv == 0.0 {
            r.improvement_reason = Some(format!(
                "the reference run '{}' has a convergence ratio of 0 (RMS {}, PV {}): an \
                 improvement relative to it is undefined",
                first.name, first.cr_rms, first.cr_pv
            ));
            continue;
        }
        let i_rms = (r.cr_rms - first.cr_rms) / first.cr_rms;
        let i_pv = (r.cr_pv - first.cr_pv) / first.cr_pv;
        let noise = match (&first.spread, &r.spread) {
            (Some(_), Some(_)) => {
                let rc = |run: &RunResult, rms: bool| {
                    if rms {
                        repeat_cr(&run.rms_before_each_nm, &run.rms_after_each_nm)
                    } else {
                        repeat_cr(&run.pv_before_each_nm, &run.pv_after_each_nm)
                    }
                };
                let err = |e: bonnetlab_surface::SurfaceError| CompareError {
                    file: None,
                    message: format!("run '{}': {e}", r.name),
                    bad_input: false,
                };
                let c_rms: RunComparison =
                    compare_runs(&rc(first, true).map_err(err)?, &rc(r, true).map_err(err)?);
                let c_pv: RunComparison =
                    compare_runs(&rc(first, false).map_err(err)?, &rc(r, false).map_err(err)?);
                Some(NoiseVerdict {
                    improvement_cr_rms_sd: c_rms.improvement_sd,
                    improvement_cr_pv_sd: c_pv.improvement_sd,
                    cr_rms_difference: c_rms.difference,
                    cr_rms_difference_sd: c_rms.difference_sd,
                    cr_pv_difference: c_pv.difference,
                    cr_pv_difference_sd: c_pv.difference_sd,
                    rms_within_noise: c_rms.within_noise,
                    pv_within_noise: c_pv.within_noise,
                })
            }
            _ => None,
        };
        r.improvement_cr_rms = Some(i_rms);
        r.improvement_cr_pv = Some(i_pv);
        r.improvement = Some(Improvement {
            reference: first.name.clone(),
            improvement_cr_rms: i_rms,
            improvement_cr_pv: i_pv,
            noise,
        });
    }
    Ok(())
}
