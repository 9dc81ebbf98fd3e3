//! Bilateral coupling: mapping, force sign, limits, P/D modes, closed loop.

#![allow(clippy::unwrap_used)]

use kilotouch_dsp::chain::ChainCoefficients;
use kilotouch_dsp::spectral::{WelchConfig, welch};
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::*;
use kilotouch_rig::device::{ActuatorFrame, Rig};
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::plant::{Axis, AxisModel, Channel};
use kilotouch_rig::tweezer::{Tweezer, TweezerSample};
use kilotouch_rig::{Condition, PMode};

fn coupling() -> Coupling {
    Coupling::from_config(&RigConfig::default()).unwrap()
}

#[test]
fn handle_maps_to_trap_with_scale_offset_and_workspace() {
    let cfg = RigConfig::default();
    let mut c = coupling();
    let s = cfg.coupling.position_scale;
    let t = c.trap_target([10e-3, -5e-3]);
    assert!((t[0] - s * 10e-3).abs() < 1e-18 && (t[1] + s * 5e-3).abs() < 1e-18);
    // Far outside the workspace: clamped to its corners.
    let t = c.trap_target([1.0, -1.0]);
    assert_eq!(t, [cfg.coupling.trap_max_m[0], cfg.coupling.trap_min_m[1]]);
    assert_eq!(c.counters().workspace_clamped, 1);
    // Non-finite handle: the trap holds.
    let t2 = c.trap_target([f64::NAN, f64::INFINITY]);
    assert_eq!(t2, t);
    assert_eq!(c.counters().nonfinite, 2);
}

#[test]
fn felt_force_resists_pushing_into_an_obstacle() {
    let cfg = RigConfig::default();
    let c = coupling();
    // Bead held back at x = 5 µm while the trap is at 5.3 µm (pushing +x).
    let k = cfg.tweezer.stiffness_n_per_m;
    let s = TweezerSample {
        bead_m: [5.0e-6, 0.0],
        trap_m: [5.3e-6, 0.0],
        force_n: [k * 0.3e-6, 0.0],
        trapped: true,
        ..Default::default()
    };
    let f = c.image(&s);
    assert!(f[0] < 0.0, "must push the handle back (−x)");
    assert!((f[0] + cfg.coupling.force_scale * k * 0.3e-6).abs() < 1e-12);
}

#[test]
fn routing_by_condition_and_nonfinite_forces() {
    let cfg = RigConfig::default();
    let free = TweezerSample {
        force_n: [1e-12, -2e-12],
        trapped: true,
        ..Default::default()
    };
    for cond in Condition::ALL {
        let mut c = coupling();
        c.set_condition_now(cond);
        let r = c.render([0.0; 2], &free);
        let img = c.image(&free);
        match cond {
            Condition::V => {
                assert_eq!(r.command, ActuatorFrame::default());
                assert_eq!(r.image_n, [0.0; 2]);
            }
            // Full band on both axes, Haptuator off (C_L = 1: the force itself).
            Condition::P => {
                assert_eq!(r.command.force_n, img);
                assert_eq!(r.command.haptuator_v, 0.0);
                assert_eq!(r.image_n, img);
            }
            // y: full band; x: the chain's first sample (LR4 low b0·C_L).
            Condition::D => {
                assert_eq!(r.command.force_n[1], img[1]);
                assert!(r.command.haptuator_v != 0.0);
            }
        }
        // A non-finite force reaches no filter and no output.
        let bad = TweezerSample {
            force_n: [f64::NAN, f64::INFINITY],
            ..free
        };
        let r = c.render([0.0; 2], &bad);
        assert!(
            r.command.force_n.iter().all(|v| v.is_finite()) && r.command.haptuator_v.is_finite()
        );
        assert_eq!(c.counters().nonfinite, 1);
    }
    let _ = cfg;
}

