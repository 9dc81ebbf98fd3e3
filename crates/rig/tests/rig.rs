//! Rig interface and simulated rig: frames, limits, faults, pacing.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::*;
use kilotouch_rig::lti::Integrator;
use kilotouch_rig::plant::{Axis, AxisModel, Channel};
use kilotouch_rig::sim::{Pacing, SimRig};
use num_complex::Complex64 as C64;
use std::f64::consts::PI;
use std::time::Duration;

fn batch() -> SimRig {
    let mut r = SimRig::new(&RigConfig::default()).unwrap();
    r.start().unwrap();
    r
}

fn run(rig: &mut impl Rig, cmds: &[ActuatorFrame]) -> Vec<SensorFrame> {
    let mut out = vec![SensorFrame::default(); cmds.len()];
    rig.process_block(cmds, &mut out).unwrap();
    out
}

#[test]
fn identity_and_sequence_numbers() {
    let mut r = batch();
    let id = r.identity().clone();
    assert_eq!(id.kind, RigKind::Simulated);
    assert_eq!(id.sample_rate_hz, 10_000.0);
    assert_eq!(id.force_max_n, 5.0);
    let mut next = 0;
    for n in [1usize, 7, 64, 3] {
        let out = run(&mut r, &vec![ActuatorFrame::default(); n]);
        for f in &out {
            assert_eq!(f.seq, next);
            next += 1;
        }
    }
    assert_eq!(r.status().frames, 75);
    let j = serde_json::to_string(&id).unwrap();
    assert!(j.contains("simulated"));
}

#[test]
fn handle_follows_the_hand_and_is_quantised() {
    let mut r = batch();
    r.set_hand([3.2e-3, -1.0e-3]);
    let mut last = SensorFrame::default();
    for _ in 0..400 {
        last = *run(&mut r, &[ActuatorFrame::default(); 100])
            .last()
            .unwrap();
    }
    let res = RigConfig::default().rig.encoder_resolution_m;
    for (h, want) in last.handle_m.iter().zip([3.2e-3, -1.0e-3]) {
        assert!((h - want).abs() <= 0.5 * res + 1e-12, "{h} vs {want}");
        assert!(((h / res) - (h / res).round()).abs() < 1e-6);
    }
    // Gravity on the accelerometer's z axis.
    assert!((last.accel_m_s2[2] - 9.80665).abs() < 0.3);
}

/// A 100 Hz Pantograph force reaches the accelerometer with the gain of the
/// analytic channel times the sensor's exposed response.
#[test]
fn sine_force_reaches_the_accelerometer_with_the_model_gain() {
    let cfg = RigConfig::default();
    let mut r = batch();
    let fs = 10_000.0;
    let f = 100.0;
    let amp = 1.0;
    let n = 40_000;
    let cmds: Vec<ActuatorFrame> = (0..n)
        .map(|k| ActuatorFrame {
            force_n: [amp * (2.0 * PI * f * k as f64 / fs).sin(), 0.0],
            haptuator_v: 0.0,
        })
        .collect();
    let out = run(&mut r, &cmds);
    let (mut acc, mut refc) = (C64::new(0.0, 0.0), C64::new(0.0, 0.0));
    for (k, fr) in out.iter().enumerate().skip(n / 2) {
        let e = C64::from_polar(1.0, -2.0 * PI * f * k as f64 / fs);
        acc += fr.accel_m_s2[0] * e;
        refc += cmds[k].force_n[0] * e;
    }
    let measured = (acc / refc).norm();
    let m = AxisModel::new(&cfg, Axis::X).unwrap();
    let expect = m.channel_response(Channel::Low, f).unwrap().norm()
        * r.accelerometer().response(0, f).norm();
    assert!(
        (measured / expect - 1.0).abs() < 0.02,
        "{measured} vs {expect}"
    );
}

#[test]
fn limits_and_nonfinite_commands_are_flagged() {
    let mut r = batch();
    let cmds = [
        ActuatorFrame {
            force_n: [10.0, -10.0],
            haptuator_v: 0.0,
        },
        ActuatorFrame {
            force_n: [f64::NAN, 0.0],
            haptuator_v: f64::INFINITY,
        },
        ActuatorFrame {
            force_n: [0.0, 0.0],
            haptuator_v: 5.0,
        },
    ];
    let out = run(&mut r, &cmds);
    assert!(out[0].flags.has(FrameFlags::LIMITED));
    assert!(out[1].flags.has(FrameFlags::NONFINITE_COMMAND));
    assert!(out[2].flags.has(FrameFlags::LIMITED));
    for f in &out {
        assert!(
            f.accel_m_s2
                .iter()
                .chain(&f.handle_m)
                .all(|v| v.is_finite())
        );
    }
    let mut faults = Vec::new();
    while let Some(f) = r.pop_fault() {
        faults.push(f);
    }
    assert!(faults.contains(&RigFault::ActuatorLimited { seq: 0 }));
    assert!(faults.contains(&RigFault::NonFiniteCommand { seq: 1 }));
    let st = r.status();
    assert_eq!(st.limited_frames, 2);
    assert_eq!(st.nonfinite_commands, 1);
    assert_eq!(st.faults_pending, 0);
}

