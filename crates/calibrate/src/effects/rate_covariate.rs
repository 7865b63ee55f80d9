//! `rate_covariate`: the removal rate depends linearly on a covariate of the commanded path,
//! `rate = rate_0 (1 + coefficient * q)`, q in natural units: x, y (mm), feed (mm/s), height (nm)
//! and slope (nm/mm = urad) of the before map without piston/tilt at the tool centre, signed
//! distance to the part edge (mm). (A dependence on time is `rate_drift`.) Exactly linear:
//! column `K * D_q`.
//!
//! "Height without piston/tilt" depends on the region the plane is fitted over (the whole map,
//! the clear aperture, the part): two definitions differ by a plane, which turns
//! `1 + c h` into `1 + c h' + c (a + b x + d y)`. So the height candidate carries rate-vs-x and
//! rate-vs-y companion columns (`lin:` columns: fitted, not reported, and not un-centred into
//! the reference rate, which is therefore the rate at the dwell-weighted mean position). Without
//! them, a run whose generator removed the plane over a round aperture was explained as height
//! plus a spurious drift and x dependence (final 0.66 nm against a 0.42 nm floor).

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

pub const COVARIATES: [(&str, &str); 6] = [
    ("x", "1/mm"),
    ("y", "1/mm"),
    ("feed", "s/mm"),
    ("height", "1/nm"),
    ("slope", "mm/nm"),
    ("edge_distance", "1/mm"),
];

#[derive(Debug, Clone)]
pub struct RateCovariate {
    pub covariate: &'static str,
    pub units: &'static str,
    /// Companion covariates fitted with it but not reported (the height's reference plane).
    pub companions: Vec<&'static str>,
}

impl RateCovariate {
    fn col(&self) -> String {
        format!("rate:cov:{}", self.covariate)
    }
}

/// Companions of a covariate (see the module note), leaving out covariates already accepted
/// as effects of their own (their columns would be duplicated).
fn companions(name: &str, cur: &Current) -> Vec<&'static str> {
    match name {
        "height" => ["x", "y"]
            .into_iter()
            .filter(|c| !cur.has(&format!("rate_covariate:{c}")))
            .collect(),
        _ => Vec::new(),
    }
}

impl Effect for RateCovariate {
    fn kind(&self) -> &'static str {
        "rate_covariate"
    }
    fn key(&self) -> String {
        format!("rate_covariate:{}", self.covariate)
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn rate_terms(&self, p: &Problem) -> Vec<(String, Vec<f64>)> {
        let values = |name: &str| {
            p.covariates
                .get(name)
                .map(|v| v.to_vec())
                .unwrap_or_default()
        };
        let mut terms = vec![(self.col(), values(self.covariate))];
        for c in &self.companions {
            terms.push((format!("lin:{}:ref_{c}", self.col()), values(c)));
        }
        terms
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        vec![
            ("covariate".into(), Param::Text(self.covariate.into())),
            (
                "coefficient".into(),
                Param::Num(lin.get(&self.col()) / lin.s0()),
            ),
            ("coefficient_units".into(), Param::Text(self.units.into())),
        ]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    let mut out = Vec::new();
    for (name, units) in COVARIATES {
        let e = RateCovariate {
            covariate: name,
            units,
            companions: Vec::new(),
        };
        if cur.has(&e.key()) {
            continue;
        }
        let Some(q) = cur.p.covariates.get(name) else {
            continue;
        };
        let centred = |q: &[f64]| -> Vec<f64> {
            let mean = cur.p.samples.dwell_mean(q);
            q.iter().map(|v| v - mean).collect()
        };
        let g = centred(q);
        if g.iter().all(|v| v.abs() < 1e-12) {
            continue;
        }
        let comp = companions(name, cur);
        let mut extra = vec![cur.column(&[(&g, Channel::Value)])];
        for c in &comp {
            if let Some(qc) = cur.p.covariates.get(c) {
                extra.push(cur.column(&[(&centred(qc), Channel::Value)]));
            }
        }
        out.push(Candidate {
            key: e.key(),
            kind: "rate_covariate",
            extra,
            make: Box::new(move |_, _| {
                Box::new(RateCovariate {
                    covariate: name,
                    units,
                    companions: comp.clone(),
                })
            }),
        });
    }
    out
}
