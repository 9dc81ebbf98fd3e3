//! UI test of the Study page with egui_kittest: load a tiny protocol file,
//! choose the simulated participant (as fast as possible) and the inline
//! participant view, open the session (the sitting becomes the engine's
//! driver), click Start, and see the rows appear in the page's table and in
//! `trials.csv`; free exploration takes the engine back, stopped, when the
//! sitting ends.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{AppHarness, open_session, step_until_every};
use egui_kittest::kittest::Queryable;
use kilotouch::session::{FinishReason, ParticipantKind, Speed};
use kilotouch_study::export::{TRIALS_FILE, read_trials};
use std::path::Path;
use std::time::Duration;

/// The tiny study of `data/tiny.toml` without practice trials: 2
/// participants × 3 conditions × 1 trial.
fn tiny() -> String {
    include_str!("data/tiny.toml").replace("practice_trials = 1", "practice_trials = 0")
}

/// The pause between UI steps while waiting (the sitting runs as fast as
/// possible).
const POLL: Duration = Duration::from_millis(5);

/// The app on the Study page ([`common::study_page`]) with the simulated
/// participant at full speed.
fn study_page(proto: &Path, participant: &str, out: &Path) -> AppHarness {
    let mut h = common::study_page(proto, participant, out, 900.0);
    let s = &mut h.state_mut().study.form;
    s.kind = ParticipantKind::Simulated;
    s.speed = Speed::Fast;
    h
}

/// A temporary folder with the tiny protocol file: (folder, protocol
/// file, study folder to write).
fn tiny_folder() -> (tempfile::TempDir, std::path::PathBuf, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let proto = dir.path().join("tiny.toml");
    std::fs::write(&proto, tiny()).unwrap();
    let out = dir.path().join("out");
    (dir, proto, out)
}

#[test]
fn study_page_runs_a_simulated_sitting() {
    let (_dir, proto, out) = tiny_folder();
    let mut h = study_page(&proto, "jane@example.org", &out);
    assert!(common::until_engine_reporting(&mut h, POLL));
    h.step();
    // An e-mail address is refused as participant ID.
    assert!(h.query_by_label_contains("e-mail").is_some());
    h.state_mut().study.form.participant_text = "P02".into();
    h.step();
    h.step();
    // The counterbalanced order of P02 (Williams row 2 of 6 for 3 conditions).
    assert!(h.query_by_label_contains("P02: order").is_some());
    assert!(h.query_by_label_contains("new study folder").is_some());
    // P02 is not next in plan order (P01 is): opening is refused with a
    // clear message (once the size check let it through to the sitting).
    h.get_by_label("Open session").click();
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |a| a
        .study
        .error()
        .is_some()));
    let err = h.state().study.error().unwrap_or_default().to_owned();
    assert!(err.contains("P01"), "{err}");
    assert!(!h.state().study.is_running());

    h.state_mut().study.form.participant_text = "P01".into();
    h.step();
    open_session(&mut h);
    // One engine: the sitting is its driver, the status bar says so.
    assert!(h.state().engine.is_some());
    h.step();
    assert!(h.query_by_label_contains("study sitting: P01").is_some());
    assert!(
        h.query_by_label_contains("Participant view (inline)")
            .is_some()
    );
    h.get_by_label("Start").click();
    assert!(common::until_study_finished(&mut h, POLL));
    assert_eq!(
        h.state().study.finished(),
        Some(&FinishReason::ParticipantDone("P01".into()))
    );
    h.step();
    h.step();
    // Rows in the page's table and in trials.csv, the same three.
    assert!(h.query_by_label_contains("Finished trials: 3").is_some());
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), 3);
    assert_eq!(h.state().study.rows(), &rows[..]);
    assert!(rows.iter().all(|r| r.participant == "P01"));
    // Free exploration has the engine back, stopped.
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |a| {
        common::engine_health(a).is_some_and(|h| !h.running)
    }));
    // The folder now offers to resume at P02's first trial.
    h.step();
    assert!(h.query_by_label_contains("Resume at trial P02").is_some());
}

