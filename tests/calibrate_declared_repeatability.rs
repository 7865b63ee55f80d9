//! A declared instrument repeatability (`[measurement] repeatability_nm`, issue #15).
//!
//! Without it, calibrate cannot tell a smooth rate map on a near-uniform removal from a smooth
//! difference the instrument makes between two measurements (drift, air), and it turns the
//! rate down (`fallback::smooth_additive_columns`): on a real instrument's repeatability series
//! a false rate map was accepted in 12 of 12 null runs before. The declared repeatability
//! bounds how large that difference can be, so a rate map well above the bound stands.
//!
//! The run is made by the independent generator (exact time-domain deposition, a power-law
//! surface to the pixel scale, a 90 mm round aperture, white noise 1 and 1.4 nm, dropouts): a
//! drift-free instrument, whose two measurements of an unchanged part differ by their white
//! noise alone. Its recipe declares that, as a lab would.

use bonnetlab::calibrate::run::{Calibration, Options};
use bonnetlab::calibrate::synth::write::write_run;
use bonnetlab::calibrate::synth::{generate, InitialSurface, Injected, SynthConfig, SynthRun};
use bonnetlab::pipeline::calibrate::{calibrate, load};

fn rate_map_run() -> SynthRun {
    let n = 200;
    let cfg = SynthConfig {
        pitch_mm: 3.0,
        deposit_step_mm: 0.06_f64.min(0.25 * 100.0 / n as f64),
        effects: vec![Injected::RateMap {
            amplitude_fraction: 0.05,
            correlation_mm: 15.0,
        }],
        ..SynthConfig::realistic(2, n, 100.0, InitialSurface::realistic_texture(2.2))
            .with_noise_nm(1.0, 1.4)
            .with_round_aperture(true, 90.0)
    };
    generate(&cfg).expect("the run is generated")
}

/// Calibrates the run through its recipe file, with `repeatability_nm` declared or not.
fn calibrate_declared(run: &SynthRun, repeatability_nm: Option<f64>) -> Calibration {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let recipe = write_run(dir.path(), run).expect("the run is written");
    if let Some(r) = repeatability_nm {
        let text = std::fs::read_to_string(&recipe).expect("the recipe reads");
        let with = text.replace(
            "[measurement]\n",
            &format!("[measurement]\nrepeatability_nm = {r}\n"),
        );
        assert_ne!(with, text, "the recipe has a [measurement] table");
        std::fs::write(&recipe, with).expect("the recipe is written");
    }
    let p = load(&recipe).unwrap_or_else(|e| panic!("{}", e.message));
    assert_eq!(p.repeatability_nm, repeatability_nm);
    calibrate(&recipe, &p, &Options::default()).unwrap_or_else(|e| panic!("{}", e.message))
}

fn kinds(c: &Calibration) -> Vec<&str> {
    c.effects.iter().map(|e| e.kind.as_str()).collect()
}

#[test]
fn a_rate_map_far_above_the_declared_repeatability_stands() {
    let run = rate_map_run();
    let floor = run.true_noise_floor_nm;

    // Undeclared: the map is turned down and said to be a rate or the instrument's drift.
    let open = calibrate_declared(&run, None);
    assert!(open.effects.is_empty(), "accepted {:?}", kinds(&open));
    let check = open.rounds[0]
        .smooth_check
        .expect("the round made the check");
    assert!(check.applied && check.drift_bound_nm.is_none(), "{check:?}");
    let said = open
        .unexplained
        .iter()
        .filter_map(|u| u.below_bar.as_ref())
        .find(|b| b.z_beyond_smooth.is_some())
        .unwrap_or_else(|| panic!("no rate-or-drift entry: {:?}", open.unexplained));
    assert!(said.kind.starts_with("rate_"), "{}", said.kind);

    // Declared (the two maps' white noise in quadrature: no drift): the smooth structure is
    // several nm, far above the bound, so the rate map stands and takes the excess.
    let declared = calibrate_declared(&run, Some(floor));
    let check = declared.rounds[0]
        .smooth_check
        .expect("the round made the check");
    let bound = check
        .drift_bound_nm
        .expect("a bound from the declared value");
    assert!(!check.applied, "{check:?}");
    assert!(
        check.map_rms_nm > 2.0 && check.map_rms_nm > 3.0 * bound,
        "{check:?}"
    );
    assert_eq!(kinds(&declared)[0], "rate_map", "{:?}", kinds(&declared));
    let excess = |r: f64| (r * r - floor * floor).max(0.0);
    let (b, f) = (
        declared.baseline.residual_rms_nm,
        declared.final_.residual_rms_nm,
    );
    assert!(
        excess(f) <= 0.1 * excess(b),
        "baseline {b}, final {f}, floor {floor}"
    );
    assert!(f <= 1.1 * floor, "final {f} vs floor {floor}");

    // The declared value is echoed in the JSON, beside each round's check.
    let json = serde_json::to_value(&declared).expect("the calibration serialises");
    assert_eq!(json["repeatability_nm"].as_f64(), Some(floor));
    assert_eq!(json["repeatability_used"].as_bool(), Some(true));
    assert!(
        json["repeatability_note"].is_null(),
        "{}",
        json["repeatability_note"]
    );
    let sc = &json["rounds"][0]["smooth_check"];
    assert_eq!(sc["applied"].as_bool(), Some(false), "{sc}");
    assert!(sc["map_rms_nm"].as_f64().is_some_and(|v| v > 2.0), "{sc}");
}

/// A declared value well below the run's white floor contradicts it (these maps are noisier
/// than the measurements it came from): it is not used, the JSON says why with both values,
/// and the selection is the undeclared one, check for check.
#[test]
fn a_repeatability_below_the_runs_noise_is_not_used_and_says_why() {
    let run = rate_map_run();
    let floor = run.true_noise_floor_nm;
    let open = calibrate_declared(&run, None);
    let low = calibrate_declared(&run, Some(0.5 * floor));
    assert!(!low.repeatability_used);
    let note = low
        .repeatability_note
        .as_deref()
        .expect("a note says why the value was not used");
    assert!(
        note.contains(&format!("{:.4} nm", 0.5 * floor)) && note.contains("noisier"),
        "{note}"
    );
    assert!(!open.repeatability_used && open.repeatability_note.is_none());
    // The same selection as undeclared: the map turned down, the check made without a bound.
    assert_eq!(kinds(&low), kinds(&open));
    let check = low.rounds[0]
        .smooth_check
        .expect("the round made the check");
    assert!(check.applied && check.drift_bound_nm.is_none(), "{check:?}");
    assert_eq!(
        low.final_.residual_rms_nm.to_bits(),
        open.final_.residual_rms_nm.to_bits()
    );
}
