//! The closed loop's stability analysis against independent references
//! (`tests/stability_reference.py`: python-control and a loop model built
//! from the paper's equations with numpy/scipy), and its internal
//! consistency (margins vs eigenvalues, memo, refusal).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::plant::Axis;
use kilotouch_rig::stability::margins::{grid, margins};
use kilotouch_rig::stability::{Case, Hand, LoopAnalysis, LoopState, analyse};
use kilotouch_rig::{Condition, RigError};
use num_complex::Complex64 as C64;
use serde_json::Value;
use std::f64::consts::PI;

fn reference() -> Value {
    let text = include_str!("data/stability_reference.json");
    serde_json::from_str(text).unwrap()
}

fn poly_z(c: &[f64], z: C64) -> C64 {
    // Coefficients of descending powers of z.
    c.iter().fold(C64::new(0.0, 0.0), |acc, &x| acc * z + x)
}

#[test]
fn margins_match_python_control() {
    let r = reference();
    for g in r["generic"].as_array().unwrap() {
        let num: Vec<f64> = serde_json::from_value(g["num"].clone()).unwrap();
        let den: Vec<f64> = serde_json::from_value(g["den"].clone()).unwrap();
        let fs = g["fs"].as_f64().unwrap();
        let l = |f: f64| {
            let z = C64::from_polar(1.0, 2.0 * PI * f / fs);
            poly_z(&num, z) / poly_z(&den, z)
        };
        let fr = grid(fs);
        let v: Vec<C64> = fr.iter().map(|&f| l(f)).collect();
        let m = margins(&fr, &v, &l, fs);
        let cmp = |got: f64, want: &Value, tol: f64, what: &str| match want.as_f64() {
            Some(w) => assert!(
                (got - w).abs() <= tol,
                "{what}: {got} vs {w} ({num:?}/{den:?})"
            ),
            None => assert!(!got.is_finite(), "{what}: {got} vs none"),
        };
        cmp(m.gain_margin_db, &g["gain_margin_db"], 1e-4, "GM dB");
        cmp(m.phase_margin_deg, &g["phase_margin_deg"], 1e-3, "PM deg");
        if m.phase_crossover_hz.is_finite() {
            cmp(m.phase_crossover_hz, &g["phase_crossover_hz"], 1e-6, "f180");
        }
        if m.gain_crossover_hz.is_finite() {
            cmp(m.gain_crossover_hz, &g["gain_crossover_hz"], 1e-6, "fc");
        }
    }
}

