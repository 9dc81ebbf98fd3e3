//! Safety layer: state machine, ramp, limits, velocity trip and watchdog
//! with exact sample counts derived from the definitions in `safety.rs`.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::{RigConfig, SafetyConfig};
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::device::{ActuatorFrame, FrameFlags, Rig, SensorFrame};
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::safety::*;

const FS: f64 = 1000.0;

fn limits() -> HardLimits {
    HardLimits::new(5.0, 6.0, 2.0).unwrap()
}

fn cfg() -> SafetyConfig {
    SafetyConfig {
        force_norm_max_n: 6.0,
        force_slew_max_n_per_s: 1000.0, // 1 N per sample at 1 kHz
        ramp_time_s: 0.01,              // 10 samples
        enable_force_max_n: 0.05,
        handle_velocity_max_m_s: 1.0,
        velocity_span_samples: 5,
        watchdog_window_s: 0.1,             // 100 samples
        watchdog_max_missed_fraction: 0.03, // M = 3
        arm_on_start: true,
        ..SafetyConfig::default()
    }
}

fn layer(c: &SafetyConfig) -> SafetyLayer {
    SafetyLayer::new(c, limits(), FS).unwrap()
}

fn frame(fx: f64, fy: f64, v: f64) -> ActuatorFrame {
    ActuatorFrame {
        force_n: [fx, fy],
        haptuator_v: v,
    }
}

fn at(x: f64) -> SensorFrame {
    SensorFrame {
        handle_m: [x, 0.0],
        ..Default::default()
    }
}

/// Raised-cosine gain of ramp sample k of N (the documented formula).
fn g(k: u64, n: u64) -> f64 {
    0.5 * (1.0 - (std::f64::consts::PI * k as f64 / n as f64).cos())
}

/// Arm and feed a small command until Enabled; returns samples used.
fn enable(l: &mut SafetyLayer) -> usize {
    l.arm().unwrap();
    let mut n = 0;
    while l.state() != SafetyState::Enabled {
        l.apply(frame(0.0, 0.0, 0.0), &at(0.0), false);
        n += 1;
        assert!(n < 1000);
    }
    n
}

#[test]
fn disabled_outputs_zero_and_arming_waits_for_a_small_command() {
    let mut l = layer(&cfg());
    for _ in 0..50 {
        let o = l.apply(frame(1.0, 1.0, 1.0), &at(0.0), false);
        assert_eq!(o, ActuatorFrame::default());
    }
    assert_eq!(l.state(), SafetyState::Disabled);
    l.arm().unwrap();
    // A large command keeps it in Arming with zero output.
    for _ in 0..50 {
        let o = l.apply(frame(1.0, 0.0, 1.0), &at(0.0), false);
        assert_eq!(o, ActuatorFrame::default());
        assert_eq!(l.state(), SafetyState::Arming);
    }
    // Just at the threshold: still waiting (strictly below is required).
    l.apply(frame(0.05, 0.0, 0.0), &at(0.0), false);
    assert_eq!(l.state(), SafetyState::Arming);
    // Below: the ramp starts on this very sample, at gain g(1).
    let c = frame(0.03, -0.02, 0.5);
    let o = l.apply(c, &at(0.0), false);
    assert_eq!(l.state(), SafetyState::Ramping);
    let n = l.ramp_samples();
    assert_eq!(n, 10);
    assert_eq!(o.force_n, [g(1, n) * 0.03, g(1, n) * -0.02]);
    assert_eq!(o.haptuator_v, g(1, n) * 0.5);
}

