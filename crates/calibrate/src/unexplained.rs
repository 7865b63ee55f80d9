//! Residual structure that no accepted effect explains: bands of the residual's X and Y PSDs
//! (one-sided, nm^2 mm) that stand above the white-noise level implied by the noise floor
//! (`2 sigma^2 d` one-sided), with where on the part they sit.
//!
//! A band is a run of bins whose 5-bin running mean exceeds `EXCESS` times the white level,
//! gaps of up to 2 bins bridged; its RMS is the excess over the white level, summed as bin sums.
//! Its region: the residual low-passed to the band (Gaussian, sigma = 1 / (4 f_high)), RMS per
//! hold-out block, and the bounding box of blocks holding at least half the largest block RMS.

use ndarray::Array2;
use serde::Serialize;

use crate::band::{BandResidual, ProcessBand};
use crate::grid::{smooth_masked, MapGrid};
use bonnetlab_spectrum::psd1d::{psd_x, psd_y, PsdOptions};
use bonnetlab_surface::stats::height_stats;
use bonnetlab_surface::Surface;

pub const EXCESS: f64 = 3.0;

#[derive(Debug, Clone, Serialize)]
pub struct Unexplained {
    pub description: String,
    pub band_per_mm: [f64; 2],
    pub rms_nm: f64,
    /// "x" (along rows, scan) or "y" (along columns, feed), or "both" for broadband.
    pub direction: String,
    /// [x_min, x_max, y_min, y_max] in mm.
    pub region_mm: [f64; 4],
    /// Set when the entry is a candidate effect significant on held-out data but below the
    /// selection's size bar (so not added to the model): what it is and how large.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub below_bar: Option<BelowBar>,
}

/// A candidate effect that the held-out test finds (z at least `run::REPORT_Z`) but whose
/// held-out reduction of the sum of squares is under the size bar an effect needs to be
/// added (`selection::MIN_FRACTION`, the fallback's `FALLBACK_FRACTION`).
#[derive(Debug, Clone, Serialize)]
pub struct BelowBar {
    pub kind: String,
    pub key: String,
    pub heldout_z: f64,
    pub heldout_reduction_fraction: f64,
    /// Its parameters refined jointly with the accepted effects, as `effects[].params`.
    pub params: serde_json::Map<String, serde_json::Value>,
    /// The full-band residual RMS (nm) the model would leave with it added.
    pub residual_rms_if_added_nm: f64,
    /// Other kinds significant on the same residual below the bars: (key, held-out z).
    pub also: Vec<(String, f64)>,
    /// Peak of the one-sided 1-D PSD of its added removal along `direction` (cycles/mm; set by
    /// [`below_bar_entry`]).
    pub peak_per_mm: f64,
    /// The forward model's stated accuracy on this run (nm RMS: `run::MODEL_ACCURACY` of the
    /// measured removal's RMS). An added removal smaller than this may be the model's own error
    /// rather than the run's.
    pub model_accuracy_nm: f64,
    /// Set when the candidate is a rate that the data find (`heldout_z`,
    /// `heldout_reduction_fraction` on the data) but that stays under the selection's bar beyond
    /// a smooth additive map (this is its held-out z there; `fallback::smooth_additive_columns`):
    /// a rate change the data cannot tell from a smooth difference between the two
    /// measurements, not added to the model for that reason.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_beyond_smooth: Option<f64>,
}

