//! The runner's hold between trials (the participant's screens) and the
//! clean end of a sitting: a held runner waits in `Waiting(next)` after
//! start, after every committed trial and after a pause between trials, and
//! writes nothing while it waits; `proceed` begins exactly the held trial;
//! `end_sitting` journals a trial in progress as aborted and closes the
//! sitting, so the next opening reports no unclosed sitting and runs that
//! trial again.

#![allow(clippy::unwrap_used)]

use kilotouch_study::export::{StudyMeta, StudyStore, TRIALS_FILE, read_trials};
use kilotouch_study::journal::{JOURNAL_FILE, Record, read_journal};
use kilotouch_study::operator::SimCohort;
use kilotouch_study::protocol::Protocol;
use kilotouch_study::runner::{RunnerConfig, RunnerState, SessionRunner};
use kilotouch_study::task::sim_station::SimStation;

use crate::common::{protocol_from, sim_runner};

fn protocol() -> Protocol {
    protocol_from(
        "name = \"hold-test\"\nparticipants = 1\nconditions = [\"V\", \"D\"]\n\
         trials_per_session = 2\n[training]\npractice_trials = 0\n\
         [task.circling]\ntimeout_s = 0.3\n[seeds]\nstudy = 7\n",
    )
}

fn runner(dir: &std::path::Path) -> SessionRunner<SimStation> {
    let store = StudyStore::open(dir, &protocol(), &StudyMeta::new("hold-test")).unwrap();
    sim_runner(store, RunnerConfig::default())
}

fn journal_len(dir: &std::path::Path) -> usize {
    read_journal(&dir.join(JOURNAL_FILE)).unwrap().entries.len()
}

#[test]
fn a_held_runner_waits_for_proceed_between_trials() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut r = runner(&dir);
    r.set_hold(true);
    let mut who = SimCohort::new(7, 1000.0, 10_000.0);
    let ev = r.start(&mut who).unwrap();
    assert!(ev.started.is_none());
    let RunnerState::Waiting(first) = r.state() else {
        panic!("{:?}", r.state())
    };
    // Waiting runs nothing and writes nothing.
    let n = journal_len(&dir);
    assert_eq!(r.advance(&mut who, 1000).unwrap().samples, 0);
    assert_eq!(journal_len(&dir), n);
    let ev = r.proceed(&mut who).unwrap();
    assert_eq!(ev.started, Some(first));
    assert_eq!(r.state(), RunnerState::Trial(first));
    assert!(
        r.proceed(&mut who).is_err(),
        "nothing waits while a trial runs"
    );
    // Run the trial out: the row is committed, then the runner waits again.
    loop {
        let ev = r.advance(&mut who, 500).unwrap();
        if ev.needs_service {
            let sev = r.service(&mut who).unwrap();
            assert!(sev.committed.is_some());
            assert!(sev.started.is_none());
            break;
        }
    }
    let RunnerState::Waiting(second) = r.state() else {
        panic!("{:?}", r.state())
    };
    assert_ne!(second, first);
    // A pause while waiting is journaled; resuming waits again.
    r.pause("break").unwrap();
    assert_eq!(r.state(), RunnerState::Paused(None));
    r.resume(&mut who).unwrap();
    assert_eq!(r.state(), RunnerState::Waiting(second));
    // The held trial begins on proceed; stop the sitting in the middle.
    r.proceed(&mut who).unwrap();
    r.advance(&mut who, 100).unwrap();
    r.end_sitting("sitting stopped by the experimenter")
        .unwrap();
    assert!(r.store().is_none());
    let entries = read_journal(&dir.join(JOURNAL_FILE)).unwrap().entries;
    assert!(matches!(
        entries.last().unwrap().record,
        Record::SessionDone { completed: 1, .. }
    ));
    assert!(entries.iter().any(|e| matches!(
        &e.record,
        Record::TrialAborted { trial, .. } if *trial == second
    )));
    // Reopening: a clean previous sitting, the stopped trial next.
    drop(r);
    let store = StudyStore::open_existing(&dir, &StudyMeta::new("hold-test")).unwrap();
    assert!(!store.recovery().previous_sitting_unclosed);
    assert!(store.recovery().interrupted.is_empty());
    assert_eq!(store.next_pending().unwrap().key, second);
    assert_eq!(read_trials(&dir.join(TRIALS_FILE)).unwrap().rows.len(), 1);
}

#[test]
fn an_unheld_runner_goes_straight_on() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut r = runner(&dir);
    let mut who = SimCohort::new(7, 1000.0, 10_000.0);
    assert!(r.start(&mut who).unwrap().started.is_some());
    r.run_to_end(&mut who, 1000, &mut |_, _| {}).unwrap();
    assert_eq!(r.state(), RunnerState::Done);
    assert_eq!(read_trials(&dir.join(TRIALS_FILE)).unwrap().rows.len(), 4);
}
