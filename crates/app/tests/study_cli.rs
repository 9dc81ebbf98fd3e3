//! `kilotouch study simulate`: the export it writes, its errors, and a real
//! kill of the process followed by `--resume`; `study run`'s size check.

#![allow(clippy::unwrap_used)]

use common::{bin, kilotouch as run, rows_without_start_time as rows, simulate_study};
use kilotouch_testkit as common;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

use kilotouch_study::export::{TRIALS_FILE, TrialRow, read_trials};
use kilotouch_study::seeds::Phase;
use serde_json::Value;

fn write_protocol(dir: &Path, trials: u32, practice: u32) -> String {
    common::write_circling_protocol(dir, "cli-test", trials, practice, 1)
}

#[test]
fn simulate_writes_the_full_export() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 2, 1);
    let out = tmp.path().join("study");
    let o = simulate_study(
        &proto,
        &out,
        &["--participants", "2", "--seed", "7", "--json"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    // participants × conditions × trials; practice: participants × conditions × 1.
    assert_eq!(j["test_rows"], 2 * 3 * 2);
    assert_eq!(j["practice_rows"], 2 * 3);
    assert_eq!(j["seed"], 7);
    assert_eq!(j["raw"], true);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("18/18 trials"),
        "progress on stderr: {stderr}"
    );
    let rs = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rs.len(), 18);
    assert_eq!(rs.iter().filter(|r| r.phase == Phase::Practice).count(), 6);
    for r in &rs {
        assert!(out.join(&r.raw_file).is_file());
        assert_eq!(r.task.as_str(), "circling");
    }
    for f in [
        "cells_long.csv",
        "cells_wide.csv",
        "session.json",
        "journal.jsonl",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let session: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    assert_eq!(session["seeds"]["study"], 7);
    assert_eq!(session["protocol"]["participants"], 2);
    let header = std::fs::read_to_string(out.join("cells_long.csv")).unwrap();
    assert!(header.starts_with("participant,condition,session_index,n_trials"));
}

#[test]
fn simulate_reports_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let o = simulate_study("nope", &out, &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("not a built-in protocol"), "{e}");
    let o = run(&[
        "study",
        "simulate",
        "--participants",
        "0",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("participants"));
    // An existing study needs --resume, and resuming it with another seed
    // is a protocol mismatch.
    let proto = write_protocol(tmp.path(), 1, 0);
    let args = [
        "study",
        "simulate",
        "--protocol",
        &proto,
        "--no-raw",
        "--out",
        out.to_str().unwrap(),
    ];
    assert!(run(&args).status.success());
    let o = run(&args);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--resume"));
    let mut a = args.to_vec();
    a.extend(["--resume", "--seed", "8"]);
    let o = run(&a);
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("protocol"), "{e}");
}

/// Kill the process mid-way (SIGKILL), resume: the rows equal an
/// uninterrupted run's, nothing lost or duplicated.
#[test]
fn killed_simulation_resumes_to_the_uninterrupted_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 4, 1);
    let full = tmp.path().join("full");
    let base = |out: &Path| {
        vec![
            "study".to_owned(),
            "simulate".into(),
            "--protocol".into(),
            proto.clone(),
            "--threads".into(),
            "1".into(),
            "--out".into(),
            out.to_string_lossy().into_owned(),
        ]
    };
    let o = bin().args(base(&full)).output().unwrap();
    assert!(o.status.success());
    let reference = rows(&full);
    assert_eq!(reference.len(), 15);

    let cut = tmp.path().join("cut");
    let mut child = bin()
        .args(base(&cut))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let mut killed_after = 0;
    loop {
        let n = std::fs::read_to_string(cut.join(TRIALS_FILE))
            .map(|s| s.lines().count().saturating_sub(1))
            .unwrap_or(0);
        if n >= 4 {
            child.kill().unwrap();
            killed_after = n;
            break;
        }
        if child.try_wait().unwrap().is_some() || t0.elapsed() > Duration::from_secs(120) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    child.wait().unwrap();
    assert!(
        killed_after >= 4,
        "the child finished before it could be killed"
    );
    let partial = read_trials(&cut.join(TRIALS_FILE)).unwrap().rows.len();
    assert!(partial < 15, "killed before the end: {partial} rows");
    let mut args = base(&cut);
    args.push("--resume".into());
    args.push("--json".into());
    let o = bin().args(&args).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["already_completed"].as_u64().unwrap() as usize, partial);
    assert_eq!(rows(&cut), reference);
}

/// Bytes of every file under `dir`.
fn folder_bytes(dir: &Path) -> u64 {
    let mut total = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let m = e.metadata().unwrap();
        total += if m.is_dir() {
            folder_bytes(&e.path())
        } else {
            m.len()
        };
    }
    total
}

