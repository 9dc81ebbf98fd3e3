//! The engine keeps its rate while the GUI is busy resizing and plotting:
//! the whole app on the Explore page (live traces, histogram,
//! spectrum, microscope scene through the painter) is stepped as fast as the
//! test thread can for `KILOTOUCH_BUSY_GUI_TEST_S` seconds (default 20),
//! resizing the window every frame through six sizes, while the engine runs
//! paced on the simulated rig and an idle reference thread runs the engine's
//! pacer on the same schedule ([`kilotouch::engine::soak::ReferenceThread`]:
//! the machine's own floor of late wake-ups).
//!
//! Asserted: the GUI really was busy (≥ 10 frames per second of layout and
//! plotting), the loop rate stayed at 10 kHz, no telemetry was dropped (the
//! GUI drained every sample), no stall beyond the re-anchor lag, and the
//! engine's deadline misses stay within the reference's floor — zero with
//! `KILOTOUCH_STRICT_RT=1` (docs/PERFORMANCE.md, "Paced engine", explains
//! why zero is not the default on a virtual machine).

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use kilotouch::engine::EngineOptions;
use kilotouch::engine::soak::ReferenceThread;
use kilotouch::gui::Page;
use std::time::Instant;

#[test]
fn the_engine_keeps_its_rate_while_the_gui_resizes_and_plots() {
    let secs: f64 = std::env::var("KILOTOUCH_BUSY_GUI_TEST_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|s: &f64| s.is_finite() && *s >= 2.0)
        .unwrap_or(20.0);
    let strict = std::env::var("KILOTOUCH_STRICT_RT").is_ok_and(|v| v == "1");
    let mut h = common::app_harness(common::fresh_app(Some(Page::Explore)), 1280.0, 860.0, None);
    assert!(
        common::step_until(&mut h, common::WAIT_S, common::engine_reporting),
        "the engine did not start"
    );
    let opts = EngineOptions::default();
    let fs = h.state().rig_config.rig.sample_rate_hz;
    let period_s = opts.block_len as f64 / fs;
    let before = *h.state().engine.as_ref().unwrap().health().unwrap();
    let reference = ReferenceThread::start(period_s, &opts).unwrap();
    let sizes = [
        (1280.0, 860.0),
        (900.0, 700.0),
        (1600.0, 1000.0),
        (700.0, 560.0),
        (1100.0, 900.0),
        (1400.0, 760.0),
    ];
    let t0 = Instant::now();
    let mut frames = 0usize;
    while t0.elapsed().as_secs_f64() < secs {
        let (w, ht) = sizes[frames % sizes.len()];
        h.set_size(egui::vec2(w, ht));
        h.step();
        frames += 1;
    }
    let floor = reference.stop().unwrap();
    // One more health report after the busy period.
    let seen = h.state().engine.as_ref().unwrap().health().unwrap().blocks;
    assert!(common::step_until(&mut h, common::WAIT_S, |a| {
        common::engine_health(a).is_some_and(|x| x.blocks > seen)
    }));
    let after = *h.state().engine.as_ref().unwrap().health().unwrap();
    let misses = after.deadline_misses - before.deadline_misses;
    let fps = frames as f64 / secs;
    eprintln!(
        "busy GUI {secs} s: {frames} frames ({fps:.0}/s); engine: {misses} misses in {} blocks, \
         worst lateness {:.2} ms, overruns {}, rate {:.1} Hz, load {:.2} %, telemetry dropped {}; \
         idle reference: {} misses in {} blocks, worst {:.2} ms",
        after.blocks - before.blocks,
        1e3 * after.worst_lateness_total_s,
        after.overruns,
        after.loop_rate_hz,
        100.0 * after.load,
        after.telemetry_dropped,
        floor.misses,
        floor.blocks,
        1e3 * floor.worst_lateness_s
    );
    assert!(fps >= 10.0, "the GUI was not busy: {fps:.1} frames/s");
    assert!(
        (after.loop_rate_hz - fs).abs() < 0.05 * fs,
        "rate {}",
        after.loop_rate_hz
    );
    let blocks = (after.blocks - before.blocks) as f64;
    assert!(
        (blocks * period_s - secs).abs() < 0.02 * secs + 2.5,
        "{blocks} blocks in about {secs} s"
    );
    assert_eq!(after.telemetry_dropped, 0, "the GUI drained every sample");
    assert_eq!(after.overruns, 0, "no stall beyond the re-anchor lag");
    assert!(
        floor.explains(misses),
        "engine misses {misses} beyond the machine's floor ({} by an idle thread)",
        floor.misses
    );
    if strict {
        assert_eq!(misses, 0, "deadline misses (strict mode)");
    }
}
