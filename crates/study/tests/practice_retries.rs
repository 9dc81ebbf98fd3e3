//! Extra practice trials (`training.practice_retries`): each unsuccessful
//! practice row earns one more practice trial of its condition while the
//! condition's extra trials last; the plan grows at the commit, in place
//! (before the next condition's practice), and a resumed folder rebuilds the
//! same plan from its rows.
//!
//! Reference: an independent count per (participant, condition) from the
//! fake runner's outcomes alone (`common::outcome`, a pure function of the
//! trial key): run trial 1, 2, …; every failure adds one trial to the block
//! while fewer than `practice_retries` were added.

#![allow(clippy::unwrap_used)]

use crate::common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{Stop, outcome, run_trial};
use kilotouch_study::export::{StudyStore, TRIALS_FILE, read_session, read_trials};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::seeds::{Phase, TrialKey};

const SEED: u64 = 2016;
const PARTICIPANTS: u32 = 4;
const PRACTICE: u32 = 3;
const RETRIES: u32 = 2;

fn protocol(retries: u32) -> Protocol {
    let mut p = common::protocol(PARTICIPANTS, 2, PRACTICE, SEED);
    p.training.practice_retries = retries;
    p.validate().expect("test setup");
    p
}

fn open(dir: &Path, p: &Protocol) -> StudyStore {
    StudyStore::open(dir, p, &common::meta()).expect("test setup")
}

/// The independent count: practice trials of one block.
fn expected_block(participant: u32, c: Condition) -> u32 {
    let (mut t, mut added, mut last) = (1, 0, PRACTICE);
    while t <= last {
        let key = TrialKey::new(participant, c, Phase::Practice, t);
        if !outcome(SEED, key).success && added < RETRIES {
            added += 1;
            last += 1;
        }
        t += 1;
    }
    last
}

/// Practice rows per (participant, condition) in `trials.csv`, in file
/// order of their trial numbers.
fn practice_blocks(dir: &Path) -> BTreeMap<(String, Condition), Vec<u32>> {
    let mut out: BTreeMap<_, Vec<u32>> = BTreeMap::new();
    for r in read_trials(&dir.join(TRIALS_FILE)).unwrap().rows {
        if r.phase == Phase::Practice {
            out.entry((r.participant.clone(), r.condition))
                .or_default()
                .push(r.trial);
        }
    }
    out
}

#[test]
fn unsuccessful_practice_trials_earn_extra_ones_up_to_the_bound_and_survive_a_resume() {
    let dir = tempfile::tempdir().unwrap();
    let p = protocol(RETRIES);
    let mut store = open(dir.path(), &p);
    let static_len = store.plan().len();
    assert_eq!(
        static_len as u32,
        PARTICIPANTS * 3 * (2 + PRACTICE),
        "the plan starts with the protocol's trials"
    );
    // Run until a participant earned extra trials, crash mid-trial in the
    // next participant's first one and reopen: the extra trials planned so
    // far come back from the rows.
    let (mut n, mut grew) = (0, None);
    while let Some(next) = store.next_pending() {
        if grew.is_some_and(|p| next.key.participant > p) {
            break;
        }
        if grew.is_none() && store.plan().len() > static_len {
            grew = Some(next.key.participant);
        }
        let key = next.key;
        run_trial(&mut store, key, Stop::Complete, 0);
        n += 1;
    }
    let before: Vec<_> = store.plan().iter().map(|t| (t.key, t.seed)).collect();
    assert!(
        before.len() > static_len,
        "unsuccessful practice earned extras before the crash"
    );
    let next = store.next_pending().unwrap().key;
    run_trial(&mut store, next, Stop::MidRaw, 0);
    drop(store);
    let mut store = open(dir.path(), &p);
    let after: Vec<_> = store.plan().iter().map(|t| (t.key, t.seed)).collect();
    assert_eq!(
        after, before,
        "the resumed plan is the plan before the crash"
    );
    assert_eq!(store.recovery().completed, n);
    assert_eq!(store.recovery().pending, after.len() - n);
    common::run_pending(&mut store, 0);
    let planned = store.plan().len();
    store.close().unwrap();

    // Every block as the independent count says, numbered 1, 2, … in the
    // order run; the extra trials follow their block at once.
    let blocks = practice_blocks(dir.path());
    let mut extra_total = 0;
    for pi in 0..PARTICIPANTS {
        for c in [Condition::V, Condition::P, Condition::D] {
            let id = format!("P{:02}", pi + 1);
            let got = &blocks[&(id.clone(), c)];
            let want = expected_block(pi, c);
            assert_eq!(
                got,
                &(1..=want).collect::<Vec<_>>(),
                "{id} {c}: practice trials"
            );
            assert!(want <= PRACTICE + RETRIES);
            extra_total += want - PRACTICE;
        }
    }
    assert!(
        extra_total > 0,
        "the fake runner's 25 % failures earn extras"
    );
    assert_eq!(
        planned as u32,
        PARTICIPANTS * 3 * (2 + PRACTICE) + extra_total
    );
    let rows = read_trials(&dir.path().join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), planned);
    // Sitting order: a block's extra trials come before the next block.
    let order: Vec<_> = rows
        .iter()
        .map(|r| (r.participant.clone(), r.phase, r.condition))
        .collect();
    let mut seen_blocks = Vec::new();
    for b in &order {
        if seen_blocks.last() != Some(b) {
            assert!(!seen_blocks.contains(b), "block {b:?} split in trials.csv");
            seen_blocks.push(b.clone());
        }
    }
    let info = read_session(&dir.path().join(kilotouch_study::export::SESSION_FILE)).unwrap();
    assert_eq!(info.progress.planned, planned as u64);
    assert_eq!(info.progress.completed, planned as u64);
    // A complete folder reopens complete: nothing pending.
    let store = open(dir.path(), &p);
    assert_eq!(store.plan().len(), planned);
    assert!(store.next_pending().is_none());
}