#[test]
fn simulate_states_its_size_first_and_writes_within_20_percent_of_it() {
    // 4 participants × 3 conditions × (1 practice + 2 test) = 36 trials with
    // raw files (≈ 10 s each, time-out 20 s); the estimate comes from a
    // pilot of 3 of the 12 trials of each condition, before anything is
    // written.
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 2, 1);
    for (raw, dir) in [(true, "raw"), (false, "no-raw")] {
        let out = tmp.path().join(dir);
        let mut flags = vec!["--participants", "4", "--json"];
        if !raw {
            flags.push("--no-raw");
        }
        let o = simulate_study(&proto, &out, &flags);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        // Stated before the run, on stderr (before the progress bar).
        let said = err
            .find("the run will write about")
            .expect("estimate stated");
        assert!(
            said < err.find("36/36 trials").unwrap_or(usize::MAX),
            "{err}"
        );
        let j: Value = serde_json::from_slice(&o.stdout).unwrap();
        let e = &j["estimate"];
        assert_eq!(e["trials"], 36, "{e}");
        let estimate = e["bytes"].as_f64().unwrap();
        let written = folder_bytes(&out) as f64;
        assert!(
            (written / estimate - 1.0).abs() < 0.2,
            "raw {raw}: wrote {written} bytes, estimated {estimate} ({err})"
        );
        if raw {
            assert_eq!(e["basis"]["kind"], "pilot", "{e}");
            assert_eq!(e["basis"]["trials"], 9, "{e}");
            // The upper bound (every trial to its 20 s time-out) is above.
            assert!(e["timeout_bytes"].as_f64().unwrap() > written, "{e}");
        }
    }
}

#[test]
fn simulate_refuses_a_run_larger_than_the_free_space() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 2, 1);
    let out = tmp.path().join("study");
    let o = simulate_study(
        &proto,
        &out,
        &["--participants", "4", "--assume-free-bytes", "2000000"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("not enough disk space")
            && err.contains("2.0 MB free")
            && err.contains("--no-raw")
            && err.contains("--participants"),
        "{err}"
    );
    // Nothing was written.
    assert!(!out.join(TRIALS_FILE).exists());
    // Without raw files the same study fits.
    let o = simulate_study(
        &proto,
        &out,
        &[
            "--participants",
            "4",
            "--no-raw",
            "--assume-free-bytes",
            "2000000",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `study run` (a sitting on the engine) states what it will write and
/// refuses a sitting larger than the free space before anything is
/// written; without raw files the same sitting fits and runs.
#[test]
fn study_run_states_its_size_and_refuses_a_sitting_larger_than_the_free_space() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 1, 0);
    let out = tmp.path().join("study");
    let args = |extra: &[&str]| {
        let mut a = vec![
            "study",
            "run",
            "--protocol",
            proto.as_str(),
            "--participant",
            "P01",
            "--fast",
            "--out",
            out.to_str().unwrap(),
            "--assume-free-bytes",
            "100000",
        ];
        a.extend_from_slice(extra);
        run(&a)
    };
    let o = args(&[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("the sitting will write")
            && err.contains("not enough disk space")
            && err.contains("100 kB free")
            && err.contains("add --no-raw"),
        "{err}"
    );
    assert!(!out.join(TRIALS_FILE).exists());
    let o = args(&["--no-raw"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("the sitting will write about"), "{err}");
    assert_eq!(rows(&out).len(), 3);
}

/// Extra practice trials (`training.practice_retries = 2`): with a 1 s
/// time-out every trial is unsuccessful, so each condition's one practice
/// trial earns both extras. `study simulate` and a `study run` sitting
/// write the same rows in the same order, and both count the extras in
/// what they report.
#[test]
fn unsuccessful_practice_trials_are_run_again_by_simulate_and_by_a_sitting() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = tmp.path().join("retry.toml");
    std::fs::write(
        &proto,
        "name = \"retry\"\nparticipants = 1\nconditions = [\"V\", \"P\", \"D\"]\n\
         trials_per_session = 1\n[training]\npractice_trials = 1\npractice_retries = 2\n\
         [task.circling]\ntimeout_s = 1.0\n[seeds]\nstudy = 3\n",
    )
    .unwrap();
    let proto = proto.to_str().unwrap();
    let sim = tmp.path().join("sim");
    let o = simulate_study(proto, &sim, &["--no-raw", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    // 3 conditions × (1 practice + 2 extra) practice rows, 3 test rows.
    assert_eq!(j["practice_rows"], 9, "{j}");
    assert_eq!(j["test_rows"], 3, "{j}");
    assert_eq!(j["planned"], 12, "{j}");
    assert_eq!(j["ran"], 12, "{j}");
    let sitting = tmp.path().join("sitting");
    let o = run(&[
        "study",
        "run",
        "--protocol",
        proto,
        "--participant",
        "P01",
        "--fast",
        "--no-raw",
        "--out",
        sitting.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["planned"], 12, "{j}");
    let key = |r: &TrialRow| (r.phase, r.condition, r.trial);
    let a = rows(&sim);
    let b = rows(&sitting);
    assert!(
        a.iter()
            .filter(|r| r.phase == Phase::Practice)
            .all(|r| r.reject_reason == "timeout"),
        "the premise: every practice trial times out"
    );
    // Both practise each condition to its end before the next.
    for r in [&a, &b] {
        let practice: Vec<_> = r
            .iter()
            .filter(|r| r.phase == Phase::Practice)
            .map(|r| r.trial)
            .collect();
        assert_eq!(practice, [1, 2, 3, 1, 2, 3, 1, 2, 3]);
    }
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(
            (key(x), x.success, &x.reject_reason, x.seed),
            (key(y), y.success, &y.reject_reason, y.seed)
        );
    }
}