/// Extra practice trials from the Study page: the protocol's line states
/// them; in a sitting where every 2 s practice trial times out, each
/// condition's practice earns its one extra and the page's plan count
/// grows with them.
#[test]
fn unsuccessful_practice_trials_are_run_again_in_a_sitting_from_the_study_page() {
    let dir = tempfile::tempdir().unwrap();
    let proto = dir.path().join("retry.toml");
    std::fs::write(
        &proto,
        include_str!("data/tiny.toml").replace(
            "practice_trials = 1",
            "practice_trials = 1\npractice_retries = 1",
        ),
    )
    .unwrap();
    let out = dir.path().join("out");
    let mut h = study_page(&proto, "P01", &out);
    assert!(common::until_engine_reporting(&mut h, POLL));
    h.step();
    assert!(
        h.query_by_label_contains(
            "1 practice trials per condition (up to 1 more for unsuccessful ones)"
        )
        .is_some()
    );
    open_session(&mut h);
    assert!(
        h.query_by_label_contains("committed 0 of 12 trials")
            .is_some()
    );
    h.get_by_label("Start").click();
    assert!(common::until_study_finished(&mut h, POLL));
    h.step();
    h.step();
    // P01: 3 practice trials, 3 extra ones, 3 test trials; the plan grew
    // from 12 to 15 trials.
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), 9);
    assert_eq!(h.state().study.planned(), 15, "the plan counts the extras");
    let extra: Vec<_> = rows.iter().filter(|r| r.trial == 2).collect();
    assert_eq!(extra.len(), 3);
    assert!(
        extra
            .iter()
            .all(|r| r.phase == kilotouch_study::seeds::Phase::Practice)
    );
}

/// The sitting runs and records the calibration chosen on the page: the
/// file and its SHA-256 land in `session.json`; "as designed" is recorded
/// as uncalibrated.
#[test]
fn study_page_records_the_chosen_calibration() {
    use kilotouch::gui::pages::study::CalibrationChoice;
    use kilotouch_rig::calibration::{CalibrationConfig, NoProgress, calibrate_sim};
    let dir = tempfile::tempdir().unwrap();
    let cal = dir.path().join("cal.toml");
    calibrate_sim(
        None,
        Some(3),
        &CalibrationConfig::default(),
        Some(&cal),
        &mut NoProgress,
        &std::sync::atomic::AtomicBool::new(false),
    )
    .unwrap();
    let proto = dir.path().join("tiny.toml");
    std::fs::write(&proto, tiny()).unwrap();
    for (choice, out_name) in [
        (CalibrationChoice::File, "with-cal"),
        (CalibrationChoice::AsDesigned, "uncal"),
    ] {
        let out = dir.path().join(out_name);
        let mut h = study_page(&proto, "P01", &out);
        {
            let s = &mut h.state_mut().study.form;
            s.calibration = choice;
            s.calibration_file = cal.display().to_string();
        }
        assert!(common::until_engine_reporting(&mut h, POLL));
        h.step();
        h.step();
        let shown = match choice {
            CalibrationChoice::File => format!("recorded: {} with its SHA-256", cal.display()),
            _ => "recorded as uncalibrated".to_owned(),
        };
        assert!(h.query_by_label_contains(&shown).is_some(), "{shown}");
        open_session(&mut h);
        h.get_by_label("Start").click();
        assert!(common::until_study_finished(&mut h, POLL));
        let session: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap())
                .unwrap();
        match choice {
            CalibrationChoice::File => {
                assert_eq!(session["calibration"]["path"], cal.display().to_string());
                assert_eq!(session["calibration"]["sha256"].as_str().unwrap().len(), 64);
            }
            _ => assert!(session["calibration"].is_null(), "{session}"),
        }
    }
}

/// After P01 finishes normally: the folder reopens without a false crash
/// report; switching the participant clears the last sitting's rows and
/// messages; the Resume button and the controls under it keep their place
/// whether or not there is something to resume.
#[test]
fn a_finished_participant_is_no_crash_and_switching_clears_the_console() {
    let (_dir, proto, out) = tiny_folder();
    let mut h = study_page(&proto, "P01", &out);
    assert!(common::until_engine_reporting(&mut h, POLL));
    h.step();
    h.step();
    let resume_before = h.get_by_label("Resume").rect();
    let radio_before = h.get_by_label("person (mouse)").rect();
    open_session(&mut h);
    h.get_by_label("Start").click();
    assert!(common::until_study_finished(&mut h, POLL));
    h.step();
    h.step();
    assert!(
        h.query_by_label_contains("participant P01 finished")
            .is_some()
    );
    assert!(h.query_by_label_contains("Finished trials: 3").is_some());
    let resume_after = h.get_by_label_contains("Resume at trial P02").rect();
    assert_eq!(resume_before.top(), resume_after.top());
    assert_eq!(resume_before.left(), resume_after.left());
    assert_eq!(radio_before, h.get_by_label("person (mouse)").rect());
    // Another participant: nothing of P01's sitting stays on screen.
    h.state_mut().study.form.participant_text = "P02".into();
    h.step();
    h.step();
    assert!(
        h.query_by_label_contains("participant P01 finished")
            .is_none()
    );
    assert!(h.query_by_label_contains("Finished trials: 0").is_some());
    // P01's sitting was closed: resuming reports no crash.
    h.get_by_label_contains("Resume at trial P02").click();
    assert!(common::until_sitting_opened(&mut h));
    h.step();
    assert!(h.query_by_label_contains("resumed:").is_some());
    assert!(
        h.query_by_label_contains("without closing").is_none(),
        "false crash report after a normal finish"
    );
}