/// The entry for a below-bar candidate whose added removal (nm, full grid) is `map`: its RMS
/// (mean removed) over the valid pixels, the direction of its 1-D PSDs (one-sided) holding
/// more power and the band holding the central 80 % of that power, and its region.
pub fn below_bar_entry(
    g: &MapGrid,
    map: &Array2<f64>,
    valid: &Array2<bool>,
    mut what: BelowBar,
    summary: &str,
) -> Unexplained {
    // The project's one masked surface: its Sq (about the valid pixels' mean) and its PSDs.
    let surf = Surface::with_mask(map.clone(), valid.clone(), Some(g.dx_mm), Some(g.dy_mm)).ok();
    let rms = surf
        .as_ref()
        .and_then(|sf| height_stats(sf).ok())
        .map_or(0.0, |h| h.rms_nm);
    let (direction, band, peak) = power_band(g, surf.as_ref());
    what.peak_per_mm = peak;
    let (bbox, share) = region(g, map, valid, band[1].max(1e-3));
    let caveat = if rms < what.model_accuracy_nm {
        format!(
            " (smaller than the forward model's accuracy on this run, {:.3} nm RMS: it may be \
             the model's own error)",
            what.model_accuracy_nm
        )
    } else {
        String::new()
    };
    let also = if what.also.is_empty() {
        String::new()
    } else {
        let v: Vec<String> = what
            .also
            .iter()
            .map(|(k, z)| format!("{k} (z {z:.1})"))
            .collect();
        format!(
            "; also significant below the bars on this residual: {}",
            v.join(", ")
        )
    };
    let why = match what.z_beyond_smooth {
        None => format!(
            "significant on held-out data (z {:.1}) but under the size bar ({:.3} % of the \
             held-out sum of squares), so not added to the model",
            what.heldout_z,
            100.0 * what.heldout_reduction_fraction
        ),
        Some(zb) => format!(
            "significant on held-out data (z {:.1}, {:.3} % of the held-out sum of squares) but \
             under the bar beyond a smooth additive difference between the two measurements \
             (z {zb:.1} there): a rate change or the instrument's drift between the maps (air, \
             alignment), which the data cannot tell apart, so not added to the model",
            what.heldout_z,
            100.0 * what.heldout_reduction_fraction
        ),
    };
    // Periods (mm) of the peak and the band; a band reaching 0 /mm has no longest period.
    let peak_period = if peak > 0.0 {
        format!("period {:.2} mm", 1.0 / peak)
    } else {
        "no finite period".into()
    };
    let periods = match (band[0] > 0.0, band[1] > 0.0) {
        (true, true) => format!("periods {:.2}-{:.2} mm", 1.0 / band[1], 1.0 / band[0]),
        (false, true) => format!("periods {:.2} mm and longer", 1.0 / band[1]),
        _ => "no finite period".into(),
    };
    Unexplained {
        description: format!(
            "{}: {why}: {summary}; {rms:.3} nm RMS{caveat} \
             varying along {direction}, peaking at {peak:.3} /mm ({peak_period}), 80 % of its \
             power at {:.3}-{:.3} /mm ({periods}), {}{also}",
            what.key,
            band[0],
            band[1],
            located(bbox, share)
        ),
        band_per_mm: band,
        rms_nm: rms,
        direction: direction.into(),
        region_mm: bbox,
        below_bar: Some(what),
    }
}

/// The direction ("x" or "y") whose one-sided 1-D PSD of `surf` holds more power, the band
/// (cycles/mm) from 10 % to 90 % of that PSD's cumulative power, and the PSD's peak (cycles/mm).
fn power_band(g: &MapGrid, surf: Option<&Surface>) -> (&'static str, [f64; 2], f64) {
    let nyq = 0.5 / g.dx_mm.max(g.dy_mm);
    let Some(surf) = surf else {
        return ("both", [0.0, nyq], 0.0);
    };
    let opts = PsdOptions::default();
    let mut best: Option<(&'static str, f64, Vec<f64>, Vec<f64>)> = None;
    for (dir, psd) in [("x", psd_x(surf, &opts)), ("y", psd_y(surf, &opts))] {
        let Ok(p) = psd else { continue };
        let total: f64 = p.psd_nm2_mm.iter().sum();
        if best.as_ref().is_none_or(|b| total > b.1) {
            best = Some((dir, total, p.freq_per_mm, p.psd_nm2_mm));
        }
    }
    let Some((dir, total, f, psd)) = best else {
        return ("both", [0.0, nyq], 0.0);
    };
    if total.is_nan() || total <= 0.0 {
        return (dir, [0.0, nyq], 0.0);
    }
    let peak = f
        .iter()
        .zip(&psd)
        .max_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0.0, |(fk, _)| *fk);
    let (mut cum, mut lo, mut hi) = (0.0, None, None);
    for (fk, pk) in f.iter().zip(&psd) {
        cum += pk;
        if lo.is_none() && cum >= 0.1 * total {
            lo = Some(*fk);
        }
        if hi.is_none() && cum >= 0.9 * total {
            hi = Some(*fk);
        }
    }
    let lo = lo.unwrap_or(0.0);
    (dir, [lo, hi.unwrap_or(nyq).max(lo)], peak)
}

