//! The 2-DOF response against independent references: the paper's closed form written out
//! term by term, time integration (a Newmark integrator local to this test and the crate's RK4),
//! analytic ring-down and random-vibration variance, and the acceptance numbers of issue 6.

use bonnetlab_vibration::params::{Bonnet, VibrationParams};
use bonnetlab_vibration::response::{forced_response, resonance_peaks};
use bonnetlab_vibration::timeseries::{rk4_step, AccelPulse, Excitations, ToolTipGenerator};
use std::f64::consts::PI;

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-300)
}

/// The paper's formulas with its sign convention (friction on the +x1 side), by hand.
fn paper_closed_form(p: &VibrationParams, zeta: [f64; 2], rpm: f64) -> [(f64, f64); 2] {
    let th = p.theta_deg * PI / 180.0;
    let f1 = p.fn_n * (th.sin() + p.mu * th.cos());
    let f2 = p.fn_n * (th.cos() - p.mu * th.sin());
    let w = 2.0 * PI * rpm / 60.0;
    let mut out = [(0.0, 0.0); 2];
    for (i, (f, k)) in [(f1, p.k1_n_per_mm), (f2, p.k2_n_per_mm)]
        .into_iter()
        .enumerate()
    {
        let wn = (k * 1000.0 / p.mass_kg).sqrt();
        let l = w / wn;
        let x = (f / k) / ((1.0 - l * l).powi(2) + (2.0 * zeta[i] * l).powi(2)).sqrt();
        let phi = (2.0 * zeta[i] * l).atan2(1.0 - l * l);
        out[i] = (x, phi.to_degrees());
    }
    out
}

#[test]
fn steady_state_equals_the_closed_form_to_1e9() {
    for (mu, fn_n, theta) in [(0.3, 2.0, 13.2), (0.1, 40.0, 13.2), (0.45, 5.0, 30.0)] {
        let p = VibrationParams {
            mu,
            fn_n,
            theta_deg: theta,
            ..Default::default()
        };
        for bonnet in Bonnet::ALL {
            let z = match bonnet {
                Bonnet::Original => [p.zeta1, p.zeta2],
                Bonnet::Suppression => [p.zeta1 + 0.115 / 2.0, p.zeta2 + 0.115 / 2.0],
            };
            for rpm in [250.0, 560.0, 1000.0, 1186.0, 1500.0, 2000.0] {
                let r = forced_response(&p, bonnet, rpm);
                let cf = paper_closed_form(&p, z, rpm);
                assert!(cf[0].0 > 0.0 && cf[1].0 > 0.0);
                assert!(
                    rel(r.x1_amplitude_mm, cf[0].0) < 1e-9,
                    "{} vs {}",
                    r.x1_amplitude_mm,
                    cf[0].0
                );
                assert!(rel(r.x2_amplitude_mm, cf[1].0) < 1e-9);
                assert!(
                    rel(r.x1_phase_deg, cf[0].1) < 1e-9,
                    "{} vs {}",
                    r.x1_phase_deg,
                    cf[0].1
                );
                assert!(rel(r.x2_phase_deg, cf[1].1) < 1e-9);
                assert!(rel(r.zeta1_effective, z[0]) < 1e-12);
                assert!(rel(r.excitation_hz, rpm / 60.0) < 1e-15);
            }
        }
    }
}

/// Newmark average-acceleration integration of x'' + 2ζω x' + ω² x = a0 sin(Ω t) from rest.
fn newmark(omega: f64, zeta: f64, a0: f64, big_omega: f64, dt: f64, n: usize) -> Vec<f64> {
    let (beta, gamma) = (0.25, 0.5);
    let c = 2.0 * zeta * omega;
    let k = omega * omega;
    let keff = k + gamma / (beta * dt) * c + 1.0 / (beta * dt * dt);
    let (mut x, mut v) = (0.0, 0.0);
    let mut a = 0.0;
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        out.push(x);
        let t1 = (i + 1) as f64 * dt;
        let f1 = a0 * (big_omega * t1).sin();
        let rhs = f1
            + (1.0 / (beta * dt * dt)) * x
            + (1.0 / (beta * dt)) * v
            + (0.5 / beta - 1.0) * a
            + c * (gamma / (beta * dt) * x
                + (gamma / beta - 1.0) * v
                + dt * (0.5 * gamma / beta - 1.0) * a);
        let x1 = rhs / keff;
        let a1 = (x1 - x) / (beta * dt * dt) - v / (beta * dt) - (0.5 / beta - 1.0) * a;
        let v1 = v + dt * ((1.0 - gamma) * a + gamma * a1);
        x = x1;
        v = v1;
        a = a1;
    }
    out
}

