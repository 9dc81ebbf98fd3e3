//! The engine with a live tweezer: the tweezer emulator (`kilotouch emulate
//! tweezer --pty`) behind a real pty, as an instrument would be behind a
//! USB serial port, on the simulated rig and beside the DAQ emulator.
//!
//! * the loop runs the link's bead: it is trapped and jiggles with the
//!   equipartition spread √(k_BT/κ) of the emulated trap (paper §4.1,
//!   eq. 5), and the optical force the loop renders is κ(trap − bead);
//! * the engine reports the tweezer, its command lead and the loop delay
//!   both links add, and the stability clearance includes it;
//! * a killed tweezer emulator ends the loop as a *link* failure naming
//!   the tweezer within 5 s (never as an escape), outputs at zero;
//! * a trap calibration applied to the live loop changes the optical force
//!   it computes by the ratio of the stiffnesses.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::Emulator;
use kilotouch::engine::{EngineEvent, EngineHandle, EngineOptions, TelemetrySample, flags};
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::{RigSpec, TweezerSpec};
use kilotouch_rig::tweezer::{AppliedTrap, BOLTZMANN};
use std::time::{Duration, Instant};

fn tweezer_spec(emu: &Emulator, opts: &str) -> TweezerSpec {
    format!("serial:{}{opts}", emu.path).parse().unwrap()
}

/// Collect at least `n` telemetry samples (≤ `timeout`), keeping the
/// events.
fn samples(
    h: &mut EngineHandle,
    n: usize,
    timeout: Duration,
) -> (Vec<TelemetrySample>, Vec<EngineEvent>) {
    let t0 = Instant::now();
    let (mut t, mut ev) = (Vec::new(), Vec::new());
    while t.len() < n && t0.elapsed() < timeout {
        std::thread::sleep(Duration::from_millis(5));
        h.drain_telemetry(|s| t.push(*s));
        ev.extend(h.poll_events());
    }
    (t, ev)
}