fn region(g: &MapGrid, r: &Array2<f64>, valid: &Array2<bool>, f_hi: f64) -> ([f64; 4], f64) {
    let sigma_px = (0.25 / f_hi.max(1e-9) / g.dx_mm.min(g.dy_mm)).clamp(0.0, 20.0);
    let s = if sigma_px >= 0.7 {
        smooth_masked(r, valid, sigma_px)
    } else {
        r.clone()
    };
    let b = (g.rows.min(g.cols) / 10).max(4);
    let (nbr, nbc) = (g.rows.div_ceil(b), g.cols.div_ceil(b));
    let mut acc = vec![(0.0, 0usize); nbr * nbc];
    for ((i, j), &v) in valid.indexed_iter() {
        if v {
            let a = &mut acc[(i / b) * nbc + j / b];
            a.0 += s[(i, j)] * s[(i, j)];
            a.1 += 1;
        }
    }
    let rms: Vec<f64> = acc
        .iter()
        .map(|(s2, n)| if *n > 0 { (s2 / *n as f64).sqrt() } else { 0.0 })
        .collect();
    let max = rms.iter().cloned().fold(0.0, f64::max);
    let mut bbox = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    let mut hit = 0usize;
    for (k, &v) in rms.iter().enumerate() {
        if max > 0.0 && v >= 0.5 * max {
            hit += 1;
            let (bi, bj) = (k / nbc, k % nbc);
            bbox[0] = bbox[0].min(g.x_mm(bj * b));
            bbox[1] = bbox[1].max(g.x_mm(((bj + 1) * b).min(g.cols) - 1));
            bbox[2] = bbox[2].min(g.y_mm(bi * b));
            bbox[3] = bbox[3].max(g.y_mm(((bi + 1) * b).min(g.rows) - 1));
        }
    }
    if hit == 0 {
        bbox = [g.x_mm(0), g.x_mm(g.cols - 1), g.y_mm(0), g.y_mm(g.rows - 1)];
    }
    (
        bbox,
        hit as f64 / rms.iter().filter(|v| **v > 0.0).count().max(1) as f64,
    )
}

/// Unexplained structure band by band: the PSD bands above the noise (and a broadband entry
/// when none stands out but the process band is above its floor) searched in the residual's
/// process-band component, and one entry for the fine band's excess above its floor
/// (structure the process cannot make: texture that does not resample identically, aliasing),
/// located from the fine-band component. `bands` is the residual's split (`band::split`).
pub fn find_by_band(
    g: &MapGrid,
    band: &ProcessBand,
    r: &Array2<f64>,
    valid: &Array2<bool>,
    noise_rms_nm: f64,
    bands: &[BandResidual],
) -> Vec<Unexplained> {
    let fine = band.fine_part(g, r, valid);
    let low = r - &fine;
    let process = bands.iter().find(|b| b.band == "process");
    let mut out = match process {
        Some(b) => find_in(
            g,
            &low,
            valid,
            noise_rms_nm,
            (b.rms_nm, b.floor_nm, b.band_per_mm),
        ),
        None => Vec::new(),
    };
    if let Some(b) = bands.iter().find(|b| b.band == "fine") {
        let excess = (b.rms_nm.powi(2) - b.floor_nm.powi(2)).max(0.0).sqrt();
        if excess > 0.5 * b.floor_nm {
            let [f1, f2] = b.band_per_mm;
            let (bbox, share) = region(g, &fine, valid, f2);
            out.push(Unexplained {
                description: format!(
                    "fine texture the process cannot make (resampling, texture): {excess:.3} nm RMS \
                     above the noise floor at {f1:.3}-{f2:.3} /mm (periods below {:.2} mm, where \
                     the TIF's |MTF| is under {}), {}",
                    1.0 / f1.max(1e-12),
                    band.mtf_threshold,
                    located(bbox, share)
                ),
                band_per_mm: [f1, f2],
                rms_nm: excess,
                direction: "both".into(),
                region_mm: bbox,
                below_bar: None,
            });
        }
    }
    out.sort_by(|a, b| b.rms_nm.total_cmp(&a.rms_nm));
    out
}

