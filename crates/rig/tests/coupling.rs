//! Bilateral coupling: mapping, force sign, limits, P/D modes, closed loop.

#![allow(clippy::unwrap_used)]

use kilotouch_dsp::chain::ChainCoefficients;
use kilotouch_dsp::spectral::{WelchConfig, welch};
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::*;
use kilotouch_rig::plant::{Axis, AxisModel, Channel};
use kilotouch_rig::rig::{Rig, SensorFrame, SimRig};
use kilotouch_rig::tweezer::{SimTweezer, Tweezer, TweezerParams, TweezerSample};

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
    let f = c.handle_force(&s);
    assert!(f[0] < 0.0, "must push the handle back (−x)");
    assert!((f[0] + cfg.coupling.force_scale * k * 0.3e-6).abs() < 1e-12);
}

#[test]
fn outputs_are_clamped_and_never_nonfinite() {
    let cfg = RigConfig::default();
    for mode in [CouplingMode::Pantograph, CouplingMode::Dual] {
        let mut c = coupling();
        c.set_mode(mode);
        for k in 0..2000 {
            let f = match k % 4 {
                0 => [1e6, -1e6],
                1 => [f64::NAN, f64::INFINITY],
                2 => [-1e6, 1e6],
                _ => [f64::NEG_INFINITY, 0.0],
            };
            let a = c.actuate(f);
            assert!(
                a.force_n
                    .iter()
                    .all(|v| v.is_finite() && v.abs() <= cfg.limits.pantograph_force_max_n)
            );
            assert!(
                a.haptuator_v.is_finite()
                    && a.haptuator_v.abs() <= cfg.limits.haptuator_drive_max_v
            );
            if mode == CouplingMode::Pantograph {
                assert_eq!(a.haptuator_v, 0.0);
            }
        }
        assert!(c.counters().clamped > 0);
    }
}

fn grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// Paper Fig. 7: with the crossover and both compensators (D mode) the
/// device's force → tip-acceleration response is flat within a few dB
/// (here ±4 dB of K_sys) from 63 Hz to 1 kHz; the Pantograph alone (P mode)
/// has lost 20 dB by 1 kHz.
#[test]
fn dual_mode_flattens_the_device_response() {
    let cfg = RigConfig::default();
    let d = model_chain_design(&cfg).unwrap();
    let chain = ChainCoefficients::design(&d).unwrap();
    let m = AxisModel::new(&cfg, Axis::X).unwrap();
    let p = PantographOnly::new(cfg.coupling.pantograph_band_hz, cfg.rig.sample_rate_hz).unwrap();
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
    let tp = p.response(1000.0, cfg.rig.sample_rate_hz)
        * m.channel_response(Channel::Low, 1000.0).unwrap();
    assert!(20.0 * (tp.norm() / d.k_sys).log10() < -20.0);
}

/// Mode switches at run time: no step in the output beyond what the signal
/// itself does (both paths are warm).
#[test]
fn mode_switch_is_glitch_free() {
    let mut c = coupling();
    c.set_mode(CouplingMode::Pantograph);
    let f = |k: usize| [0.5 * (k as f64 * 0.01).sin(), 0.0];
    let mut prev = c.actuate(f(0));
    let mut max_step: f64 = 0.0;
    for k in 1..5000 {
        if k == 2500 {
            c.set_mode(CouplingMode::Dual);
        }
        let a = c.actuate(f(k));
        if k > 100 && k != 2500 {
            max_step = max_step.max((a.force_n[0] - prev.force_n[0]).abs());
        }
        if k == 2500 {
            // The low outputs of the two paths agree at 16 Hz within 5 %·amplitude.
            assert!(
                (a.force_n[0] - prev.force_n[0]).abs() < 0.05,
                "{} {}",
                a.force_n[0],
                prev.force_n[0]
            );
        }
        prev = a;
    }
    assert!(max_step < 0.02);
}

fn felt_band_power(mode: CouplingMode, press: bool) -> (f64, u64) {
    let cfg = RigConfig::default();
    let mut rig = SimRig::new(&cfg).unwrap();
    rig.start().unwrap();
    let mut tw = SimTweezer::new(
        TweezerParams::from_config(&cfg.tweezer),
        cfg.rig.sample_rate_hz,
    )
    .unwrap();
    let mut c = Coupling::from_config(&cfg).unwrap();
    c.set_mode(mode);
    // Obstacle surface contact at trap x = 12 − 5 − 1.5 = 5.5 µm.
    let hand_x = if press {
        5.5e-6 / cfg.coupling.position_scale + 3.0e-3
    } else {
        0.0
    };
    let n = 60_000;
    let mut sensors = SensorFrame::default();
    let mut acc = Vec::with_capacity(n);
    let mut contact = 0;
    for k in 0..n {
        // Move the hand slowly to its target over the first 2 s.
        let a = (k as f64 / 20_000.0).min(1.0);
        rig.set_hand([a * hand_x, 0.0]);
        if k == 0 {
            tw.reset(c.trap_target(sensors.handle_m));
        }
        let (cmd, s) = c.step(&sensors, &mut tw);
        let mut out = [SensorFrame::default()];
        rig.process_block(&[cmd], &mut out).unwrap();
        sensors = out[0];
        assert!(s.trapped, "the bead must stay trapped");
        if k >= 30_000 {
            acc.push(rig.truth().accel_m_s2[0]);
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

/// Closed loop (paper §4.1): in free space the Brownian agitation reaches the
/// finger at 400–1000 Hz only through the Haptuator (D ≫ P); pressing the bead
/// against an obstacle makes it collapse (Fig. 9f–g).
#[test]
fn closed_loop_brownian_agitation_and_pressing() {
    let (free_d, c0) = felt_band_power(CouplingMode::Dual, false);
    let (free_p, _) = felt_band_power(CouplingMode::Pantograph, false);
    let (press_d, c1) = felt_band_power(CouplingMode::Dual, true);
    assert_eq!(c0, 0);
    assert!(c1 > 25_000, "should be in contact most of the time: {c1}");
    assert!(free_d > 5.0 * free_p, "D {free_d:e} vs P {free_p:e}");
    assert!(
        press_d < 0.2 * free_d,
        "pressed {press_d:e} vs free {free_d:e}"
    );
}

#[test]
fn closed_loop_helper_runs() {
    let cfg = RigConfig::default();
    let rig = SimRig::new(&cfg).unwrap();
    let tw = SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), 1e4).unwrap();
    let mut cl = ClosedLoop::new(rig, tw, Coupling::from_config(&cfg).unwrap()).unwrap();
    for _ in 0..1000 {
        let (cmd, s) = cl.step().unwrap();
        assert!(cmd.force_n.iter().all(|v| v.is_finite()) && s.trapped);
    }
    assert_eq!(cl.rig.status().frames, 1000);
    assert!(cl.tweezer.sample_rate_hz() == 1e4);
}
