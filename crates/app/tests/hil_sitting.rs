//! Hardware in the loop on one machine: a participant's sitting on the DAQ
//! emulator (`kilotouch emulate daq --pty --participant operator:SEED`,
//! the study's simulated participant at the emulated handle) through the
//! real-time engine, as a lab runs it on its rig — `kilotouch study run
//! --rig serial:PTY`. The folder, journal, raw files and `session.json` are
//! those of every study; a device killed mid-trial ends the sitting with
//! the device's name and `--resume` on a new device continues at the
//! aborted trial; a link too slow for the loop's margins is refused with
//! the numbers.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use std::path::Path;
use std::time::{Duration, Instant};

use common::{Emulator, rows_so_far as rows};
use kilotouch::engine::{EngineHandle, EngineOptions};
use kilotouch::session::FinishReason;
use kilotouch_rig::RigConfig;
use kilotouch_study::protocol::Protocol;
use serde_json::Value;

/// 2 participants × 3 conditions × 1 test trial, 1 practice trial per
/// condition, 2 s time-outs: P01's sitting is 6 trials.
const TINY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tiny.toml");

fn tiny() -> Protocol {
    Protocol::load(Path::new(TINY)).unwrap()
}

/// The emulated DAQ with the simulated participants of the protocol's
/// study seed at its handle.
fn device(extra: &[&str]) -> Emulator {
    let p = format!("operator:{}", tiny().seeds.study);
    let mut args = vec!["--participant", p.as_str()];
    args.extend_from_slice(extra);
    Emulator::spawn("daq", &args)
}

/// The `--rig` of `dev` with a command lead of one block: 20 samples of
/// loop delay (2 ms), inside D's margins. The automatic lead sizes itself
/// from round trips measured at connection, which a loaded test machine
/// can stretch past what a USB link has; a fixed lead keeps the loop delay
/// (and so the clearance) the same on every run.
fn rig_of(dev: &Emulator) -> String {
    format!("{},lead=1{}", dev.rig(), common::TEST_HOST_TIMEOUT)
}

fn study_run(rig: &str, out: &Path, resume: bool) -> std::process::Output {
    common::study_run_p01(TINY, rig, out, resume, &[])
}

