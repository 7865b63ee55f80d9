//! `registration`: the after map is shifted by (dx_mm, dy_mm) and rotated by rotation_deg about
//! the map centre c against the before map and the path frame: a feature at true position p
//! appears in the after map at `R(theta)(p - c) + c + d`. Corrected by resampling the after map;
//! detected from the gradient of the (current) after map: `M(theta0) ~ M(theta) +
//! (theta - theta0) . G`, `G = [dA/dx, dA/dy, -(y - cy) dA/dx + (x - cx) dA/dy]`
//! (A lightly smoothed so its noise does not bias the fit).
//!
//! The same smoothed gradient is the refinement's Jacobian for these three parameters
//! ([`jacobian`]): finite differences of the resampled *noisy* map carry the noise's own
//! gradient, which on fine pixels outweighs the surface's (0.3 nm white noise on 0.125 mm
//! pixels: ~4 nm/mm against ~2.5 nm/mm of MSF slope). Gauss-Newton then sees a curvature the
//! expected objective does not have, takes steps a fraction of the way and stalls (0.018 mm
//! short on dy in an 800 x 800 run while the objective kept falling towards the truth).

use crate::effects::{Candidate, Current};
use crate::grid::smooth_masked;
use ndarray::Array2;

use crate::model::{Effect, Eval, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct Registration {
    /// dx_mm, dy_mm, rotation (rad).
    pub p: [f64; 3],
    pub pixel_mm: f64,
    /// Centre of the rotation: the map centre (mm), reported so that the convention is explicit.
    pub centre_mm: (f64, f64),
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
            (
                "convention".into(),
                Param::Text(format!(
                    "a feature at p in the before map appears in the after map at \
                     R(rotation) (p - c) + c + (dx, dy), c = ({:.4}, {:.4}) mm, the map centre",
                    self.centre_mm.0, self.centre_mm.1
                )),
            ),
        ]
    }
}

/// Derivatives of the resampled after map `A(T_theta x)` with respect to (dx, dy, theta) at
/// the evaluation's registration, from the map lightly smoothed (sigma 1 px), as full maps.
pub fn after_derivatives(p: &Problem, ev: &Eval) -> [Array2<f64>; 3] {
    after_derivatives_at(p, &ev.after_res, &ev.after_res_valid, ev.reg, 1.0)
}

/// [`after_derivatives`] of an after map resampled at registration `reg`.
fn after_derivatives_at(
    p: &Problem,
    after_res: &Array2<f64>,
    valid: &Array2<bool>,
    reg: [f64; 3],
    sigma_px: f64,
) -> [Array2<f64>; 3] {
    let g = &p.grid;
    let a = smooth_masked(after_res, valid, sigma_px);
    let (r, c) = a.dim();
    let (cx, cy) = g.centre_mm();
    let (ct, st) = (reg[2].cos(), reg[2].sin());
    let mut gx = Array2::<f64>::zeros((r, c));
    let mut gy = gx.clone();
    let mut gr = gx.clone();
    for i in 0..r {
        for j in 0..c {
            let (jp, jm) = ((j + 1).min(c - 1), j.saturating_sub(1));
            let (ip, im) = ((i + 1).min(r - 1), i.saturating_sub(1));
            // Gradient of the resampled map in map coordinates, rotated into the after map's
            // frame: grad A(T x) = R(theta) grad_x (A o T)(x).
            let sx = (a[(i, jp)] - a[(i, jm)]) / ((jp - jm).max(1) as f64 * g.dx_mm);
            let sy = (a[(ip, j)] - a[(im, j)]) / ((ip - im).max(1) as f64 * g.dy_mm);
            let (ax, ay) = (ct * sx - st * sy, st * sx + ct * sy);
            let (ux, uy) = (g.x_mm(j) - cx, g.y_mm(i) - cy);
            gx[(i, j)] = ax;
            gy[(i, j)] = ay;
            // d/dtheta of R(theta) u = (-sin u_x - cos u_y, cos u_x - sin u_y)
            gr[(i, j)] = ax * (-st * ux - ct * uy) + ay * (ct * ux - st * uy);
        }
    }
    [gx, gy, gr]
}

