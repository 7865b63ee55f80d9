//! `path_offset`: the executed spot sits at a constant offset (dx_mm, dy_mm) from the commanded
//! position (tool-centre calibration, TIF centre off the spindle axis). Linearised columns
//! `-(dK/dx) * D`, `-(dK/dy) * D`. Unlike `registration` it moves only the removal, not the
//! before-map structure.

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct PathOffset {
    pub d: [f64; 2],
}

impl Effect for PathOffset {
    fn kind(&self) -> &'static str {
        "path_offset"
    }
    fn key(&self) -> String {
        "path_offset".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        self.d.to_vec()
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.d.copy_from_slice(&v[..2]);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![0.01, 0.01]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn perturb(&self, _p: &Problem, xs: &mut [f64], ys: &mut [f64]) {
        xs.iter_mut().for_each(|x| *x += self.d[0]);
        ys.iter_mut().for_each(|y| *y += self.d[1]);
    }
    fn params(&self, _lin: &Linear) -> Vec<(String, Param)> {
        vec![
            ("dx_mm".into(), Param::Num(self.d[0])),
            ("dy_mm".into(), Param::Num(self.d[1])),
        ]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("path_offset") {
        return Vec::new();
    }
    let cx: Vec<f64> = cur
        .plain_column(Channel::Dx)
        .into_iter()
        .map(|v| -v)
        .collect();
    let cy: Vec<f64> = cur
        .plain_column(Channel::Dy)
        .into_iter()
        .map(|v| -v)
        .collect();
    vec![Candidate {
        key: "path_offset".into(),
        kind: "path_offset",
        extra: vec![cx, cy],
        make: Box::new(|c, s0| {
            Box::new(PathOffset {
                d: [c[0] / s0, c[1] / s0],
            })
        }),
    }]
}
