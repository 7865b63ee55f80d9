//! Per-spot metrics from one spot map: centre, removal map, peak and volumetric rate, FWHM,
//! asymmetry, and the RMS / PV of the polished region.
//!
//! Steps (each one's convention is in its module):
//! 1. Rough background: piston + tilt on the outer frame of the map (one tenth of the smaller
//!    side, rounded, at least 2 pixels: the border ring of the process TIF front end); rough removal, its smoothed maximum, the rough centroid of the
//!    pixels above half of it, and `R5` = sqrt(area / pi) of the pixels above 5 % of it within
//!    three half-maximum radii of that centroid.
//! 2. Background: piston + tilt fitted on the ring `[1.4 R5, 1.9 R5]` about the rough centre
//!    (`background`), giving the removal map in nm and the noise estimate (ring residual RMS).
//! 3. Centre and peak: paraboloid vertex on the top 15 % (`centre`), else the centroid.
//! 4. Peak rate = peak removal / dwell (nm/s). Volumetric rate = sum of removal over the valid
//!    pixels within the ring's inner radius times dx dy / dwell, in nm mm^2/s (x 1e-6 = mm^3/s).
//! 5. FWHM along X and Y through the centre (`profile`); asymmetry = right/left and up/down
//!    half-width ratios, FWHM_y / FWHM_x, and the offset of the removal-weighted centroid (pixels
//!    above 5 % of the peak within the ring's inner radius) from the peak centre.
//! 6. Polished region as reported (the paper's Figure 18 RMS / PV): the heights, after the ring's
//!    piston + tilt, over the disc of radius `R5` about the centre; RMS about their mean (Sq) and
//!    PV = max - min. Also given over the whole map after piston + tilt fitted on the whole map
//!    (the interferometer's default view of the measured field).

use serde::{Deserialize, Serialize};

use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};

use crate::background::{
    fit_background, frame_mask, removal_after_plane, MapKind, Ring, RING_INNER_PER_R5,
    RING_OUTER_PER_R5,
};
use crate::centre::{
    centroid, paraboloid_peak, smoothed_max, CentreMethod, REFINE_FRACTION, TOP_FRACTION,
};
use crate::error::SpotsError;
use crate::profile::crossing;

/// Options of the spot analysis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct SpotOptions {
    pub kind: MapKind,
    /// Override of the ring's inner radius (mm); default 1.4 R5.
    pub ring_inner_mm: Option<f64>,
    /// Override of the ring's outer radius (mm); default 1.9 R5.
    pub ring_outer_mm: Option<f64>,
}

/// The metrics of one spot. Lengths in mm, removal in nm, rates per second of dwell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct SpotMetrics {
    pub dwell_s: f64,
    pub centre_x_mm: f64,
    pub centre_y_mm: f64,
    pub centre_method: CentreMethod,
    pub peak_removal_nm: f64,
    pub peak_rate_nm_per_s: f64,
    /// Removed volume per second: nm mm^2/s (1 nm mm^2 = 1e-6 mm^3).
    pub volume_rate_nm_mm2_per_s: f64,
    /// The same in mm^3/s.
    pub volume_rate_mm3_per_s: f64,
    pub fwhm_x_mm: f64,
    pub fwhm_y_mm: f64,
    pub half_width_left_mm: f64,
    pub half_width_right_mm: f64,
    pub half_width_down_mm: f64,
    pub half_width_up_mm: f64,
    /// right / left half-width along X (1 = symmetric).
    pub asymmetry_x: f64,
    /// up / down half-width along Y (+y over -y).
    pub asymmetry_y: f64,
    /// FWHM_y / FWHM_x.
    pub aspect_yx: f64,
    /// Removal-weighted centroid minus peak centre (mm).
    pub centroid_offset_x_mm: f64,
    pub centroid_offset_y_mm: f64,
    pub centroid_offset_mm: f64,
    /// Equivalent radius of the pixels removed by more than 5 % of the peak.
    pub r5_mm: f64,
    pub ring_inner_mm: f64,
    pub ring_outer_mm: f64,
    pub ring_pixels: usize,
    /// Residual RMS on the ring after piston + tilt (noise estimate).
    pub noise_rms_nm: f64,
    /// Invalid pixels inside the volume disc (the volume misses them).
    pub invalid_in_disc: usize,
    /// Heights over the disc of radius R5 after the ring's piston + tilt: RMS (Sq) and PV.
    pub region_rms_nm: f64,
    pub region_pv_nm: f64,
    /// Whole map after piston + tilt fitted on the whole map.
    pub map_rms_nm: f64,
    pub map_pv_nm: f64,
}

