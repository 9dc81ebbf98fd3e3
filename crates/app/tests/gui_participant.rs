//! The participant's screens and the experimenter console during a sitting,
//! driven through egui_kittest as a person would: the protocol file's
//! texts and timings, Space and clicks on the participant's screen, the
//! emergency stop (Esc) and its confirmed reset before Resume.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::step_until_every;
use egui_kittest::kittest::Queryable;
use kilotouch::gui::participant_screen::Routine;
use kilotouch::session::{FinishReason, ParticipantKind, Speed};
use kilotouch_study::export::{TRIALS_FILE, read_trials};
use kilotouch_study::runner::RunnerState;
use std::time::{Duration, Instant};

type H = common::AppHarness;

/// One participant, sessions V then D (fixed order), two 0.6 s trials
/// each, no practice; every screen text recognisable, a 0.4 s
/// inter-trial interval.
const PROTOCOL: &str = r#"
name = "screens"
participants = 1
conditions = ["V", "D"]
trials_per_session = 2

[training]
practice_trials = 0

[task.circling]
timeout_s = 0.6

[counterbalance]
scheme = "fixed"

[screens]
instructions = "INSTRUCTIONS: go around the sphere."
ready = "READY: press space or click."
break = "BREAK: rest a moment."
end = "END: thank you."
iti_s = 0.4
break_min_s = 0.0
[screens.condition_instructions]
D = "D-TEXT: you will feel the contact."
"#;

const POLL: Duration = Duration::from_millis(5);

/// Open the session ([`common::open_session`]) and click Start.
fn open_and_start(h: &mut H) {
    common::open_session(h);
    h.get_by_label("Start").click();
    h.step();
}

fn open(dir: &std::path::Path) -> H {
    let proto = dir.join("screens.toml");
    std::fs::write(&proto, PROTOCOL).unwrap();
    let mut h = common::study_page(&proto, "P01", &dir.join("out"), 1400.0);
    {
        let s = &mut h.state_mut().study.form;
        s.kind = ParticipantKind::Mouse;
        s.speed = Speed::RealTime;
    }
    assert!(common::until_engine_reporting(&mut h, POLL));
    h.step();
    open_and_start(&mut h);
    h
}

fn routine(h: &H) -> Option<Routine> {
    h.state().study.participant_screen().map(|s| s.routine)
}

/// Step (≤ [`common::WAIT_S`]) until the sitting is paused with no trial
/// in progress.
fn until_paused_between_trials(h: &mut H) -> bool {
    step_until_every(h, POLL, common::WAIT_S, |a| {
        matches!(a.study.runner_state(), Some(RunnerState::Paused(None)))
    })
}

fn step_until_routine(h: &mut H, secs: f64, want: impl Fn(&Routine) -> bool) -> bool {
    step_until_every(h, POLL, secs, |a| {
        a.study
            .participant_screen()
            .is_some_and(|s| want(&s.routine))
    })
}

/// Clears egui's keyboard focus (a clicked button keeps it), as a
/// participant's window never has a focused field.
fn press_space(h: &mut H) {
    h.ctx.memory_mut(|m| {
        if let Some(id) = m.focused() {
            m.surrender_focus(id);
        }
    });
    h.step();
    h.key_press(egui::Key::Space);
    h.step();
    h.step();
}

