//! `rate_step`: the removal rate jumps once (a pressure or slurry change),
//! `rate = rate_0 (1 + fraction * H(tau - at_fraction))`, tau = run-time fraction.
//! Detection: CUSUM of the residual's rate matched filter along time, normalised by the step's
//! dwell variance; the column is exactly linear, the step time refined by variable projection.

use crate::effects::{Candidate, Current};
use crate::model::{Channel, Effect, Linear, Param, Problem};

#[derive(Debug, Clone)]
pub struct RateStep {
    pub at_tau: f64,
    /// The step time's scan step and the uncertainties' difference step (run-time fraction):
    /// [`scan_step`], inside the span where the residual is quadratic in the step time (0 when
    /// the run has no feed: no scan, and the uncertainties take [`REFINE_STEP`]). The
    /// refinement's [`REFINE_STEP`] (about 3 s, 15 mm of path on issue 15's harness) spans the
    /// profile's V: its column is a secant, and the step time's sigma from it came out about
    /// 1.6x wide once the estimate sat at the minimum (harness, 50 runs: 1-sigma cover of the
    /// step time 45/50 with 0.004, 34/50 with this step).
    pub h_tau: f64,
}

const COL: &str = "rate:step";

/// The step's rate weights: per sample, the share of its dwell span (half of each adjacent
/// interval, the span its `dt_s` stands for) that lies after `at`. The sample the step falls
/// in takes the fraction after it, so the weighted dwell is the step's own for any `at`, and
/// the model moves continuously with it. A weight of 1 from the first sample at or after `at`
/// made the model a staircase in `at` (flat between samples, which the refinement's
/// forward differences straddle) and put the step, as the forward model interpolates weights
/// between samples, up to half a sample early. On issue 15's harness (50 rate_step runs at
/// 400^2) the 1-sigma coverage went 55 -> 57 of 100 with this; the step time's median
/// error / sigma +0.29 -> +0.25 (the densified samples are 0.125 mm apart, so the half
/// sample was small against the other errors).
fn step(p: &Problem, at: f64) -> Vec<f64> {
    let taus: Vec<f64> = (0..p.samples.len()).map(|k| p.samples.tau(k)).collect();
    step_weights(&taus, at)
}

/// [`step`]'s weights for samples at run-time fractions `taus` (increasing).
fn step_weights(taus: &[f64], at: f64) -> Vec<f64> {
    let n = taus.len();
    (0..n)
        .map(|k| {
            let t = taus[k];
            let lo = if k > 0 { 0.5 * (taus[k - 1] + t) } else { t };
            let hi = if k + 1 < n {
                0.5 * (t + taus[k + 1])
            } else {
                t
            };
            if at <= lo {
                1.0
            } else if at >= hi {
                0.0
            } else {
                (hi - at) / (hi - lo)
            }
        })
        .collect()
}

/// The refinement's difference step of the step time (run-time fraction): a secant across
/// several spot transits, which carries the steps over the residual's small-scale roughness
/// (a step of [`scan_step`] there left two runs of issue 15's harness 50 at 0.0015-0.004 of the
/// run from the truth, process band 1.08-1.45x the floor, where this one and the scan found
/// every run's minimum). Also the uncertainties' step when the run has no feed to scale by.
const REFINE_STEP: f64 = 0.004;

/// The step time's scan step (run-time fraction, see `Effect::nl_scan`): the time the tool
/// takes to travel half the TIF radius at the median feed, over the run's duration. Within
/// about a spot transit of the truth the residual's profile is quadratic; beyond, it grows
/// like the misassigned stretch of path.
pub fn scan_step(p: &Problem) -> f64 {
    let s = &p.samples;
    let mut feed: Vec<f64> = s
        .feed_mm_per_s
        .iter()
        .copied()
        .filter(|v| *v > 0.0)
        .collect();
    let span = s.t1_s - s.t0_s;
    if feed.is_empty() || span.is_nan() || span <= 0.0 {
        return 0.0;
    }
    feed.sort_by(f64::total_cmp);
    let v = feed[feed.len() / 2];
    0.5 * p.tif_radius_mm / v / span
}

/// Share of the TIF radius within which analysis pixels make a path sample visible.
const SEEN_RADIUS_SHARE: f64 = 0.5;

