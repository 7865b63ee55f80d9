//! The dwell trade-off curve for people (a plot) and pipelines (CSV columns): residual RMS (nm)
//! against total dwell (min), the chosen point and the case's reference methods marked; and the
//! one-line summary of `bonnetlab dwell`.

use super::format::sig;
use super::plot::{LinePlot, PlotError, Series, PALETTE};
use crate::pipeline::dwell::DwellReport;
use bonnetlab_process::dwell::TradeOffPoint;

/// `dwell: wrote A and B: method M, total dwell T min, residual RMS R nm (PV P nm) in the clear
/// aperture`: one line, numbers to their precision.
pub fn summary(r: &DwellReport, wrote: &[String]) -> String {
    format!(
        "dwell: wrote {}: {}, total dwell {} min, residual RMS {} nm (PV {} nm) in the clear aperture{}",
        wrote.join(" and "),
        r.method,
        sig(r.total_dwell_s / 60.0, 4),
        sig(r.residual_rms_nm, 4),
        sig(r.residual_pv_nm, 4),
        if r.target_met { "" } else { "; target not met" },
    )
}

/// The reference methods' (total dwell min, residual nm) points of a case's `[reference]`.
pub fn reference_points(reference: Option<&serde_json::Value>) -> Vec<RefPoint> {
    let Some(obj) = reference.and_then(|v| v.as_object()) else {
        return Vec::new();
    };
    obj.iter()
        .filter_map(|(name, v)| {
            let min = v.get("total_dwell_min")?.as_f64()?;
            let rms = v.get("residual_rms_nm")?.as_f64()?;
            Some((name.clone(), min, rms))
        })
        .collect()
}

/// CSV header and columns of a trade-off curve: extra uniform removal (nm), total dwell (min),
/// residual RMS (nm).
pub fn trade_off_columns(curve: &[TradeOffPoint]) -> ([&'static str; 3], [Vec<f64>; 3]) {
    (
        ["offset_nm", "total_dwell_min", "residual_rms_nm"],
        [
            curve.iter().map(|p| p.parameter).collect(),
            curve.iter().map(|p| p.total_dwell_s / 60.0).collect(),
            curve.iter().map(|p| p.residual_rms_nm).collect(),
        ],
    )
}

/// A reference method's point: name, total dwell (min), residual RMS (nm).
pub type RefPoint = (String, f64, f64);

/// The trade-off plot (PNG bytes): the curve, the chosen point and the reference points.
pub fn trade_off_png(
    curve: &[TradeOffPoint],
    chosen: &TradeOffPoint,
    references: &[RefPoint],
) -> Result<Vec<u8>, PlotError> {
    let mut plot = LinePlot::new(
        "dwell trade-off: residual vs total dwell",
        "total dwell (min)",
        "residual RMS in the clear aperture (nm, piston + tilt removed)",
    )
    .series(
        Series::new(
            "min-dwell sweep (extra uniform removal)",
            curve.iter().map(|p| p.total_dwell_s / 60.0).collect(),
            curve.iter().map(|p| p.residual_rms_nm).collect(),
        )
        .colour(PALETTE[0]),
    )
    .series(
        Series::new(
            "chosen",
            vec![chosen.total_dwell_s / 60.0; 2],
            vec![chosen.residual_rms_nm * 0.97, chosen.residual_rms_nm * 1.03],
        )
        .colour(PALETTE[1]),
    );
    for (k, (name, min, rms)) in references.iter().enumerate() {
        plot = plot.series(
            Series::new(
                format!("reference: {name}"),
                vec![min * 0.99, min * 1.01],
                vec![*rms, *rms],
            )
            .colour(PALETTE[2 + k % 5])
            .dashed(),
        );
    }
    plot.to_png()
}