/// Least-squares amplitude and phase lag (deg) of x ≈ A sin(Ω t − φ) over the samples given.
fn fit_sine(x: &[f64], t0: f64, dt: f64, big_omega: f64) -> (f64, f64) {
    let (mut ss, mut sc, mut cc, mut xs, mut xc) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (i, &v) in x.iter().enumerate() {
        let (s, c) = (big_omega * (t0 + i as f64 * dt)).sin_cos();
        ss += s * s;
        sc += s * c;
        cc += c * c;
        xs += v * s;
        xc += v * c;
    }
    let det = ss * cc - sc * sc;
    let a = (xs * cc - xc * sc) / det; // A cos φ
    let b = (xc * ss - xs * sc) / det; // −A sin φ
    ((a * a + b * b).sqrt(), (-b).atan2(a).to_degrees())
}

#[test]
fn time_integration_converges_to_the_steady_state() {
    let p = VibrationParams::default();
    let bonnet = Bonnet::Original;
    let fproj = p.project(p.force_vector_n());
    let wn = p.omega_n_rad_per_s();
    let z = p.zeta_effective(bonnet);
    for rpm in [560.0, 1000.0, 1186.0] {
        let r = forced_response(&p, bonnet, rpm);
        let big = 2.0 * PI * rpm / 60.0;
        let dt = 1.0 / 4000.0;
        let n = 40_000; // 10 s: transients decay as exp(−ζ ω t) < exp(−29)
        let tail = 8_000;
        for i in 0..2 {
            let a0 = 1e3 * fproj[i] / p.mass_kg;
            // Newmark (local) and RK4 (the crate's) from rest.
            let nm = newmark(wn[i], z[i], a0, big, dt, n);
            let mut s = [0.0, 0.0];
            let mut rk = Vec::with_capacity(n);
            for k in 0..n {
                rk.push(s[0]);
                let mut g = |t: f64| a0 * (big * t).sin();
                s = rk4_step(s, k as f64 * dt, dt, wn[i], z[i], &mut g);
            }
            let t0 = (n - tail) as f64 * dt;
            let (amp_cf, ph_cf) = if i == 0 {
                (r.x1_amplitude_mm, r.x1_phase_deg)
            } else {
                (r.x2_amplitude_mm, r.x2_phase_deg)
            };
            let (a_rk, ph_rk) = fit_sine(&rk[n - tail..], t0, dt, big);
            let (a_nm, ph_nm) = fit_sine(&nm[n - tail..], t0, dt, big);
            assert!(rel(a_rk, amp_cf) < 1e-6, "rk4 {a_rk} vs {amp_cf}");
            assert!((ph_rk - ph_cf).abs() < 1e-4, "rk4 phase {ph_rk} vs {ph_cf}");
            // Newmark's period elongation is (Ω dt)²/12 relative: 2e-3 deg-scale phase error.
            assert!(rel(a_nm, amp_cf) < 2e-3, "newmark {a_nm} vs {amp_cf}");
            assert!(
                (ph_nm - ph_cf).abs() < 0.5,
                "newmark phase {ph_nm} vs {ph_cf}"
            );
        }
    }
}

#[test]
fn paper_stiffnesses_give_resonant_amplitudes_of_order_1e_2_mm() {
    let p = VibrationParams::default();
    assert_eq!(
        (p.k1_n_per_mm, p.k2_n_per_mm, p.theta_deg),
        (1476.0, 328.9, 13.2)
    );
    // Scan the spindle band (250–2000 rpm) finely, independently of the FRF helper.
    let mut max = [0.0f64; 2];
    for k in 0..=175_000 {
        let rpm = 250.0 + k as f64 * 0.01;
        let r = forced_response(&p, Bonnet::Original, rpm);
        max[0] = max[0].max(r.x1_amplitude_mm);
        max[1] = max[1].max(r.x2_amplitude_mm);
    }
    // Both principal modes (19.8 and 9.3 Hz) lie in the band; peaks of order 1e-2 mm.
    for m in max {
        assert!(m > 3e-3 && m < 0.1, "resonant amplitude {m} mm");
    }
    let static2 = p.project(p.force_vector_n())[1] / p.k2_n_per_mm;
    assert!(
        max[1] > 5.0 * static2,
        "no resonance: {} vs static {}",
        max[1],
        static2
    );
}

#[test]
fn suppression_lowers_the_peak_by_the_damping_ratio() {
    let p = VibrationParams::default();
    let zo = p.zeta_effective(Bonnet::Original);
    let zs = p.zeta_effective(Bonnet::Suppression);
    let mut peak = [[0.0f64; 2]; 2];
    for (b, bonnet) in Bonnet::ALL.into_iter().enumerate() {
        for k in 0..=350_000 {
            let rpm = 250.0 + k as f64 * 0.005;
            let r = forced_response(&p, bonnet, rpm);
            peak[b][0] = peak[b][0].max(r.x1_amplitude_mm);
            peak[b][1] = peak[b][1].max(r.x2_amplitude_mm);
        }
    }
    for i in 0..2 {
        // Peak ∝ 1 / (2ζ sqrt(1 − ζ²)); ≈ ζ_e / ζ for light damping.
        let predicted =
            (zs[i] * (1.0 - zs[i] * zs[i]).sqrt()) / (zo[i] * (1.0 - zo[i] * zo[i]).sqrt());
        let ratio = peak[0][i] / peak[1][i];
        assert!(
            rel(ratio, predicted) < 1e-6,
            "dir {}: {ratio} vs {predicted}",
            i + 1
        );
        assert!(rel(ratio, zs[i] / zo[i]) < 0.01);
        let pk = resonance_peaks(&p, Bonnet::Original)[i].amplitude_mm;
        assert!(rel(pk, peak[0][i]) < 1e-6);
    }
}