#[test]
fn a_whole_participant_on_emulated_hardware() {
    let dev = device(&[]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let run = study_run(&rig_of(&dev), &out, false);
    assert!(
        run.status.success(),
        "study run failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(report["finish"], "participant_done", "{report}");
    assert_eq!(report["committed"], 6, "{report}");
    assert!(
        report["device"]["spec"]
            .as_str()
            .is_some_and(|s| s.contains(&dev.path)),
        "{report}"
    );
    // Training (3 practice trials) then the 3 sessions, every row of P01.
    let got = rows(&out);
    assert_eq!(got.len(), 6);
    assert!(got.iter().all(|r| r.participant == "P01"));
    assert_eq!(
        got.iter()
            .filter(|r| r.phase == kilotouch_study::seeds::Phase::Practice)
            .count(),
        3
    );
    for r in &got {
        assert!(r.time_s.is_some_and(|t| t > 0.0 && t <= 2.1), "{r:?}");
        assert!(
            !r.raw_file.is_empty() && out.join(&r.raw_file).is_file(),
            "{}",
            r.raw_file
        );
    }
    // session.json names the device and its measured loop delay.
    let session: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    let d = &session["sittings"][0]["device"];
    assert!(
        d["spec"].as_str().is_some_and(|s| s.contains(&dev.path)),
        "{session}"
    );
    assert_eq!(d["kind"], "SerialDaq");
    let delay = d["loop_delay_ms"].as_f64().unwrap();
    let samples = d["loop_delay_samples"].as_u64().unwrap();
    assert!((delay - samples as f64 * 0.1).abs() < 1e-9, "{d}");
    // Block (10) + one block of command lead.
    assert_eq!(samples, 20, "{d}");
    assert!(d["round_trip_ms"].as_f64().unwrap() > 0.0, "{d}");
    // The sitting's timing verdict: its samples, blocks and the rule.
    let tm = &session["sittings"][0]["timing"];
    let samples = tm["samples"].as_u64().unwrap();
    assert!(
        samples > 6 * 1000 && tm["blocks"].as_u64().unwrap() > samples / 10,
        "{tm}"
    );
    let lf = tm["late_fraction"].as_f64().unwrap();
    let max = tm["max_late_fraction"].as_f64().unwrap();
    assert_eq!(max, 1e-3, "the rig file's sitting_max_late_fraction");
    let late = (tm["deadline_misses"].as_u64().unwrap() * 10
        + tm["late_commands"].as_u64().unwrap()) as f64
        / samples as f64;
    assert!((lf - late.min(1.0)).abs() < 1e-12, "{tm}");
    assert_eq!(
        tm["verdict"],
        if lf > max { "late" } else { "on_time" },
        "{tm}"
    );
    assert_eq!(
        report["timing"], *tm,
        "the report gives session.json's verdict"
    );
    // The journal: the sitting's opening with the device, six completed
    // trials, a clean end.
    let journal = std::fs::read_to_string(out.join("journal.jsonl")).unwrap();
    assert!(journal.contains(&dev.path), "{journal}");
    assert_eq!(journal.matches("\"trial_completed\"").count(), 6);
    assert!(journal.contains("session_done"));
}

#[test]
fn a_killed_device_ends_the_sitting_and_resume_continues_at_the_aborted_trial() {
    let mut dev = device(&[]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let rig = RigConfig::default();
    let mut engine = EngineHandle::spawn_spec(
        &rig,
        &dev.spec(&format!(",lead=1{}", common::TEST_HOST_TIMEOUT)),
        EngineOptions::default(),
    )
    .unwrap();
    let mut s = common::start_p01_at_the_handle(tiny(), &out, rig, &mut engine);
    // Wait for the second trial to be under way (one row committed).
    let mut committed = common::until_trials_started(&mut engine, &mut s, 2);
    std::thread::sleep(Duration::from_millis(300));
    // The cable is pulled: the device vanishes mid-trial.
    dev.kill();
    let killed = Instant::now();
    let (reason, ended_s) = common::until_finished(&mut engine, &mut s, &mut committed, killed);
    let FinishReason::Failed(why) = reason else {
        panic!("{reason:?}")
    };
    assert!(
        why.contains(&dev.path),
        "the reason names the device: {why}"
    );
    assert!(
        ended_s < 5.0,
        "the sitting ended {ended_s:.2} s after the kill"
    );
    // Outputs held at zero: the engine's loop stopped with the safety
    // layer tripped.
    let _ = s.close(&mut engine);
    common::until_engine_stopped(&mut engine, common::WAIT_S);
    assert!(
        engine
            .health()
            .is_some_and(|h| !h.running && h.safety.latched())
    );
    engine.shutdown();
    // Nothing committed is lost; the trial in progress has no row.
    let on_disk = rows(&out);
    assert_eq!(on_disk, committed);
    assert!(!committed.is_empty() && committed.len() < 6);
    // A new device (a new pty): --resume continues at the aborted trial.
    let dev2 = device(&[]);
    let run = study_run(&rig_of(&dev2), &out, true);
    common::assert_resumed(&run, &out, &committed, 6);
    eprintln!("the sitting ended {ended_s:.3} s after the device was killed");
}

#[test]
fn a_link_too_slow_for_the_margins_is_refused_with_the_numbers() {
    // 1 ms each way: a round trip of at least 2 ms, an automatic lead of at
    // least 4 blocks, a loop delay of at least 5 ms: D's phase margin is
    // below the rig file's 30° (docs/theory/coupling-and-stability.md, loop
    // delay: 24° at 5 ms). A round trip stretched by a loaded machine only
    // lengthens the delay, and a longer delay may break another margin
    // first (at 9.9 ms: P's phase margin and D's gain margin), so the test
    // asks for any failing margin of P or D, named.
    let dev = device(&["--link-delay-ms", "1"]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let run = study_run(&dev.rig(), &out, false);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    let margin_named = [
        "P has a phase margin of",
        "P has a gain margin of",
        "D has a phase margin of",
        "D has a gain margin of",
        "P is unstable (phase margin",
        "D is unstable (phase margin",
    ]
    .iter()
    .any(|m| err.contains(m));
    assert!(margin_named, "{err}");
    assert!(
        err.contains("extra loop delay of") && err.contains(" ms ("),
        "names the delay: {err}"
    );
    assert!(
        err.contains("largest safe force scale at that delay"),
        "names the largest safe force scale: {err}"
    );
    // Nothing was written.
    assert!(rows(&out).is_empty());
}
