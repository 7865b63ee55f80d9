//! `registration`: the after map is shifted by (dx_mm, dy_mm) and rotated by rotation_deg about
//! the map centre c against the before map and the path frame: a feature at true position p
//! appears in the after map at `R(theta)(p - c) + c + d`. Corrected by resampling the after map;
//! detected from the gradient of the (current) after map: `M(theta0) ~ M(theta) +
//! (theta - theta0) . G`, `G = [dA/dx, dA/dy, -(y - cy) dA/dx + (x - cx) dA/dy]`
//! (A lightly smoothed so its noise does not bias the fit).

use crate::effects::{Candidate, Current};
use crate::grid::smooth_masked;
use crate::model::{Effect, Linear, Param};

#[derive(Debug, Clone)]
pub struct Registration {
    /// dx_mm, dy_mm, rotation (rad).
    pub p: [f64; 3],
    pub pixel_mm: f64,
}

impl Effect for Registration {
    fn kind(&self) -> &'static str {
        "registration"
    }
    fn key(&self) -> String {
        "registration".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        self.p.to_vec()
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.p.copy_from_slice(&v[..3]);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![0.05 * self.pixel_mm, 0.05 * self.pixel_mm, 2e-5]
    }
    fn registration(&self) -> Option<[f64; 3]> {
        Some(self.p)
    }
    fn params(&self, _lin: &Linear) -> Vec<(String, Param)> {
        vec![
            ("dx_mm".into(), Param::Num(self.p[0])),
            ("dy_mm".into(), Param::Num(self.p[1])),
            ("rotation_deg".into(), Param::Num(self.p[2].to_degrees())),
        ]
    }
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("registration") {
        return Vec::new();
    }
    let p = cur.p;
    let g = &p.grid;
    let a = smooth_masked(&cur.ev.after_res, &cur.ev.after_res_valid, 1.0);
    let (r, c) = a.dim();
    let (cx, cy) = g.centre_mm();
    let mut gx = ndarray::Array2::<f64>::zeros((r, c));
    let mut gy = gx.clone();
    let mut gr = gx.clone();
    for i in 0..r {
        for j in 0..c {
            let (jp, jm) = ((j + 1).min(c - 1), j.saturating_sub(1));
            let (ip, im) = ((i + 1).min(r - 1), i.saturating_sub(1));
            let dx = (a[(i, jp)] - a[(i, jm)]) / ((jp - jm).max(1) as f64 * g.dx_mm);
            let dy = (a[(ip, j)] - a[(im, j)]) / ((ip - im).max(1) as f64 * g.dy_mm);
            gx[(i, j)] = dx;
            gy[(i, j)] = dy;
            gr[(i, j)] = -(g.y_mm(i) - cy) * dx + (g.x_mm(j) - cx) * dy;
        }
    }
    let base = cur.ev.reg;
    let pix = g.dx_mm.max(g.dy_mm);
    vec![Candidate {
        key: "registration".into(),
        kind: "registration",
        extra: vec![p.compress(&gx), p.compress(&gy), p.compress(&gr)],
        make: Box::new(move |c, _s0| {
            Box::new(Registration {
                p: [base[0] + c[0], base[1] + c[1], base[2] + c[2]],
                pixel_mm: pix,
            })
        }),
    }]
}
