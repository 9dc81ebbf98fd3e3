//! The engine on a live rig: the serial DAQ emulator (`kilotouch emulate daq
//! --pty`) behind a real pty, as a firmware would be behind a USB serial port.
//!
//! * the loop runs at the device's rate (10 kHz, from the device's
//!   sequence numbers against the wall clock), every sample accounted for,
//!   the closed loop works (the commands reach the device: its accelerometer
//!   follows the Haptuator drive), outputs stay finite and within the
//!   device's limits, the emergency stop zeroes them;
//! * a killed emulator is reported within 200 ms, the engine stops (no
//!   hang, no panic) and reconnects to a restarted emulator without being
//!   restarted;
//! * a stalled device is detected by the host timeout and the same port is
//!   reopened once it answers again.

#![allow(clippy::unwrap_used)]

mod common;

use common::{Emulator, rms};
use kilotouch::engine::{
    Condition, EngineEvent, EngineHandle, EngineOptions, SafetyState, TelemetrySample, flags,
};
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigState;
use std::time::{Duration, Instant};

/// Drain telemetry and events for `d`; returns the samples and the events
/// the user should see.
fn collect(h: &mut EngineHandle, d: Duration) -> (Vec<TelemetrySample>, Vec<EngineEvent>) {
    let t0 = Instant::now();
    let (mut t, mut ev) = (Vec::new(), Vec::new());
    while t0.elapsed() < d {
        std::thread::sleep(Duration::from_millis(10));
        h.drain_telemetry(|s| t.push(*s));
        ev.extend(h.poll_events());
    }
    h.drain_telemetry(|s| t.push(*s));
    ev.extend(h.poll_events());
    (t, ev)
}