fn sd(x: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = x.clone().count() as f64;
    let m = x.clone().sum::<f64>() / n;
    (x.map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}

#[test]
fn explore_runs_the_live_bead_and_reports_the_tweezer_and_its_delay() {
    let cfg = RigConfig::default();
    let emu = Emulator::spawn("tweezer", &[]);
    let opts = EngineOptions::default();
    let mut h =
        EngineHandle::spawn_devices(&cfg, &RigSpec::Sim, &tweezer_spec(&emu, ",lead=1"), opts)
            .unwrap();
    let t = h.live_tweezer().cloned().expect("a live tweezer");
    assert!(t.name.contains("tweezer"), "{t:?}");
    // The simulated rig exchanging blocks with a live tweezer: the block,
    // plus the tweezer link's one-block lead.
    assert_eq!(t.lead_samples as usize, opts.block_len, "{t:?}");
    assert_eq!(h.loop_delay_samples() as usize, 2 * opts.block_len);
    let fs = h.sample_rate_hz();
    assert!((h.latency_s() - (2 * opts.block_len - 1) as f64 / fs).abs() < 1e-12);
    // 1 s of the live bead (skip the first 0.1 s: the lead's held trap).
    let (tel, ev) = samples(&mut h, 11_000, Duration::from_secs(60));
    assert!(
        !ev.iter().any(|e| matches!(e, EngineEvent::RigError(_))),
        "{ev:?}"
    );
    assert!(tel.len() >= 11_000, "only {} samples", tel.len());
    let tel = &tel[1000..];
    assert!(tel.iter().all(|s| s.has(flags::TRAPPED)));
    // Equipartition: SD of the bead about the (still) trap is √(k_BT/κ).
    let p = &cfg.tweezer;
    let want = (BOLTZMANN * p.temperature_k / p.stiffness_n_per_m).sqrt();
    let got = sd(tel.iter().map(|s| s.bead_m[0] - s.trap_m[0]));
    assert!(
        (0.7..1.3).contains(&(got / want)),
        "bead SD {got:e} m against √(k_BT/κ) = {want:e} m"
    );
    // The loop's optical force is κ (trap − bead), sample by sample.
    for s in tel.iter().step_by(97) {
        let f = p.stiffness_n_per_m * (s.trap_m[0] - s.bead_m[0]);
        assert!(
            (s.bead_force_n[0] - f).abs() <= 1e-9 * f.abs().max(1e-15),
            "{s:?}"
        );
    }
}

#[test]
fn a_killed_tweezer_ends_the_loop_as_a_link_failure_naming_the_tweezer() {
    let cfg = RigConfig::default();
    let mut emu = Emulator::spawn("tweezer", &[]);
    let mut h = EngineHandle::spawn_devices(
        &cfg,
        &RigSpec::Sim,
        &tweezer_spec(&emu, ",lead=1,timeout-ms=500"),
        EngineOptions::default(),
    )
    .unwrap();
    let (tel, _) = samples(&mut h, 2000, Duration::from_secs(30));
    assert!(tel.len() >= 2000);
    emu.kill();
    let t0 = Instant::now();
    let mut seen = None;
    let mut escaped = false;
    while t0.elapsed() < Duration::from_secs(10) && seen.is_none() {
        h.drain_telemetry(|s| escaped |= s.has(flags::ESCAPED));
        for e in h.poll_events() {
            if let EngineEvent::RigError(e) = e {
                seen = Some((e.to_string(), t0.elapsed()));
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let (msg, after) = seen.expect("the engine reports the lost tweezer");
    assert!(msg.contains("tweezer"), "{msg}");
    assert!(after < Duration::from_secs(5), "reported after {after:?}");
    assert!(!escaped, "a link failure must not be shown as an escape");
    // Outputs at zero: nothing more is sent while the loop is stopped.
    let mut late = Vec::new();
    h.drain_telemetry(|s| late.push(*s));
    assert!(
        late.iter().all(|s| s.output.force_n == [0.0; 2]),
        "{late:?}"
    );
}

#[test]
fn an_applied_trap_calibration_sets_the_stiffness_of_the_live_force() {
    let cfg = RigConfig::default();
    let emu = Emulator::spawn("tweezer", &[]);
    let mut h = EngineHandle::spawn_devices(
        &cfg,
        &RigSpec::Sim,
        &tweezer_spec(&emu, ",lead=1"),
        EngineOptions::default(),
    )
    .unwrap();
    let (before, _) = samples(&mut h, 5000, Duration::from_secs(30));
    let kappa = cfg.tweezer.stiffness_n_per_m;
    let ratio = |tel: &[TelemetrySample], k: f64| {
        tel.iter()
            .filter(|s| (s.trap_m[0] - s.bead_m[0]).abs() > 1e-9)
            .map(|s| s.bead_force_n[0] / (k * (s.trap_m[0] - s.bead_m[0])))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
                (lo.min(r), hi.max(r))
            })
    };
    let (lo, hi) = ratio(&before[1000..], kappa);
    assert!(
        (lo - 1.0).abs() < 1e-9 && (hi - 1.0).abs() < 1e-9,
        "{lo} {hi}"
    );
    // A calibration with twice the stiffness and the emulator's own
    // detector sensitivity: the force is κ_cal (trap − bead) from now on.
    let rd = [1.0 / cfg.tweezer.detector.sensitivity_v_per_m; 2];
    let cal = AppliedTrap {
        stiffness_n_per_m: 2.0 * kappa,
        rd_m_per_v: rd,
    };
    h.apply_trap_calibration(Some(cal)).unwrap();
    // Skip what was in flight when it was applied.
    let _ = samples(&mut h, 2000, Duration::from_secs(30));
    let (after, _) = samples(&mut h, 3000, Duration::from_secs(30));
    let (lo, hi) = ratio(&after, 2.0 * kappa);
    assert!(
        (lo - 1.0).abs() < 1e-9 && (hi - 1.0).abs() < 1e-9,
        "{lo} {hi}"
    );
    // The bead now comes from the detector volts (R_d·V, its filter and
    // noise), so the force's spread is about twice the uncalibrated one.
    let spread = |tel: &[TelemetrySample]| sd(tel.iter().map(|s| s.bead_force_n[0]));
    let r = spread(&after) / spread(&before[1000..]);
    assert!((1.6..2.6).contains(&r), "force spread ratio {r}");
    // And an invalid one is refused before it reaches the loop.
    let bad = AppliedTrap {
        stiffness_n_per_m: f64::NAN,
        rd_m_per_v: rd,
    };
    assert!(h.apply_trap_calibration(Some(bad)).is_err());
}
