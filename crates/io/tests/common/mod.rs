//! Helpers shared by the integration tests: where the real Zygo files live, statistics after
//! form removal through `bonnetlab_surface`.

#![allow(dead_code)]

use std::path::PathBuf;

use bonnetlab_surface::{height_stats, remove_terms, Surface, Term};

#[path = "../../../../tests/common/shared_data.rs"]
pub mod shared_data;

/// `shared/data/real` (see `tests/common/shared_data.rs` at the workspace root). Panics with
/// instructions when the data is absent; tests that call it are marked
/// `#[cfg_attr(no_shared_data, ignore = ...)]` so a clone without the data lists them as ignored.
pub fn real_dir() -> PathBuf {
    shared_data::data_dir("real")
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