#[test]
fn without_extra_trials_the_plan_stays_the_protocols_and_its_text_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let p = protocol(0);
    assert!(
        !p.to_toml_string().unwrap().contains("practice_retries"),
        "the default leaves the protocol's recorded text (and identity) as it was"
    );
    assert!(
        protocol(RETRIES)
            .to_toml_string()
            .unwrap()
            .contains("practice_retries = 2")
    );
    let mut store = open(dir.path(), &p);
    let planned = store.plan().len();
    common::run_pending(&mut store, 0);
    assert_eq!(store.plan().len(), planned);
    drop(store);
    for (block, trials) in practice_blocks(dir.path()) {
        assert_eq!(trials, (1..=PRACTICE).collect::<Vec<_>>(), "{block:?}");
    }
}

#[test]
fn an_absurd_bound_is_refused_naming_the_field() {
    let text = format!(
        "name = \"x\"\nparticipants = 2\nconditions = [\"V\"]\ntrials_per_session = 1\n\
         [training]\npractice_trials = 1\npractice_retries = {}\n[task.circling]\n",
        kilotouch_study::protocol::MAX_PRACTICE_TRIALS + 1
    );
    let e = Protocol::from_toml_str(&text, "x.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("training.practice_retries"), "{e}");
}

/// `study simulate --resume` on a folder cut after an extra practice trial
/// was earned (and one more was earned by the last row kept): the resumed
/// run rebuilds the plan from the rows, runs the pending extra first and
/// writes the uninterrupted run's rows in the same order.
#[test]
fn a_resumed_simulation_writes_the_uninterrupted_rows_with_their_extras() {
    use kilotouch_study::export::SimulationInfo;
    use kilotouch_study::runner::RunnerConfig;
    use kilotouch_study::simulate::{SimulateOptions, sim_meta, simulate};

    // A 1 s time-out: every practice trial is unsuccessful and earns its
    // one extra.
    let p = Protocol::from_toml_str(
        "name = \"retry\"\nparticipants = 2\nconditions = [\"P\", \"D\"]\n\
         trials_per_session = 1\n[training]\npractice_trials = 1\npractice_retries = 1\n\
         [task.circling]\ntimeout_s = 1.0\n[seeds]\nstudy = 4\n",
        "retry.toml",
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let opts = |out: &Path, resume: bool| SimulateOptions {
        runner: RunnerConfig {
            raw: None,
            ..RunnerConfig::default()
        },
        threads: 2,
        resume,
        ..SimulateOptions::new(p.clone(), out)
    };
    let full = dir.path().join("full");
    simulate(&opts(&full, false), &mut |_, _| {}).unwrap();
    let want = read_trials(&full.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(want.len(), 12, "2 × 2 × (1 practice + 1 extra + 1 test)");

    // The first three rows: P01's first practice trial, its extra, and the
    // second condition's practice trial (whose extra is pending).
    let cut = dir.path().join("cut");
    let o = opts(&cut, false);
    let (meta, _) = sim_meta(&o.rig, None, false, None).unwrap();
    let mut store = StudyStore::open(&cut, &p, &meta).unwrap();
    store
        .set_simulation(SimulationInfo {
            fidelity: o.fidelity,
            shard: None,
        })
        .unwrap();
    for r in &want[..3] {
        let key = store.next_pending().unwrap().key;
        assert_eq!(key, r.key(0), "plan order");
        let t = store.begin_trial(key, r.started_utc).unwrap();
        store.commit_trial(t, r).unwrap();
    }
    assert_eq!(store.plan().len(), 10, "two extras planned so far");
    drop(store);
    // The size estimate's trials: the 7 pending ones (with D's earned
    // extra), and at most P02's two extras more.
    let pending = kilotouch_study::size::pending_trials(&p, &cut, None).unwrap();
    assert_eq!(pending.len(), 7);
    let most = kilotouch_study::size::pending_trials_at_most(&p, &cut, None).unwrap();
    assert_eq!(most.len(), 9, "no extra counted twice");
    assert_eq!(3 + most.len(), want.len(), "the bound is reached here");

    let report = simulate(&opts(&cut, true), &mut |_, _| {}).unwrap();
    assert_eq!(report.already_completed, 3);
    assert_eq!((report.ran, report.planned), (9, 12));
    let got = read_trials(&cut.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(&want) {
        let mut g = g.clone();
        g.started_utc = w.started_utc;
        assert_eq!(&g, w);
    }
}