/// Whether the tool at sample k removes material on the analysis pixels: an analysis pixel
/// within half the TIF radius of its centre.
fn seen(p: &Problem, k: usize, mask: &[bool]) -> bool {
    let g = &p.grid;
    let r = SEEN_RADIUS_SHARE * p.tif_radius_mm;
    let (x, y) = (p.samples.x_mm[k], p.samples.y_mm[k]);
    let j0 = ((x - r - g.x0_mm) / g.dx_mm).floor().max(0.0) as usize;
    let j1 = (((x + r - g.x0_mm) / g.dx_mm).ceil().max(-1.0) + 1.0) as usize;
    let i0 = ((y - r - g.y0_mm) / g.dy_mm).floor().max(0.0) as usize;
    let i1 = (((y + r - g.y0_mm) / g.dy_mm).ceil().max(-1.0) + 1.0) as usize;
    for i in i0..i1.min(g.rows) {
        let dy = g.y_mm(i) - y;
        for j in j0..j1.min(g.cols) {
            let dx = g.x_mm(j) - x;
            if dx * dx + dy * dy <= r * r && mask[i * g.cols + j] {
                return true;
            }
        }
    }
    false
}

/// Run-time fraction over which the tool is off the analysis pixels around `at` (0 when the
/// sample at `at` is seen): a step inside that span changes nothing measured.
pub fn unseen_span(p: &Problem, at: f64) -> f64 {
    let s = &p.samples;
    let n = s.len();
    if n < 2 {
        return 0.0;
    }
    let mut mask = vec![false; p.grid.rows * p.grid.cols];
    for &k in &p.idx {
        mask[k] = true;
    }
    let k0 = (0..n).find(|&k| s.tau(k) >= at).unwrap_or(n - 1);
    if seen(p, k0, &mask) {
        return 0.0;
    }
    let mut lo = k0;
    while lo > 0 && !seen(p, lo - 1, &mask) {
        lo -= 1;
    }
    let mut hi = k0;
    while hi + 1 < n && !seen(p, hi + 1, &mask) {
        hi += 1;
    }
    // From the last seen sample before to the first seen one after.
    s.tau((hi + 1).min(n - 1)) - s.tau(lo.saturating_sub(1))
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
        vec![REFINE_STEP]
    }
    fn nl_sigma_steps(&self) -> Vec<f64> {
        vec![if self.h_tau > 0.0 {
            self.h_tau
        } else {
            REFINE_STEP
        }]
    }
    fn moves_path(&self) -> bool {
        true
    }
    fn nl_scan(&self, _p: &Problem) -> Vec<f64> {
        vec![self.h_tau]
    }
    fn nl_unresolved(&self, p: &Problem) -> Vec<f64> {
        vec![unseen_span(p, self.at_tau)]
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
    let h_tau = scan_step(p);
    let g = step(p, at);
    let col = cur.column(&[(&s.centred(&g), Channel::Value)]);
    vec![Candidate {
        key: "rate_step".into(),
        kind: "rate_step",
        extra: vec![col],
        make: Box::new(move |_, _| Box::new(RateStep { at_tau: at, h_tau })),
    }]
}

#[cfg(test)]
mod tests {
    use super::step_weights;

    /// The weighted dwell is the true step's: with each sample's span half of each adjacent
    /// interval (what its dwell share stands for), the dwell after the step is
    /// `tau_end - at` for every `at`, also inside a sample's span, and the weights move
    /// continuously with `at` (a step at a sample's own time keeps half of it: the old
    /// threshold weights gave all or nothing there).
    #[test]
    fn the_weighted_dwell_is_the_steps_own_for_any_step_time() {
        let taus: Vec<f64> = (0..40)
            .map(|k| {
                let x = k as f64 / 39.0;
                x + 0.004 * (7.0 * x).sin() * (k > 0 && k < 39) as u8 as f64
            })
            .collect();
        let n = taus.len();
        let span = |k: usize| {
            let lo = if k > 0 {
                0.5 * (taus[k - 1] + taus[k])
            } else {
                taus[k]
            };
            let hi = if k + 1 < n {
                0.5 * (taus[k] + taus[k + 1])
            } else {
                taus[k]
            };
            hi - lo
        };
        // Between two step times 1 / 2000 apart a weight changes by at most that over its span.
        let bound = (0..n).map(span).fold(f64::INFINITY, f64::min).recip() / 2000.0 + 1e-12;
        let mut last: Option<Vec<f64>> = None;
        for i in 0..=2000 {
            let at = i as f64 / 2000.0;
            let g = step_weights(&taus, at);
            let after: f64 = g.iter().enumerate().map(|(k, w)| w * span(k)).sum();
            assert!((after - (1.0 - at)).abs() < 1e-12, "at {at}: {after}");
            if let Some(prev) = &last {
                let jump = g
                    .iter()
                    .zip(prev)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(jump <= bound, "at {at}: weights jumped by {jump} > {bound}");
            }
            last = Some(g);
        }
        let k = 17;
        assert!((step_weights(&taus, taus[k])[k] - 0.5).abs() < 0.1);
    }
}
