//! A Study-page sitting while the Rig page streams to Lab Streaming Layer
//! (the `lsl` feature), read by a real LSL inlet: `sitting_start`, the
//! experimenter's note, every trial's start and end in the order of
//! `trials.csv`, `sitting_end`; and the sitting's entry in `lsl_clock.json`.

#![allow(clippy::unwrap_used)]

use kilotouch_testkit as common;

use common::{AppHarness, engine_reporting, open_session, step_until_every};
use egui_kittest::kittest::Queryable;
use kilotouch::gui::Page;
use kilotouch::lsl::{CLOCK_FILE, SittingClock, sys};
use kilotouch::session::{FinishReason, ParticipantKind, Speed};
use kilotouch_study::export::{TRIALS_FILE, read_trials};
use std::time::Duration;
use sys::Pullable;

/// The pause between UI steps while waiting.
const POLL: Duration = Duration::from_millis(5);

/// The Rig page's marker stream: study `explore`, no participant.
const EXPLORE_MARKERS: &str = "kilotouch-explore--markers";

/// Steps the app until `done`, or fails with `what`.
fn wait(h: &mut AppHarness, what: &str, done: impl FnMut(&kilotouch::gui::KilotouchApp) -> bool) {
    assert!(step_until_every(h, POLL, common::WAIT_S, done), "{what}");
}

#[test]
fn a_study_page_sitting_sends_its_start_notes_trials_and_end_to_lsl() {
    let dir = tempfile::tempdir().unwrap();
    let proto = dir.path().join("tiny.toml");
    std::fs::write(
        &proto,
        include_str!("data/tiny.toml").replace("practice_trials = 1", "practice_trials = 0"),
    )
    .unwrap();
    let out = dir.path().join("out");
    let mut h = common::study_page(&proto, "P01", &out, 900.0);
    {
        let f = &mut h.state_mut().study.form;
        f.kind = ParticipantKind::Simulated;
        f.speed = Speed::Fast;
    }
    wait(&mut h, "the engine did not start", engine_reporting);

    // Streaming on (Rig page), and an inlet on its marker stream.
    h.state_mut().page = Page::Rig;
    h.step();
    h.get_by_label("Stream to Lab Streaming Layer (1 kHz)")
        .click();
    wait(&mut h, "streaming did not start", |a| {
        a.rig_page().lsl().is_some()
    });
    let found = sys::resolve_bypred(&format!("source_id='{EXPLORE_MARKERS}'"), 1, 30.0).unwrap();
    assert!(!found.is_empty(), "the marker stream was not resolved");
    let inlet = sys::StreamInlet::new(&found[0], 360, 0, true).unwrap();
    inlet.open_stream(30.0).unwrap();
    wait(&mut h, "the inlet never connected", |a| {
        a.rig_page().lsl().is_some_and(|p| p.consumers().0)
    });

    // The sitting: opened, a note, started, run to its end.
    h.state_mut().page = Page::Study;
    h.step();
    open_session(&mut h);
    h.get_by_label("Note:").focus();
    h.step();
    h.get_by_label("Note:").type_text("lights dimmed");
    h.step();
    h.get_by_label("Add note").click();
    wait(&mut h, "the note was not journaled", |a| {
        a.study
            .model()
            .log()
            .iter()
            .any(|l| l == "note: lights dimmed")
    });
    h.get_by_label("Start").click();
    wait(&mut h, "the sitting did not end", |a| {
        a.study.finished().is_some()
    });
    assert_eq!(
        h.state().study.finished(),
        Some(&FinishReason::ParticipantDone("P01".into()))
    );
    assert_eq!(h.state().study.error(), None);

    // Every marker up to `sitting_end` (sent when the sitting ended).
    let mut markers: Vec<(f64, String)> = Vec::new();
    while !markers
        .last()
        .is_some_and(|(_, m)| m.starts_with("sitting_end"))
    {
        let (sample, t): (Vec<String>, f64) = inlet.pull_sample(30.0).unwrap();
        assert!(
            !sample.is_empty(),
            "no marker within 30 s; so far {markers:?}"
        );
        markers.push((t, sample[0].clone()));
    }
    let texts: Vec<&str> = markers
        .iter()
        .map(|(_, m)| m.as_str())
        .filter(|m| !m.starts_with("contact_") && *m != "escape")
        .collect();
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), 3);
    let mut want = vec![
        "sitting_start participant=P01 study=tiny".to_owned(),
        "note lights dimmed".to_owned(),
    ];
    for r in &rows {
        let fields = format!(
            "participant={} condition={} phase={} trial={}",
            r.participant, r.condition, r.phase, r.trial
        );
        want.push(format!("trial_start {fields}"));
        want.push(format!("trial_end {fields}"));
    }
    want.push("sitting_end participant=P01 study=tiny".to_owned());
    assert_eq!(texts, want);
    assert!(
        markers.windows(2).all(|w| w[0].0 <= w[1].0),
        "time stamps out of order: {markers:?}"
    );

    // The sitting's clocks, around its markers.
    let clock: Vec<SittingClock> =
        serde_json::from_slice(&std::fs::read(out.join(CLOCK_FILE)).unwrap()).unwrap();
    assert_eq!(clock.len(), 1);
    let c = &clock[0];
    assert_eq!(c.participant, "P01");
    assert!(c.start.lsl_s <= markers[0].0, "{c:?} {markers:?}");
    assert!(
        markers.last().unwrap().0 <= c.end.lsl_s,
        "{c:?} {markers:?}"
    );
    assert!(c.start.lsl_s < c.end.lsl_s, "{c:?}");
    assert!(c.end.unix_s > c.start.unix_s, "{c:?}");
}
