//! The real-time engine without a GUI: commands take effect, the emergency
//! stop zeroes every output within one block and latches, telemetry
//! overflow never blocks, boxes come back to be dropped on the GUI side.
//!
//! Most tests step the engine core on the test thread with a manual clock
//! (deterministic, no sleeping); one runs the engine on its own thread.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::rms;
use kilotouch::engine::{
    BlockCtx, BlockDriver, Command, Condition, EngineCore, EngineEvent, EngineHandle,
    EngineOptions, SafetyState, TelemetrySample, engine_pair, flags, splitter::SwapOutcome,
};
use kilotouch_dsp::chain::{ChainCoefficients, ChainDesign};
use kilotouch_rig::RigConfig;
use kilotouch_rig::coupling::{ChainSource, LoopChain, model_chain_design};
use kilotouch_rig::device::ManualClock;
use kilotouch_rig::error::RigError;
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::tweezer::Obstacle;
use std::time::{Duration, Instant};

fn opts() -> EngineOptions {
    EngineOptions {
        paced: false,
        ramp_s: 0.01,
        telemetry_capacity: 1 << 16,
        ..Default::default()
    }
}

fn pair(o: EngineOptions) -> (EngineCore<ManualClock>, EngineHandle) {
    engine_pair(&RigConfig::default(), o, ManualClock::default()).unwrap()
}

/// Run `blocks` blocks and return the telemetry they produced.
fn run(
    core: &mut EngineCore<ManualClock>,
    h: &mut EngineHandle,
    blocks: usize,
) -> Vec<TelemetrySample> {
    let mut out = Vec::new();
    for _ in 0..blocks {
        assert!(core.run_block());
        h.drain_telemetry(|s| out.push(*s));
    }
    out
}

#[test]
fn conditions_route_the_force_to_the_right_actuators() {
    let (mut core, mut h) = pair(opts());
    // D (the rig file's mode): both channels carry the bead's agitation.
    let t = run(&mut core, &mut h, 300);
    let late = &t[t.len() / 2..];
    assert!(rms(late.iter().map(|s| s.output.force_n[0])) > 1e-4);
    assert!(rms(late.iter().map(|s| s.output.haptuator_v)) > 1e-4);
    // The handle force is force_scale·κ(bead − trap) = −force_scale·(optical force).
    let cfg = RigConfig::default();
    for s in late.iter().take(50) {
        let expect = -cfg.coupling.force_scale * s.bead_force_n[0];
        assert!((s.handle_force_n[0] - expect).abs() <= 1e-12 * expect.abs().max(1e-9));
    }
    // P: after the cross-fade (50 ms = 500 samples) the Haptuator is
    // silent (exactly), the Pantograph still pushes.
    let fade = (kilotouch_rig::coupling::CONDITION_FADE_S * 1e4) as usize;
    assert!(h.set_condition(Condition::P));
    let t = run(&mut core, &mut h, 300);
    assert!(t[fade + 10..].iter().all(|s| s.output.haptuator_v == 0.0));
    assert!(
        t[..fade / 2].iter().any(|s| s.output.haptuator_v != 0.0),
        "fades, no step"
    );
    assert!(rms(t[t.len() / 2..].iter().map(|s| s.output.force_n[0])) > 1e-4);
    // V: after the fade every output is exactly zero.
    assert!(h.set_condition(Condition::V));
    let t = run(&mut core, &mut h, 100);
    assert!(
        t[fade + 10..]
            .iter()
            .all(|s| s.output == Default::default())
    );
    assert_eq!(core.condition(), Condition::V);
}

