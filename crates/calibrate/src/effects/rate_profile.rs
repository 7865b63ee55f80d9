//! `rate_profile_time`: a generic slow rate variation in time, piecewise linear between
//! `KNOTS` equally spaced knots in run-time fraction (the first knot is the reference, so the
//! profile is relative to the rate at the start). It absorbs rate histories outside the exact
//! forms of `rate_drift` / `rate_step` / `rate_oscillation`; selection prefers those when they
//! fit as well, since the profile spends more parameters.

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

pub const KNOTS: usize = 7;

#[derive(Debug, Clone)]
pub struct RateProfile;

fn hats(p: &Problem) -> Vec<(String, Vec<f64>)> {
    let n = KNOTS - 1;
    (1..KNOTS)
        .map(|m| {
            let c = m as f64 / n as f64;
            let g = (0..p.samples.len())
                .map(|k| (1.0 - ((p.samples.tau(k) - c) * n as f64).abs()).max(0.0))
                .collect();
            (format!("rate:hat{m}"), g)
        })
        .collect()
}

impl Effect for RateProfile {
    fn kind(&self) -> &'static str {
        "rate_profile_time"
    }
    fn key(&self) -> String {
        "rate_profile_time".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn rate_terms(&self, p: &Problem) -> Vec<(String, Vec<f64>)> {
        hats(p)
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        let s0 = lin.s0();
        let mut v = vec![(
            "knots_fraction".into(),
            Param::List((0..KNOTS).map(|m| m as f64 / (KNOTS - 1) as f64).collect()),
        )];
        let mut rel = vec![0.0];
        rel.extend((1..KNOTS).map(|m| lin.get(&format!("rate:hat{m}")) / s0));
        v.push(("rate_change_fraction".into(), Param::List(rel)));
        v
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("rate_profile_time") {
        return Vec::new();
    }
    let s = &cur.p.samples;
    let cols = hats(cur.p)
        .iter()
        .map(|(_, g)| cur.column(&[(&s.centred(g), Channel::Value)]))
        .collect();
    vec![Candidate {
        key: "rate_profile_time".into(),
        kind: "rate_profile_time",
        extra: cols,
        make: Box::new(|_, _| Box::new(RateProfile)),
    }]
}