/// The metrics and the removal map they were taken from.
#[derive(Debug, Clone)]
pub struct SpotAnalysis {
    pub metrics: SpotMetrics,
    /// Removal in nm (positive = removed), background removed.
    pub removal: Surface,
}

/// Radius (mm) and centre of the pixels above 5 % of the peak, and the half-max centroid.
fn footprint_radius(removal: &Surface, peak: f64) -> Result<((f64, f64), f64), SpotsError> {
    let big = f64::INFINITY;
    let (cx, cy, n50) = centroid(removal, 0.5 * peak, (0.0, 0.0), big)
        .ok_or_else(|| SpotsError::Spot("no removal above half the peak".into()))?;
    let (dx, dy) = (removal.dx_mm.unwrap_or(1.0), removal.dy_mm.unwrap_or(1.0));
    let r50 = (n50 as f64 * dx * dy / std::f64::consts::PI).sqrt();
    let (_, _, n5) = centroid(removal, 0.05 * peak, (cx, cy), 3.0 * r50.max(dx.max(dy)))
        .ok_or_else(|| SpotsError::Spot("no removal above 5 % of the peak".into()))?;
    Ok((
        (cx, cy),
        (n5 as f64 * dx * dy / std::f64::consts::PI).sqrt(),
    ))
}

