//! The engine keeps its rate while the GUI side is busy: 60 s paced by the
//! wall clock on the simulated rig, with the test thread hammering the
//! command queue (hand moves every ~50 µs, condition switches, obstacle
//! swaps, chain swaps) and draining telemetry and events as fast as it can,
//! beside an idle reference thread on the same schedule
//! ([`kilotouch::engine::soak`]; `kilotouch bench --paced 60` runs the same).
//!
//! In its own test binary so that it runs alone (cargo runs test binaries
//! one after another). Duration: `KILOTOUCH_PACED_TEST_S` (default 60):
//! this test adds that much wall time (mostly sleeping) to `cargo test`.
//!
//! Asserted:
//! * every sample of the run is simulated at the rig rate (loop rate 10 kHz,
//!   simulated time = wall time within 0.5 %), the engine never fell more
//!   than the re-anchor lag (100 ms) behind — **0 overruns**: no sample was
//!   ever skipped —, and the hammering never made it drop telemetry;
//! * **deadline misses** (a 1 ms block ending more than the tolerated
//!   latency, 2 ms, after its deadline): no more than the machine's floor,
//!   i.e. than an idle thread running the same pacer misses at the same
//!   time (within the scatter of [`kilotouch::engine::soak::FLOOR_FACTOR`]:
//!   3 × its count plus 1 ‰ of the blocks).
//!   Zero is the result on a machine that runs a ready thread within 3 ms;
//!   the 2-vCPU virtual machine this project is developed on does not (an
//!   idle thread sleeping to 1 ms deadlines there wakes more than 3 ms late
//!   ≈ 40 times a minute, up to 35 ms, and a thread that never sleeps sees
//!   gaps up to 27 ms: docs/PERFORMANCE.md). With `KILOTOUCH_STRICT_RT=1`
//!   the test requires 0 misses (for a quiet, non-virtualised machine or a
//!   real-time kernel).

#![allow(clippy::unwrap_used)]

use kilotouch::engine::EngineOptions;
use kilotouch::engine::soak::{SoakVerdict, run_soak};
use kilotouch_rig::RigConfig;

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
    let x = run_soak(&cfg, EngineOptions::default(), secs, &mut |_| {}).unwrap();
    eprintln!("{}", x.describe());
    assert!(
        x.commands as f64 > secs * 1000.0,
        "the hammer thread ran ({} commands)",
        x.commands
    );
    assert_eq!(x.telemetry_dropped, 0, "the draining GUI thread kept up");
    let ratio = x.real_time_ratio(fs);
    assert!(
        (ratio - 1.0).abs() < 0.005 + 0.3 / secs,
        "simulated / wall time {ratio}"
    );
    assert!(
        (x.samples_received as f64) >= 0.99 * x.samples_simulated as f64,
        "the GUI saw every sample ({} of {})",
        x.samples_received,
        x.samples_simulated
    );
    assert!(
        (x.loop_rate_hz - fs).abs() < 0.05 * fs,
        "rate {}",
        x.loop_rate_hz
    );
    assert_eq!(x.overruns, 0, "no stall beyond the re-anchor lag");
    assert!(
        x.reference_blocks as f64 > 0.9 * secs / x.period_s,
        "the reference thread ran ({} blocks)",
        x.reference_blocks
    );
    assert_ne!(
        x.verdict(),
        SoakVerdict::EngineLate,
        "engine misses beyond the machine's floor"
    );
    if strict {
        assert_eq!(x.deadline_misses, 0, "deadline misses (strict mode)");
    }
}