/// "Run all remaining participants" (simulated dry run): one click runs
/// every pending trial of every participant in one sitting.
#[test]
fn run_all_remaining_participants_finishes_the_study() {
    let (dir, proto, out) = tiny_folder();
    let mut h = study_page(&proto, "", &out);
    assert!(common::until_engine_reporting(&mut h, POLL));
    h.step();
    h.step();
    h.get_by_label("Run all remaining participants").click();
    assert!(common::until_study_finished(&mut h, POLL));
    assert_eq!(h.state().study.finished(), Some(&FinishReason::StudyDone));
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), 6, "2 participants × 3 conditions × 1 trial");
    assert_eq!(rows.iter().filter(|r| r.participant == "P02").count(), 3);
    h.step();
    h.step();
    assert!(h.query_by_label_contains("study complete").is_some());
    // Another folder: the stale "study complete" goes.
    h.state_mut().study.form.out_text = dir.path().join("other").display().to_string();
    h.step();
    h.step();
    assert!(h.query_by_label_contains("study complete").is_none());
}

/// Step until a widget whose label contains `text` is shown (≤ 60 s).
fn until_label(
    h: &mut egui_kittest::Harness<'static, kilotouch::gui::KilotouchApp>,
    text: &str,
) -> bool {
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(60) {
        h.step();
        if h.query_by_label_contains(text).is_some() {
            return true;
        }
        std::thread::sleep(POLL);
    }
    false
}

/// Before a sitting writes more than the page's threshold, the page states
/// the estimate and asks: Cancel opens nothing, "Without raw signals" runs
/// the sitting without raw files. A sitting larger than the free space of
/// its disk is refused with the numbers.
#[test]
fn a_large_sitting_is_confirmed_first_and_one_beyond_the_free_space_refused() {
    let (dir, proto, out) = tiny_folder();
    let mut h = study_page(&proto, "P01", &out);
    assert!(common::until_engine_reporting(&mut h, POLL));
    // Every sitting with raw files is "large" at a 1 kB threshold.
    h.state_mut().study.size_gate.confirm_over_bytes = 1_000;
    h.step();
    h.get_by_label("Open session").click();
    assert!(
        until_label(&mut h, "This sitting will write"),
        "no confirmation: {:?}",
        h.state().study.error()
    );
    assert!(!h.state().study.is_running());
    h.get_by_label_contains("more than the 1.0 kB the page asks about");
    h.get_by_label("Cancel").click();
    h.step();
    h.step();
    assert!(!h.state().study.is_running());
    assert!(
        h.query_by_label_contains("This sitting will write")
            .is_none()
    );
    // The cancelled sitting's estimate stays as one line.
    h.get_by_label_contains("the sitting would write about");
    assert!(!out.join("session.json").exists(), "nothing written");

    // Asked again; written without raw signals.
    h.get_by_label("Open session").click();
    assert!(until_label(&mut h, "Without raw signals"));
    h.get_by_label_contains("Without raw signals").click();
    assert!(common::until_sitting_opened(&mut h));
    assert!(
        h.state().study.size_gate.last.is_none(),
        "an opened sitting clears it"
    );
    h.step();
    h.get_by_label("Start").click();
    assert!(common::until_study_finished(&mut h, POLL));
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), 3);
    assert!(rows.iter().all(|r| r.raw_file.is_empty()), "{rows:?}");
    assert!(!out.join("raw").exists() || std::fs::read_dir(out.join("raw")).unwrap().count() == 0);

    // A new folder on a "disk" with 1 kB free: refused, with the numbers.
    let out2 = dir.path().join("out2");
    h.state_mut().study.form.out_text = out2.display().to_string();
    h.state_mut().study.size_gate.confirm_over_bytes = 1_000_000_000;
    h.state_mut().study.size_gate.assume_free_bytes = Some(1_000);
    h.step();
    h.step();
    h.get_by_label("Open session").click();
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |a| a
        .study
        .error()
        .is_some()));
    let err = h.state().study.error().unwrap().to_owned();
    assert!(
        err.contains("not enough disk space") && err.contains("1.0 kB free"),
        "{err}"
    );
    assert!(!h.state().study.is_running());
    assert!(!out2.join("session.json").exists());
}

/// With the participant's view in a window of its own, the experimenter's
/// page mirrors it (not interactive).
#[test]
fn a_separate_participant_window_is_mirrored_on_the_study_page() {
    let (_dir, proto, out) = tiny_folder();
    let mut h = study_page(&proto, "P01", &out);
    h.state_mut().study.separate_window = true;
    assert!(common::until_engine_reporting(&mut h, POLL));
    h.step();
    open_session(&mut h);
    h.step();
    h.get_by_label_contains("Participant's screen (mirror of their window)");
    h.get_by_label("participant screen (mirror)");
    assert!(
        h.query_by_label_contains("Participant view (inline)")
            .is_none()
    );
}
