//! `rate_step`: the removal rate jumps once (a pressure or slurry change),
//! `rate = rate_0 (1 + fraction * H(tau - at_fraction))`, tau = run-time fraction.
//! Detection: CUSUM of the residual's rate matched filter along time, normalised by the step's
//! dwell variance; the column is exactly linear, the step time refined by variable projection.

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct RateStep {
    pub at_tau: f64,
}

const COL: &str = "rate:step";

fn step(p: &Problem, at: f64) -> Vec<f64> {
    (0..p.samples.len())
        .map(|k| if p.samples.tau(k) >= at { 1.0 } else { 0.0 })
        .collect()
}

impl Effect for RateStep {
    fn kind(&self) -> &'static str {
        "rate_step"
    }
    fn key(&self) -> String {
        "rate_step".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.at_tau]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.at_tau = v[0].clamp(0.0, 1.0);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![0.004]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn rate_terms(&self, p: &Problem) -> Vec<(String, Vec<f64>)> {
        vec![(COL.into(), step(p, self.at_tau))]
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        vec![
            ("at_fraction".into(), Param::Num(self.at_tau)),
            ("fraction".into(), Param::Num(lin.get(COL) / lin.s0())),
        ]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("rate_step") {
        return Vec::new();
    }
    let p = cur.p;
    let s = &p.samples;
    let h = cur.matched(Channel::Value);
    let wt: f64 = s.dt_s.iter().sum();
    let ht: f64 = h.iter().sum();
    // Scan from the end: after-sums of h and dwell.
    let (mut ha, mut wa) = (0.0, 0.0);
    let mut best = (0.0, 0.5);
    for k in (0..s.len()).rev() {
        ha += h[k];
        wa += s.dt_s[k];
        let tau = s.tau(k);
        if !(0.03..=0.97).contains(&tau) {
            continue;
        }
        let wb = wt - wa;
        let score = (ha - ht * wa / wt).powi(2) / (wa * wb / wt).max(1e-300);
        if score > best.0 {
            best = (score, tau);
        }
    }
    let at = best.1;
    let g = step(p, at);
    let m = s.dwell_mean(&g);
    let gc: Vec<f64> = g.iter().map(|v| v - m).collect();
    let col = cur.column(&[(&gc, Channel::Value)]);
    vec![Candidate {
        key: "rate_step".into(),
        kind: "rate_step",
        extra: vec![col],
        make: Box::new(move |_, _| Box::new(RateStep { at_tau: at })),
    }]
}