#[test]
fn a_person_goes_through_every_screen_of_the_protocol() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = open(dir.path());
    // Instructions of the first block (V: no condition text).
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Instructions { .. }
    )));
    h.step();
    assert!(
        h.query_by_label_contains("INSTRUCTIONS: go around")
            .is_some()
    );
    assert!(h.query_by_label_contains("D-TEXT").is_none());
    // Nothing begins before the participant: 0.5 s later still waiting.
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(500) {
        h.step();
        std::thread::sleep(POLL);
    }
    assert!(matches!(
        h.state().study.runner_state(),
        Some(RunnerState::Waiting(_))
    ));
    press_space(&mut h);
    assert!(matches!(routine(&h), Some(Routine::Ready { .. })));
    assert!(h.query_by_label_contains("READY: press space").is_some());
    // A click on the ready screen begins the trial.
    h.get_by_label_contains("READY: press space").click();
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Trial(_)
    )));
    let first = match routine(&h) {
        Some(Routine::Trial(k)) => k,
        r => panic!("{r:?}"),
    };
    let counter = h
        .state()
        .study
        .participant_screen()
        .unwrap()
        .counter(first)
        .0;
    assert_eq!(counter, "Session 1 of 2 — trial 1 of 2");
    // The trial times out; the interval is blank and lasts iti_s.
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| *r == Routine::Iti));
    let iti_start = Instant::now();
    assert!(h.query_by_label_contains("READY").is_none());
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Trial(k) if k.trial == 2
    )));
    let iti = iti_start.elapsed().as_secs_f64();
    assert!(iti >= 0.4 - 0.02, "inter-trial interval {iti} s < 0.4 s");
    // After the session: the break, then D's instructions with its text.
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Break { .. }
    )));
    h.step();
    assert!(h.query_by_label_contains("BREAK: rest").is_some());
    press_space(&mut h);
    assert!(matches!(routine(&h), Some(Routine::Instructions { .. })));
    assert!(h.query_by_label_contains("D-TEXT: you will feel").is_some());
    press_space(&mut h);
    assert!(matches!(routine(&h), Some(Routine::Ready { .. })));
    press_space(&mut h);
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Trial(k) if k.trial == 1
    )));
    let d1 = match routine(&h) {
        Some(Routine::Trial(k)) => k,
        r => panic!("{r:?}"),
    };
    assert_eq!(d1.condition.code(), "D");
    assert_eq!(
        h.state().study.participant_screen().unwrap().counter(d1).0,
        "Session 2 of 2 — trial 1 of 2"
    );
    // Last trial → the study is done → the end screen stays.
    assert!(common::until_study_finished(&mut h, POLL));
    assert_eq!(h.state().study.finished(), Some(&FinishReason::StudyDone));
    h.step();
    h.step();
    assert_eq!(routine(&h), Some(Routine::End));
    assert!(h.query_by_label_contains("END: thank you").is_some());
    let rows = read_trials(&dir.path().join("out").join(TRIALS_FILE))
        .unwrap()
        .rows;
    assert_eq!(rows.len(), 4);
    // The experimenter closes the participant's screen.
    h.get_by_label("Close participant screen").click();
    h.step();
    assert!(h.state().study.participant_screen().is_none());
}

/// Step until the engine has begun the trial the participant's screen
/// shows. A stop pressed in the block or two between the screen and the
/// engine's start refuses that trial instead (the next trial did not begin:
/// the stop is latched; no row, it runs again after the reset), which is
/// not the case these tests press Esc for.
fn until_engine_began_the_trial(h: &mut H) {
    assert!(step_until_every(h, POLL, common::WAIT_S, |a| a
        .study
        .trial_started()
        .is_some()));
}