#[test]
fn ramp_is_a_monotone_raised_cosine_then_enabled() {
    let mut l = layer(&cfg());
    l.arm().unwrap();
    // Warm the velocity estimator (L + 3 samples) while commanding zero.
    for _ in 0..8 {
        l.apply(frame(0.0, 0.0, 0.0), &at(0.0), false);
    }
    assert_eq!(l.state(), SafetyState::Ramping);
    let k0 = l.status().gain;
    // Constant command 0.04 N (below threshold, so the state already moved on).
    let n = l.ramp_samples();
    let mut prev = 0.0;
    let mut k = 1; // the sample that entered Ramping was k = 1
    assert!((k0 - g(1, n)).abs() < 1e-15);
    while l.state() == SafetyState::Ramping {
        let o = l.apply(frame(0.04, 0.0, 0.0), &at(0.0), false);
        k += 1;
        let want = if k >= n { 1.0 } else { g(k, n) };
        assert!((o.force_n[0] - want * 0.04).abs() < 1e-15, "k={k}");
        assert!(o.force_n[0] >= prev);
        prev = o.force_n[0];
    }
    assert_eq!(k, n);
    assert_eq!(l.state(), SafetyState::Enabled);
    assert_eq!(
        l.apply(frame(0.04, 0.0, 0.0), &at(0.0), false).force_n[0],
        0.04
    );
}

#[test]
fn zero_ramp_time_passes_the_small_command_unchanged() {
    let mut c = cfg();
    c.ramp_time_s = 0.0;
    let mut l = layer(&c);
    l.arm().unwrap();
    // Velocity estimator warm-up: L + 2 samples with no estimate.
    for _ in 0..7 {
        let o = l.apply(frame(0.01, 0.01, 0.1), &at(0.0), false);
        assert_eq!(o, ActuatorFrame::default());
    }
    let o = l.apply(frame(0.01, 0.02, 0.1), &at(0.0), false);
    assert_eq!(l.state(), SafetyState::Enabled);
    assert_eq!(o, frame(0.01, 0.02, 0.1), "first enabled output = command");
}

#[test]
fn hard_limits_axis_norm_drive_and_slew() {
    let mut c = cfg();
    c.force_slew_max_n_per_s = 1100.0;
    let mut l = layer(&c);
    enable(&mut l);
    // Slew: 1.1 N per sample; axis 5 N; norm 6 N; drive 2 V.
    let mut prev = [0.0, 0.0];
    for _ in 0..20 {
        let o = l.apply(frame(100.0, 100.0, -50.0), &at(0.0), false);
        let d = (o.force_n[0] - prev[0]).hypot(o.force_n[1] - prev[1]);
        assert!(d <= 1.1 + 1e-12);
        assert!(o.force_n[0].abs() <= 5.0 && o.force_n[1].abs() <= 5.0);
        assert!(o.force_n[0].hypot(o.force_n[1]) <= 6.0 * (1.0 + 1e-15));
        assert_eq!(o.haptuator_v, -2.0);
        assert!(l.last_flags().has(FrameFlags::LIMITED));
        prev = o.force_n;
    }
    // Converged onto the limited target: (5, 5) scaled onto the 6 N disk.
    let t = 6.0 / 50f64.sqrt() * 5.0;
    assert!((prev[0] - t).abs() < 1e-12 && (prev[1] - t).abs() < 1e-12);
    // floor(6 / 1.1) = 5 slew-limited steps, the 6th lands on the target.
    let st = l.status().counters;
    assert_eq!(st.slew_limited, 5);
}

#[test]
fn stateless_hard_limit_matches_its_definition() {
    let lim = limits();
    let (o, f) = hard_limit(frame(3.0, -4.0, 1.0), &lim);
    assert_eq!((o, f.0), (frame(3.0, -4.0, 1.0), 0));
    let (o, f) = hard_limit(frame(1e300, -1e300, -1e300), &lim);
    let s = 6.0 / 50f64.sqrt();
    assert_eq!(o.force_n, [5.0 * s, -5.0 * s]);
    assert_eq!(o.haptuator_v, -2.0);
    assert!(f.has(FrameFlags::LIMITED));
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let (o, f) = hard_limit(frame(1.0, 1.0, bad), &lim);
        assert_eq!(o, ActuatorFrame::default());
        assert!(f.has(FrameFlags::NONFINITE_COMMAND));
    }
}

