//! Sittings on the real-time engine without any GUI (`kilotouch::session`):
//! simulated participant as fast as possible, fsync ordering of committed
//! rows, participant sittings, pause/resume, abort, kill + resume.
//!
//! Reference: `kilotouch_study::simulate::simulate` (the headless
//! `kilotouch study simulate`, an independent driver of the same trials:
//! worker threads, rows committed in plan order). Every trial is a pure
//! function of its key, so the rows written through the engine (its own
//! closed loop on the simulated rig) must equal the headless rows in every
//! column but `started_utc`.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use std::path::Path;
use std::time::{Duration, Instant};

use kilotouch::engine::{EngineHandle, EngineOptions};
use kilotouch::session::{
    FinishReason, FolderStatus, ParticipantKind, SessionCommand, SessionEvent, SessionHandle,
    SessionOptions, Speed, inspect_folder, validate_participant_id,
};
use kilotouch_rig::RigConfig;
use kilotouch_study::export::{TRIALS_FILE, TrialRow, read_trials};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::runner::{RunnerConfig, RunnerState};
use kilotouch_study::seeds::Phase;
use kilotouch_study::simulate::{SimulateOptions, simulate};

/// 2 participants × 3 conditions × 1 test trial, 1 practice trial per
/// condition, 2 s time-outs: 12 short trials.
const TINY: &str = include_str!("data/tiny.toml");

fn tiny() -> Protocol {
    Protocol::from_toml_str(TINY, "tiny.toml").unwrap()
}

fn runner_cfg(raw: bool) -> RunnerConfig {
    RunnerConfig {
        raw: raw.then_some(kilotouch_study::rawsig::Dtype::F32),
        ..RunnerConfig::default()
    }
}

/// The real-time engine on the simulated rig, as the app starts it.
fn engine() -> EngineHandle {
    EngineHandle::spawn(&RigConfig::default(), EngineOptions::default()).unwrap()
}

fn opts(out: &Path, protocol: Option<Protocol>, raw: bool) -> SessionOptions {
    let mut o = SessionOptions::new(out, protocol, RigConfig::default());
    o.participant = ParticipantKind::Simulated;
    o.speed = Speed::Fast;
    o.runner = runner_cfg(raw);
    o
}

/// Spawn and start a real-time sitting of the tiny protocol without raw
/// files, its participant at the mouse (of `only` the participant with that
/// index, if given).
fn start_at_the_mouse(eng: &mut EngineHandle, out: &Path, only: Option<u32>) -> SessionHandle {
    let mut o = opts(out, Some(tiny()), false);
    o.speed = Speed::RealTime;
    o.participant = ParticipantKind::Mouse;
    o.only_participant = only;
    let mut h = SessionHandle::spawn(o, eng).unwrap();
    assert!(h.send(SessionCommand::Start));
    h
}

/// The headless reference rows.
fn reference(dir: &Path, raw: bool) -> Vec<TrialRow> {
    reference_of(tiny(), dir, raw)
}

/// The headless reference rows of `protocol`.
fn reference_of(protocol: Protocol, dir: &Path, raw: bool) -> Vec<TrialRow> {
    let o = SimulateOptions {
        runner: runner_cfg(raw),
        threads: 2,
        fidelity: kilotouch_study::fidelity::Fidelity::Full,
        ..SimulateOptions::new(protocol, dir)
    };
    simulate(&o, &mut |_, _| {}).unwrap();
    rows(dir)
}

fn rows(dir: &Path) -> Vec<TrialRow> {
    read_trials(&dir.join(TRIALS_FILE)).unwrap().rows
}

/// Rows equal in every column but the start time.
fn assert_same_rows(got: &[TrialRow], want: &[TrialRow]) {
    assert_eq!(got.len(), want.len(), "row count");
    for (g, w) in got.iter().zip(want) {
        let mut g = g.clone();
        g.started_utc = w.started_utc;
        assert_eq!(&g, w);
    }
}

