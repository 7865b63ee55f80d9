//! `tif_scale`: the working spot is the measured one widened by `scale` (`T_s(r) = T(r / s)`;
//! its peak rate is left to the global rate fit). Linearised column `(dK/ds) * D`.

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, MAX_SCALE};

#[derive(Debug, Clone)]
pub struct TifScale {
    pub scale: f64,
}

impl Effect for TifScale {
    fn kind(&self) -> &'static str {
        "tif_scale"
    }
    fn key(&self) -> String {
        "tif_scale".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.scale]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.scale = v[0].clamp(0.5, MAX_SCALE);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![0.004]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn scale(&self) -> f64 {
        self.scale
    }
    fn params(&self, _lin: &Linear) -> Vec<(String, Param)> {
        vec![("scale".into(), Param::Num(self.scale))]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("tif_scale") {
        return Vec::new();
    }
    let col = cur.plain_column(Channel::Ds);
    let s = cur.ev.scale;
    vec![Candidate {
        key: "tif_scale".into(),
        kind: "tif_scale",
        extra: vec![col],
        make: Box::new(move |c, s0| {
            Box::new(TifScale {
                scale: (s + c[0] / s0).clamp(0.5, MAX_SCALE),
            })
        }),
    }]
}
