//! Helpers shared by the integration tests: where the real Zygo files live, statistics after
//! form removal through `bonnetlab_surface`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};

/// `shared/data/real`, found by walking up from this crate (the repository may be cloned next to
/// `shared/` or inside it). `None` (and a printed note) when it is absent, so a clone without the
/// shared data still passes.
pub fn real_dir() -> Option<PathBuf> {
    if let Ok(d) = std::env::var("BONNETLAB_REAL_DATA") {
        return Some(PathBuf::from(d));
    }
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    for anc in here.ancestors() {
        let cand = anc.join("shared").join("data").join("real");
        if cand.is_dir() {
            return Some(cand);
        }
    }
    eprintln!(
        "skipping: shared/data/real not found above {}",
        here.display()
    );
    None
}

/// PV and RMS (nm) after removing `terms`.
pub fn pv_rms(s: &Surface, terms: &[Term]) -> (f64, f64) {
    let (r, _) = remove_terms(s, terms).expect("form removal");
    let st = height_stats(&r).expect("stats");
    (st.pv_nm, st.rms_nm)
}

pub fn assert_rel(what: &str, got: f64, want: f64, tol: f64) {
    let rel = ((got - want) / want).abs();
    assert!(
        rel <= tol,
        "{what}: got {got}, want {want} (relative error {rel:.2e} > {tol:.0e})"
    );
}
