//! `rate_oscillation`: the removal rate oscillates in time (pressure or spindle-speed ripple),
//! `rate = rate_0 (1 + a sin(2 pi t / P) + b cos(2 pi t / P))`; amplitude_fraction = hypot(a, b).
//! Detection: periodogram of the residual's rate matched filter `h_k = dt_k (r * K)(p_k)` along
//! time; the columns for sin and cos are exactly linear; the period is refined by variable
//! projection.

use crate::effects::{spectral_peaks, Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct RateOscillation {
    pub period_s: f64,
}

fn terms(p: &Problem, period_s: f64) -> Vec<(String, Vec<f64>)> {
    let w = 2.0 * std::f64::consts::PI / period_s;
    let t = &p.samples;
    vec![
        (
            "rate:osc_sin".into(),
            t.t_s.iter().map(|v| (w * (v - t.t0_s)).sin()).collect(),
        ),
        (
            "rate:osc_cos".into(),
            t.t_s.iter().map(|v| (w * (v - t.t0_s)).cos()).collect(),
        ),
    ]
}

impl Effect for RateOscillation {
    fn kind(&self) -> &'static str {
        "rate_oscillation"
    }
    fn key(&self) -> String {
        "rate_oscillation".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.period_s]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.period_s = v[0].abs().max(1e-6);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![self.period_s * 5e-4]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn rate_terms(&self, p: &Problem) -> Vec<(String, Vec<f64>)> {
        terms(p, self.period_s)
    }
    fn implausible(&self, p: &Problem, lin: &Linear) -> Option<String> {
        let s0 = lin.s0();
        let amp = lin.get("rate:osc_sin").hypot(lin.get("rate:osc_cos")) / s0;
        let duration = p.samples.t1_s - p.samples.t0_s;
        if amp.is_nan() || amp >= 1.0 {
            Some(format!(
                "amplitude {amp:.3} of the rate is not below 1 (the rate would turn negative)"
            ))
        } else if self.period_s > duration {
            Some(format!(
                "period {:.1} s is longer than the run ({duration:.1} s)",
                self.period_s
            ))
        } else {
            None
        }
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        let s0 = lin.s0();
        let (a, b) = (lin.get("rate:osc_sin") / s0, lin.get("rate:osc_cos") / s0);
        vec![
            ("period_s".into(), Param::Num(self.period_s)),
            ("amplitude_fraction".into(), Param::Num(a.hypot(b))),
            ("phase_deg".into(), Param::Num(b.atan2(a).to_degrees())),
        ]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("rate_oscillation") {
        return Vec::new();
    }
    let p = cur.p;
    let s = &p.samples;
    let duration = (s.t1_s - s.t0_s).max(1e-9);
    let mean_feed = s.arc_mm.last().copied().unwrap_or(0.0) / duration;
    let pix = p.grid.dx_mm.max(p.grid.dy_mm);
    let h = cur.matched(Channel::Value);
    let t: Vec<f64> = s.t_s.iter().map(|v| v - s.t0_s).collect();
    let mut out = Vec::new();
    for (period, _) in spectral_peaks(&t, &h, 4.0 * pix / mean_feed.max(1e-9), duration / 2.5, 3) {
        let cols: Vec<Vec<f64>> = terms(p, period)
            .iter()
            .map(|(_, g)| cur.column(&[(&s.centred(g), Channel::Value)]))
            .collect();
        out.push(Candidate {
            key: "rate_oscillation".into(),
            kind: "rate_oscillation",
            extra: cols,
            make: Box::new(move |_, _| Box::new(RateOscillation { period_s: period })),
        });
    }
    out
}
