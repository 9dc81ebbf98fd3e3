//! `kilotouch rig check` judges what it saw, through the real executable
//! against the emulator's test devices: a device that flags every sample
//! (late commands, fault flags, watchdog samples) fails with each reason,
//! and so does one that streams 7 times faster than the rate it announces.

use kilotouch_testkit as common;

use common::{Emulator, kilotouch};
use serde_json::Value;

/// `rig check --json` against `emu`: exit code, the report, stderr.
fn check(emu: &Emulator, seconds: &str) -> (Option<i32>, Value, String) {
    let o = kilotouch(&common::rig_check_args(&emu.rig(), seconds));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap_or(Value::Null);
    (
        o.status.code(),
        v,
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn a_device_that_flags_every_sample_fails_with_the_reasons() {
    let emu = Emulator::spawn("daq", &["--flag-every-sample"]);
    let (code, v, e) = check(&emu, "1");
    assert_eq!(code, Some(1), "{v} {e}");
    assert_eq!(v["passed"].as_bool(), Some(false), "{v}");
    let received = v["received"].as_u64().expect("received");
    assert!(received > 1000, "{v}");
    assert_eq!(v["late_commands"].as_u64(), Some(received), "{v}");
    assert_eq!(v["flagged"].as_u64(), Some(received), "{v}");
    assert_eq!(v["watchdog_samples"].as_u64(), Some(received), "{v}");
    let why = v["failure"].as_str().expect("a failure");
    for reason in [
        "late commands",
        "(--max-late)",
        "fault flag",
        "(--max-flagged)",
        "watchdog's safe outputs",
    ] {
        assert!(why.contains(reason), "`{reason}` missing: {why}");
        assert!(e.contains(reason), "stderr lacks `{reason}`: {e}");
    }
}

#[test]
fn a_device_streaming_seven_times_its_announced_rate_fails() {
    let emu = Emulator::spawn("daq", &["--speed", "7"]);
    let (code, v, e) = check(&emu, "1");
    assert_eq!(code, Some(1), "{v} {e}");
    assert_eq!(v["nominal_rate_hz"].as_f64(), Some(10_000.0));
    let rate = v["rate_hz"].as_f64().expect("rate");
    assert!(rate > 1.05 * 10_000.0, "{v}");
    let why = v["failure"].as_str().expect("a failure");
    assert!(
        why.contains("off the nominal 10000 Hz the device announced")
            && why.contains("(--rate-tolerance)"),
        "{why}"
    );
}

#[test]
fn an_honest_device_passes_every_limit() {
    let emu = Emulator::spawn("daq", &[]);
    let (code, v, e) = check(&emu, "1");
    assert_eq!(code, Some(0), "{v} {e}");
    assert_eq!(v["passed"].as_bool(), Some(true));
    for k in [
        "late_commands",
        "flagged",
        "watchdog_samples",
        "stray_samples",
    ] {
        assert_eq!(v[k].as_u64(), Some(0), "{k}: {v}");
    }
}