/// Bands of unexplained structure in a residual map, given the noise floor (nm RMS, full
/// band) and the map's RMS, its floor and its band `total` (the broadband fallback's test).
fn find_in(
    g: &MapGrid,
    r: &Array2<f64>,
    valid: &Array2<bool>,
    noise_rms_nm: f64,
    total: (f64, f64, [f64; 2]),
) -> Vec<Unexplained> {
    let (total_rms_nm, total_floor_nm, total_band) = total;
    let mut out = Vec::new();
    // The project's one 1-D PSD (one-sided, nm^2 mm; per-segment mean removed, the spectrum
    // crate's dropout and segment rules); the residual already has its piston and tilt fitted.
    let Ok(surf) = Surface::with_mask(r.clone(), valid.clone(), Some(g.dx_mm), Some(g.dy_mm))
    else {
        return out;
    };
    let opts = PsdOptions {
        remove: Vec::new(),
        ..PsdOptions::default()
    };
    for along_x in [true, false] {
        let d = if along_x { g.dx_mm } else { g.dy_mm };
        let psd = if along_x {
            psd_x(&surf, &opts)
        } else {
            psd_y(&surf, &opts)
        };
        let Ok(p) = psd else { continue };
        let white = 2.0 * noise_rms_nm * noise_rms_nm * d;
        let n = p.psd_nm2_mm.len();
        let sm: Vec<f64> = (0..n)
            .map(|k| {
                let (a, b) = (k.saturating_sub(2), (k + 3).min(n));
                p.psd_nm2_mm[a..b].iter().sum::<f64>() / (b - a) as f64
            })
            .collect();
        let mut k = 1;
        while k < n {
            if sm[k] > EXCESS * white {
                let start = k;
                let mut end = k;
                let mut gap = 0;
                while k < n && gap <= 2 {
                    if sm[k] > EXCESS * white {
                        end = k;
                        gap = 0;
                    } else {
                        gap += 1;
                    }
                    k += 1;
                }
                let ex: f64 = (start..=end)
                    .map(|b| (p.psd_nm2_mm[b] - white).max(0.0) * p.df_per_mm)
                    .sum();
                let rms = ex.sqrt();
                if rms > 0.3 * noise_rms_nm.max(1e-12) {
                    let (f1, f2) = (p.freq_per_mm[start], p.freq_per_mm[end]);
                    let (bbox, share) = region(g, r, valid, f2.max(p.df_per_mm));
                    let dir = if along_x { "x" } else { "y" };
                    let per = |f: f64| {
                        if f > 0.0 {
                            format!("{:.2}", 1.0 / f)
                        } else {
                            "inf".into()
                        }
                    };
                    out.push(Unexplained {
                        description: format!(
                            "structure varying along {dir} at {f1:.4}-{f2:.4} /mm (periods {}-{} mm), {} nm RMS above the noise, \
                             {}",
                            per(f2),
                            per(f1),
                            format_args!("{rms:.3}"),
                            located(bbox, share)
                        ),
                        band_per_mm: [f1, f2],
                        rms_nm: rms,
                        direction: dir.into(),
                        region_mm: bbox,
                        below_bar: None,
                    });
                }
            } else {
                k += 1;
            }
        }
    }
    out.sort_by(|a, b| b.rms_nm.total_cmp(&a.rms_nm));
    out.truncate(4);
    let excess_total = (total_rms_nm.powi(2) - total_floor_nm.powi(2))
        .max(0.0)
        .sqrt();
    // A fraction of the full floor (not of the band's share, which can be a hundredth of it).
    if out.is_empty() && excess_total > 0.5 * noise_rms_nm.max(total_floor_nm) {
        let (bbox, share) = region(g, r, valid, 0.5 / g.dx_mm.max(g.dy_mm));
        out.push(Unexplained {
            description: format!(
                "broadband residual {excess_total:.3} nm RMS above the noise floor at {:.3}-{:.3} /mm, {}",
                total_band[0],
                total_band[1],
                located(bbox, share)
            ),
            band_per_mm: total_band,
            rms_nm: excess_total,
            direction: "both".into(),
            region_mm: bbox,
            below_bar: None,
        });
    }
    out
}

