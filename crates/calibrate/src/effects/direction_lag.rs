//! `direction_lag`: the spot trails the commanded position along the direction of travel:
//! executed = commanded - lag_mm * u (u the unit travel direction of the commanded path).
//! Linearised column `(dK/dx) * D_{ux} + (dK/dy) * D_{uy}` (from `K(x - p + L u)`).

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct DirectionLag {
    pub lag_mm: f64,
}

impl Effect for DirectionLag {
    fn kind(&self) -> &'static str {
        "direction_lag"
    }
    fn key(&self) -> String {
        "direction_lag".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.lag_mm]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.lag_mm = v[0];
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![0.01]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn perturb(&self, p: &Problem, xs: &mut [f64], ys: &mut [f64]) {
        for k in 0..xs.len() {
            xs[k] -= self.lag_mm * p.samples.ux[k];
            ys[k] -= self.lag_mm * p.samples.uy[k];
        }
    }
    fn implausible(&self, p: &Problem, _lin: &Linear) -> Option<String> {
        (self.lag_mm.abs() > p.tif_radius_mm).then(|| {
            format!(
                "lag {:.3} mm is larger than the spot (radius {:.3} mm)",
                self.lag_mm.abs(),
                p.tif_radius_mm
            )
        })
    }
    fn params(&self, _lin: &Linear) -> Vec<(String, Param)> {
        vec![("lag_mm".into(), Param::Num(self.lag_mm))]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("direction_lag") {
        return Vec::new();
    }
    let s = &cur.p.samples;
    let col = cur.column(&[(&s.ux, Channel::Dx), (&s.uy, Channel::Dy)]);
    vec![Candidate {
        key: "direction_lag".into(),
        kind: "direction_lag",
        extra: vec![col],
        make: Box::new(|c, s0| Box::new(DirectionLag { lag_mm: c[0] / s0 })),
    }]
}