/// The high-band gain multiplies D's Haptuator drive and nothing else: the
/// Pantograph forces, P and V are the same sample for sample.
#[test]
fn the_high_band_gain_scales_the_haptuator_drive_only() {
    let mut plain = RigConfig::default();
    plain.coupling.high_band_gain = 1.0;
    let mut loud = RigConfig::default();
    loud.coupling.high_band_gain = 25.0;
    for cond in Condition::ALL {
        let mut a = Coupling::from_config(&plain).unwrap();
        let mut b = Coupling::from_config(&loud).unwrap();
        assert_eq!(b.high_band_gain(), 25.0);
        a.set_condition_now(cond);
        b.set_condition_now(cond);
        for k in 0..2000 {
            let t = k as f64 * 1e-4;
            let s = TweezerSample {
                force_n: [1e-12 * (2e3 * t).sin(), 3e-13 * (7e2 * t).cos()],
                trapped: true,
                ..Default::default()
            };
            let (ra, rb) = (a.render([0.0; 2], &s), b.render([0.0; 2], &s));
            assert_eq!(ra.command.force_n, rb.command.force_n, "{cond} sample {k}");
            assert_eq!(ra.image_n, rb.image_n);
            assert_eq!(25.0 * ra.command.haptuator_v, rb.command.haptuator_v);
            if cond == Condition::D && k > 0 {
                assert!(rb.command.haptuator_v != 0.0);
            }
        }
    }
}

/// In the closed loop, a high-band gain g_H raises the Brownian agitation
/// the fingertip feels in D at 400–1000 Hz, where the Haptuator carries it,
/// by nearly g_H² in power, and it still collapses on contact.
#[test]
fn a_high_band_gain_magnifies_the_felt_agitation() {
    let (free1, _) = felt_band_power_at(Condition::D, PMode::FullBand, false, 1.0);
    let (free10, _) = felt_band_power_at(Condition::D, PMode::FullBand, false, 10.0);
    let (press10, c) = felt_band_power_at(Condition::D, PMode::FullBand, true, 10.0);
    let gain = free10 / free1;
    eprintln!("free-space 400–1000 Hz power at g_H = 10 over g_H = 1: {gain:.1}");
    assert!(gain > 80.0 && gain < 105.0, "{gain}");
    assert!(c > 25_000, "{c}");
    assert!(
        press10 < 0.2 * free10,
        "pressed {press10:e} vs free {free10:e}"
    );
}

fn grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// Paper Fig. 7: with the crossover and both compensators (D) the device's
/// force → tip-acceleration response is flat within a few dB (here ±4 dB of
/// K_sys) from 63 Hz to 1 kHz; the Pantograph alone (P, full band) is not.
#[test]
fn dual_mode_flattens_the_device_response() {
    let cfg = RigConfig::default();
    let d = model_chain_design(&cfg).unwrap();
    let chain = ChainCoefficients::design(&d).unwrap();
    let m = AxisModel::new(&cfg, Axis::X).unwrap();
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for f in grid(63.0, 1000.0, 500) {
        let (l, h) = chain.response(f);
        let t = l * m.channel_response(Channel::Low, f).unwrap()
            + h * m.channel_response(Channel::High, f).unwrap();
        let db = 20.0 * (t.norm() / d.k_sys).log10();
        lo = lo.min(db);
        hi = hi.max(db);
    }
    assert!(hi < 4.0 && lo > -4.0, "D mode {lo:.2}…{hi:.2} dB");
    // P, full band: the Pantograph's own response (C_L = 1), with its
    // modes: +7 dB at the 300 Hz resonance, −9 dB at 1 kHz.
    let p_db =
        |f: f64| 20.0 * (m.channel_response(Channel::Low, f).unwrap().norm() / d.k_sys).log10();
    assert!(
        p_db(300.0) > 6.0 && p_db(1000.0) < -8.0,
        "{} {}",
        p_db(300.0),
        p_db(1000.0)
    );
}

/// Condition switches at run time cross-fade: no step in the output beyond
/// what the signal itself does (every path is warm).
#[test]
fn condition_switch_is_glitch_free() {
    let mut c = coupling();
    c.set_condition_now(Condition::V);
    let s = |k: usize| TweezerSample {
        force_n: [5e-12 * (k as f64 * 0.01).sin(), 0.0],
        trapped: true,
        ..Default::default()
    };
    let mut prev = c.render([0.0; 2], &s(0)).command;
    let mut max_step: f64 = 0.0;
    for k in 1..8000 {
        match k {
            2000 => c.set_condition(Condition::P),
            4000 => c.set_condition(Condition::D),
            6000 => c.set_condition(Condition::V),
            _ => {}
        }
        let a = c.render([0.0; 2], &s(k)).command;
        if k > 100 {
            max_step = max_step.max((a.force_n[0] - prev.force_n[0]).abs());
        }
        prev = a;
    }
    // The signal itself moves by ≤ 0.5 N·0.01 per sample; the fades add
    // at most amplitude/fade length.
    assert!(max_step < 0.012, "{max_step}");
}