#[test]
fn ringdown_matches_the_analytic_pulse_response() {
    // Undamped-start rectangular base-acceleration pulse: x = −a d (s(t) − s(t − T)), with the
    // damped step response s(t) = (1/ω²)(1 − e^{−ζωt}(cos ω_d t + ζ/√(1−ζ²) sin ω_d t)).
    let p = VibrationParams {
        noise_force_rms_n: 0.0,
        ..Default::default()
    };
    let bonnet = Bonnet::Original;
    let pulse = AccelPulse {
        t0_s: 0.1,
        duration_s: 0.032,
        accel_mm_per_s2: 100.0,
    };
    let ex = Excitations {
        steady: false,
        noise: false,
        ringdown: true,
    };
    let mut g = ToolTipGenerator::new(&p, bonnet, 4000.0, vec![pulse], ex, 1).unwrap();
    let wn = p.omega_n_rad_per_s();
    let z = p.zeta_effective(bonnet);
    let (e1, e2) = p.axes();
    let d = [e1[0], e2[0]];
    let step = |t: f64, i: usize| {
        if t <= 0.0 {
            return 0.0;
        }
        let wd = wn[i] * (1.0 - z[i] * z[i]).sqrt();
        let q = z[i] / (1.0 - z[i] * z[i]).sqrt();
        (1.0 - (-z[i] * wn[i] * t).exp() * ((wd * t).cos() + q * (wd * t).sin())) / (wn[i] * wn[i])
    };
    let mut max_err = [0.0f64; 2];
    let mut max_amp = [0.0f64; 2];
    for _ in 0..8000 {
        let s = g.next_sample();
        for i in 0..2 {
            let exact = -100.0 * d[i] * (step(s.t_s - 0.1, i) - step(s.t_s - 0.132, i));
            max_err[i] = max_err[i].max((s.ringdown[i] - exact).abs());
            max_amp[i] = max_amp[i].max(exact.abs());
        }
    }
    for i in 0..2 {
        assert!(
            max_amp[i] > 1e-4,
            "pulse response too small to test: {}",
            max_amp[i]
        );
        // The pulse edges fall between samples: first-order error in dt at the discontinuity.
        assert!(
            max_err[i] < 0.01 * max_amp[i],
            "dir {}: err {} amp {}",
            i + 1,
            max_err[i],
            max_amp[i]
        );
    }
}

#[test]
fn broadband_noise_response_variance_matches_random_vibration_theory() {
    // σ² = π f_n G(f_n) / (4 ζ k²) for one-sided force PSD G; linear interpolation of white
    // samples at rate r gives G(f) = 2 σ_s² / r sinc⁴(f / r) with σ_s² = 1.5 σ_F².
    let p = VibrationParams {
        noise_force_rms_n: 1.0,
        ..Default::default()
    };
    let bonnet = Bonnet::Original;
    let ex = Excitations {
        steady: false,
        noise: true,
        ringdown: false,
    };
    let fs = 1000.0;
    let mut g = ToolTipGenerator::new(&p, bonnet, fs, vec![], ex, 11).unwrap();
    let n = 1_500_000usize;
    let mut ms = [0.0f64; 2];
    for k in 0..n {
        let s = g.next_sample();
        if k >= 10_000 {
            ms[0] += s.noise[0] * s.noise[0];
            ms[1] += s.noise[1] * s.noise[1];
        }
    }
    let rate = 2.0 * p.noise_band_hz;
    let fproj = p.project([p.mu, 1.0]);
    let fnat = p.natural_freq_hz();
    let z = p.zeta_effective(bonnet);
    for i in 0..2 {
        let var = ms[i] / (n - 10_000) as f64;
        let x = PI * fnat[i] / rate;
        let sinc = x.sin() / x;
        let g_f = 2.0 * 1.5 / rate * sinc.powi(4) * fproj[i] * fproj[i];
        let k = p.stiffness_n_per_mm()[i];
        let theory = PI * fnat[i] * g_f / (4.0 * z[i] * k * k);
        assert!(
            rel(var, theory) < 0.08,
            "dir {}: var {var} vs theory {theory}",
            i + 1
        );
    }
}
