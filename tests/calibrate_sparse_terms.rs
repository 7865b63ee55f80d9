//! A rate term that is zero on most samples (a knot of the rate map, a raster line, a time
//! window) has its centred column formed as `R(g) - mean R(1)` (`Problem::rate_term_column`),
//! and the removal leaves out its sub-steps of weight zero. Checked here against the direct
//! column `R(g - mean)`, whose weights are zero nowhere (so nothing is left out), on every
//! fallback basis of a generated run.

use bonnetlab::calibrate::model::{evaluate, Channel};
use bonnetlab::calibrate::synth::{generate, SynthConfig};
use bonnetlab_process::removal::Fidelity;

#[test]
fn sparse_rate_terms_match_the_direct_centred_columns() {
    let run = generate(&SynthConfig::default()).expect("synthetic run");
    let p = run.problem().expect("problem");
    let ev = evaluate(&p, &[], None).expect("evaluation");
    let one = p
        .column_at(
            Fidelity::Full,
            &ev.kernels,
            &ev.exec,
            &[(Channel::Value, None)],
        )
        .expect("plain column");
    let scale = one.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    assert!(scale > 0.0);
    let mut sparse = 0;
    for sh in p.fallback_shapes() {
        for (name, g) in &sh.cols {
            let zeros = g.iter().filter(|v| **v == 0.0).count();
            if 2 * zeros >= g.len() {
                sparse += 1;
            }
            let (c, mean) = p
                .rate_term_column(Fidelity::Full, &ev.kernels, &ev.exec, g)
                .expect("rate term column");
            let gc: Vec<f64> = g.iter().map(|v| v - mean).collect();
            let direct = p
                .column_at(
                    Fidelity::Full,
                    &ev.kernels,
                    &ev.exec,
                    &[(Channel::Value, Some(&gc))],
                )
                .expect("direct column");
            let worst = c
                .iter()
                .zip(&direct)
                .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
            assert!(
                worst <= 1e-9 * scale,
                "{name}: largest difference {worst:e} against a plain column of {scale:e}"
            );
        }
    }
    // The run's rate map, lines and windows are sparse: the check is not vacuous.
    assert!(sparse >= 10, "only {sparse} sparse terms");
}