#[test]
fn full_drive_at_50_hz_hits_the_end_stops() {
    let mut r = batch();
    let cmds: Vec<ActuatorFrame> = (0..5000)
        .map(|k| ActuatorFrame {
            force_n: [0.0; 2],
            haptuator_v: 2.0 * (2.0 * PI * 50.0 * k as f64 / 1e4).sin(),
        })
        .collect();
    let out = run(&mut r, &cmds);
    assert!(out.iter().any(|f| f.flags.has(FrameFlags::END_STOP)));
    assert!(r.status().end_stop_frames > 0);
    assert!(r.truth().stroke_m.abs() < 2.0 * RigConfig::default().haptuator.stroke_m);
}

#[test]
fn usage_errors() {
    let mut r = SimRig::new(&RigConfig::default()).unwrap();
    let mut s = [SensorFrame::default(); 2];
    assert!(matches!(
        r.process_block(&[ActuatorFrame::default(); 2], &mut s),
        Err(kilotouch_rig::RigError::NotReady(_))
    ));
    r.start().unwrap();
    assert!(
        r.process_block(&[ActuatorFrame::default(); 3], &mut s)
            .is_err()
    );
    r.stop().unwrap();
    assert_eq!(r.status().state, RigState::Idle);
}

#[test]
fn fault_queue_is_bounded() {
    let mut q = FaultQueue::default();
    for i in 0..(FaultQueue::CAPACITY as u64 + 10) {
        q.push(RigFault::EndStop { seq: i });
    }
    assert_eq!(q.len(), FaultQueue::CAPACITY);
    assert_eq!(q.dropped(), 10);
    assert_eq!(q.pop(), Some(RigFault::EndStop { seq: 10 }));
}

fn paced(clock: &ManualClock, max_lag: f64) -> SimRig<ManualClock> {
    let mut r = SimRig::with_clock(
        &RigConfig::default(),
        Integrator::Zoh,
        Pacing::WallClock { max_lag_s: max_lag },
        clock.clone(),
    )
    .unwrap();
    r.start().unwrap();
    r
}

/// Pacing derives each deadline from the anchor and the sample count: after
/// k blocks the clock stands at exactly k·n/fs (no accumulated sleep error).
#[test]
fn paced_rig_follows_the_clock() {
    let clock = ManualClock::default();
    let mut r = paced(&clock, 1.0);
    let n = 37; // 3.7 ms, not a round number of microseconds
    for k in 1..=1000u64 {
        run(&mut r, &vec![ActuatorFrame::default(); n]);
        let expect = Duration::from_secs_f64((k * n as u64) as f64 / 1e4);
        let diff = clock.now().as_secs_f64() - expect.as_secs_f64();
        assert!(diff.abs() < 2e-9, "block {k}: {diff:e}");
    }
    assert_eq!(clock.sleeps(), 1000);
}

/// After a stall shorter than the tolerated lag, blocks run back to back
/// (no sleeping) until the simulation has caught up with the clock; then
/// pacing resumes. A stall longer than the lag is skipped and reported.
#[test]
fn paced_rig_catches_up_after_a_stall_and_skips_a_long_one() {
    let clock = ManualClock::default();
    let mut r = paced(&clock, 0.5);
    let n = 100; // 10 ms blocks
    for _ in 0..10 {
        run(&mut r, &vec![ActuatorFrame::default(); n]);
    }
    assert_eq!(clock.sleeps(), 10);
    clock.advance(Duration::from_millis(50));
    assert_eq!(r.frames_due(), 500);
    let mut no_sleep_blocks = 0;
    let mut reports = Vec::new();
    for _ in 0..10 {
        let before = clock.sleeps();
        let mut s = vec![SensorFrame::default(); n];
        reports.push(
            r.process_block(&vec![ActuatorFrame::default(); n], &mut s)
                .unwrap(),
        );
        if clock.sleeps() == before {
            no_sleep_blocks += 1;
        }
    }
    // 50 ms behind = 5 blocks of 10 ms run without sleeping (the 5th lands
    // exactly on its deadline), then pacing resumes.
    assert_eq!(no_sleep_blocks, 5, "{reports:?}");
    assert!(reports[0].lag_s > 0.039 && reports[0].lag_s < 0.041);
    assert_eq!(r.frames_due(), 0);
    // Long stall: 3 s > 0.5 s tolerated → skipped, reported, no catch-up.
    clock.advance(Duration::from_secs(3));
    let mut s = vec![SensorFrame::default(); n];
    let rep = r
        .process_block(&vec![ActuatorFrame::default(); n], &mut s)
        .unwrap();
    assert_eq!(rep.skipped_samples, 30_000);
    assert!(matches!(
        r.pop_fault(),
        Some(RigFault::Overrun {
            skipped: 30_000,
            ..
        })
    ));
    let before = clock.sleeps();
    run(&mut r, &vec![ActuatorFrame::default(); n]);
    assert_eq!(clock.sleeps(), before + 1);
}

/// With the system clock, a paced run of 50 ms of samples takes at least
/// 50 ms of wall time (the deadline is never early).
#[test]
fn paced_rig_on_the_system_clock_is_never_early() {
    let mut r = SimRig::paced(&RigConfig::default(), 1.0).unwrap();
    r.start().unwrap();
    let t0 = std::time::Instant::now();
    for _ in 0..10 {
        run(&mut r, &[ActuatorFrame::default(); 50]);
    }
    assert!(t0.elapsed() >= Duration::from_millis(50));
}