#[test]
fn emergency_stop_during_a_trial_then_a_confirmed_resume() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = open(dir.path());
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Instructions { .. }
    )));
    press_space(&mut h);
    press_space(&mut h);
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Trial(_)
    )));
    until_engine_began_the_trial(&mut h);
    // Esc: the trial is aborted (its row kept), the sitting paused.
    h.key_press(egui::Key::Escape);
    assert!(until_paused_between_trials(&mut h));
    h.step();
    h.step();
    assert!(h.state().study.estop_latched());
    // The shell says what happened to the study, not "no rig connected".
    assert!(h.query_by_label_contains("no rig connected").is_none());
    // Which trial, in the notice and on the page.
    assert!(
        h.state()
            .notices()
            .any(|n| n.starts_with("emergency stop: trial ")
                && n.contains("was aborted (its row is kept as `aborted`")),
        "{:?}",
        h.state().notices().collect::<Vec<_>>()
    );
    assert!(
        h.query_by_label_contains("EMERGENCY STOP: trial ")
            .is_some()
    );
    // The status bar: the engine's stop and the sitting's state.
    assert!(h.query_by_label_contains("study sitting: P01").is_some());
    assert!(h.query_by_label_contains("OUTPUTS HELD AT ZERO").is_some());
    // The aborted trial's row, committed by the sitting's worker.
    let trials = dir.path().join("out").join(TRIALS_FILE);
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |_| {
        read_trials(&trials).is_ok_and(|t| t.rows.len() == 1)
    }));
    let rows = read_trials(&trials).unwrap().rows;
    assert_eq!(rows[0].reject_reason, "aborted");
    // Resume is refused until the stop is reset with the confirmation.
    h.get_by_label("Resume").click();
    h.step();
    h.step();
    assert!(matches!(
        h.state().study.runner_state(),
        Some(RunnerState::Paused(None))
    ));
    h.get_by_label("Reset emergency stop…").click();
    // The dialog's first frame is a sizing pass.
    h.step();
    h.step();
    h.step();
    h.get_by_label("Re-enable outputs (ramped)").click();
    h.step();
    assert!(h.state().study.estop_latched(), "not without the tick");
    h.get_by_label("I have checked that the rig is safe")
        .click();
    h.step();
    h.get_by_label("Re-enable outputs (ramped)").click();
    h.step();
    h.step();
    assert!(!h.state().study.estop_latched());
    // After the reset no notice of the stop remains (newest or "+N more").
    assert_no_stop_notice(&mut h);
    // Resume: the next trial waits for the participant's ready screen.
    h.get_by_label("Resume").click();
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Instructions { .. }
    )));
    assert!(matches!(
        h.state().study.runner_state(),
        Some(RunnerState::Waiting(_))
    ));
    // Esc on the instructions screen: no trial was running, and it says so.
    h.key_press(egui::Key::Escape);
    h.step();
    h.step();
    assert!(h.state().study.estop_latched());
    assert!(
        h.state()
            .notices()
            .any(|n| n.contains("no trial was running, none was aborted"))
    );
    assert!(
        h.query_by_label_contains("EMERGENCY STOP: no trial was running")
            .is_some()
    );
    assert!(h.query_by_label_contains("was aborted (its row").is_none());
    confirm_reset(&mut h);
    h.step();
    h.step();
    assert!(!h.state().study.estop_latched());
    assert_no_stop_notice(&mut h);
    // Stop sitting: the Explore engine takes the rig back, not armed.
    h.get_by_label("Stop sitting").click();
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |a| {
        common::engine_health(a).is_some()
    }));
    // Give it time to (wrongly) arm itself.
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(300) {
        h.step();
        std::thread::sleep(POLL);
    }
    let health = *h.state().engine.as_ref().unwrap().health().unwrap();
    assert!(!health.running, "the engine came back running: {health:?}");
    // The sitting ended cleanly: reopening reports no crash.
    let status = kilotouch::session::inspect_folder(&dir.path().join("out"));
    assert!(matches!(
        status,
        kilotouch::session::FolderStatus::Study { completed: 1, .. }
    ));
    h.get_by_label_contains("Resume at trial").click();
    assert!(common::until_sitting_opened(&mut h));
    h.step();
    assert!(
        h.query_by_label_contains("without closing").is_none(),
        "a stopped sitting is not a crash"
    );
}

/// The reset dialog, confirmed: open it (its first frame is a sizing
/// pass), tick the check, re-enable.
fn confirm_reset(h: &mut H) {
    h.get_by_label("Reset emergency stop…").click();
    h.step();
    h.step();
    h.step();
    h.get_by_label("I have checked that the rig is safe")
        .click();
    h.step();
    h.get_by_label("Re-enable outputs (ramped)").click();
}

/// No notice of the emergency stop remains, nor the page's red line (the
/// reset's own "emergency stop reset: …" aside).
fn assert_no_stop_notice(h: &mut H) {
    h.step();
    let left: Vec<_> = h
        .state()
        .notices()
        .filter(|n| n.starts_with("emergency stop: "))
        .map(str::to_owned)
        .collect();
    assert!(left.is_empty(), "{left:?}");
    assert!(h.query_by_label_contains("EMERGENCY STOP:").is_none());
}

/// An emergency stop that is never reset outlives the sitting: the engine
/// that takes the rig back starts latched.
#[test]
fn an_unreset_stop_keeps_the_engine_latched_after_the_sitting() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = open(dir.path());
    assert!(step_until_routine(&mut h, common::WAIT_S, |r| matches!(
        r,
        Routine::Instructions { .. }
    )));
    h.key_press(egui::Key::Escape);
    assert!(until_paused_between_trials(&mut h));
    h.get_by_label("Stop sitting").click();
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |a| a.estop_latched()));
    assert!(h.state().any_estop_latched());
}

