//! The engine keeps its rate while the GUI side is busy: 60 s paced by the
//! wall clock on the simulated rig, with another thread hammering the
//! command queue (hand moves every ~50 µs, condition switches, obstacle
//! swaps, chain swaps) and draining telemetry and events as fast as it can.
//!
//! In its own test binary so that it runs alone (cargo runs test binaries
//! one after another). Duration: `KILOTOUCH_PACED_TEST_S` (default 60).
//!
//! What is asserted, and why this is the honest variant:
//! * the loop rate over the run is the rig rate (every sample of the 60 s
//!   is simulated: total samples within 0.5 % of 60 s × 10 kHz), and the
//!   engine was never stalled beyond the re-anchor lag (0 overruns);
//! * **zero deadline misses**, a miss being a 1 ms block that ends more
//!   than the tolerated latency after its deadline. The tolerance used is
//!   the engine default, 2 ms (a live rig's output buffer of two blocks).
//!   The engine's computation takes ~1 % of each block; what can make it
//!   miss is the OS not waking the thread in time. On a 2-core CI box that
//!   is also compiling, wake-ups later than 2 ms do happen under a normal
//!   (non-real-time) scheduling policy; the test therefore reports the
//!   worst lateness and the misses it saw, and fails on misses only when
//!   `KILOTOUCH_STRICT_RT=1` (set it on a quiet machine or with RT
//!   scheduling). Without it the test still fails if more than 0.1 % of the
//!   blocks missed, which no scheduling hiccup explains — only an engine
//!   that blocks on the GUI or allocates/locks in its loop would.

use kilotouch::engine::{Condition, EngineHandle, EngineOptions};
use kilotouch_dsp::chain::{ChainCoefficients, ChainDesign};
use kilotouch_rig::RigConfig;
use kilotouch_rig::tweezer::Obstacle;
use std::time::{Duration, Instant};

#[test]
fn sixty_seconds_paced_with_a_hammering_gui_thread() {
    let secs: f64 = std::env::var("KILOTOUCH_PACED_TEST_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|s: &f64| s.is_finite() && *s > 0.5)
        .unwrap_or(60.0);
    let strict = std::env::var("KILOTOUCH_STRICT_RT").is_ok_and(|v| v == "1");
    let cfg = RigConfig::default();
    let fs = cfg.rig.sample_rate_hz;
    let h = EngineHandle::spawn(&cfg, EngineOptions::default()).unwrap();
    let hammer = std::thread::spawn(move || {
        let mut h = h;
        let t0 = Instant::now();
        let (mut cmds, mut rejected, mut samples, mut k) = (0u64, 0u64, 0u64, 0u64);
        let conds = [Condition::Pantograph, Condition::Dual, Condition::Vision];
        let chain = ChainCoefficients::design(&ChainDesign::paper()).unwrap();
        while t0.elapsed().as_secs_f64() < secs {
            let t = t0.elapsed().as_secs_f64();
            let hand = [0.01 * (3.0 * t).sin(), 0.01 * (2.0 * t).cos()];
            if h.set_hand(hand) {
                cmds += 1;
            } else {
                rejected += 1;
            }
            k += 1;
            if k.is_multiple_of(5000) {
                h.set_condition(conds[(k / 5000) as usize % 3]);
            }
            if k.is_multiple_of(20_000) {
                let _ = h.set_obstacles(&[Obstacle {
                    centre_m: [12e-6, (k % 7) as f64 * 1e-6],
                    radius_m: 5e-6,
                }]);
                let _ = h.apply_chain(chain.clone());
            }
            samples += h.drain_telemetry(|_| {}) as u64;
            h.poll_events();
            std::thread::sleep(Duration::from_micros(50));
        }
        // Let the last health report arrive.
        std::thread::sleep(Duration::from_millis(250));
        samples += h.drain_telemetry(|_| {}) as u64;
        h.poll_events();
        let health = *h.health().expect("health");
        h.shutdown();
        (health, cmds, rejected, samples)
    });
    let (x, cmds, rejected, samples) = hammer.join().unwrap();
    let expected = secs * fs;
    eprintln!(
        "paced {secs} s: {} blocks, {samples} samples (expected ≈ {expected}), misses {}, overruns {}, \
         worst lateness {:.3} ms, last-window load {:.3} %, rate {:.1} Hz, commands {cmds} (+{rejected} rejected), \
         telemetry dropped {}",
        x.blocks,
        x.deadline_misses,
        x.overruns,
        1e3 * x.worst_lateness_total_s,
        100.0 * x.load,
        x.loop_rate_hz,
        x.telemetry_dropped
    );
    assert!(
        cmds as f64 > secs * 1000.0,
        "the hammer thread ran ({cmds} commands)"
    );
    assert_eq!(x.telemetry_dropped, 0, "the draining GUI thread kept up");
    let sim = (x.seq as f64) / fs;
    assert!(
        (sim - secs).abs() < 0.005 * secs + 0.3,
        "simulated {sim} s in {secs} s of wall time"
    );
    assert!(
        (x.loop_rate_hz - fs).abs() < 0.05 * fs,
        "rate {}",
        x.loop_rate_hz
    );
    assert_eq!(x.overruns, 0, "no stall beyond the re-anchor lag");
    if strict {
        assert_eq!(x.deadline_misses, 0);
    } else {
        assert!(
            (x.deadline_misses as f64) < 1e-3 * x.blocks as f64,
            "{} of {} blocks missed",
            x.deadline_misses,
            x.blocks
        );
    }
}