/// Analyses one spot map polished for `dwell_s` seconds.
pub fn measure_spot(
    s: &Surface,
    dwell_s: f64,
    opt: &SpotOptions,
) -> Result<SpotAnalysis, SpotsError> {
    let (dx, dy) = s.pixel_mm("spot analysis")?;
    if !(dwell_s.is_finite() && dwell_s > 0.0) {
        return Err(SpotsError::Spot(format!(
            "dwell time {dwell_s} s must be positive"
        )));
    }
    // 1. Rough background on the frame, rough centre and size.
    let (rough, _, _) = removal_after_plane(s, frame_mask(s), opt.kind)?;
    let (_, _, rough_peak) = smoothed_max(&rough).ok_or(SpotsError::Surface(
        bonnetlab_surface::SurfaceError::NoValidPixel,
    ))?;
    if rough_peak.is_nan() || rough_peak <= 0.0 {
        return Err(SpotsError::Spot(
            "no removal found (the map shows no dip below its border; is `kind` right?)".into(),
        ));
    }
    let ((rcx, rcy), r5_rough) = footprint_radius(&rough, rough_peak)?;

    // 2. Background on the ring.
    let inner = opt.ring_inner_mm.unwrap_or(RING_INNER_PER_R5 * r5_rough);
    let outer = opt.ring_outer_mm.unwrap_or(RING_OUTER_PER_R5 * r5_rough);
    if !(inner > 0.0 && outer > inner) {
        return Err(SpotsError::Spot(format!(
            "ring radii {inner} .. {outer} mm: the outer radius must exceed the inner one"
        )));
    }
    let ring = Ring {
        centre_x_mm: rcx,
        centre_y_mm: rcy,
        inner_mm: inner,
        outer_mm: outer,
    };
    let bg = fit_background(s, ring, opt.kind)?;
    let removal = bg.removal;

    // 3. Centre and peak.
    let (mi, mj, smooth_peak) =
        smoothed_max(&removal).ok_or(SpotsError::Spot("empty map".into()))?;
    if smooth_peak.is_nan() || smooth_peak <= 0.0 {
        return Err(SpotsError::Spot(
            "no removal left after the background fit".into(),
        ));
    }
    let ((_, _), r5) = footprint_radius(&removal, smooth_peak)?;
    let start = (removal.x_mm(mj), removal.y_mm(mi));
    let top = paraboloid_peak(&removal, start, r5, TOP_FRACTION * smooth_peak).and_then(
        |(x, y, p, _)| {
            // Refit about the vertex so the cap is centred on the data it describes.
            paraboloid_peak(&removal, (x, y), r5, REFINE_FRACTION * p)
        },
    );
    let (gx, gy, _) = centroid(&removal, 0.05 * smooth_peak, (rcx, rcy), inner)
        .ok_or(SpotsError::Spot("no removal inside the ring".into()))?;
    let (cx, cy, peak, method) = match top {
        Some((x, y, p, _)) => (x, y, p, CentreMethod::Paraboloid),
        None => (gx, gy, smooth_peak, CentreMethod::Centroid),
    };
    // The centroid about the final centre, for the asymmetry.
    let (gx, gy, _) = centroid(&removal, 0.05 * peak, (cx, cy), inner).unwrap_or((gx, gy, 0));

    // 4. Volume over the disc inside the ring.
    let (mut vol, mut holes) = (0.0, 0usize);
    for ((i, j), &v) in removal.heights_nm().indexed_iter() {
        if (removal.x_mm(j) - cx).hypot(removal.y_mm(i) - cy) <= inner {
            if removal.valid()[(i, j)] {
                vol += v;
            } else {
                holes += 1;
            }
        }
    }
    vol *= dx * dy;

    // 5. FWHM and asymmetry.
    let half = 0.5 * peak;
    let walk = |u: (f64, f64)| {
        crossing(&removal, (cx, cy), u, half, outer).ok_or_else(|| {
            SpotsError::Spot(format!(
                "the profile from the centre along ({}, {}) leaves the valid data before half maximum",
                u.0, u.1
            ))
        })
    };
    let (right, left) = (walk((1.0, 0.0))?, walk((-1.0, 0.0))?);
    let (up, down) = (walk((0.0, 1.0))?, walk((0.0, -1.0))?);

    // 6. Polished region and whole map.
    let disc = ndarray::Array2::from_shape_fn(removal.dim(), |(i, j)| {
        removal.valid()[(i, j)] && (removal.x_mm(j) - cx).hypot(removal.y_mm(i) - cy) <= r5
    });
    let heights_after_ring = removal.with_heights(removal.heights_nm().mapv(|v| -v))?;
    let region = height_stats(&heights_after_ring.with_valid(disc)?)?;
    let (whole, _) = remove_terms(s, &[Term::Piston, Term::Tilt])?;
    let whole = height_stats(&whole)?;

    let metrics = SpotMetrics {
        dwell_s,
        centre_x_mm: cx,
        centre_y_mm: cy,
        centre_method: method,
        peak_removal_nm: peak,
        peak_rate_nm_per_s: peak / dwell_s,
        volume_rate_nm_mm2_per_s: vol / dwell_s,
        volume_rate_mm3_per_s: vol / dwell_s * 1e-6,
        fwhm_x_mm: left + right,
        fwhm_y_mm: down + up,
        half_width_left_mm: left,
        half_width_right_mm: right,
        half_width_down_mm: down,
        half_width_up_mm: up,
        asymmetry_x: right / left,
        asymmetry_y: up / down,
        aspect_yx: (down + up) / (left + right),
        centroid_offset_x_mm: gx - cx,
        centroid_offset_y_mm: gy - cy,
        centroid_offset_mm: (gx - cx).hypot(gy - cy),
        r5_mm: r5,
        ring_inner_mm: inner,
        ring_outer_mm: outer,
        ring_pixels: bg.ring_pixels,
        noise_rms_nm: bg.ring_residual_rms_nm,
        invalid_in_disc: holes,
        region_rms_nm: region.rms_nm,
        region_pv_nm: region.pv_nm,
        map_rms_nm: whole.rms_nm,
        map_pv_nm: whole.pv_nm,
    };
    Ok(SpotAnalysis { metrics, removal })
}