#[test]
fn nonfinite_command_trips_and_zeroes() {
    let mut l = layer(&cfg());
    enable(&mut l);
    l.apply(frame(0.5, 0.0, 0.0), &at(0.0), false);
    let o = l.apply(frame(f64::NAN, 0.0, 0.0), &at(0.0), false);
    assert_eq!(o, ActuatorFrame::default());
    assert!(l.last_flags().has(FrameFlags::NONFINITE_COMMAND));
    assert_eq!(l.state(), SafetyState::Fault);
    assert_eq!(
        l.status().last_trip.unwrap().reason,
        TripReason::NonFiniteCommand
    );
    // Latched: arm refused until reset.
    assert!(l.arm().is_err());
    for _ in 0..10 {
        assert_eq!(
            l.apply(frame(0.01, 0.0, 0.0), &at(0.0), false),
            ActuatorFrame::default()
        );
    }
    l.reset();
    assert_eq!(l.state(), SafetyState::Disabled);
    l.arm().unwrap();
    let o = l.apply(frame(0.01, 0.0, 0.0), &at(0.0), false);
    assert_eq!(l.state(), SafetyState::Ramping);
    assert!(o.force_n[0] < 0.01 && o.force_n[0] > 0.0);
}

/// Handle moving at constant speed v from sample s0: span estimates ramp up
/// over L samples; the median of three lags one estimate, so the speed at
/// sample s0 + j is v·min(j − 1, L)/L and the trip comes at the first j with
/// v(j − 1)/L > v_max, i.e. j = floor(L·v_max/v) + 2.
#[test]
fn velocity_trip_at_the_predicted_sample_and_not_below_the_limit() {
    let c = cfg();
    let l_span = c.velocity_span_samples as f64;
    for (v, trips) in [(0.9, false), (1.5, true), (4.0, true), (1e3, true)] {
        let mut l = layer(&c);
        enable(&mut l);
        let mut x = 0.0;
        let mut tripped_at = None;
        for j in 1..=200u64 {
            x += v / FS;
            l.apply(frame(0.0, 0.0, 0.0), &at(x), false);
            if l.state() == SafetyState::Fault {
                tripped_at = Some(j);
                break;
            }
        }
        if trips {
            let want = (l_span * c.handle_velocity_max_m_s / v).floor() as u64 + 2;
            assert_eq!(tripped_at, Some(want), "v = {v}");
            let t = l.status().last_trip.unwrap();
            assert_eq!(t.reason, TripReason::HandleVelocity);
            assert!(t.value > c.handle_velocity_max_m_s);
        } else {
            assert_eq!(tripped_at, None);
            let s = l.status().handle_speed_m_s.unwrap();
            assert!((s - v).abs() < 1e-9, "{s}");
        }
    }
}

#[test]
fn a_single_bad_position_sample_does_not_trip_two_do() {
    for bad_run in [1usize, 2] {
        let mut l = layer(&cfg());
        enable(&mut l);
        let mut tripped = false;
        for k in 0..100 {
            // A 1 m glitch (10 000 m/s apparent speed).
            let x = if (50..50 + bad_run).contains(&k) {
                1.0
            } else {
                0.0
            };
            l.apply(frame(0.0, 0.0, 0.0), &at(x), false);
            tripped |= l.state() == SafetyState::Fault;
        }
        assert_eq!(tripped, bad_run == 2, "run of {bad_run}");
    }
    // NaN positions are held: L of them are tolerated, L + 1 trip.
    let c = cfg();
    let span = c.velocity_span_samples as usize;
    for run in [span, span + 1] {
        let mut l = layer(&c);
        enable(&mut l);
        for k in 0..60 {
            let x = if (20..20 + run).contains(&k) {
                f64::NAN
            } else {
                0.0
            };
            let o = l.apply(frame(0.01, 0.0, 0.0), &at(x), false);
            assert!(o.force_n[0].is_finite());
        }
        let st = l.status();
        assert_eq!(st.counters.nonfinite_sensors, run as u64);
        if run > span {
            assert_eq!(st.state, SafetyState::Fault);
            let t = st.last_trip.unwrap();
            assert_eq!(t.reason, TripReason::SensorInvalid);
            assert_eq!(t.value, (span + 1) as f64);
        } else {
            assert_eq!(st.state, SafetyState::Enabled);
        }
    }
}

