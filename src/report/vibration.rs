//! The vibration response for people (the summary lines, the FRF plots) and pipelines (the
//! tool-tip time series as CSV).

use std::fmt::Write as _;

use bonnetlab_vibration::modal::MODES;
use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use bonnetlab_vibration::response::FrfPoint;
use bonnetlab_vibration::timeseries::TimeSeries;

use super::format::{fixed, sig};
use super::plot::{LinePlot, Series};
use crate::pipeline::vibration::BonnetOut;

/// `vibration: wrote FILES: original offset A mm, suppression offset B mm at N rpm`: the
/// success line when the JSON went to a file.
pub fn written_line(wrote: &[String], outs: &[BonnetOut]) -> String {
    let per: Vec<String> = outs
        .iter()
        .map(|o| {
            format!(
                "{} offset amplitude {} mm (transfer {})",
                o.response.bonnet.name(),
                sig(o.response.offset_amplitude_mm, 4),
                sig(o.offset_transfer, 3)
            )
        })
        .collect();
    format!(
        "vibration: wrote {}: {}",
        wrote.join(" and "),
        per.join(", ")
    )
}

/// The text summary (principal frame, force, each bonnet's response and peaks, the robot's
/// modes), one fact a line.
pub fn summary(p: &VibrationParams, outs: &[BonnetOut]) -> String {
    let mut s = String::new();
    let f = p.natural_freq_hz();
    let _ = writeln!(
        s,
        "principal frame: k1 {:.1} N/mm, k2 {:.1} N/mm, theta {:.2} deg, m {:.2} kg -> f1 {:.2} Hz, f2 {:.2} Hz",
        p.k1_n_per_mm, p.k2_n_per_mm, p.theta_deg, p.mass_kg, f[0], f[1]
    );
    let _ = writeln!(
        s,
        "force: Fn {:.3} N, mu {:.3}; spindle {:.0} rpm = {:.3} Hz",
        p.fn_n,
        p.mu,
        p.spindle_rpm,
        p.excitation_hz()
    );
    for o in outs {
        let r = &o.response;
        let _ = writeln!(
            s,
            "{:<12} zeta ({:.4}, {:.4})  X1 {:.3e} mm @ {:.1} deg  X2 {:.3e} mm @ {:.1} deg  offset {:.3e} mm (transfer {:.3})",
            r.bonnet.name(),
            r.zeta1_effective,
            r.zeta2_effective,
            r.x1_amplitude_mm,
            r.x1_phase_deg,
            r.x2_amplitude_mm,
            r.x2_phase_deg,
            r.offset_amplitude_mm,
            o.offset_transfer
        );
        for pk in &o.peaks {
            let _ = writeln!(
                s,
                "             peak x{} {:.3e} mm at {:.2} Hz ({:.0} rpm)",
                pk.direction,
                pk.amplitude_mm,
                pk.freq_hz,
                pk.freq_hz * 60.0
            );
        }
    }
    let modes: Vec<String> = MODES
        .iter()
        .map(|m| format!("{}:{} Hz", m.order, fixed(m.best_hz(), 2)))
        .collect();
    let _ = writeln!(
        s,
        "robot modes (measured where available): {}",
        modes.join(", ")
    );
    s
}

/// The steady-response plot along `x{dof + 1}` (`dof` 0 or 1) of each bonnet's spindle-band
/// FRF (the paper's figures 10 and 15), the spindle speed and the robot's modes marked.
pub fn frf_plot(p: &VibrationParams, curves: &[(Bonnet, Vec<FrfPoint>)], dof: usize) -> LinePlot {
    let mut plot = LinePlot::new(
        format!(
            "Steady response along x{} (Fn {} N, mu {})",
            dof + 1,
            p.fn_n,
            p.mu
        ),
        "excitation frequency n/60 (Hz)",
        format!("x{} amplitude (mm)", dof + 1),
    );
    for (b, c) in curves {
        let x: Vec<f64> = c.iter().map(|q| q.freq_hz).collect();
        let y: Vec<f64> = c
            .iter()
            .map(|q| {
                if dof == 0 {
                    q.x1_amplitude_mm
                } else {
                    q.x2_amplitude_mm
                }
            })
            .collect();
        plot = plot.series(Series::new(format!("{} bonnet", b.name()), x, y));
    }
    plot = plot.marker(
        p.excitation_hz(),
        format!("spindle {} rpm", fixed(p.spindle_rpm, 0)),
    );
    for m in MODES.iter() {
        plot = plot.marker(m.best_hz(), format!("mode {}", m.order));
    }
    plot
}

/// The tool-tip time series as CSV: `t_s,x1_mm,x2_mm,normal_mm,lateral_mm,offset_change_mm`.
pub fn timeseries_csv(ts: &TimeSeries) -> Vec<u8> {
    use std::io::Write as _;
    let mut buf = Vec::with_capacity(ts.t_s.len() * 80);
    let _ = writeln!(buf, "t_s,x1_mm,x2_mm,normal_mm,lateral_mm,offset_change_mm");
    for k in 0..ts.t_s.len() {
        let _ = writeln!(
            buf,
            "{:.4},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e}",
            ts.t_s[k],
            ts.x1_mm[k],
            ts.x2_mm[k],
            ts.normal_mm[k],
            ts.lateral_mm[k],
            ts.offset_change_mm[k]
        );
    }
    buf
}
