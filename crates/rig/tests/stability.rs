//! The closed loop's stability analysis against independent references
//! (`tests/stability_reference.py`: python-control and a loop model built
//! from the paper's equations with numpy/scipy), and its internal
//! consistency (margins vs eigenvalues, memo, refusal).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::plant::Axis;
use kilotouch_rig::stability::margins::{Margins, grid, grid_for_delay, margins};
use kilotouch_rig::stability::{
    Case, Hand, LoopAnalysis, LoopState, analyse, analyse_with_latency, delay_samples,
};
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

/// The reference transfer function of `g`: numerator and denominator
/// coefficients (descending powers of z) and the sample rate, Hz.
fn transfer(g: &Value) -> (Vec<f64>, Vec<f64>, f64) {
    let num: Vec<f64> = serde_json::from_value(g["num"].clone()).unwrap();
    let den: Vec<f64> = serde_json::from_value(g["den"].clone()).unwrap();
    (num, den, g["fs"].as_f64().unwrap())
}

/// The loop num/den at `fs` Hz with `d` samples of pure delay, at `f` Hz.
fn response(num: &[f64], den: &[f64], fs: f64, d: usize, f: f64) -> C64 {
    let z = C64::from_polar(1.0, 2.0 * PI * f / fs);
    let l = poly_z(num, z) / poly_z(den, z);
    if d == 0 { l } else { l * z.powi(-(d as i32)) }
}

/// The margins of the loop `l` from its response on the grid `fr`, Hz.
fn margins_on(fr: &[f64], l: &dyn Fn(f64) -> C64, fs: f64) -> Margins {
    let v: Vec<C64> = fr.iter().map(|&f| l(f)).collect();
    margins(fr, &v, l, fs)
}

/// `got` is within `tol` of the reference `want`, or both are absent
/// (a reference `null` is a margin or crossover that does not exist).
fn agrees(got: f64, want: &Value, tol: f64, what: &str) {
    match want.as_f64() {
        Some(w) => assert!((got - w).abs() <= tol, "{what}: {got} vs {w}"),
        None => assert!(!got.is_finite(), "{what}: {got} vs none"),
    }
}

/// The case of a reference entry `c`.
fn case_from(c: &Value) -> Case {
    Case {
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
    }
}

/// The margins `m` of a loop case agree with the reference entry `c`: gain
/// margin to 0.02 dB, phase margin to 0.05° and the gain crossover to 0.1 %,
/// or no gain crossover where the reference has none.
fn assert_margins_match(m: &Margins, c: &Value, what: &str) {
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
}

/// The closed-loop spectral radius `rho` agrees with the reference entry `c`.
/// 1e-8 in ρ is 0.001 dB/s in the growth rate 20·log₁₀(ρ)·f_s (two
/// eigenvalue solvers on a 30-state non-normal matrix).
fn assert_spectral_radius_matches(rho: f64, c: &Value, what: &str) {
    let want = c["spectral_radius"].as_f64().unwrap();
    assert!((rho - want).abs() < 1e-8, "{what}: ρ {rho} vs {want}");
}

