//! `rate_drift`: the removal rate changes linearly in time, `rate(t) = rate_start (1 + f tau)`,
//! tau = run-time fraction 0..1; `fraction_per_run` = f (relative to the rate at the start).
//! Exactly linear: column `K * D_tau`.

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct RateDrift;

const COL: &str = "rate:tau";

fn tau(p: &Problem) -> Vec<f64> {
    (0..p.samples.len()).map(|k| p.samples.tau(k)).collect()
}

impl Effect for RateDrift {
    fn kind(&self) -> &'static str {
        "rate_drift"
    }
    fn key(&self) -> String {
        "rate_drift".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn rate_terms(&self, p: &Problem) -> Vec<(String, Vec<f64>)> {
        vec![(COL.into(), tau(p))]
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        let f = lin.get(COL) / lin.s0();
        vec![("fraction_per_run".into(), Param::Num(f))]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("rate_drift") {
        return Vec::new();
    }
    let t = tau(cur.p);
    let g = cur.p.samples.centred(&t);
    let col = cur.column(&[(&g, Channel::Value)]);
    vec![Candidate {
        key: "rate_drift".into(),
        kind: "rate_drift",
        extra: vec![col],
        make: Box::new(|_, _| Box::new(RateDrift)),
    }]
}