/// Where a structure sits: its bounding box (x0, x1, y0, y1 in mm) and whether it is local
/// (under 30 % of the valid area) or widespread.
fn located(bbox: [f64; 4], share: f64) -> String {
    format!(
        "strongest at x {:.1}-{:.1} mm, y {:.1}-{:.1} mm ({})",
        bbox[0],
        bbox[1],
        bbox[2],
        bbox[3],
        if share < 0.3 { "local" } else { "widespread" }
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cosine along y (period 4 mm) on a 120 x 100 map of 0.5 mm pixels with a round hole
    /// masked out: its entry varies along y, peaks at 0.25 /mm within a bin of the 60 mm map's
    /// PSD, has the band around it and the cosine's RMS (amplitude / sqrt 2) within 2 %.
    #[test]
    fn a_below_bar_entry_finds_the_direction_peak_and_rms_of_its_removal() {
        let (rows, cols, d) = (120, 100, 0.5);
        let g = MapGrid::new(rows, cols, d, d, 0.0, 0.0).unwrap();
        let amp = 0.3;
        let map = Array2::from_shape_fn((rows, cols), |(i, _)| {
            amp * (2.0 * std::f64::consts::PI * 0.25 * i as f64 * d).cos()
        });
        let valid = Array2::from_shape_fn((rows, cols), |(i, j)| {
            let (x, y) = (j as f64 * d - 30.0, i as f64 * d - 20.0);
            x.hypot(y) > 5.0
        });
        let what = BelowBar {
            kind: "k".into(),
            key: "k".into(),
            heldout_z: 6.0,
            heldout_reduction_fraction: 0.001,
            params: serde_json::Map::new(),
            residual_rms_if_added_nm: 1.0,
            also: Vec::new(),
            peak_per_mm: 0.0,
            model_accuracy_nm: 0.5,
            z_beyond_smooth: None,
        };
        let u = below_bar_entry(&g, &map, &valid, what, "a test");
        let b = u.below_bar.as_ref().unwrap();
        assert_eq!(u.direction, "y");
        assert!(
            (b.peak_per_mm - 0.25).abs() <= 1.0 / 60.0,
            "{}",
            b.peak_per_mm
        );
        assert!(
            u.band_per_mm[0] <= 0.25 && 0.25 <= u.band_per_mm[1],
            "{:?}",
            u.band_per_mm
        );
        assert!(
            (u.rms_nm / (amp / 2f64.sqrt()) - 1.0).abs() < 0.02,
            "{}",
            u.rms_nm
        );
        // Smaller than the model's accuracy: said so.
        assert!(
            u.description.contains("the model's own error"),
            "{}",
            u.description
        );
    }
}