/// Wait until `pred` holds on a polled event (or time out); returns the
/// time it took.
fn wait_event(
    h: &mut EngineHandle,
    timeout: Duration,
    mut pred: impl FnMut(&EngineEvent) -> bool,
) -> Option<Duration> {
    let t0 = Instant::now();
    while t0.elapsed() < timeout {
        h.drain_telemetry(|_| {});
        if h.poll_events().iter().any(&mut pred) {
            return Some(t0.elapsed());
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    None
}

/// Wait (≤ 2 s) for a health report satisfying `pred`.
fn wait_health(
    h: &mut EngineHandle,
    mut pred: impl FnMut(&kilotouch::engine::Health) -> bool,
) -> Option<kilotouch::engine::Health> {
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < common::WAIT_S {
        h.drain_telemetry(|_| {});
        let _ = h.poll_events();
        if let Some(x) = h.health().filter(|x| pred(x)) {
            return Some(*x);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

/// Largest |normalised correlation| of `y[k]` with `x[k − lag]` over lags
/// 0..40, `x` first rotated by `shift` samples (a shift of half the record
/// gives the null level).
fn best_correlation(y: &[f64], x: &[f64], shift: usize) -> (f64, usize) {
    let n = y.len().min(x.len());
    let xs: Vec<f64> = (0..n).map(|k| x[(k + shift) % n]).collect();
    let m = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (my, mx) = (m(&y[..n]), m(&xs));
    let mut best = (0.0f64, 0usize);
    for lag in 0..40 {
        let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
        for k in lag..n {
            let (a, b) = (y[k] - my, xs[k - lag] - mx);
            sxy += a * b;
            sxx += b * b;
            syy += a * a;
        }
        let r = (sxy / (sxx * syy).sqrt()).abs();
        if r > best.0 {
            best = (r, lag);
        }
    }
    best
}

/// Every sample present once, in order.
fn assert_contiguous(t: &[TelemetrySample]) {
    for w in t.windows(2) {
        assert_eq!(w[1].seq, w[0].seq + 1, "gap in the telemetry");
    }
}

fn opts() -> EngineOptions {
    EngineOptions {
        ramp_s: 0.01,
        ..Default::default()
    }
}

#[test]
fn serial_loop_runs_at_the_device_rate_closes_the_loop_and_estop_zeroes() {
    let emu = Emulator::spawn("daq", &["--seed", "7"]);
    // Generous host timeout: a shared machine may deschedule a process for
    // tens of ms; what is tested here is the stream, not fault timing.
    let cfg = RigConfig::default();
    let mut h =
        EngineHandle::spawn_spec(&cfg, &emu.spec(",timeout-ms=1000,lead=1"), opts()).unwrap();
    assert!(h.is_live());
    let fs = h.sample_rate_hz();
    assert_eq!(
        fs, cfg.rig.sample_rate_hz,
        "the emulator serves the default rig"
    );
    let id = h.identity().clone();

    // D condition (default): 1.5 s of closed loop.
    let t_wall = Instant::now();
    let (d, ev) = collect(&mut h, Duration::from_millis(1500));
    let wall = t_wall.elapsed().as_secs_f64();
    assert!(
        !ev.iter().any(|e| matches!(e, EngineEvent::RigError(_))),
        "{ev:?}"
    );
    assert!(d.len() > 7500, "only {} samples in 1.5 s", d.len());
    assert_contiguous(&d);
    // Rate from the device's own sequence numbers: the samples that arrived
    // over the collection window (start-up latency ≤ one block either side).
    let rate = d.len() as f64 / wall;
    let health = *h.health().unwrap();
    assert!(
        (health.loop_rate_hz - fs).abs() < 0.05 * fs,
        "health rate {} Hz",
        health.loop_rate_hz
    );
    assert!((rate - fs).abs() < 0.1 * fs, "rate {rate} Hz");
    eprintln!(
        "live serial loop: {:.0} Hz (health), {rate:.0} Hz (telemetry), load {:.1} %, \
         deadline misses {}, worst lateness {:.2} ms",
        health.loop_rate_hz,
        100.0 * health.load,
        health.deadline_misses,
        1e3 * health.worst_lateness_total_s
    );
    assert!(health.load < 0.5, "load {} (computation only)", health.load);
    assert_eq!(health.rig.lost_frames, 0);
    assert_eq!(health.rig.state, RigState::Running);
    assert_eq!(health.safety, SafetyState::Enabled);
    // Outputs finite, within the device's limits.
    for s in &d {
        let o = s.output;
        assert!(
            o.force_n
                .iter()
                .all(|f| f.is_finite() && f.abs() <= id.force_max_n)
        );
        assert!(o.haptuator_v.is_finite() && o.haptuator_v.abs() <= id.haptuator_max_v);
        assert!(s.accel_m_s2.iter().all(|a| a.is_finite()));
        // The hand is the real handle.
        assert_eq!(s.hand_m, s.handle_m);
        // Coupling identity: handle force = −force_scale · optical force.
        let expect = -cfg.coupling.force_scale * s.bead_force_n[0];
        assert!((s.handle_force_n[0] - expect).abs() <= 1e-12 * expect.abs().max(1e-9));
    }
    let late = &d[d.len() / 10..];
    let drive: Vec<f64> = late.iter().map(|s| s.output.haptuator_v).collect();
    let acc: Vec<f64> = late.iter().map(|s| s.accel_m_s2[0]).collect();
    assert!(
        rms(drive.iter().copied()) > 1e-4,
        "the bead's agitation drives the Haptuator"
    );
    // The commands reach the device: the x acceleration (the Haptuator's
    // axis) is correlated with the drive a few samples earlier (the
    // device's response). Independent signals give |ρ| ~ 1/√n per lag
    // (max over 40 lags ≈ 3/√n, as the shifted null shows); demand 6/√n
    // and twice the null (the thermal drive is small against the
    // accelerometer's noise, so ρ itself is only ≈ 0.1).
    let (rho, lag) = best_correlation(&acc, &drive, 0);
    let (null, _) = best_correlation(&acc, &drive, acc.len() / 2);
    let floor = 6.0 / (acc.len() as f64).sqrt();
    eprintln!("drive → accel correlation {rho:.3} at lag {lag}, null {null:.3}, floor {floor:.3}");
    assert!(rho > floor && rho > 2.0 * null, "ρ = {rho}, null {null}");

    // Mouse requests do nothing on a live rig.
    assert!(h.set_hand([1e-3, 1e-3]));

    // V: outputs exactly zero; the hand is still the real handle.
    assert!(h.set_condition(Condition::V));
    let (v, _) = collect(&mut h, Duration::from_millis(300));
    let quiet = &v[v.len() / 2..];
    assert!(quiet.iter().all(|s| s.output == Default::default()));
    assert!(quiet.iter().all(|s| s.hand_m == s.handle_m));

    // Emergency stop: from the next block on, every output exactly zero.
    assert!(h.set_condition(Condition::D));
    let _ = collect(&mut h, Duration::from_millis(200));
    h.emergency_stop();
    let (e, _) = collect(&mut h, Duration::from_millis(300));
    let first = e.iter().position(|s| s.has(flags::ESTOP)).unwrap();
    assert!(first <= 2 * 10, "estop after {first} samples");
    assert!(e[first..].iter().all(|s| s.output == Default::default()));
    assert_eq!(h.health().unwrap().safety, SafetyState::EStop);
    assert!(h.is_alive());
    h.shutdown();
}

#[test]
fn killed_emulator_is_reported_promptly_and_a_restarted_one_reconnects() {
    let mut emu = Emulator::start();
    let cfg = RigConfig::default();
    let mut h = EngineHandle::spawn_spec(&cfg, &emu.spec(",lead=1"), opts()).unwrap();
    let (t, ev) = collect(&mut h, Duration::from_millis(300));
    assert!(
        t.len() > 1000 && ev.is_empty(),
        "{} samples, {ev:?}",
        t.len()
    );

    emu.kill();
    let took = wait_event(&mut h, Duration::from_secs_f64(common::WAIT_S), |e| {
        matches!(e, EngineEvent::RigError(_))
    })
    .expect("a rig error after the emulator was killed");
    assert!(took < Duration::from_millis(200), "reported after {took:?}");
    let msg = h.last_error().unwrap().to_owned();
    assert!(
        msg.contains("disconnected") || msg.contains(&emu.path),
        "{msg}"
    );
    // The engine stopped (no more telemetry), its thread lives on.
    let (after, _) = collect(&mut h, Duration::from_millis(150));
    assert!(after.is_empty(), "{} samples after the fault", after.len());
    let hl = wait_health(&mut h, |x| !x.running).expect("a health report while stopped");
    assert_eq!(hl.safety, SafetyState::Fault);
    assert!(!hl.running);
    assert_eq!(hl.rig.state, RigState::Disconnected);
    assert!(h.is_alive());

    // Reconnecting to the dead port fails cleanly; a restarted emulator
    // (new pty) is picked up without restarting the engine.
    assert!(h.reconnect(None));
    wait_event(&mut h, Duration::from_secs_f64(common::WAIT_S), |e| {
        matches!(e, EngineEvent::RigError(_))
    })
    .expect("reconnect to a dead port reports an error");
    let emu2 = Emulator::start();
    assert!(h.reconnect(Some(emu2.spec(",lead=1"))));
    wait_event(&mut h, Duration::from_secs_f64(common::WAIT_S), |e| {
        matches!(e, EngineEvent::Reconnected(_))
    })
    .expect("reconnected");
    assert!(h.last_error().is_none());
    let (t2, ev2) = collect(&mut h, Duration::from_millis(400));
    assert!(
        !ev2.iter().any(|e| matches!(e, EngineEvent::RigError(_))),
        "{ev2:?}"
    );
    assert!(t2.len() > 2000, "{} samples after reconnect", t2.len());
    assert_contiguous(&t2);
    assert!(t2.iter().all(|s| s.output.haptuator_v.is_finite()));
    let hl = *h.health().unwrap();
    assert!(hl.running);
    assert_ne!(hl.safety, SafetyState::Fault);
    h.shutdown();
}

#[test]
fn stalled_device_times_out_and_the_same_port_reconnects() {
    // The device hangs 0.4 s after start, for 0.5 s.
    let emu = Emulator::spawn("daq", &["--stall-after-s", "0.4", "--stall-for-s", "0.5"]);
    let cfg = RigConfig::default();
    let mut h =
        EngineHandle::spawn_spec(&cfg, &emu.spec(",timeout-ms=100,lead=1"), opts()).unwrap();
    let t0 = Instant::now();
    let mut last_sample = None;
    let mut err_at = None;
    while t0.elapsed() < Duration::from_secs(3) && err_at.is_none() {
        if h.drain_telemetry(|_| {}) > 0 {
            last_sample = Some(Instant::now());
        }
        if h.poll_events()
            .iter()
            .any(|e| matches!(e, EngineEvent::RigError(_)))
        {
            err_at = Some(Instant::now());
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let err_at = err_at.expect("the stall is reported");
    let gap = err_at - last_sample.unwrap();
    // Host timeout 100 ms + one poll period + scheduling.
    assert!(
        gap < Duration::from_millis(250),
        "error {gap:?} after the last sample"
    );
    wait_health(&mut h, |x| !x.running && x.safety == SafetyState::Fault)
        .expect("the engine stopped in the fault state");
    // After the stall the device answers again on the same port.
    // (The stall ends 0.9 s after the emulator started, before t0.)
    std::thread::sleep(
        (t0 + Duration::from_millis(1000)).saturating_duration_since(Instant::now()),
    );
    assert!(h.reconnect(None));
    wait_event(&mut h, Duration::from_secs_f64(common::WAIT_S), |e| {
        matches!(e, EngineEvent::Reconnected(_))
    })
    .expect("same port reconnected");
    let (t, _) = collect(&mut h, Duration::from_millis(300));
    assert!(t.len() > 1500, "{} samples after reconnect", t.len());
    assert_contiguous(&t);
    h.shutdown();
}

/// The loop delay of a live rig (its block plus the link's command lead)
/// is in the stability clearance: the engine arms the loop only when the
/// margins hold with that delay (docs/theory/coupling-and-stability.md, loop delay), re-analyses a
/// chain cleared for less delay before swapping it in, and refuses a lead
/// long enough to break D's phase margin, naming the delay.
#[test]
fn the_loop_delay_of_a_live_rig_is_in_the_stability_clearance() {
    use kilotouch_rig::haptic_loop::Clearance;
    let emu = Emulator::start();
    let cfg = RigConfig::default();
    let mut h = EngineHandle::spawn_spec(&cfg, &emu.spec(",lead=1"), opts()).unwrap();
    let fs = h.sample_rate_hz();
    // Block 10 + lead 1 block = 20 samples, 19 beyond the simulated loop's one.
    assert_eq!(h.loop_delay_samples(), 20);
    assert!(
        (h.latency_s() - 19.0 / fs).abs() < 1e-12,
        "{}",
        h.latency_s()
    );
    let (chain, armed) = h.chain_and_clearance().unwrap();
    assert_eq!(armed.latency_s(), h.latency_s());
    assert_eq!(armed.report().unwrap().latency_samples, 19);
    // A clearance analysed without the delay is analysed again with it.
    let at_zero = Clearance::check(&cfg, &chain).unwrap();
    assert_eq!(at_zero.latency_s(), 0.0);
    h.apply_chain(&chain, &at_zero).unwrap();
    let (_, applied) = h.chain_and_clearance().unwrap();
    assert_eq!(applied.latency_s(), h.latency_s());
    let pm = |c: &Clearance, cond: Condition| {
        c.report()
            .unwrap()
            .condition(cond)
            .unwrap()
            .phase_margin_deg
    };
    // D's worst case loses 0.27° per sample of delay at f_c = 7.43 Hz.
    let lost = pm(&at_zero, Condition::D) - pm(&applied, Condition::D);
    assert!((lost - 19.0 * 360.0 * 7.43 / fs).abs() < 0.2, "{lost}");
    // Reconnecting to a device whose link needs a longer lead (3 blocks:
    // 39 samples beyond one) is refused: the clearance was made for 19.
    let emu3 = Emulator::start();
    assert!(h.reconnect(Some(emu3.spec(",lead=3"))));
    wait_event(&mut h, Duration::from_secs_f64(common::WAIT_S), |e| {
        matches!(e, EngineEvent::RigError(_))
    })
    .expect("a longer loop delay on reconnection is refused");
    let msg = h.last_error().unwrap().to_owned();
    assert!(
        msg.contains("3.90 ms") && msg.contains("connect again"),
        "{msg}"
    );
    assert!(
        wait_health(&mut h, |x| !x.running).is_some(),
        "the loop stays stopped"
    );
    h.shutdown();
    drop(emu);

    // A lead of 8 blocks: 90 samples, 9 ms; D's phase margin is far below
    // the rig file's 30°: refused before the loop runs.
    let emu = Emulator::start();
    let err = EngineHandle::spawn_spec(&cfg, &emu.spec(",lead=8"), opts())
        .expect_err("a 9 ms loop delay is refused")
        .to_string();
    assert!(err.contains("ms") && err.contains("89"), "{err}");
}
