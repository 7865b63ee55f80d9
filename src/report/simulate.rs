//! Rendering of a simulation (`pipeline::simulate`): the spindle-sweep CSV, the PSD and sweep
//! plots, and the one-line summary.

use std::path::Path;

use bonnetlab_spectrum::Psd1d;
use bonnetlab_vibration::coupling::SweepRow;
use bonnetlab_vibration::params::Bonnet;

use super::format;
use super::plot::{LinePlot, PlotError, Series};
use crate::pipeline::simulate::{Simulation, SimulationReport};

/// The sweep as CSV text: one row per (rpm, bonnet), mechanisms' band RMS as columns.
pub fn sweep_csv(rows: &[SweepRow]) -> String {
    let mut out = String::from(
        "spindle_rpm,bonnet,x1_amplitude_mm,x2_amplitude_mm,offset_amplitude_mm,\
         induced_msf_band_rms_nm,ripple_sigma1_nm",
    );
    if let Some(r) = rows.first() {
        for m in &r.mechanisms {
            out.push_str(&format!(",{}_msf_band_rms_nm", m.name));
        }
    }
    out.push('\n');
    for r in rows {
        out.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e},{}",
            r.spindle_rpm,
            r.bonnet.name(),
            r.x1_amplitude_mm,
            r.x2_amplitude_mm,
            r.offset_amplitude_mm,
            r.induced_msf_band_rms_nm,
            r.ripple_sigma1_nm
                .map(|v| format!("{v:e}"))
                .unwrap_or_default()
        ));
        for m in &r.mechanisms {
            out.push_str(&format!(",{:e}", m.msf_band_rms_nm));
        }
        out.push('\n');
    }
    out
}

/// The one line `simulate` prints on success.
pub fn summary(out: &Path, r: &SimulationReport) -> String {
    let fixed = format::fixed;
    let ripple = match &r.ripple {
        Some(p) => format!(
            ", ripple sigma1 {} nm at the {} mm pitch",
            fixed(p.sigma1_nm, 4),
            format::sig(p.pitch_mm, 4)
        ),
        None => String::new(),
    };
    let sweep = match &r.spindle_sweep {
        Some(rows) if !rows.is_empty() => {
            let rpm = |f: fn(f64, f64) -> f64| {
                rows.iter()
                    .map(|row| row.spindle_rpm)
                    .fold(rows[0].spindle_rpm, f)
            };
            format!(
                "; spindle sweep ({} rows, {} to {} rpm) in {} and spindle_sweep.png",
                rows.len(),
                format::sig(rpm(f64::min), 6),
                format::sig(rpm(f64::max), 6),
                out.join("spindle_sweep.csv").display()
            )
        }
        _ => String::new(),
    };
    format!(
        "simulate: wrote {} ({}, {} bonnet): RMS {} -> {} nm predicted (CR {}, piston and tilt removed){ripple}{sweep}",
        out.join("simulation.json").display(),
        r.mode,
        r.bonnet,
        fixed(r.rms_before_nm, 3),
        fixed(r.rms_after_nm, 3),
        r.cr_rms
            .map_or("undefined: flat before map".into(), |c| fixed(100.0 * c, 1) + " %"),
    )
}

/// The PSD along Y of the before and predicted after maps (log-log, grating markers at the
/// recipe's pitch), as PNG.
pub fn psd_y_png(sim: &Simulation) -> Result<Vec<u8>, PlotError> {
    let positive = |p: &Psd1d| -> (Vec<f64>, Vec<f64>) {
        p.freq_per_mm
            .iter()
            .zip(&p.psd_nm2_mm)
            .filter(|(f, v)| **f > 0.0 && **v > 0.0)
            .map(|(f, v)| (*f, *v))
            .unzip()
    };
    let (fb, vb) = positive(&sim.psd_y_before);
    let (fa, va) = positive(&sim.psd_y_after);
    let mut plot = LinePlot::new(
        "PSD along Y (one-sided, Hann, piston+tilt removed)",
        "frequency (1/mm)",
        "PSD (nm^2 mm)",
    )
    .log_log()
    .series(Series::new("before", fb, vb))
    .series(Series::new("predicted after", fa, va));
    if let Some(p) = sim.report.pitch_mm {
        plot = plot.grating_markers(p, 3);
    }
    plot.to_png()
}

/// The predicted removal ripple σ1 against spindle speed, one curve per bonnet, as PNG.
pub fn spindle_sweep_png(rows: &[SweepRow]) -> Result<Vec<u8>, PlotError> {
    let mut plot = LinePlot::new(
        "predicted removal ripple sigma1 (Y, 1/pitch) vs spindle speed",
        "spindle speed (rpm)",
        "sigma1 (nm)",
    );
    for b in Bonnet::ALL {
        let (x, y): (Vec<f64>, Vec<f64>) = rows
            .iter()
            .filter(|r| r.bonnet == b)
            .filter_map(|r| r.ripple_sigma1_nm.map(|s| (r.spindle_rpm, s)))
            .unzip();
        if !x.is_empty() {
            plot = plot.series(Series::new(b.name(), x, y));
        }
    }
    plot.to_png()
}
