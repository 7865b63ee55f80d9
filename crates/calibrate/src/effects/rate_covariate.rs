//! `rate_covariate`: the removal rate depends linearly on a covariate of the commanded path,
//! `rate = rate_0 (1 + coefficient * q)`, q in natural units: x, y (mm), feed (mm/s), height (nm)
//! and slope (nm/mm = urad) of the before map without piston/tilt at the tool centre, signed
//! distance to the part edge (mm). (A dependence on time is `rate_drift`.) Exactly linear:
//! column `K * D_q`.

use crate::effects::{Candidate, Current};
use crate::model::{Effect, Linear, Param, Problem};

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
}

impl RateCovariate {
    fn col(&self) -> String {
        format!("rate:cov:{}", self.covariate)
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
        vec![(
            self.col(),
            p.covariates
                .get(self.covariate)
                .map(|v| v.to_vec())
                .unwrap_or_default(),
        )]
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
        };
        if cur.has(&e.key()) {
            continue;
        }
        let Some(q) = cur.p.covariates.get(name) else {
            continue;
        };
        let mean = cur.p.samples.dwell_mean(q);
        let g: Vec<f64> = q.iter().map(|v| v - mean).collect();
        if g.iter().all(|v| v.abs() < 1e-12) {
            continue;
        }
        let col = cur.column(&[(&g, &cur.ev.kernels.k)]);
        out.push(Candidate {
            key: e.key(),
            kind: "rate_covariate",
            extra: vec![col],
            make: Box::new(move |_, _| {
                Box::new(RateCovariate {
                    covariate: name,
                    units,
                })
            }),
        });
    }
    out
}