/// Press Space whenever the participant's screen waits for it, until
/// `want` (a person at the rig moving on through the screens).
fn space_through_screens_until(h: &mut H, secs: f64, want: impl Fn(&H) -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed().as_secs_f64() < secs {
        if want(h) {
            return true;
        }
        match routine(h) {
            Some(Routine::Instructions { .. } | Routine::Ready { .. } | Routine::Break { .. }) => {
                press_space(h)
            }
            _ => {
                h.step();
                std::thread::sleep(POLL);
            }
        }
    }
    want(h)
}

/// A short sitting on the emulated rig from the Study page, as a lab runs
/// one: the DAQ emulator hosts the simulated participant at its handle;
/// the experimenter connects it (the Study page's rig line shows it and its
/// loop delay), opens the session, starts; an emergency stop mid-trial
/// aborts the trial (its row kept) with the outputs held at zero, the
/// confirmed reset and Resume continue, the sitting completes on the
/// device and `session.json` records it.
#[test]
fn a_short_sitting_on_the_emulated_rig_from_the_study_page() {
    let dir = tempfile::tempdir().unwrap();
    let proto = dir.path().join("screens.toml");
    std::fs::write(&proto, PROTOCOL).unwrap();
    let seed = kilotouch_study::protocol::Protocol::load(&proto)
        .unwrap()
        .seeds
        .study;
    let emu = common::Emulator::spawn("daq", &["--participant", &format!("operator:{seed}")]);
    let out = dir.path().join("out");
    let mut h = common::study_page(&proto, "P01", &out, 1400.0);
    {
        let a = h.state_mut();
        // A fixed lead of one block (hil_sitting.rs: a loaded machine
        // stretches the round trips the automatic lead measures).
        a.rig_page_mut().rig_text = format!("{},lead=1{}", emu.rig(), common::TEST_HOST_TIMEOUT);
        a.connect();
    }
    assert!(
        step_until_every(&mut h, POLL, common::WAIT_S, |a| a
            .engine
            .as_ref()
            .is_some_and(|e| e.is_live() && e.health().is_some())),
        "the emulated rig did not come up"
    );
    h.step();
    h.step();
    // The rig choice: the connected rig with its loop delay, and the way
    // back to the simulation.
    assert!(h.query_by_label_contains(&emu.path).is_some());
    assert!(h.query_by_label_contains("loop delay").is_some());
    assert!(h.query_by_label("Use the simulated rig").is_some());
    open_and_start(&mut h);
    // Into the first trial, then the emergency stop.
    assert!(space_through_screens_until(
        &mut h,
        common::WAIT_S,
        |h| matches!(routine(h), Some(Routine::Trial(_)))
    ));
    until_engine_began_the_trial(&mut h);
    h.key_press(egui::Key::Escape);
    assert!(until_paused_between_trials(&mut h));
    h.step();
    h.step();
    assert!(h.query_by_label_contains("OUTPUTS HELD AT ZERO").is_some());
    assert!(
        step_until_every(&mut h, POLL, common::WAIT_S, |a| a.estop_latched()),
        "the engine's stop is latched"
    );
    // The aborted trial's row, committed by the sitting's worker.
    let trials = out.join(TRIALS_FILE);
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |_| {
        read_trials(&trials).is_ok_and(|t| t.rows.len() == 1)
    }));
    let rows = read_trials(&trials).unwrap().rows;
    assert_eq!(rows[0].reject_reason, "aborted");
    // The confirmed reset, then Resume.
    confirm_reset(&mut h);
    // The engine reports the reset with its next health report.
    assert!(step_until_every(&mut h, POLL, common::WAIT_S, |a| !a.any_estop_latched()));
    h.get_by_label("Resume").click();
    h.step();
    // The rest of the sitting on the device: every trial's row.
    assert!(
        space_through_screens_until(&mut h, common::WAIT_S, |h| h
            .state()
            .study
            .finished()
            .is_some()),
        "the sitting did not finish"
    );
    assert_eq!(h.state().study.finished(), Some(&FinishReason::StudyDone));
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(
        rows.len(),
        4,
        "the aborted trial (kept, not run again) and the protocol's three others"
    );
    assert_eq!(
        rows.iter().filter(|r| r.reject_reason != "aborted").count(),
        3
    );
    let session: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("session.json")).unwrap()).unwrap();
    let devices: Vec<_> = session["sittings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["device"]["spec"].as_str().unwrap_or_default().to_owned())
        .collect();
    assert!(devices.iter().all(|d| d.contains(&emu.path)), "{devices:?}");
}