fn felt_band_power(condition: Condition, p_mode: PMode, press: bool) -> (f64, u64) {
    felt_band_power_at(condition, p_mode, press, 1.0)
}

/// 400–1000 Hz power of the fingertip's x acceleration ((m/s²)²) over the
/// last 3 s of 6 s in `condition`, free or pressed against an obstacle, at
/// the high-band gain `g_h`; and the samples in contact.
fn felt_band_power_at(condition: Condition, p_mode: PMode, press: bool, g_h: f64) -> (f64, u64) {
    let mut cfg = RigConfig::default();
    cfg.coupling.high_band_gain = g_h;
    cfg.coupling.mode = condition;
    cfg.coupling.p_mode = p_mode;
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let mut lp = SimLoop::simulated(&cfg, &chain, Clearance::check(&cfg, &chain).unwrap()).unwrap();
    // Obstacle surface contact at trap x = 12 − 5 − 1.5 = 5.5 µm.
    let hand_x = if press {
        5.5e-6 / cfg.coupling.position_scale + 3.0e-3
    } else {
        0.0
    };
    let n = 60_000;
    let mut acc = Vec::with_capacity(n);
    let mut contact = 0;
    for k in 0..n {
        // Move the hand slowly to its target over the first 2 s.
        let a = (k as f64 / 20_000.0).min(1.0);
        lp.rig.set_hand([a * hand_x, 0.0]);
        let s = lp.step().unwrap().tweezer;
        assert!(s.trapped, "the bead must stay trapped");
        if k >= 30_000 {
            acc.push(lp.rig.truth().accel_m_s2[0]);
            contact += u64::from(s.in_contact);
        }
    }
    let spec = welch(&acc, cfg.rig.sample_rate_hz, &WelchConfig::new(2048)).unwrap();
    let band: f64 = spec
        .f
        .iter()
        .zip(&spec.p)
        .filter(|(f, _)| **f >= 400.0 && **f <= 1000.0)
        .map(|(_, p)| *p)
        .sum::<f64>()
        * (spec.f[1] - spec.f[0]);
    (band, contact)
}

/// Closed loop (paper §4.1): in free space the Brownian agitation reaches
/// the finger at 400–1000 Hz mostly through the Haptuator (D > P, by how much
/// depends on what P is: `docs/theory/coupling-and-stability.md`); pressing the bead against an
/// obstacle makes it collapse (Fig. 9f–g).
#[test]
fn closed_loop_brownian_agitation_and_pressing() {
    let (free_d, c0) = felt_band_power(Condition::D, PMode::FullBand, false);
    let (press_d, c1) = felt_band_power(Condition::D, PMode::FullBand, true);
    let mut ratios = Vec::new();
    for p in [
        PMode::FullBand,
        PMode::LowChannel,
        PMode::Lowpass { hz: 200.0 },
    ] {
        let (free_p, _) = felt_band_power(Condition::P, p, false);
        ratios.push(free_d / free_p);
    }
    eprintln!("D/P 400–1000 Hz band power: full band, low channel, low-pass 200 Hz = {ratios:?}");
    assert_eq!(c0, 0);
    assert!(c1 > 25_000, "should be in contact most of the time: {c1}");
    assert!(ratios[0] > 1.5, "{ratios:?}");
    assert!(ratios[1] > 5.0 && ratios[2] > 5.0, "{ratios:?}");
    assert!(
        press_d < 0.2 * free_d,
        "pressed {press_d:e} vs free {free_d:e}"
    );
}

#[test]
fn closed_loop_runs_and_reports_every_sample() {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    let mut cl = SimLoop::simulated(&cfg, &chain, Clearance::check(&cfg, &chain).unwrap()).unwrap();
    for _ in 0..1000 {
        let s = cl.step().unwrap();
        assert!(s.command.force_n.iter().all(|v| v.is_finite()) && s.tweezer.trapped);
    }
    assert_eq!(cl.rig.status().frames, 1000);
    assert!(cl.tweezer.sample_rate_hz() == 1e4);
    assert!(cl.clearance().report().is_some_and(|r| r.safe));
}
