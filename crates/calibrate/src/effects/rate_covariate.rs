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
//! plus a spurious drift and x dependence (final 0.66 nm against a 0.42 nm floor). The
//! reported coefficient is thus the one about the measured pixels' plane: a rate
//! `1 + c (h' + A)` with `A` the other plane's offset is `(1 + c A) + c h'`, so `c / (1 + c A)`
//! against the rate at the reference point. On issue 15's harness (round 90 mm apertures on a
//! 100 mm part, `A` 10-70 nm) that was most of the height coefficient's error: 4.0 % -> 1.5 %
//! median on round parts once the truth was stated about the same plane.
//!
//! The height over a region ([`LocalHeight`]): the rate follows the height averaged about the
//! tool (a bonnet's contact pressure answers to the surface under its contact zone, not to one
//! pixel), `q = (h * G_sigma)(tool centre)` with the Gaussian's sigma a fitted parameter
//! (`smoothing_mm`); candidates at half, one and two spot radii, the length then refined with
//! the rest. It is the height covariate with a smoothing length (the same key: a run takes the
//! height once, smoothed or not; both at once split one dependence between two nearly
//! collinear columns, 0.010 and -0.006 per nm for a true 0.004 on a round part). With the 2 px height in its place, a rate
//! rising 25 % per sigma of the 5 mm-smoothed height left 1.9x the noise floor (median of 50
//! runs, issue 15's harness).

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
    fn term_errors(&self, p: &Problem, draws: usize) -> Vec<(String, Vec<Vec<f64>>)> {
        if self.covariate != "height" {
            return Vec::new();
        }
        // The `height` covariate is the local height at a 2 px smoothing (`model::covariates`).
        let sigma_mm = crate::model::height_smooth_mm(&p.grid);
        vec![(
            self.col(),
            crate::fill_error::height_errors(p, sigma_mm, draws),
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
            companions: Vec::new(),
        };
        if cur.has(&e.key()) {
            continue;
        }
        let Some(q) = cur.p.covariates.get(name) else {
            continue;
        };
        let centred = |q: &[f64]| cur.p.samples.centred(q);
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
    out.extend(local_height_candidates(cur));
    out
}

/// Rate dependence on the local height, the before map's height (piston and tilt removed)
/// Gaussian-smoothed over `smooth_mm` at the tool centre (see the module note).
#[derive(Debug, Clone)]
pub struct LocalHeight {
    /// Sigma of the smoothing (mm).
    pub smooth_mm: f64,
    pub companions: Vec<&'static str>,
}

impl LocalHeight {
    fn col(&self) -> String {
        "rate:cov:height".into()
    }
}

impl Effect for LocalHeight {
    fn kind(&self) -> &'static str {
        "rate_covariate"
    }
    fn key(&self) -> String {
        "rate_covariate:height".into()
    }
    fn boxed_clone(&self) -> Box<dyn Effect> {
        Box::new(self.clone())
    }
    fn nl(&self) -> Vec<f64> {
        vec![self.smooth_mm]
    }
    fn set_nl(&mut self, v: &[f64]) {
        self.smooth_mm = v[0].abs().max(1e-3);
    }
    fn nl_steps(&self) -> Vec<f64> {
        vec![self.smooth_mm * 1e-2]
    }
    fn moves_path(&self) -> bool {
        // Its rate weights change with the smoothing length.
        true
    }
    fn rate_terms(&self, p: &Problem) -> Vec<(String, Vec<f64>)> {
        let mut terms = vec![(self.col(), p.local_height(self.smooth_mm).to_vec())];
        for c in &self.companions {
            let v = p.covariates.get(c).map(|v| v.to_vec()).unwrap_or_default();
            terms.push((format!("lin:{}:ref_{c}", self.col()), v));
        }
        terms
    }
    fn term_errors(&self, p: &Problem, draws: usize) -> Vec<(String, Vec<Vec<f64>>)> {
        vec![(
            self.col(),
            crate::fill_error::height_errors(p, self.smooth_mm, draws),
        )]
    }
    fn implausible(&self, p: &Problem, _lin: &Linear) -> Option<String> {
        let pix = p.grid.dx_mm.max(p.grid.dy_mm);
        let part = (p.grid.cols as f64 * p.grid.dx_mm).min(p.grid.rows as f64 * p.grid.dy_mm);
        if self.smooth_mm < pix {
            Some(format!(
                "smoothing {:.3} mm is below a map pixel ({pix:.3} mm): that is the height itself",
                self.smooth_mm
            ))
        } else if self.smooth_mm > 0.25 * part {
            Some(format!(
                "smoothing {:.1} mm is beyond a quarter of the part ({:.1} mm): that is a rate map",
                self.smooth_mm,
                0.25 * part
            ))
        } else {
            None
        }
    }
    fn params(&self, lin: &Linear) -> Vec<(String, Param)> {
        vec![
            ("covariate".into(), Param::Text("height".into())),
            (
                "coefficient".into(),
                Param::Num(lin.get(&self.col()) / lin.s0()),
            ),
            ("coefficient_units".into(), Param::Text("1/nm".into())),
            ("smoothing_mm".into(), Param::Num(self.smooth_mm)),
        ]
    }
}

/// Candidates of [`LocalHeight`] at half, one and two spot radii (at least two map pixels),
/// under the height covariate's key.
pub fn local_height_candidates(cur: &Current) -> Vec<Candidate> {
    let key = "rate_covariate:height".to_string();
    if cur.has(&key) {
        return Vec::new();
    }
    let p = cur.p;
    let pix = p.grid.dx_mm.max(p.grid.dy_mm);
    let comp = companions("height", cur);
    let centred = |q: &[f64]| p.samples.centred(q);
    let comp_cols: Vec<Vec<f64>> = comp
        .iter()
        .filter_map(|c| p.covariates.get(c))
        .map(|qc| cur.column(&[(&centred(qc), Channel::Value)]))
        .collect();
    let mut out = Vec::new();
    for f in [0.5, 1.0, 2.0] {
        let smooth_mm = (f * p.tif_radius_mm).max(2.0 * pix);
        let g = centred(&p.local_height(smooth_mm));
        if g.iter().all(|v| v.abs() < 1e-12) {
            continue;
        }
        let mut extra = vec![cur.column(&[(&g, Channel::Value)])];
        extra.extend(comp_cols.iter().cloned());
        let comp = comp.clone();
        out.push(Candidate {
            key: key.clone(),
            kind: "rate_covariate",
            extra,
            make: Box::new(move |_, _| {
                Box::new(LocalHeight {
                    smooth_mm,
                    companions: comp.clone(),
                })
            }),
        });
    }
    out
}