/// Jacobian columns of the residual `m - prediction` (m = before - A o T) with respect to
/// (dx, dy, theta) on the analysis pixels: `-dA(T x)/dtheta`, 0 where the pixel is not used.
pub fn jacobian(p: &Problem, ev: &Eval) -> Vec<Vec<f64>> {
    jacobian_smoothed(p, ev, 1.0)
}

/// [`jacobian`] from the after map smoothed with `sigma_px` (pixels) instead of 1 px: a second
/// estimating equation for the same parameters. Where the residual holds structure that does
/// not resample identically (sub-pixel texture alias), the two equations have different zeros,
/// and their distance measures the registration's systematic error (see `uncertainty`).
pub fn jacobian_smoothed(p: &Problem, ev: &Eval, sigma_px: f64) -> Vec<Vec<f64>> {
    after_derivatives_at(p, &ev.after_res, &ev.after_res_valid, ev.reg, sigma_px)
        .iter()
        .map(|d| {
            p.compress(d)
                .into_iter()
                .zip(&ev.w)
                .map(|(v, w)| -v * w)
                .collect()
        })
        .collect()
}

pub fn candidates(cur: &Current) -> Vec<Candidate> {
    if cur.has("registration") {
        return Vec::new();
    }
    let p = cur.p;
    let g = &p.grid;
    let base = cur.ev.reg;
    let pix = g.dx_mm.max(g.dy_mm);
    let centre = g.centre_mm();
    // A coarse estimate far from the current state (more than half a pixel anywhere on the
    // map): linearise there instead, with one more column for the jump to it.
    let radius = 0.5 * (g.cols as f64 * g.dx_mm).hypot(g.rows as f64 * g.dy_mm);
    if let Some(c) = p
        .coarse()
        .filter(|c| c.peak_ratio >= crate::coarse::MIN_PEAK_RATIO)
    {
        let jump =
            (c.reg[0] - base[0]).hypot(c.reg[1] - base[1]) + radius * (c.reg[2] - base[2]).abs();
        if jump > 0.5 * pix {
            let (a0, v0) = p.resample_after(c.reg);
            let both: Vec<bool> = p
                .idx
                .iter()
                .map(|&k| {
                    let ij = (k / g.cols, k % g.cols);
                    v0[ij] && cur.ev.after_res_valid[ij]
                })
                .collect();
            // m(current) - m(coarse) = A(coarse) - A(current): coefficient 1 at the coarse state.
            let jump_col: Vec<f64> = p
                .compress(&(&a0 - &cur.ev.after_res))
                .into_iter()
                .zip(&both)
                .map(|(v, &ok)| if ok { v } else { 0.0 })
                .collect();
            let [gx, gy, gr] = after_derivatives_at(p, &a0, &v0, c.reg, 1.0);
            let at = c.reg;
            return vec![Candidate {
                key: "registration".into(),
                kind: "registration",
                extra: vec![jump_col, p.compress(&gx), p.compress(&gy), p.compress(&gr)],
                make: Box::new(move |k, _s0| {
                    Box::new(Registration {
                        p: [at[0] + k[1], at[1] + k[2], at[2] + k[3]],
                        pixel_mm: pix,
                        centre_mm: centre,
                    })
                }),
            }];
        }
    }
    let [gx, gy, gr] = after_derivatives(p, cur.ev);
    vec![Candidate {
        key: "registration".into(),
        kind: "registration",
        extra: vec![p.compress(&gx), p.compress(&gy), p.compress(&gr)],
        make: Box::new(move |c, _s0| {
            Box::new(Registration {
                p: [base[0] + c[0], base[1] + c[1], base[2] + c[2]],
                pixel_mm: pix,
                centre_mm: centre,
            })
        }),
    }]
}
