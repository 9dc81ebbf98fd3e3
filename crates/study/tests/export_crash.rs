//! A real crash: a child process (this test binary re-invoked with an
//! environment variable) runs the study and is killed with SIGKILL while it
//! writes; the study is then resumed (several times) and must end with
//! exactly the files of an uninterrupted run.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{protocol, run_pending};
use kilotouch_study::export::{StudyStore, TRIALS_FILE};
use kilotouch_study::journal::{JOURNAL_FILE, Record, read_journal};

const CHILD_ENV: &str = "KILOTOUCH_CRASH_CHILD_DIR";
const SEED: u64 = 77;
/// 3 participants × 3 conditions × (1 practice + 4 test) = 45 trials.
const SHAPE: (u32, u32, u32) = (3, 4, 1);

fn open(dir: &Path) -> StudyStore {
    let (p, t, pr) = SHAPE;
    StudyStore::open(dir, &protocol(p, t, pr, SEED), &common::meta()).expect("test setup")
}

/// The child's work: resume the study in the folder and run it slowly
/// (sleeps between raw chunks), until killed or done. Not a test unless
/// re-invoked by `killed_sessions_resume_to_the_uninterrupted_result`.
#[test]
fn crash_child() {
    let Ok(dir) = std::env::var(CHILD_ENV) else {
        return;
    };
    let mut store = open(Path::new(&dir));
    run_pending(&mut store, 300);
    store.close().unwrap();
}

fn completed_rows(dir: &Path) -> usize {
    std::fs::read(dir.join(TRIALS_FILE))
        .map(|b| b.iter().filter(|&&c| c == b'\n').count().saturating_sub(1))
        .unwrap_or(0)
}

/// Starts the child on `dir` and SIGKILLs it once `rows` rows exist (plus a
/// little time, so the kill lands at an arbitrary point of a trial).
fn run_and_kill(dir: &Path, rows: usize, extra: Duration) {
    let exe = std::env::current_exe().expect("test setup");
    let mut child = Command::new(exe)
        // The test's path in the one test binary: `module::name`.
        .args([
            "--exact",
            concat!(module_path!(), "::crash_child")
                .split_once("::")
                .map_or("crash_child", |(_, path)| path),
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("test setup");
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Some(status) = child.try_wait().expect("test setup") {
            panic!("child ended before it was killed: {status}");
        }
        if completed_rows(dir) >= rows {
            std::thread::sleep(extra);
            // Child::kill sends SIGKILL on Unix: no destructor, no flush.
            child.kill().expect("test setup");
            let status = child.wait().expect("test setup");
            #[cfg(unix)]
            {
                use std::os::unix::process::ExitStatusExt;
                assert_eq!(status.signal(), Some(9), "{status}");
            }
            #[cfg(not(unix))]
            assert!(!status.success());
            return;
        }
        assert!(Instant::now() < deadline, "child too slow");
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn killed_sessions_resume_to_the_uninterrupted_result() {
    let tmp = tempfile::tempdir().unwrap();
    let reference: PathBuf = tmp.path().join("reference");
    let mut store = open(&reference);
    run_pending(&mut store, 0);
    store.close().unwrap();
    let expected = common::data_files(&reference);
    let total = completed_rows(&reference);
    assert_eq!(total, 45);

    let dir = tmp.path().join("killed");
    // Kill three times at increasing progress, with different delays so
    // the kill hits different phases of a trial.
    for (rows, extra_ms) in [(3_usize, 0_u64), (12, 7), (30, 3)] {
        run_and_kill(&dir, rows, Duration::from_millis(extra_ms));
        let store = open(&dir);
        let rec = store.recovery();
        println!("after kill at ≥ {rows} rows: {rec}");
        assert!(rec.resumed && rec.previous_sitting_unclosed);
        assert!(rec.completed >= rows.min(total), "{rec}");
        // Every recovered row is unique and continues the plan's prefix
        // (the runner works in plan order).
        let done: Vec<bool> = store
            .plan()
            .iter()
            .map(|p| store.is_completed(&p.key))
            .collect();
        let first_pending = done.iter().position(|d| !d).unwrap_or(done.len());
        assert!(
            done[first_pending..].iter().all(|d| !d),
            "holes in the plan"
        );
        drop(store);
    }
    // Final resume in-process.
    let mut store = open(&dir);
    run_pending(&mut store, 0);
    store.close().unwrap();
    let got = common::data_files(&dir);
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        expected.keys().collect::<Vec<_>>()
    );
    for (name, bytes) in &expected {
        assert!(
            got[name] == *bytes,
            "{name} differs from the uninterrupted run"
        );
    }
    // The journal records each trial completed exactly once and at least
    // four sittings.
    let j = read_journal(&dir.join(JOURNAL_FILE)).unwrap();
    let mut done = std::collections::HashMap::new();
    for e in &j.entries {
        if let Record::TrialCompleted { trial, .. } = &e.record {
            *done.entry(*trial).or_insert(0) += 1;
        }
    }
    assert_eq!(done.len(), total);
    assert!(done.values().all(|&n| n == 1));
    let sittings = j
        .entries
        .iter()
        .filter(|e| matches!(e.record, Record::SessionStarted(_)))
        .count();
    assert!(sittings >= 4, "{sittings}");
}
