//! `kilotouch sim tweezer`'s simulation against docs/REFERENCE-VALUES.md:
//! equipartition, the aliased-Lorentzian fit, Faxén's wall correction, the
//! Euler–Maruyama bias and the exact update's stability.

#![allow(clippy::unwrap_used)]

use kilotouch::tweezer_sim::{TweezerSimArgs, simulate_tweezer};
use kilotouch_rig::tweezer::*;
use std::f64::consts::PI;

const KB: f64 = 1.380649e-23;

fn default_args() -> TweezerSimArgs {
    TweezerSimArgs {
        duration_s: 100.0,
        seed: 7,
        ..TweezerSimArgs::default()
    }
}

/// ⟨x²⟩ = k_BT/κ within 3 %, and the aliased-Lorentzian fit recovers f_c
/// within 5 % and D within 8 % (R = 1.5 µm, water at 20 °C, κ = 20 pN/µm).
#[test]
fn equipartition_and_lorentzian_fit() {
    let r = simulate_tweezer(&default_args()).unwrap();
    let kt = KB * 293.15;
    let var = kt / 2e-5;
    assert!((r.var_theory_m2 / var - 1.0).abs() < 1e-12);
    for v in [r.var_x_m2, r.var_y_m2] {
        assert!((v / var - 1.0).abs() < 0.03, "var {v:e} vs {var:e}");
    }
    let gamma = 6.0 * PI * 1.0016e-3 * 1.5e-6;
    let corner_hz = 2e-5 / (2.0 * PI * gamma);
    let d = kt / gamma;
    assert!((r.fc_theory_hz / corner_hz - 1.0).abs() < 1e-12);
    assert!(
        (r.fc_fit_hz / corner_hz - 1.0).abs() < 0.05,
        "corner_hz {} vs {corner_hz}",
        r.fc_fit_hz
    );
    assert!(
        (r.d_fit_m2_s / d - 1.0).abs() < 0.08,
        "D {:e} vs {d:e}",
        r.d_fit_m2_s
    );
    // Serialisable for the CLI.
    let j = serde_json::to_string(&r).unwrap();
    assert!(j.contains("fc_fit_hz") && j.contains("var_theory_m2"));
}

/// dt ≫ τ: κ = 1000 pN/µm at 10 kHz (dt/τ ≈ 3.5) and at 2 kHz (≈ 18): the
/// exact update is stable and keeps the equipartition variance;
/// Euler–Maruyama is refused, and run by hand it diverges.
#[test]
fn exact_update_is_stable_for_dt_much_larger_than_tau() {
    let args = TweezerSimArgs {
        stiffness_pn_um: 1000.0,
        duration_s: 20.0,
        ..default_args()
    };
    for fs in [10e3, 2e3] {
        let a = TweezerSimArgs {
            fs_hz: fs,
            ..args.clone()
        };
        let r = simulate_tweezer(&a).unwrap();
        assert!(r.dt_over_tau > 3.0, "{}", r.dt_over_tau);
        let var = KB * 293.15 / 1e-3;
        for v in [r.var_x_m2, r.var_y_m2] {
            assert!((v / var - 1.0).abs() < 0.03, "fs {fs}: {v:e} vs {var:e}");
        }
        // f_c (5.6 kHz) is at or above Nyquist, yet the aliased form fits it.
        if fs > 5e3 {
            assert!(
                (r.fc_fit_hz / r.fc_theory_hz - 1.0).abs() < 0.05,
                "{} vs {}",
                r.fc_fit_hz,
                r.fc_theory_hz
            );
        }
    }
    let euler = TweezerSimArgs {
        integrator: TweezerIntegrator::Euler,
        ..args
    };
    assert!(simulate_tweezer(&euler).is_err());
    let p = TweezerParams {
        stiffness_n_per_m: 1e-3,
        integrator: TweezerIntegrator::Euler,
        escape_distance_m: f64::MAX,
        ..TweezerParams::paper_default()
    };
    let mut t = SimTweezer::new(p, 1e4).unwrap();
    let mut peak: f64 = 0.0;
    for _ in 0..2000 {
        let s = t.step([0.0, 0.0]);
        peak = peak.max(s.bead_m[0].abs());
    }
    assert!(
        peak > 1e-3 || t.nonfinite_resets() > 0,
        "Euler should diverge: {peak:e}"
    );
}

/// Euler–Maruyama's stationary variance is (k_BT/κ)/(1 − dt/2τ): at
/// dt/τ = 1 it is twice the truth (docs/REFERENCE-VALUES.md).
#[test]
fn euler_maruyama_variance_bias_matches_theory() {
    let p = TweezerParams::paper_default();
    let fs = 1.0 / p.tau(); // dt = τ
    let args = TweezerSimArgs {
        fs_hz: fs,
        duration_s: 200_000.0 / fs,
        integrator: TweezerIntegrator::Euler,
        ..default_args()
    };
    let r = simulate_tweezer(&args).unwrap();
    assert!((r.dt_over_tau - 1.0).abs() < 1e-9);
    let expect = r.var_theory_m2 / (1.0 - 0.5);
    for v in [r.var_x_m2, r.var_y_m2] {
        assert!((v / expect - 1.0).abs() < 0.03, "{v:e} vs {expect:e}");
    }
}

/// Near the coverslip (h = 1.5 R) the dynamics slow by Faxén's factor
/// 1.615 (docs/REFERENCE-VALUES.md) while the variance stays k_BT/κ.
#[test]
fn fitted_corner_near_a_wall_follows_faxen() {
    let args = TweezerSimArgs {
        wall_distance_um: Some(2.25),
        ..default_args()
    };
    let r = simulate_tweezer(&args).unwrap();
    assert!((r.wall_factor - 1.615).abs() < 2e-3, "{}", r.wall_factor);
    let fc0 = 2e-5 / (2.0 * PI * 6.0 * PI * 1.0016e-3 * 1.5e-6);
    assert!(
        (r.fc_fit_hz / (fc0 / 1.615) - 1.0).abs() < 0.05,
        "{} vs {}",
        r.fc_fit_hz,
        fc0 / 1.615
    );
    for v in [r.var_x_m2, r.var_y_m2] {
        assert!((v / r.var_theory_m2 - 1.0).abs() < 0.03);
    }
}

/// Same seed, same trajectory; different seed, different trajectory.
#[test]
fn seeded_and_reproducible() {
    let a = simulate_tweezer(&TweezerSimArgs {
        duration_s: 1.0,
        ..default_args()
    })
    .unwrap();
    let b = simulate_tweezer(&TweezerSimArgs {
        duration_s: 1.0,
        ..default_args()
    })
    .unwrap();
    let c = simulate_tweezer(&TweezerSimArgs {
        duration_s: 1.0,
        seed: 8,
        ..default_args()
    })
    .unwrap();
    assert_eq!(a, b);
    assert_ne!(a.var_x_m2, c.var_x_m2);
}
