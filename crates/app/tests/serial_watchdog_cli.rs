//! The host's watchdog on stream progress, through the real executable: a
//! fake device (`kilotouch emulate daq --misbehave MODE`) that keeps
//! sending valid frames which never advance the sample stream must end
//! `rig check --duration 1` within a few seconds with an error saying what
//! the device sent instead, the counters printed; and the `rig check`
//! verdict on loss and CRC errors.
#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{Emulator, kilotouch as run};
use std::time::{Duration, Instant};

/// Each misbehaving mode: `rig check --duration 1 --json` ends within 3 s,
/// exit code 1, the JSON report (counters, `passed: false`) on stdout and
/// an error naming what the device did on stderr.
#[test]
fn each_misbehaving_device_ends_rig_check_promptly_with_a_clear_error() {
    for (mode, said) in [
        ("status-only", "STATUS frame(s) only"),
        ("unknown-frames", "frame(s) of unknown type"),
        ("stray-seq", "sample(s) with stray sequence numbers"),
    ] {
        let emu = Emulator::spawn("daq", &["--misbehave", mode]);
        let t = Instant::now();
        let o = run(&common::rig_check_args(&emu.rig(), "1"));
        let took = t.elapsed();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{mode}: {err}");
        assert!(took < Duration::from_secs(3), "{mode}: took {took:?}");
        assert!(
            err.contains("did not advance") && err.contains(said),
            "{mode}: {err}"
        );
        assert!(err.contains("outputs commanded to zero"), "{mode}: {err}");
        assert!(!err.contains("panicked"), "{mode}: {err}");
        let v: serde_json::Value =
            serde_json::from_slice(&o.stdout).expect("the report is printed");
        assert_eq!(v["passed"].as_bool(), Some(false), "{mode}: {v}");
        assert_eq!(v["received"].as_u64(), Some(0), "{mode}: {v}");
        assert!(v["failure"].as_str().unwrap().contains(said), "{mode}: {v}");
        eprintln!(
            "{mode}: ended after {took:?}: {}",
            err.lines().next().unwrap_or("")
        );
    }
}

/// Heavy corruption: the check runs to the end, prints its counters and
/// fails on the loss limit; the same run passes with a looser limit.
#[test]
fn rig_check_fails_above_the_loss_limit_and_always_prints_counters() {
    let emu = Emulator::spawn("daq", &["--corrupt-rate", "1e-2", "--seed", "5"]);
    let o = run(&common::rig_check_args(&emu.rig(), "1"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("counters printed");
    let (frames, lost) = (v["frames"].as_u64().unwrap(), v["lost"].as_u64().unwrap());
    assert!(frames > 5_000 && lost > frames / 2, "{v}");
    assert_eq!(v["passed"].as_bool(), Some(false));
    assert!(
        err.contains("of the frames lost") && err.contains("--max-loss"),
        "{err}"
    );
    // Human output: the counters and the verdict line.
    // At 1 % byte corruption the handshake itself can be hit (then the
    // check ends before streaming, with that error): up to three attempts.
    let mut last = String::new();
    let mut shown = false;
    for _ in 0..3 {
        let o = run(&["rig", "check", "--rig", &emu.rig(), "--duration", "0.5"]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert_eq!(o.status.code(), Some(1));
        if out.contains("verdict   FAIL") && out.contains("lost") {
            shown = true;
            break;
        }
        last = format!("{out}\n{}", String::from_utf8_lossy(&o.stderr));
    }
    assert!(shown, "{last}");
}

/// A clean link passes the verdict.
#[test]
fn a_clean_link_passes_the_verdict() {
    let emu = Emulator::spawn("daq", &[]);
    let o = run(&["rig", "check", "--rig", &emu.rig(), "--duration", "0.5"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("verdict   PASS"), "{out}");
}