#[test]
fn margins_match_python_control() {
    let r = reference();
    for g in r["generic"].as_array().unwrap() {
        let (num, den, fs) = transfer(g);
        let l = |f: f64| response(&num, &den, fs, 0, f);
        let m = margins_on(&grid(fs), &l, fs);
        let cmp = |got: f64, want: &Value, tol: f64, what: &str| {
            agrees(got, want, tol, &format!("{what} ({num:?}/{den:?})"));
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

/// Small loops with a long pure delay (the phase turns hundreds of times up
/// to Nyquist): the grid refined for the delay and the refinement of the
/// decisive crossings only give python-control's margins.
#[test]
fn delayed_margins_match_python_control() {
    let r = reference();
    for g in r["generic_delayed"].as_array().unwrap() {
        let (num, den, fs) = transfer(g);
        let d = g["delay_samples"].as_u64().unwrap() as usize;
        let l = |f: f64| response(&num, &den, fs, d, f);
        let fr = grid_for_delay(fs, d);
        // Increasing, the delay turning by at most 45° between points.
        assert!(fr.len() >= grid(fs).len());
        assert!(
            fr.windows(2)
                .all(|w| { w[1] > w[0] && 360.0 * (w[1] - w[0]) * d as f64 / fs <= 45.0 + 1e-9 })
        );
        let m = margins_on(&fr, &l, fs);
        let cmp = |got: f64, want: &Value, tol: f64, what: &str| {
            agrees(got, want, tol, &format!("{what} (d = {d})"));
        };
        cmp(m.gain_margin_db, &g["gain_margin_db"], 1e-4, "GM dB");
        cmp(m.phase_margin_deg, &g["phase_margin_deg"], 1e-3, "PM deg");
        cmp(m.phase_crossover_hz, &g["phase_crossover_hz"], 1e-6, "f180");
        if g["gain_crossover_hz"].is_number() {
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
    // The reference cases are built with the force image as it is (g_H = 1).
    let mut cfg = RigConfig::default();
    cfg.coupling.high_band_gain = 1.0;
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let a = LoopAnalysis::new(&cfg, &chain.coefficients).unwrap();
    let kappa = cfg.tweezer.stiffness_n_per_m;
    let g0 = cfg.coupling.force_scale;
    for c in r["loop_cases"].as_array().unwrap() {
        let case = case_from(c);
        let got = a.case(&case, kappa, g0, true).unwrap();
        let m = got.margins.unwrap();
        let what = format!("{case:?}");
        assert_margins_match(&m, c, &what);
        assert_spectral_radius_matches(got.spectral_radius, c, &what);
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
    assert!(r.critical_trap_stiffness_n_per_m > r.trap_stiffness_n_per_m);
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
        .critical_trap_stiffness_n_per_m;
    stiff.tweezer.stiffness_n_per_m = 1.2 * crit;
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

/// The analysis of `cfg`'s loop with `d` samples of extra delay.
fn delayed(cfg: &RigConfig, chain: &LoopChain, d: usize) -> LoopAnalysis {
    let fs = cfg.rig.sample_rate_hz;
    let a = LoopAnalysis::new(cfg, &chain.coefficients)
        .unwrap()
        .with_latency(d as f64 / fs)
        .unwrap();
    assert_eq!(a.latency_samples(), d);
    a
}

/// The loop with an extra delay z⁻ᵈ against python-control (margins of
/// the delayed frequency response, poles of its own state space with the
/// delay appended) and the delay at which the pressed D loop turns
/// unstable (bisection on python-control's poles).
#[test]
fn delayed_loop_matches_python_control() {
    let r = reference();
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let (kappa, g) = (cfg.tweezer.stiffness_n_per_m, cfg.coupling.force_scale);
    for c in r["delay_cases"].as_array().unwrap() {
        let d = c["delay_samples"].as_u64().unwrap() as usize;
        let case = case_from(c);
        let got = delayed(&cfg, &chain, d)
            .case(&case, kappa, g, true)
            .unwrap();
        let m = got.margins.unwrap();
        let what = format!("{case:?} d = {d}");
        assert_margins_match(&m, c, &what);
        let f180 = c["phase_crossover_hz"].as_f64().unwrap();
        assert!(
            (m.phase_crossover_hz / f180 - 1.0).abs() < 1e-3,
            "{what}: f180 {} vs {f180}",
            m.phase_crossover_hz
        );
        assert_spectral_radius_matches(got.spectral_radius, c, &what);
    }
    // The delay at which the pressed D loop with the rig file's finger
    // turns unstable, by the eigenvalues of the delay-augmented loop.
    let cd = &r["critical_delay"];
    let case = case_from(cd);
    let last = cd["last_stable_samples"].as_u64().unwrap() as usize;
    let first = cd["first_unstable_samples"].as_u64().unwrap() as usize;
    assert!(
        delayed(&cfg, &chain, last)
            .case(&case, kappa, g, false)
            .unwrap()
            .stable
    );
    assert!(
        !delayed(&cfg, &chain, first)
            .case(&case, kappa, g, false)
            .unwrap()
            .stable
    );
}

/// A pure delay leaves |L| and so the gain crossover where it is and turns
/// the phase there by 360°·f_c·d/f_s: on every case of the real loop whose
/// crossover the delay does not change (the smallest |PM| of several
/// crossovers can move to another one), PM_d = PM_0 − 360°·f_c·d/f_s
/// (wrapped to [−180°, 180°)).
#[test]
fn a_delay_lowers_the_phase_margin_by_the_phase_of_the_delay() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let fs = cfg.rig.sample_rate_hz;
    let (kappa, g) = (cfg.tweezer.stiffness_n_per_m, cfg.coupling.force_scale);
    let a0 = LoopAnalysis::new(&cfg, &chain.coefficients).unwrap();
    let base = a0.evaluate(kappa, g, true).unwrap();
    let mut checked = 0;
    for d in [1usize, 30, 100] {
        let ad = delayed(&cfg, &chain, d);
        for (r0, rd) in base.iter().zip(ad.evaluate(kappa, g, true).unwrap()) {
            assert_eq!(r0.case, rd.case);
            let (m0, md) = (r0.margins.unwrap(), rd.margins.unwrap());
            let what = format!("{:?} d = {d}", r0.case);
            if !m0.gain_crossover_hz.is_finite() {
                // No gain crossover: |L| < 1 everywhere, with or without delay.
                assert!(!md.gain_crossover_hz.is_finite(), "{what}");
                continue;
            }
            if (md.gain_crossover_hz / m0.gain_crossover_hz - 1.0).abs() > 1e-9 {
                continue;
            }
            let want = (m0.phase_margin_deg - 360.0 * m0.gain_crossover_hz * d as f64 / fs + 180.0)
                .rem_euclid(360.0)
                - 180.0;
            assert!(
                (md.phase_margin_deg - want).abs() < 1e-6,
                "{what}: PM {} vs {want} (PM₀ {} at {} Hz)",
                md.phase_margin_deg,
                m0.phase_margin_deg,
                m0.gain_crossover_hz
            );
            checked += 1;
        }
    }
    // Every pressed case has a gain crossover (the pressed spring against
    // the finger), and with a single one it cannot move.
    let pressed = base
        .iter()
        .filter(|r| r.case.state == LoopState::Pressed)
        .count();
    assert!(checked >= 3 * pressed, "{checked} cases checked");
}

/// The eigenvalue verdict and the margins agree on the delay at which the
/// loop turns unstable: bisecting the delay at which D's worst phase case
/// loses stability (eigenvalues of the delay-augmented loop), its phase
/// margin changes sign there and is within one sample's phase of zero.
#[test]
fn eigenvalues_and_phase_margin_agree_on_the_critical_delay() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let fs = cfg.rig.sample_rate_hz;
    let (kappa, g) = (cfg.tweezer.stiffness_n_per_m, cfg.coupling.force_scale);
    let r0 = LoopAnalysis::new(&cfg, &chain.coefficients)
        .unwrap()
        .report()
        .unwrap();
    let d0 = r0.condition(Condition::D).unwrap();
    let case = d0.worst_phase_case;
    let stable = |d: usize| {
        delayed(&cfg, &chain, d)
            .case(&case, kappa, g, false)
            .unwrap()
    };
    let (mut lo, mut hi) = (0usize, 400usize);
    assert!(stable(lo).stable && !stable(hi).stable);
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if stable(mid).stable {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let one_sample_deg = 360.0 * d0.gain_crossover_hz / fs;
    let pm = |d: usize| {
        delayed(&cfg, &chain, d)
            .case(&case, kappa, g, true)
            .unwrap()
            .margins
            .unwrap()
            .phase_margin_deg
    };
    let (pm_lo, pm_hi) = (pm(lo), pm(hi));
    assert!(
        pm_lo > 0.0 && pm_lo < one_sample_deg + 1e-9,
        "last stable delay {lo}: PM {pm_lo}°"
    );
    assert!(
        pm_hi < 0.0 && pm_hi > -one_sample_deg - 1e-9,
        "first unstable delay {hi}: PM {pm_hi}°"
    );
    // The spectral radius crosses 1 there.
    assert!(stable(lo).spectral_radius < 1.0 && stable(hi).spectral_radius >= 1.0);
}

/// The report at an extra delay: it states the delay, zero delay is the
/// plain analysis, and the clearance is refused once D's phase margin falls
/// below the minimum, with the delay and the largest safe force scale at
/// that delay in the message.
#[test]
fn the_clearance_at_a_delay_names_it() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let r0 = analyse(&cfg, &chain.coefficients).unwrap();
    let z = analyse_with_latency(&cfg, &chain.coefficients, 0.0).unwrap();
    assert_eq!(
        serde_json::to_value(&r0).unwrap(),
        serde_json::to_value(&z).unwrap()
    );
    assert_eq!((r0.latency_s, r0.latency_samples), (0.0, 0));
    assert!(!r0.summary().contains("delay"), "{}", r0.summary());

    let ok = Clearance::check_with_latency(&cfg, &chain, 2e-3).unwrap();
    assert_eq!(ok.latency_s(), 2e-3);
    let r2 = ok.report().unwrap();
    assert_eq!(r2.latency_samples, 20);
    assert!(r2.safe && r2.summary().contains("2.00 ms (20 samples)"));
    assert_eq!(Clearance::check(&cfg, &chain).unwrap().latency_s(), 0.0);

    let r3 = analyse_with_latency(&cfg, &chain.coefficients, 3e-3).unwrap();
    assert_eq!((r3.latency_s, r3.latency_samples), (3e-3, 30));
    let d3 = r3.condition(Condition::D).unwrap();
    assert!(!r3.safe && d3.phase_margin_deg < 30.0, "{}", r3.summary());
    assert!(r3.max_force_scale < r0.max_force_scale);
    assert!(r3.critical_force_scale < r0.critical_force_scale);
    assert!(r3.critical_trap_stiffness_n_per_m < r0.critical_trap_stiffness_n_per_m);
    match Clearance::check_with_latency(&cfg, &chain, 3e-3) {
        Err(RigError::LoopNotSafe(m)) => {
            for part in [
                "extra loop delay of 3.00 ms (30 samples)",
                "D has a phase margin of",
                "largest safe force scale at that delay",
            ] {
                assert!(m.contains(part), "{part:?} in {m}");
            }
        }
        other => panic!("{other:?}"),
    }
    for bad in [f64::NAN, f64::INFINITY, -1e-3, 0.5] {
        assert!(
            matches!(
                analyse_with_latency(&cfg, &chain.coefficients, bad),
                Err(RigError::InvalidParameter {
                    name: "latency",
                    ..
                })
            ),
            "{bad}"
        );
    }
}

/// Whole samples, rounded up; 3 ms at 10 kHz is 30, not 31.
#[test]
fn latency_rounds_up_to_whole_samples() {
    for (s, fs, d) in [
        (0.0, 1e4, 0),
        (1e-9, 1e4, 1),
        (3e-3, 1e4, 30),
        (0.25e-3, 1e4, 3),
        (14e-3, 1e4, 140),
        (1e-3, 48e3, 48),
        (0.1, 1e4, 1000),
    ] {
        assert_eq!(delay_samples(s, fs).unwrap(), d, "{s} s at {fs} Hz");
    }
    assert!(delay_samples(0.1, 2e4).is_err());
    assert!(delay_samples(f64::NAN, 1e4).is_err());
}

/// The D loop with the high band rendered g_H times stronger, case by
/// case, against the reference script's loop with g_H·C_H on the
/// Haptuator: margins, pole radius and the g_H at which the case turns
/// unstable.
#[test]
fn high_band_gain_cases_match_the_independent_model() {
    let r = reference();
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let kappa = cfg.tweezer.stiffness_n_per_m;
    let g = cfg.coupling.force_scale;
    let at = |gh: f64| {
        let mut c = cfg.clone();
        c.coupling.high_band_gain = gh;
        LoopAnalysis::new(&c, &chain.coefficients).unwrap()
    };
    for c in r["high_gain_cases"].as_array().unwrap() {
        let case = Case {
            condition: Condition::D,
            ..case_from(&serde_json::json!({
                "condition": "D",
                "state": c["state"],
                "hand_stiffness_n_per_m": c["hand_stiffness_n_per_m"],
                "hand_damping_n_s_per_m": c["hand_damping_n_s_per_m"],
            }))
        };
        let gh = c["high_band_gain"].as_f64().unwrap();
        let got = at(gh).case(&case, kappa, g, true).unwrap();
        let m = got.margins.unwrap();
        let what = format!("{case:?} at g_H = {gh}");
        let gm = c["gain_margin_db"].as_f64().unwrap();
        assert!(
            (m.gain_margin_db - gm).abs() < 0.02,
            "{what}: GM {m:?} vs {gm}"
        );
        match c["phase_margin_deg"].as_f64() {
            Some(pm) => assert!((m.phase_margin_deg - pm).abs() < 0.05, "{what}: PM {m:?}"),
            None => assert!(m.phase_margin_deg.is_infinite(), "{what}: {m:?}"),
        }
        let rho = c["spectral_radius"].as_f64().unwrap();
        assert!((got.spectral_radius - rho).abs() < 1e-8, "{what}: ρ");
        // The critical g_H of this case by bisection on the verdict.
        let Some(want) = c["critical_high_band_gain"].as_f64() else {
            continue;
        };
        let stable = |x: f64| at(x).case(&case, kappa, g, false).unwrap().stable;
        let (mut lo, mut hi) = (0.8 * want, 1.25 * want);
        assert!(
            stable(lo) && !stable(hi),
            "{what}: critical g_H near {want}"
        );
        while hi / lo > 1.0005 {
            let mid = (lo * hi).sqrt();
            if stable(mid) {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let got = (lo * hi).sqrt();
        assert!(
            (got / want - 1.0).abs() < 2e-3,
            "{what}: critical g_H {got} vs {want}"
        );
    }
}

/// Without its high band (g_H = 0) the D loop is the D chain's low channel
/// alone, which is what P renders with `p_mode = "low-channel"`: the two
/// conditions' margins agree exactly.
#[test]
fn without_the_high_band_d_is_its_low_channel() {
    let mut cfg = RigConfig::default();
    cfg.coupling.high_band_gain = 0.0;
    cfg.coupling.p_mode = kilotouch_rig::PMode::LowChannel;
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let r = analyse(&cfg, &chain.coefficients).unwrap();
    let (p, d) = (
        r.condition(Condition::P).unwrap(),
        r.condition(Condition::D).unwrap(),
    );
    assert_eq!(p.gain_margin_db, d.gain_margin_db, "{}", r.summary());
    assert_eq!(p.phase_margin_deg, d.phase_margin_deg, "{}", r.summary());
    // D's state space still carries the (zero-gain) high path's states.
    assert!((p.spectral_radius - d.spectral_radius).abs() < 1e-12);
    assert!(r.high_band_force_full_scale_n.is_infinite());
}

/// The report names the largest safe high-band gain; just below it the
/// loop is cleared, above it refused with both numbers.
#[test]
fn a_high_band_gain_beyond_the_largest_safe_one_is_refused() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let r = analyse(&cfg, &chain.coefficients).unwrap();
    assert_eq!(r.high_band_gain, 30.0, "the shipped rig's g_H");
    let max = r.max_high_band_gain;
    assert!(max.is_finite() && max > 100.0, "{}", r.summary());
    assert!(
        r.summary().contains("high-band gain g_H 30.000"),
        "{}",
        r.summary()
    );
    let mut below = cfg.clone();
    below.coupling.high_band_gain = 0.98 * max;
    let rb = analyse(&below, &chain.coefficients).unwrap();
    assert!(rb.safe, "{}", rb.summary());
    // Rendering the high band louder shrinks the Haptuator's full scale.
    assert!(
        (rb.high_band_force_full_scale_n * 0.98 * max
            / (r.high_band_force_full_scale_n * r.high_band_gain)
            - 1.0)
            .abs()
            < 1e-9
    );
    let mut above = cfg.clone();
    above.coupling.high_band_gain = 1.05 * max;
    match Clearance::check(&above, &chain) {
        Err(RigError::LoopNotSafe(m)) => {
            assert!(m.contains("D "), "{m}");
            assert!(m.contains("largest safe high-band gain"), "{m}");
        }
        other => panic!("{other:?}"),
    }
}