#[test]
fn hand_commands_move_the_trap_through_the_handle() {
    let cfg = RigConfig::default();
    let (mut core, mut h) = pair(opts());
    // Trap target 4 µm: hand = (trap − offset)/scale + origin.
    let hand = 4e-6 / cfg.coupling.position_scale;
    assert!(h.set_hand([hand, 0.0]));
    // The handle rings on the finger spring (k_f = 500 N/m against ~0.6 kg,
    // ≈ 4.6 Hz, ζ ≈ 0.1): 3 s to settle.
    let t = run(&mut core, &mut h, 3000);
    let last = t.last().unwrap();
    // The trap follows the *measured* handle: trap = offset + s·(handle − origin).
    let expect = cfg.coupling.position_scale * last.handle_m[0];
    assert!(
        (last.trap_m[0] - expect).abs() < 1e-12,
        "{} vs {expect}",
        last.trap_m[0]
    );
    assert!(
        (last.trap_m[0] - 4e-6).abs() < 0.3e-6,
        "trap at {}",
        last.trap_m[0]
    );
    // The hand reached its target smoothly (no step): first-order smoothing.
    assert!((last.hand_m[0] - hand).abs() < 1e-6 * hand);
    assert!(t[0].hand_m[0] < 0.02 * hand, "{}", t[0].hand_m[0]);
    // Non-finite hand requests are ignored.
    h.set_hand([f64::NAN, 0.0]);
    let t = run(&mut core, &mut h, 5);
    assert!(t.iter().all(|s| s.hand_m[0].is_finite()));
}

#[test]
fn obstacles_reset_bead_and_chain_swaps() {
    let (mut core, mut h) = pair(opts());
    // No obstacles: gap is infinite.
    h.set_obstacles(&[]).unwrap();
    let t = run(&mut core, &mut h, 5);
    assert!(t.iter().skip(1).all(|s| s.gap_m.is_infinite()));
    // One obstacle 5 µm from the bead's surface.
    let bead_r = RigConfig::default().tweezer.radius_m;
    h.set_obstacles(&[Obstacle {
        centre_m: [0.0, 10e-6 + bead_r],
        radius_m: 5e-6,
    }])
    .unwrap();
    let t = run(&mut core, &mut h, 5);
    let g = t.last().unwrap().gap_m;
    assert!((g - 5e-6).abs() < 0.3e-6, "gap {g}");
    // The old tweezers came back to be dropped here.
    let ev = h.poll_events();
    assert!(
        ev.iter().all(|e| !matches!(e, EngineEvent::Garbage(_))),
        "garbage is dropped by poll_events"
    );
    // Reset bead puts it on the trap.
    assert!(h.send(Command::ResetBead).is_ok());
    let t = run(&mut core, &mut h, 1);
    let s = t[0];
    assert!(
        ((s.bead_m[0] - s.trap_m[0]).powi(2) + (s.bead_m[1] - s.trap_m[1]).powi(2)).sqrt() < 0.2e-6
    );
    // A (force-normalised) chain with the same structure, cleared by the
    // stability analysis, cross-fades in.
    let cfg = RigConfig::default();
    let c = ChainCoefficients::design(&ChainDesign {
        crossover_hz: 250.0,
        ..model_chain_design(&cfg).unwrap()
    })
    .unwrap();
    let chain = LoopChain {
        coefficients: c.clone(),
        source: ChainSource::Calibration {
            path: "test".into(),
            checksum: "none".into(),
        },
    };
    let clearance = Clearance::check(&cfg, &chain).unwrap();
    h.apply_chain(&chain, &clearance).unwrap();
    assert_eq!(h.chain_source(), &chain.source);
    run(&mut core, &mut h, 20);
    let ev = h.poll_events();
    assert!(
        ev.iter()
            .any(|e| matches!(e, EngineEvent::ChainSwapped(SwapOutcome::Faded))),
        "{ev:?}"
    );
    let (l, _) = core
        .closed_loop()
        .coupling
        .splitter()
        .chain()
        .response(250.0);
    let (lr, _) = c.response(250.0);
    assert!((l - lr).norm() < 1e-12);
}