/// W = 100 samples, M = 3: four misses within any 100 consecutive samples
/// trip; misses 100 samples apart never accumulate.
#[test]
fn watchdog_window_counts_exactly() {
    let c = cfg();
    let w = c.watchdog_window_samples(FS);
    assert_eq!(w, 100);
    assert_eq!(c.watchdog_max_missed(FS), 3);
    // Misses at window offsets 0, 10, 20 and then at offset 99 (the 4th
    // within the last 100 samples, counting the current one) → trip.
    // At offset 100 the first has left the window → no trip.
    for (last, trips) in [(99usize, true), (100, false)] {
        let mut l = layer(&c);
        enable(&mut l);
        let mut tripped = None;
        for k in 0..=last {
            let missed = [0, 10, 20, last].contains(&k);
            l.apply(frame(0.0, 0.0, 0.0), &at(0.0), missed);
            if tripped.is_none() && l.state() == SafetyState::Fault {
                tripped = Some(k);
            }
        }
        assert_eq!(tripped, trips.then_some(last), "last miss at {last}");
        if trips {
            let t = l.status().last_trip.unwrap();
            assert_eq!((t.reason, t.value), (TripReason::Watchdog, 4.0));
        } else {
            assert_eq!(l.status().missed_in_window, 3);
        }
    }
    // A steady 3 % miss rate (3 per 100) never trips, forever.
    let mut l = layer(&c);
    enable(&mut l);
    for k in 0..100_000 {
        l.apply(frame(0.0, 0.0, 0.0), &at(0.0), k % 100 < 3);
        assert_eq!(l.state(), SafetyState::Enabled);
    }
    assert_eq!(l.status().missed_in_window, 3);
}

#[test]
fn estop_is_latched_until_reset_and_rearm_through_the_ramp() {
    let mut l = layer(&cfg());
    enable(&mut l);
    for _ in 0..10 {
        l.apply(frame(3.0, 0.0, 1.0), &at(0.0), false);
    }
    let h = l.estop_handle();
    let h2 = h.clone();
    std::thread::spawn(move || h2.trigger()).join().unwrap();
    assert!(h.is_triggered());
    // Cut to zero at once, then zero whatever comes in.
    for k in 0..200 {
        let c = if k % 2 == 0 {
            frame(0.0, 0.0, 0.0)
        } else {
            frame(1e9, -1e9, f64::NAN)
        };
        assert_eq!(l.apply(c, &at(0.0), false), ActuatorFrame::default());
        assert_eq!(l.state(), SafetyState::EStop);
    }
    assert!(l.arm().is_err());
    assert_eq!(l.state(), SafetyState::EStop);
    l.reset();
    assert!(!h.is_triggered());
    // Reset alone does not re-enable.
    for _ in 0..20 {
        assert_eq!(
            l.apply(frame(0.01, 0.0, 0.0), &at(0.0), false),
            ActuatorFrame::default()
        );
    }
    l.arm().unwrap();
    let o = l.apply(frame(0.01, 0.0, 0.0), &at(0.0), false);
    assert_eq!(l.state(), SafetyState::Ramping);
    assert_eq!(o.force_n[0], g(1, l.ramp_samples()) * 0.01);
    assert_eq!(l.status().counters.estops, 1);
}

