//! Lab Streaming Layer outlets (the `lsl` feature): a consumer that never
//! reads does not block the engine, and receives data.

#![allow(clippy::unwrap_used)]

use kilotouch::engine::{EngineOptions, engine_pair};
use kilotouch::lsl::{LslIdentity, SIGNAL_STREAM, sys};
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::ManualClock;
use std::time::{Duration, Instant};

#[test]
fn a_consumer_that_never_reads_does_not_block_the_engine() {
    let opts = EngineOptions {
        paced: false,
        ..Default::default()
    };
    let (mut core, h) = engine_pair(&RigConfig::default(), opts, ManualClock::default()).unwrap();
    let id = LslIdentity {
        study: "lsl-test".into(),
        participant: "P01".into(),
        id_width: 2,
    };
    let publisher = h.start_lsl(1000.0, id).unwrap();
    // A consumer that connects and then never pulls a sample.
    let found = sys::resolve_byprop("name", SIGNAL_STREAM, 1, 10.0).unwrap();
    assert!(!found.is_empty(), "the signal stream was not resolved");
    let inlet = sys::StreamInlet::new(&found[0], 1, 0, true).unwrap();
    inlet.open_stream(10.0).unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    while !publisher.consumers().1 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(publisher.consumers().1, "the inlet never connected");
    // 20 s of engine time (10 kHz, 10-sample blocks), unpaced: far faster
    // than a real-time consumer, which here never reads. The engine's only
    // contact with LSL is a clock read and a push into a bounded ring that
    // drops when full, so every block runs; a waiting push would hang here.
    // No wall-clock bound: that is `bench --paced --lsl`'s job, and a
    // timed assertion fails on a busy machine.
    for _ in 0..20_000 {
        assert!(core.run_block());
    }
    // The stalled consumer did receive data: it is attached, not idle
    // because nothing was sent.
    let deadline = Instant::now() + Duration::from_secs(10);
    while inlet.samples_available() == 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(
        inlet.samples_available() > 0,
        "no sample reached the consumer"
    );
    drop(inlet);
    publisher.stop();
}