#[test]
fn emergency_stop_zeroes_every_output_within_one_block_and_latches() {
    let (mut core, mut h) = pair(opts());
    let t = run(&mut core, &mut h, 100);
    assert!(t[t.len() - 10..].iter().any(|s| s.output.force_n[0] != 0.0));
    h.emergency_stop();
    // The very next block: all samples exactly zero and flagged.
    let t = run(&mut core, &mut h, 1);
    assert_eq!(t.len(), 10);
    for s in &t {
        assert_eq!(s.output.force_n, [0.0, 0.0]);
        assert_eq!(s.output.haptuator_v, 0.0);
        assert!(s.has(flags::ESTOP));
    }
    // Latched: condition changes and time do not release it.
    h.set_condition(Condition::D);
    let t = run(&mut core, &mut h, 200);
    assert!(t.iter().all(|s| s.output == Default::default()));
    // A reset confirmed *before* a second stop does not release it.
    let stale_ack = h.estop_count();
    h.emergency_stop();
    assert!(
        h.send(Command::ResetEmergencyStop { ack: stale_ack })
            .is_ok()
    );
    let t = run(&mut core, &mut h, 50);
    assert!(t.iter().all(|s| s.output == Default::default()));
    // A proper reset ramps the outputs back on from zero.
    assert!(h.reset_emergency_stop());
    let t = run(&mut core, &mut h, 100);
    // Ramp from zero: the first sample has gain 1/100 (10 ms ramp at 10 kHz).
    let full = rms(t[200..].iter().map(|s| s.output.force_n[0]));
    assert!(full > 1e-4);
    assert!(
        t[0].output.force_n[0].abs() < 0.05 * full,
        "{:?} vs rms {full}",
        t[0].output
    );
    assert!(t[t.len() - 10..].iter().any(|s| s.output.force_n[0] != 0.0));
    assert!(!t.last().unwrap().has(flags::ESTOP));
}

#[test]
fn telemetry_overflow_drops_and_counts_and_never_blocks() {
    let (mut core, mut h) = pair(EngineOptions {
        telemetry_capacity: 64,
        health_interval_blocks: 10,
        ..opts()
    });
    // Never drain: the engine keeps running, drops and counts.
    for _ in 0..1000 {
        assert!(core.run_block());
    }
    h.poll_events();
    let hh = *h.health().unwrap();
    assert_eq!(hh.blocks, 1000);
    assert_eq!(hh.telemetry_dropped, 10_000 - 64);
    let mut n = 0;
    h.drain_telemetry(|_| n += 1);
    assert_eq!(n, 64);
}

#[test]
fn threaded_engine_with_a_gui_that_never_reads_keeps_running() {
    let mut h = EngineHandle::spawn(
        &RigConfig::default(),
        EngineOptions {
            telemetry_capacity: 128,
            health_interval_blocks: 50,
            ..opts()
        },
    )
    .unwrap();
    let t0 = Instant::now();
    let mut blocks = 0;
    while t0.elapsed() < Duration::from_secs(20) && blocks < 2000 {
        std::thread::sleep(Duration::from_millis(20));
        h.poll_events();
        blocks = h.health().map_or(0, |x| x.blocks);
    }
    let x = *h.health().unwrap();
    assert!(x.blocks >= 2000, "engine stalled at {} blocks", x.blocks);
    assert!(x.telemetry_dropped >= x.blocks * 10 - 128 - 500);
    assert_eq!(x.safety, SafetyState::Enabled);
    h.emergency_stop();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(5) {
        h.poll_events();
        if h.health().is_some_and(|x| x.safety == SafetyState::EStop) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(h.health().unwrap().safety, SafetyState::EStop);
    h.shutdown();
}

#[derive(Debug)]
struct Circle {
    r: f64,
    seen: u64,
}

impl BlockDriver for Circle {
    fn run_block(&mut self, ctx: &mut BlockCtx<'_>) -> Result<usize, RigError> {
        for _ in 0..ctx.n {
            let a = ctx.lp.rig.next_seq() as f64 * 1e-3;
            let hand = [self.r * a.cos(), self.r * a.sin()];
            ctx.lp.rig.set_hand(hand);
            ctx.lp.advance()?;
            ctx.out.publish(ctx.lp.last(), hand);
            self.seen += 1;
        }
        Ok(ctx.n)
    }
}

#[test]
fn a_block_driver_replaces_free_exploration() {
    let (mut core, mut h) = pair(opts());
    assert!(h.set_driver(Box::new(Circle { r: 0.01, seen: 0 })));
    h.set_hand([-0.05, 0.0]); // ignored by the driver
    let t = run(&mut core, &mut h, 400);
    let s = t.last().unwrap();
    let r = (s.hand_m[0].powi(2) + s.hand_m[1].powi(2)).sqrt();
    assert!((r - 0.01).abs() < 1e-3, "hand radius {r}");
    // The free-exploration driver came back as garbage (dropped by poll_events).
    h.poll_events();
    assert!(
        h.send(Command::SetDriver(Box::new(
            kilotouch::engine::FreeExploration::new(1.0)
        )))
        .is_ok()
    );
    run(&mut core, &mut h, 1);
}