#[test]
fn config_validation_is_located_and_defaults_match_the_file() {
    let file = RigConfig::default();
    assert_eq!(file.safety, SafetyConfig::default());
    // Old rig files without the section still load, with the defaults.
    let text: String = kilotouch_rig::default_config_text()
        .split("[safety]")
        .next()
        .unwrap()
        .to_string();
    let c = RigConfig::from_toml_str(&text, "old.toml").unwrap();
    assert_eq!(c.safety, SafetyConfig::default());
    // Bad values name the key and its line.
    for (from, to, key) in [
        (
            "ramp_time_s = 0.2",
            "ramp_time_s = -1.0",
            "safety.ramp_time_s",
        ),
        (
            "velocity_span_samples = 10",
            "velocity_span_samples = 2",
            "safety.velocity_span_samples",
        ),
        (
            "watchdog_max_missed_fraction = 0.1",
            "watchdog_max_missed_fraction = 1.0",
            "safety.watchdog_max_missed_fraction",
        ),
        (
            "force_slew_max_n_per_s = 2000.0",
            "force_slew_max_n_per_s = nan",
            "safety.force_slew_max_n_per_s",
        ),
    ] {
        let text = kilotouch_rig::default_config_text().replace(from, to);
        let e = RigConfig::from_toml_str(&text, "s.toml").unwrap_err();
        let line = text.lines().position(|l| l.starts_with(to)).unwrap() + 1;
        match e {
            kilotouch_rig::RigError::Config {
                field, line: got, ..
            } => {
                assert_eq!(field, key);
                assert_eq!(got, Some(line));
            }
            other => panic!("{other:?}"),
        }
    }
    let text = kilotouch_rig::default_config_text().replace("arm_on_start", "arm_on_strat");
    assert!(RigConfig::from_toml_str(&text, "s.toml").is_err());
    // The layer re-validates at the rig's actual rate.
    let c = SafetyConfig {
        watchdog_window_s: 100.0,
        ..SafetyConfig::default()
    };
    assert!(SafetyLayer::new(&c, limits(), 10_000.0).is_ok());
    assert!(SafetyLayer::new(&c, limits(), 20_000.0).is_err()); // W > 2^20
    // The default works at any rate: M scales with W.
    for fs in [250.0, 1000.0, 10_000.0, 48_000.0, 192_000.0] {
        let l = SafetyLayer::new(&SafetyConfig::default(), limits(), fs).unwrap();
        let w = (0.1 * fs).round() as usize;
        assert_eq!(l.watchdog_window_samples(), w);
        assert_eq!(
            l.watchdog_max_missed() as usize,
            (0.1 * w as f64).round() as usize
        );
    }
    assert!(SafetyLayer::new(&c, limits(), f64::NAN).is_err());
    assert!(HardLimits::new(5.0, 0.0, 1.0).is_err());
}

fn closed_loop() -> SimLoop {
    let cfg = RigConfig::default();
    let chain = LoopChain::as_designed(&cfg).unwrap();
    SimLoop::simulated(&cfg, &chain, Clearance::check(&cfg, &chain).unwrap()).unwrap()
}

#[test]
fn closed_loop_arms_ramps_and_estops() {
    let mut cl = closed_loop();
    let cfg = SafetyConfig::default();
    assert_eq!(cl.safety_status().state, SafetyState::Arming);
    let ramp = cfg.ramp_samples(1e4) as usize;
    assert_eq!(ramp, 2000);
    let (mut ramping_at, mut enabled_at) = (None, None);
    let mut prev_gain = 0.0;
    let n = ramp + 2000;
    for k in 0..n {
        let cmd = cl.step().unwrap().command;
        let st = cl.safety_status();
        if ramping_at.is_none() && st.state == SafetyState::Ramping {
            ramping_at = Some(k);
            // No kick: the first ramp sample is g(1) times a small command.
            assert!(cmd.force_n[0].hypot(cmd.force_n[1]) < g(1, ramp as u64) * 0.05);
        }
        if enabled_at.is_none() && st.state == SafetyState::Enabled {
            enabled_at = Some(k);
        }
        assert!(st.gain >= prev_gain);
        prev_gain = st.gain;
    }
    // Warm-up: no speed estimate for L + 2 samples (the first span
    // difference needs L + 1 positions, the median three differences).
    let warm = cfg.velocity_span_samples as usize + 2;
    let r = ramping_at.unwrap();
    assert!(r >= warm);
    assert_eq!(enabled_at, Some(r + ramp - 1));
    cl.estop();
    for _ in 0..100 {
        let cmd = cl.step().unwrap().command;
        assert_eq!(cmd, ActuatorFrame::default());
    }
    assert_eq!(cl.safety_status().state, SafetyState::EStop);
    assert_eq!(cl.safety_status().counters.latched_zeroed, 100);
    assert_eq!(cl.rig.status().frames, (n + 100) as u64);
}

#[test]
fn closed_loop_rig_error_trips_the_layer() {
    let mut cl = closed_loop();
    for _ in 0..10 {
        cl.step().unwrap();
    }
    cl.rig.stop().unwrap();
    assert!(cl.step().is_err());
    let st = cl.safety_status();
    assert_eq!(st.state, SafetyState::Fault);
    assert_eq!(st.last_trip.unwrap().reason, TripReason::RigError);
}