/// Runs the thread, collecting events until it finishes (or `secs`).
fn run_until_finished(
    h: &mut SessionHandle,
    secs: f64,
    mut on: impl FnMut(&SessionEvent, &mut SessionHandle),
) -> (Vec<SessionEvent>, Option<FinishReason>) {
    let t0 = Instant::now();
    let mut all = Vec::new();
    while t0.elapsed().as_secs_f64() < secs {
        for e in h.poll() {
            on(&e, h);
            let fin = match &e {
                SessionEvent::Finished(r) => Some(r.clone()),
                _ => None,
            };
            all.push(e);
            if fin.is_some() {
                return (all, fin);
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    (all, None)
}

#[test]
fn simulated_sittings_write_the_headless_rows_with_fsync_ordering() {
    let mut eng = engine();
    let dir = tempfile::tempdir().unwrap();
    let want = reference(&dir.path().join("ref"), false);
    assert_eq!(want.len(), 12);
    let out = dir.path().join("gui");
    let table = tiny().assignment().unwrap();

    // Sitting 1: P01 only.
    let p1 = validate_participant_id("P01", &table).unwrap();
    let mut o = opts(&out, Some(tiny()), false);
    o.only_participant = Some(p1.index);
    let mut h = SessionHandle::spawn(o, &mut eng).unwrap();
    assert_eq!(h.info().planned, 12);
    assert!(h.send(SessionCommand::Start));
    let mut seen = 0usize;
    let (events, fin) = run_until_finished(&mut h, common::WAIT_S, |e, _| {
        if let SessionEvent::Committed(row) = e {
            // A committed row is on disk (fsynced) before the event is sent.
            let on_disk = rows(&out);
            assert!(on_disk.contains(row), "row {row:?} not yet in trials.csv");
            seen += 1;
        }
    });
    assert_eq!(fin, Some(FinishReason::ParticipantDone("P01".into())));
    assert_eq!(seen, 6, "P01: 3 practice + 3 test trials");
    // Training block first, then the sessions in the participant's order.
    let started: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            SessionEvent::TrialStarted { key, .. } => Some(*key),
            _ => None,
        })
        .collect();
    assert_eq!(started.len(), 6);
    assert!(
        started[..3]
            .iter()
            .all(|k| k.phase == Phase::Practice && k.participant == 0)
    );
    assert!(started[3..].iter().all(|k| k.phase == Phase::Test));
    let order = &table.participants[0].sessions;
    let test_conds: Vec<_> = started[3..].iter().map(|k| k.condition).collect();
    assert_eq!(&test_conds, order);
    drop(h);
    assert_same_rows(&rows(&out), &want[..6]);
    match inspect_folder(&out) {
        FolderStatus::Study {
            completed, next, ..
        } => {
            assert_eq!(completed, 6);
            assert_eq!(next.unwrap().key.participant, 1);
        }
        s => panic!("{s:?}"),
    }

    // P01 again: refused (the folder's next trial is P02's).
    let mut o = opts(&out, Some(tiny()), false);
    o.only_participant = Some(0);
    let e = SessionHandle::spawn(o, &mut eng).unwrap_err().to_string();
    assert!(e.contains("P02"), "{e}");

    // Sitting 2: P02 closes the study.
    let mut o = opts(&out, Some(tiny()), false);
    o.only_participant = Some(1);
    let mut h = SessionHandle::spawn(o, &mut eng).unwrap();
    assert!(h.send(SessionCommand::Start));
    let (_, fin) = run_until_finished(&mut h, common::WAIT_S, |_, _| {});
    assert_eq!(fin, Some(FinishReason::StudyDone));
    drop(h);
    assert_same_rows(&rows(&out), &want);
    assert!(out.join("cells_long.csv").exists() && out.join("cells_wide.csv").exists());
}

/// Extra practice trials (`training.practice_retries = 1`): in the tiny
/// protocol every 2 s trial times out, so each condition's practice trial
/// earns exactly one extra, run at once (before the next condition's
/// practice) in the sitting and headless alike: the same rows in the same
/// order.
#[test]
fn unsuccessful_practice_trials_run_again_in_a_sitting_as_headless() {
    let with_retry = || {
        let mut p = tiny();
        p.training.practice_retries = 1;
        p
    };
    let mut eng = engine();
    let dir = tempfile::tempdir().unwrap();
    let want = reference_of(with_retry(), &dir.path().join("ref"), false);
    let out = dir.path().join("gui");
    let mut h = SessionHandle::spawn(opts(&out, Some(with_retry()), false), &mut eng).unwrap();
    assert_eq!(h.info().planned, 12, "the plan starts as the protocol's");
    assert!(h.send(SessionCommand::Start));
    let (events, fin) = run_until_finished(&mut h, common::WAIT_S, |_, _| {});
    assert_eq!(fin, Some(FinishReason::StudyDone));
    drop(h);
    let got = rows(&out);
    // 2 participants × 3 conditions × (1 test + 1 practice + 1 extra).
    assert_eq!(got.len(), 18);
    let practice: Vec<_> = got.iter().filter(|r| r.phase == Phase::Practice).collect();
    assert!(
        practice
            .iter()
            .all(|r| !r.success && r.reject_reason == "timeout"),
        "the premise: every practice trial times out"
    );
    // In the sitting, each extra trial follows its condition's practice.
    let started: Vec<_> = events
        .iter()
        .filter_map(|e| match e {
            SessionEvent::TrialStarted { key, .. } if key.phase == Phase::Practice => {
                Some((key.participant, key.condition, key.trial))
            }
            _ => None,
        })
        .collect();
    assert_eq!(started.len(), 12);
    let replanned: Vec<usize> = events
        .iter()
        .filter_map(|e| match e {
            SessionEvent::Replanned(n) => Some(*n),
            _ => None,
        })
        .collect();
    assert_eq!(
        replanned,
        (13..=18).collect::<Vec<_>>(),
        "one per extra trial"
    );
    for pair in started.chunks(2) {
        assert_eq!((pair[0].2, pair[1].2), (1, 2), "{pair:?}");
        assert_eq!((pair[0].0, pair[0].1), (pair[1].0, pair[1].1), "{pair:?}");
    }
    // Headless, the extra trial is committed in its place too: the same
    // rows in the same order.
    assert_same_rows(&got, &want);
}

/// The Study page's folder check knows the extra practice trials: after
/// an unsuccessful practice row that was its condition's last, the next
/// trial is the extra one (as the store resumes), and the plan counts it.
#[test]
fn the_folder_check_names_an_earned_extra_practice_trial_as_next() {
    let mut p = tiny();
    p.training.practice_retries = 1;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let (meta, _) =
        kilotouch_study::simulate::sim_meta(&RigConfig::default(), None, false, None).unwrap();
    let mut store = kilotouch_study::export::StudyStore::open(&out, &p, &meta).unwrap();
    let first = store.next_pending().unwrap().key;
    assert_eq!((first.phase, first.trial), (Phase::Practice, 1));
    let ticket = store
        .begin_trial(first, kilotouch_study::export::UtcTime::now())
        .unwrap();
    let mut row = ticket.row();
    row.reject_reason = "timeout".into();
    store.commit_trial(ticket, &row).unwrap();
    drop(store);
    match inspect_folder(&out) {
        FolderStatus::Study {
            completed,
            planned,
            next,
            ..
        } => {
            assert_eq!((completed, planned), (1, 13));
            let next = next.unwrap().key;
            assert_eq!(
                (next.participant, next.condition, next.phase, next.trial),
                (first.participant, first.condition, Phase::Practice, 2),
                "the extra trial of the same condition comes next"
            );
        }
        s => panic!("{s:?}"),
    }
}

#[test]
fn kill_mid_session_then_resume_gives_the_uninterrupted_rows() {
    let mut eng = engine();
    let dir = tempfile::tempdir().unwrap();
    let want = reference(&dir.path().join("ref"), true);
    let out = dir.path().join("gui");
    let mut h = SessionHandle::spawn(opts(&out, Some(tiny()), true), &mut eng).unwrap();
    assert!(h.send(SessionCommand::Start));
    // Kill (drop the handle) right after the second row.
    let t0 = Instant::now();
    let mut n = 0;
    while n < 2 && t0.elapsed() < Duration::from_secs(20) {
        n += h
            .poll()
            .iter()
            .filter(|e| matches!(e, SessionEvent::Committed(_)))
            .count();
        std::thread::sleep(Duration::from_millis(1));
    }
    drop(h);
    let partial = rows(&out);
    assert!(
        partial.len() >= 2 && partial.len() < 12,
        "{}",
        partial.len()
    );
    assert_same_rows(&partial, &want[..partial.len()]);
    // Resume from the folder alone (its own protocol).
    let mut h = SessionHandle::spawn(opts(&out, None, true), &mut eng).unwrap();
    assert!(h.info().recovery.resumed);
    assert_eq!(h.info().completed, partial.len());
    assert_eq!(
        h.info().next.as_ref().unwrap().key,
        kilotouch_study::export::plan(
            &tiny(),
            &kilotouch_study::export::read_session(&out.join("session.json"))
                .unwrap()
                .order_table
        )[partial.len()]
        .key
    );
    assert!(h.send(SessionCommand::Start));
    let (_, fin) = run_until_finished(&mut h, common::WAIT_S, |_, _| {});
    assert_eq!(fin, Some(FinishReason::StudyDone));
    drop(h);
    let got = rows(&out);
    assert_same_rows(&got, &want);
    for r in &got {
        assert!(
            !r.raw_file.is_empty() && out.join(&r.raw_file).is_file(),
            "{}",
            r.raw_file
        );
    }
}

#[test]
fn pause_holds_the_trial_and_resume_continues_it() {
    let mut eng = engine();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let mut h = start_at_the_mouse(&mut eng, &out, None);
    let t_start = Instant::now();
    let mut last_sim = 0.0;
    let mut state = None;
    let wait = |h: &mut SessionHandle,
                eng: &mut EngineHandle,
                state: &mut Option<RunnerState>,
                sim: &mut f64,
                ms: u64| {
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_millis(ms) {
            let _ = eng.poll_events();
            *sim = h.health(eng).simulated_s;
            for e in h.poll() {
                match e {
                    SessionEvent::State(s) => *state = Some(s),
                    SessionEvent::Error(m) => panic!("{m}"),
                    _ => {}
                }
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    };
    wait(&mut h, &mut eng, &mut state, &mut last_sim, 300);
    assert!(matches!(state, Some(RunnerState::Training(_))), "{state:?}");
    // Real-time pacing: the simulated time never runs ahead of the wall clock.
    assert!(last_sim > 0.0 && last_sim <= t_start.elapsed().as_secs_f64() + 0.01);
    assert!(h.send(SessionCommand::Pause));
    wait(&mut h, &mut eng, &mut state, &mut last_sim, 150);
    assert!(
        matches!(state, Some(RunnerState::Paused(Some(_)))),
        "{state:?}"
    );
    let held = last_sim;
    wait(&mut h, &mut eng, &mut state, &mut last_sim, 250);
    assert_eq!(last_sim, held, "no sample runs while paused");
    assert!(h.send(SessionCommand::Note("participant sneezed".into())));
    assert!(h.send(SessionCommand::Resume));
    wait(&mut h, &mut eng, &mut state, &mut last_sim, 250);
    assert!(matches!(state, Some(RunnerState::Training(_))), "{state:?}");
    assert!(last_sim > held, "the trial continues");
    drop(h);
    // The pause, the resume and the note are in the journal.
    let journal = std::fs::read_to_string(out.join("journal.jsonl")).unwrap_or_default();
    let journal = if journal.is_empty() {
        std::fs::read_dir(&out)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains("journal"))
            .map(|e| std::fs::read_to_string(e.path()).unwrap())
            .collect::<String>()
    } else {
        journal
    };
    assert!(journal.contains("participant sneezed"), "{journal}");
    assert!(journal.contains("pause"));
}

#[test]
fn abort_and_emergency_stop_commit_aborted_rows() {
    let mut eng = engine();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let mut h = start_at_the_mouse(&mut eng, &out, Some(0));
    let mut committed: Vec<TrialRow> = Vec::new();
    let mut state = None;
    let t0 = Instant::now();
    let mut aborted = false;
    let mut stopped = false;
    while t0.elapsed() < Duration::from_secs(10) && committed.len() < 2 {
        for e in h.poll() {
            match e {
                SessionEvent::State(s) => state = Some(s),
                SessionEvent::TrialStarted { .. } if !aborted => {
                    std::thread::sleep(Duration::from_millis(50));
                    assert!(h.send(SessionCommand::AbortTrial));
                    aborted = true;
                }
                SessionEvent::TrialStarted { .. } if !stopped => {
                    std::thread::sleep(Duration::from_millis(50));
                    assert!(h.send(SessionCommand::EmergencyStop));
                    stopped = true;
                }
                SessionEvent::Committed(r) => committed.push(*r),
                _ => {}
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(committed.len(), 2);
    for r in &committed {
        assert_eq!(r.reject_reason, "aborted");
        assert!(!r.success);
        assert!(
            r.time_s.unwrap() > 0.0 && r.time_s.unwrap() < 1.0,
            "{:?}",
            r.time_s
        );
    }
    // After the emergency stop the session waits, paused between trials.
    let t1 = Instant::now();
    while t1.elapsed() < Duration::from_millis(200) {
        for e in h.poll() {
            if let SessionEvent::State(s) = e {
                state = Some(s);
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    assert_eq!(state, Some(RunnerState::Paused(None)));
    drop(h);
    assert_eq!(rows(&out), committed);
}

#[test]
fn participant_ids_are_pseudonyms() {
    let table = tiny().assignment().unwrap();
    for ok in ["P01", "p1", "2", "P02", " P2 "] {
        let id = validate_participant_id(ok, &table).unwrap();
        assert!(id.index <= 1);
        assert_eq!(id.id, format!("P{:02}", id.index + 1));
    }
    for bad in [
        "",
        "Jane Doe",
        "jane@example.org",
        "Jane",
        "P3",
        "P0",
        "Smith2",
        "P-1",
    ] {
        assert!(validate_participant_id(bad, &table).is_err(), "{bad}");
    }
    // Fast pacing is for the simulated participant only.
    let mut eng = engine();
    let dir = tempfile::tempdir().unwrap();
    let mut o = opts(dir.path(), Some(tiny()), false);
    o.participant = ParticipantKind::Mouse;
    assert!(SessionHandle::spawn(o, &mut eng).is_err());
    assert_eq!(
        inspect_folder(&dir.path().join("none")),
        FolderStatus::Empty
    );
}

#[test]
fn a_sitting_records_the_applied_trap_calibration_in_session_json() {
    let mut eng = engine();
    // The trap calibration the Rig page applies: 10 s of the simulated
    // tweezer's detector, both axes calibrated (aliased Lorentzian, the
    // simulated detector point-samples at the loop rate).
    let rc = RigConfig::default();
    let mut free = rc.clone();
    free.tweezer.obstacles.clear();
    let rec = kilotouch_rig::tweezer::record::record(
        &kilotouch_rig::device::RigSpec::Sim,
        &free,
        10.0,
        [0.0; 2],
        &mut |_| {},
    )
    .unwrap();
    let gui = kilotouch::gui::pages::rig_tweezer::TweezerSection::new();
    let (cal, _) = kilotouch_rig::tweezer::record::calibrate_axes(&rec, &gui.settings()).unwrap();
    cal.check().unwrap();
    let truth = rc.tweezer.stiffness_n_per_m;
    assert!((cal.kappa_n_per_m / truth - 1.0).abs() < 0.04, "{cal:?}");

    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    let mut o = opts(&out, Some(tiny()), false);
    o.only_participant = Some(0);
    o.trap_calibration = Some(cal.clone());
    let mut h = SessionHandle::spawn(o, &mut eng).unwrap();
    assert!(h.send(SessionCommand::Start));
    let (_, fin) = run_until_finished(&mut h, common::WAIT_S, |_, _| {});
    assert_eq!(fin, Some(FinishReason::ParticipantDone("P01".into())));
    drop(h);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    let t = &json["trap_calibration"];
    assert_eq!(t["source"], "sim");
    // Every field (JSON numbers read back within an ulp or two).
    let got: kilotouch_rig::tweezer::TrapCalibrationRecord =
        serde_json::from_value(t.clone()).unwrap();
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-14 * b.abs();
    assert_eq!((got.source.as_str(), got.n_samples), ("sim", 100_000));
    assert_eq!(got.settings, cal.settings);
    assert!(close(got.kappa_n_per_m, cal.kappa_n_per_m), "{t}");
    assert!(close(got.kappa_se_n_per_m, cal.kappa_se_n_per_m));
    for k in 0..2 {
        assert!(close(got.rd_m_per_v[k], cal.rd_m_per_v[k]));
    }
    for (g, c) in [(&got.x, &cal.x), (&got.y, &cal.y)] {
        for (a, b) in [
            (g.corner_hz, c.corner_hz),
            (g.corner_se_hz, c.corner_se_hz),
            (g.diffusion_v2_s, c.diffusion_v2_s),
            (g.kappa_n_per_m, c.kappa_n_per_m),
            (g.rd_m_per_v, c.rd_m_per_v),
            (g.chi2_per_dof, c.chi2_per_dof),
            (g.backing_pct, c.backing_pct),
        ] {
            assert!(close(a, b), "{a} vs {b}");
        }
        assert_eq!((g.n_points, g.iterations), (c.n_points, c.iterations));
    }

    // A resume with another trap calibration is refused, naming it.
    let mut other = cal.clone();
    other.kappa_n_per_m *= 1.1;
    let mut o = opts(&out, Some(tiny()), false);
    o.trap_calibration = Some(other);
    let e = SessionHandle::spawn(o, &mut eng).unwrap_err().to_string();
    assert!(e.contains("trap calibration"), "{e}");
    // The same one (as the GUI keeps it) resumes: P02 closes the study.
    let mut o = opts(&out, Some(tiny()), false);
    o.trap_calibration = Some(cal.clone());
    let mut h = SessionHandle::spawn(o, &mut eng).unwrap();
    assert!(h.send(SessionCommand::Start));
    let (_, fin) = run_until_finished(&mut h, common::WAIT_S, |_, _| {});
    assert_eq!(fin, Some(FinishReason::StudyDone));
    drop(h);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    // Kept in pN/µm, as written from the same calibration.
    let kept = json["trap_calibration"]["kappa_pn_um"].as_f64().unwrap();
    assert_eq!(kept, kilotouch_rig::units::to_pn_per_um(cal.kappa_n_per_m));
}
