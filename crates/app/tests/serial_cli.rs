//! The serial rig end to end through the real executable: `kilotouch
//! emulate daq --pty` in one process, `kilotouch rig check` and `kilotouch
//! calibrate --rig serial:PATH` in another (the link's checks, except the
//! 60 s run, which lives in `serial_acceptance.rs`).

use kilotouch_testkit as common;

use common::{Emulator, json_ok, kilotouch as run};
use std::process::Stdio;
use std::time::{Duration, Instant};

/// `kilotouch rig check --rig <the emulator> --duration SECONDS --json`.
fn rig_check(emu: &Emulator, seconds: &str) -> serde_json::Value {
    json_ok(&common::rig_check_args(&emu.rig(), seconds))
}

#[test]
fn rig_check_streams_10_khz_without_loss() {
    let emu = Emulator::spawn("daq", &[]);
    let v = rig_check(&emu, "3");
    assert_eq!(v["lost"].as_u64(), Some(0), "{v}");
    assert_eq!(v["crc_errors"].as_u64(), Some(0), "{v}");
    assert_eq!(v["nominal_rate_hz"].as_f64(), Some(10_000.0));
    let rate = v["rate_hz"].as_f64().unwrap();
    assert!((rate - 10_000.0).abs() < 0.02 * 10_000.0, "rate {rate}");
    let frames = v["frames"].as_u64().unwrap();
    let dur = v["duration_s"].as_f64().unwrap();
    assert!((frames as f64 / dur - rate).abs() < 1e-6 * rate);
    assert!((3.0..3.5).contains(&dur), "{dur}");
}

#[test]
fn calibration_over_the_link_verifies_within_1_db() {
    let emu = Emulator::spawn("daq", &[]);
    let dir = tempfile::tempdir().unwrap();
    let out_path = dir.path().join("cal.toml");
    // A generous host timeout: the calibration's ~16 s must not fail because
    // a shared CI machine descheduled the emulator for 100 ms.
    let rig = format!("{},timeout-ms=1000", emu.rig());
    let v = json_ok(&[
        "calibrate",
        "--rig",
        &rig,
        "--out",
        out_path.to_str().unwrap(),
        "--json",
    ]);
    // Every third-octave band 63 Hz – 1 kHz within ±1 dB, recomputed here.
    let bands = v["bands"].as_array().expect("bands");
    let main: Vec<f64> = bands
        .iter()
        .filter(|b| (63.0..=1001.0).contains(&b["f"].as_f64().unwrap()))
        .map(|b| b["db"].as_f64().unwrap())
        .collect();
    assert_eq!(main.len(), 13);
    let worst = main.iter().map(|d| d.abs()).fold(0.0, f64::max);
    assert!(worst <= 1.0, "worst band {worst} dB");
    assert_eq!(v["passed"].as_bool(), Some(true));
    assert!(v["uncompensated_max_abs_dev_db"].as_f64().unwrap() > 3.0);
    // The same procedure on the simulated rig (same plant) lands on the
    // same design: the link adds only 16-bit output quantisation.
    let sim = json_ok(&["calibrate", "--rig", "sim", "--json"]);
    for k in ["crossover_hz", "low_gain", "max_abs_dev_db"] {
        let (a, b) = (v[k].as_f64().unwrap(), sim[k].as_f64().unwrap());
        assert!((a - b).abs() <= 0.02 * b.abs().max(0.05), "{k}: {a} vs {b}");
    }
    assert_eq!(v["rig"]["serial"].as_str(), Some("emulator-0001"));
    let text = std::fs::read_to_string(&out_path).expect("calibration file");
    assert!(text.contains("emulator-0001"), "{text}");
}

#[test]
fn corrupted_and_dropped_bytes_are_counted_and_survived() {
    let emu = Emulator::spawn(
        "daq",
        &[
            "--corrupt-rate",
            "2e-4",
            "--drop-rate",
            "2e-4",
            "--seed",
            "3",
        ],
    );
    // ≈ 6 % of the frames lost: above the default verdict limit, so the
    // limits are loosened to see the counters of a passing run.
    let v = json_ok(&[
        "rig",
        "check",
        "--rig",
        &emu.rig(),
        "--duration",
        "2",
        "--max-loss",
        "0.25",
        "--max-crc-errors",
        "0.25",
        "--json",
    ]);
    common::assert_corruption_counted(&v);
    let rate = v["rate_hz"].as_f64().unwrap();
    assert!((rate - 10_000.0).abs() < 0.03 * 10_000.0, "rate {rate}");
}

#[test]
fn a_killed_emulator_is_reported_promptly_with_a_clear_error() {
    let mut emu = Emulator::spawn("daq", &[]);
    let check = common::bin()
        .args([
            "rig",
            "check",
            "--rig",
            &emu.rig(),
            "--duration",
            "30",
            "--json",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(700));
    emu.child.kill().unwrap();
    let t = Instant::now();
    let out = check.wait_with_output().unwrap();
    let waited = t.elapsed();
    assert!(!out.status.success());
    assert!(waited < Duration::from_secs(2), "exit took {waited:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("disconnected") && err.contains(&emu.path) && !err.contains("panicked"),
        "{err}"
    );
}

#[test]
fn a_stalled_emulator_is_reported_promptly() {
    let emu = Emulator::spawn("daq", &["--stall-after-s", "0.8"]);
    let t = Instant::now();
    let out = run(&["rig", "check", "--rig", &emu.rig(), "--duration", "30"]);
    assert!(!out.status.success());
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("did not advance") && err.contains("nothing at all"),
        "{err}"
    );
}

#[test]
fn unknown_ports_and_rigs_fail_cleanly() {
    let out = run(&[
        "rig",
        "check",
        "--rig",
        "serial:/dev/does-not-exist",
        "--duration",
        "1",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("/dev/does-not-exist") && !err.contains("panicked"),
        "{err}"
    );
    let out = run(&["rig", "check", "--rig", "audio", "--duration", "1"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("audio"));
    let out = run(&["emulate", "daq", "--pty", "--corrupt-rate", "2"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("corrupt_rate"));
}

#[test]
fn rig_check_on_the_paced_simulation() {
    let v = json_ok(&[
        "rig",
        "check",
        "--rig",
        "sim",
        "--duration",
        "0.5",
        "--json",
    ]);
    assert_eq!(v["lost"].as_u64(), Some(0));
    let rate = v["rate_hz"].as_f64().unwrap();
    assert!((rate - 10_000.0).abs() < 0.05 * 10_000.0, "rate {rate}");
}