/// The loop of the default rig file, case by case, against the loop the
/// reference script builds from the paper's equations: margins, closed-loop
/// pole radius and the critical force scale.
#[test]
fn loop_cases_match_the_independent_model() {
    let r = reference();
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let a = LoopAnalysis::new(&cfg, &chain.coefficients).unwrap();
    let kappa = cfg.tweezer.stiffness_n_per_m;
    let g0 = cfg.coupling.force_scale;
    for c in r["loop_cases"].as_array().unwrap() {
        let case = Case {
            condition: c["condition"].as_str().unwrap().parse().unwrap(),
            axis: Axis::X,
            state: if c["state"] == "pressed" {
                LoopState::Pressed
            } else {
                LoopState::Free
            },
            hand: Hand {
                stiffness_n_per_m: c["hand_stiffness_n_per_m"].as_f64().unwrap(),
                damping_n_s_per_m: c["hand_damping_n_s_per_m"].as_f64().unwrap(),
            },
        };
        let got = a.case(&case, kappa, g0, true).unwrap();
        let m = got.margins.unwrap();
        let what = format!("{case:?}");
        let gm = c["gain_margin_db"].as_f64().unwrap();
        assert!(
            (m.gain_margin_db - gm).abs() < 0.02,
            "{what}: GM {} vs {gm}",
            m.gain_margin_db
        );
        match c["phase_margin_deg"].as_f64() {
            Some(pm) => {
                assert!(
                    (m.phase_margin_deg - pm).abs() < 0.05,
                    "{what}: PM {} vs {pm}",
                    m.phase_margin_deg
                );
                let fc = c["gain_crossover_hz"].as_f64().unwrap();
                assert!((m.gain_crossover_hz / fc - 1.0).abs() < 1e-3, "{what}: fc");
            }
            None => assert!(
                m.phase_margin_deg.is_infinite(),
                "{what}: no gain crossover"
            ),
        }
        let rho = c["spectral_radius"].as_f64().unwrap();
        // 1e-8 in ρ is 0.001 dB/s in the growth rate 20·log₁₀(ρ)·f_s (two
        // eigenvalue solvers on a 30-state non-normal matrix).
        assert!(
            (got.spectral_radius - rho).abs() < 1e-8,
            "{what}: ρ {} vs {rho}",
            got.spectral_radius
        );
        assert!(got.stable);
        // Critical force scale of this case by bisection on the verdict.
        let (mut lo, mut hi) = (g0, g0);
        while a.case(&case, kappa, hi, false).unwrap().stable {
            lo = hi;
            hi *= 1.25;
        }
        while hi / lo > 1.0005 {
            let mid = (lo * hi).sqrt();
            if a.case(&case, kappa, mid, false).unwrap().stable {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let want = c["critical_force_scale"].as_f64().unwrap();
        assert!(
            ((lo * hi).sqrt() / want - 1.0).abs() < 2e-3,
            "{what}: critical g {} vs {want}",
            (lo * hi).sqrt()
        );
    }
}

/// Raising the loop gain by the reported gain margin puts a closed-loop
/// pole on the unit circle: the frequency-domain margin and the eigenvalue
/// verdict agree.
#[test]
fn gain_margin_and_eigenvalues_agree() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let a = LoopAnalysis::new(&cfg, &chain.coefficients).unwrap();
    // A case whose loop gain is the force scale alone (no wall damper:
    // free state, where L is proportional to g).
    let case = Case {
        condition: Condition::D,
        axis: Axis::X,
        state: LoopState::Free,
        hand: Hand {
            stiffness_n_per_m: cfg.plant.k_f,
            damping_n_s_per_m: cfg.plant.b_f,
        },
    };
    let (kappa, g) = (cfg.tweezer.stiffness_n_per_m, cfg.coupling.force_scale);
    let m = a.case(&case, kappa, g, true).unwrap().margins.unwrap();
    let k = 10f64.powf(m.gain_margin_db / 20.0);
    assert!(a.case(&case, kappa, g * k * 0.995, false).unwrap().stable);
    assert!(!a.case(&case, kappa, g * k * 1.005, false).unwrap().stable);
}

/// The default rig meets the minimum margins in P and D; without the wall
/// damper it does not, and the loop is refused with a message naming the
/// margin and the largest safe force scale.
#[test]
fn default_rig_is_safe_and_an_undamped_wall_is_refused() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let r = analyse(&cfg, &chain.coefficients).unwrap();
    assert!(r.safe, "{}", r.summary());
    for c in Condition::HAPTIC {
        let m = r.condition(c).unwrap();
        assert!(
            m.gain_margin_db >= 6.0 && m.phase_margin_deg >= 30.0,
            "{c}: {m:?}"
        );
        assert!(m.stable && m.nominal_stable);
    }
    assert!(r.max_force_scale >= cfg.coupling.force_scale);
    assert!(r.critical_force_scale > r.max_force_scale);
    assert!(r.critical_trap_stiffness_pn_um > r.trap_stiffness_pn_um);
    Clearance::check(&cfg, &chain).unwrap();

    let mut bare = cfg.clone();
    bare.coupling.contact_damping_n_s_per_m = 0.0;
    let r = analyse(&bare, &chain.coefficients).unwrap();
    assert!(!r.safe);
    let d = r.condition(Condition::D).unwrap();
    assert!(d.phase_margin_deg < 10.0, "{d:?}");
    assert!(r.max_force_scale < bare.coupling.force_scale);
    match Clearance::check(&bare, &chain) {
        Err(RigError::LoopNotSafe(m)) => {
            assert!(m.contains("phase margin") || m.contains("unstable"), "{m}");
            assert!(m.contains("largest safe force scale"), "{m}");
        }
        other => panic!("{other:?}"),
    }
    // A stiffer trap beyond the critical one is refused too.
    let mut stiff = cfg.clone();
    let crit = analyse(&cfg, &chain.coefficients)
        .unwrap()
        .critical_trap_stiffness_pn_um;
    stiff.tweezer.stiffness_n_per_m = 1.2 * crit * 1e-6;
    let r = analyse(&stiff, &chain.coefficients).unwrap();
    assert!(!r.condition(Condition::D).unwrap().stable);
}

/// The worst case really is the worst: every case of the report's cases
/// has margins at least the reported ones.
#[test]
fn condition_margins_are_the_worst_over_cases() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let a = LoopAnalysis::new(&cfg, &chain.coefficients).unwrap();
    let r = a.report().unwrap();
    let all = a
        .evaluate(
            cfg.tweezer.stiffness_n_per_m,
            cfg.coupling.force_scale,
            true,
        )
        .unwrap();
    assert_eq!(all.len(), a.cases().len());
    for c in Condition::HAPTIC {
        let m = r.condition(c).unwrap();
        for x in all.iter().filter(|x| x.case.condition == c) {
            let xm = x.margins.unwrap();
            assert!(xm.gain_margin_db >= m.gain_margin_db - 1e-12);
            assert!(xm.phase_margin_deg >= m.phase_margin_deg - 1e-12);
        }
    }
}
