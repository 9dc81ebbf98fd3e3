//! The session runner: states, pause/resume/notes/abort in the journal,
//! every trial stored before the next begins, and crash/resume producing
//! exactly the rows of an uninterrupted run (also across the parallel
//! `simulate` path and any thread count).

#![allow(clippy::unwrap_used)]

use std::path::Path;

use kilotouch_rig::config::RigConfig;
use kilotouch_study::export::{StudyMeta, StudyStore, TRIALS_FILE, TrialRow, read_trials};
use kilotouch_study::journal::{JOURNAL_FILE, Record, read_journal};
use kilotouch_study::operator::SimCohort;
use kilotouch_study::protocol::Protocol;
use kilotouch_study::rawsig::{Dtype, read_npy, read_sidecar, sidecar_path};
use kilotouch_study::runner::{RAW_CHANNELS, RunnerConfig, RunnerState, SessionRunner};
use kilotouch_study::seeds::Phase;
use kilotouch_study::simulate::{SimulateOptions, simulate};
use kilotouch_study::task::sim_station::SimStation;

use crate::common::{protocol_from, sim_runner};

fn protocol() -> Protocol {
    protocol_from(
        "name = \"runner-test\"\nparticipants = 2\nconditions = [\"V\", \"D\"]\n\
         trials_per_session = 2\n[training]\npractice_trials = 1\n\
         [task.circling]\ntimeout_s = 25.0\n[seeds]\nstudy = 4242\n",
    )
}

fn config(raw: bool) -> RunnerConfig {
    RunnerConfig {
        raw: raw.then_some(Dtype::F32),
        ..Default::default()
    }
}

fn runner(dir: &Path, raw: bool) -> SessionRunner<SimStation> {
    let store = StudyStore::open(dir, &protocol(), &StudyMeta::new("sim-test")).unwrap();
    sim_runner(store, config(raw))
}

fn cohort() -> SimCohort {
    SimCohort::new(protocol().seeds.study, 1000.0, 10_000.0)
}

/// Rows without the wall-clock columns (start time and the CRC covering it).
fn comparable(dir: &Path) -> Vec<TrialRow> {
    read_trials(&dir.join(TRIALS_FILE))
        .unwrap()
        .rows
        .into_iter()
        .map(|mut r| {
            r.started_utc = kilotouch_study::export::UtcTime::from_unix_millis(0);
            r
        })
        .collect()
}

#[test]
fn runs_a_session_through_its_states_and_stores_every_trial() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let mut r = runner(&dir, true);
    let mut who = cohort();
    assert_eq!(r.state(), RunnerState::Idle);
    // Nothing runs before start.
    assert_eq!(r.advance(&mut who, 100).unwrap().samples, 0);
    let ev = r.start(&mut who).unwrap();
    let first = ev.started.unwrap();
    assert_eq!(first.phase, Phase::Practice);
    assert_eq!(r.state(), RunnerState::Training(first));
    // Steppable in small blocks; no commit happens inside advance.
    let ev = r.advance(&mut who, 250).unwrap();
    assert_eq!(ev.samples, 250);
    assert_eq!(r.store().unwrap().completed_count(), 0);
    // Pause: advance does nothing; resume continues the same trial.
    r.pause("participant asked for a break").unwrap();
    assert_eq!(r.state(), RunnerState::Paused(Some(first)));
    assert_eq!(r.advance(&mut who, 100).unwrap().samples, 0);
    r.note("fixed the chair height").unwrap();
    r.resume(&mut who).unwrap();
    assert_eq!(r.state(), RunnerState::Training(first));
    // Run the practice trial to its end, then service commits it and
    // begins the next trial.
    let mut ended = None;
    while ended.is_none() {
        let ev = r.advance(&mut who, 1000).unwrap();
        if ev.needs_service {
            ended = ev.ended;
        }
    }
    assert_eq!(ended.unwrap().0, first);
    let ev = r.service(&mut who).unwrap();
    let row = ev.committed.unwrap();
    assert_eq!(row.phase, Phase::Practice);
    assert_eq!(row.session_index, 0);
    let second = ev.started.unwrap();
    assert_ne!(second, first);
    // On disk (fsynced) before the next trial began.
    assert_eq!(read_trials(&dir.join(TRIALS_FILE)).unwrap().rows.len(), 1);
    // Abort the second trial: it is stored as rejected, `aborted`.
    r.advance(&mut who, 500).unwrap();
    let ev = r.abort_trial().unwrap();
    assert!(ev.needs_service);
    let ev = r.service(&mut who).unwrap();
    let aborted = ev.committed.unwrap();
    assert!(!aborted.success);
    assert_eq!(aborted.reject_reason, "aborted");
    assert!((aborted.time_s.unwrap() - 0.05).abs() < 1e-9);
    // Run the rest.
    let mut calls = Vec::new();
    r.run_to_end(&mut who, 4096, &mut |d, t| calls.push((d, t)))
        .unwrap();
    assert_eq!(r.state(), RunnerState::Done);
    let planned = 2 * (2 + 2 * 2);
    assert_eq!(calls.last(), Some(&(planned, planned)));
    let rows = read_trials(&dir.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), planned);
    assert_eq!(
        rows.iter().filter(|r| r.phase == Phase::Practice).count(),
        4
    );
    for row in &rows {
        assert!(row.escaped.is_some() && row.contact_fraction.is_some());
        assert!(row.time_s.unwrap() > 0.0 && row.time_s.unwrap() <= 25.0 + 1e-9);
        let npy = dir.join(&row.raw_file);
        let a = read_npy(&npy).unwrap();
        assert_eq!(a.cols, RAW_CHANNELS);
        // One raw row per sample up to the trial's end; when the ending
        // sample carries its own event (an escape), the end code follows on
        // one more sample.
        let n = a.rows as usize;
        let ended_on_event = n >= 2 && {
            let e = a.row(n - 2)[16];
            a.row(n - 1)[16] == 9.0 && e != 0.0 && e != 5.0
        };
        let samples = a.rows as f64 - if ended_on_event { 1.0 } else { 0.0 };
        assert!((samples / 10_000.0 - row.time_s.unwrap()).abs() < 1e-9);
        if row.reject_reason == "escaped" {
            assert!(ended_on_event, "an escape ending the trial keeps code 3");
            assert_eq!(a.row(n - 2)[16], 3.0);
        }
        let side = read_sidecar(&sidecar_path(&npy)).unwrap();
        assert_eq!(side.channels.len(), RAW_CHANNELS);
        assert_eq!(side.channels[17].name, "hand_x");
        // The end sample carries the end event (an abort happens between
        // samples, so the aborted trial's last row has none).
        let last_event = a.row(a.rows as usize - 1)[16];
        if row.reject_reason == "aborted" {
            assert_ne!(last_event, 9.0);
        } else {
            assert_eq!(last_event, 9.0, "end event code");
        }
    }
    assert!(dir.join("cells_long.csv").is_file() && dir.join("cells_wide.csv").is_file());
    let j = read_journal(&dir.join(JOURNAL_FILE)).unwrap();
    let has = |f: &dyn Fn(&Record) -> bool| j.entries.iter().any(|e| f(&e.record));
    assert!(has(
        &|r| matches!(r, Record::Paused { reason } if reason.contains("break"))
    ));
    assert!(has(&|r| matches!(r, Record::Resumed)));
    assert!(has(
        &|r| matches!(r, Record::Note { text } if text.contains("chair"))
    ));
    assert!(has(&|r| matches!(r, Record::SessionDone { .. })));
    // Invalid transitions are refused.
    assert!(r.pause("x").is_err());
    assert!(r.abort_trial().is_err());
}

/// Dropping a runner in the middle of a trial (a crash) and resuming with a
/// new one gives exactly the rows of an uninterrupted run; the parallel
/// `simulate` path gives them too, for any thread count.
#[test]
fn killed_session_resumes_to_the_uninterrupted_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let full = tmp.path().join("full");
    let mut r = runner(&full, false);
    r.run_to_end(&mut cohort(), 10_000, &mut |_, _| {}).unwrap();
    let reference = comparable(&full);
    assert_eq!(reference.len(), 12);

    let cut = tmp.path().join("cut");
    let mut r = runner(&cut, false);
    let mut who = cohort();
    r.start(&mut who).unwrap();
    let mut committed = 0;
    while committed < 5 {
        let ev = r.advance(&mut who, 3000).unwrap();
        if ev.needs_service && r.service(&mut who).unwrap().committed.is_some() {
            committed += 1;
        }
    }
    r.advance(&mut who, 7777).unwrap(); // in the middle of trial 6
    drop(r); // crash: no close, trial 6 open in the journal
    let store = StudyStore::open(&cut, &protocol(), &StudyMeta::new("sim-test")).unwrap();
    assert_eq!(store.recovery().interrupted.len(), 1);
    assert_eq!(store.completed_count(), 5);
    let mut r = sim_runner(store, config(false));
    r.run_to_end(&mut cohort(), 10_000, &mut |_, _| {}).unwrap();
    assert_eq!(comparable(&cut), reference);

    for threads in [1, 3] {
        let out = tmp.path().join(format!("sim{threads}"));
        let opts = SimulateOptions {
            runner: config(false),
            threads,
            fidelity: kilotouch_study::fidelity::Fidelity::Full,
            ..SimulateOptions::new(protocol(), out.clone())
        };
        let rep = simulate(&opts, &mut |_, _| {}).unwrap();
        assert_eq!(rep.test_rows, 8);
        assert_eq!(rep.practice_rows, 4);
        assert_eq!(comparable(&out), reference, "threads = {threads}");
        // A second run without --resume is refused, with --resume it finds
        // nothing to do.
        assert!(simulate(&opts, &mut |_, _| {}).is_err());
        let rep = simulate(
            &SimulateOptions {
                resume: true,
                ..opts.clone()
            },
            &mut |_, _| {},
        )
        .unwrap();
        assert_eq!(rep.ran, 0);
    }
}

/// An engine on the simulated `rig` with the runner `cfg`, and the set-up
/// of participant 0's first V test trial of [`protocol`].
fn first_vision_trial(
    rig: &RigConfig,
    cfg: RunnerConfig,
) -> (
    kilotouch_study::runner::TrialEngine<SimStation>,
    kilotouch_study::runner::TrialSetup,
) {
    let engine =
        kilotouch_study::runner::TrialEngine::new(SimStation::new(rig).unwrap(), cfg).unwrap();
    let key = kilotouch_study::seeds::TrialKey {
        participant: 0,
        phase: Phase::Test,
        condition: kilotouch_study::protocol::Condition::V,
        trial: 1,
    };
    let setup = engine.setup(&protocol(), key);
    (engine, setup)
}

/// The participant sees, at every sample, the newest camera frame whose
/// capture is at least the camera latency old (frames every 1/fps): the
/// runner's frame queue delivers each frame on time, not earlier, and never
/// holds back a newer one.
#[test]
fn the_displayed_frame_is_the_newest_one_past_the_camera_latency() {
    use kilotouch_study::participant::{Observation, Participant};
    use kilotouch_study::runner::NoRaw;

    /// Holds the hand still and records what it was shown.
    struct Watcher(Vec<(f64, Option<(u64, f64)>)>);
    impl Participant for Watcher {
        fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
            self.0
                .push((obs.t_s, obs.frame.map(|f| (f.seq, f.captured_s))));
            obs.handle_m
        }
    }
    let (fps, latency) = (25.0, 0.013);
    let cfg = RunnerConfig {
        act_every: 1,
        raw: None,
        trajectory_every: 100,
    };
    let mut rig = RigConfig::default();
    rig.camera.frame_rate_hz = fps;
    rig.camera.latency_s = latency;
    let (mut engine, setup) = first_vision_trial(&rig, cfg);
    let mut w = Watcher(Vec::new());
    // The still hand never completes the task: the trial runs to its
    // 25 s time-out, ≈ 625 frames.
    engine.run_trial(&setup, &mut w, &mut NoRaw).unwrap();
    let dt = 1.0 / engine.sample_rate_hz();
    let period = 1.0 / fps;
    let mut shown: Option<u64> = None;
    for &(t, f) in &w.0 {
        // Frames are captured on the period grid (the first one a period
        // after the start). The one shown is the newest with capture +
        // latency ≤ t, with two samples of slack: the participant acts
        // before the sample's own capture and display, and t is the time
        // at the end of the sample.
        match f {
            None => assert!(t < period + latency + 2.0 * dt, "no frame shown at {t} s"),
            Some((seq, cap)) => {
                let k = cap / period;
                assert!(
                    (k - k.round()).abs() < 1e-6,
                    "frame {seq} captured at {cap} s"
                );
                assert!(
                    cap + latency <= t + 2.0 * dt,
                    "frame {seq} shown early at {t} s"
                );
                assert!(
                    cap + period + latency > t - 2.0 * dt,
                    "frame {seq} still shown at {t} s"
                );
                if let Some(prev) = shown {
                    assert!(
                        seq == prev || seq == prev + 1,
                        "frame {prev} → {seq} at {t} s"
                    );
                }
                shown = Some(seq);
            }
        }
    }
    let shown = shown.unwrap_or(0);
    assert!(shown > 600, "only {shown} frames shown");
}

/// With an exposure time, a frame shows the bead and trap positions
/// averaged over the exposure's samples ending at its capture (the raw
/// record's positions, sample by sample), not the positions at the
/// capture; a camera setting out of range is refused naming the key.
#[test]
fn a_frame_shows_the_mean_positions_over_its_exposure() {
    use kilotouch_study::export::ExportError;
    use kilotouch_study::participant::{Observation, Participant, VisualFrame};
    use kilotouch_study::runner::RawSink;

    /// Moves the hand steadily (so the bead moves within an exposure) and
    /// records every frame it is shown.
    struct Sweeper(Vec<VisualFrame>, f64);
    impl Participant for Sweeper {
        fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
            if let Some(f) = obs.frame
                && self.0.last().is_none_or(|g| g.seq != f.seq)
            {
                self.0.push(f);
            }
            // 2 mm/s at the hand (0.8 µm/s of trap), from rest.
            self.1 += 2e-6;
            [self.1, 0.0]
        }
    }
    #[derive(Default)]
    struct Rows(Vec<[f64; 6]>);
    impl RawSink for Rows {
        fn push(&mut self, row: &[f64]) -> Result<(), ExportError> {
            self.0
                .push([row[0], row[1], row[2], row[3], row[4], row[5]]);
            Ok(())
        }
    }
    let cfg = RunnerConfig {
        act_every: 10,
        raw: Some(Dtype::F64),
        trajectory_every: 100,
    };
    let mut rig = RigConfig::default();
    rig.camera.exposure_s = 0.02; // 200 samples at 10 kHz, half a frame
    let (mut engine, setup) = first_vision_trial(&rig, cfg);
    let (mut who, mut rows) = (Sweeper(Vec::new(), 0.0), Rows::default());
    engine.run_trial(&setup, &mut who, &mut rows).unwrap();
    let fs = engine.sample_rate_hz();
    let n = 200;
    let mut checked = 0;
    let mut blurred = 0;
    for f in &who.0 {
        // Row k − 1 is sample k (the first sample is k = 1).
        let k = (f.captured_s * fs).round() as usize;
        let window = &rows.0[k.saturating_sub(n)..k];
        let mean = |c: usize| window.iter().map(|r| r[c]).sum::<f64>() / window.len() as f64;
        let (bead, trap) = ([mean(4), mean(5)], [mean(2), mean(3)]);
        for (got, want) in [(f.bead_m, bead), (f.trap_m, trap)] {
            for i in 0..2 {
                assert!(
                    (got[i] - want[i]).abs() <= 1e-12 * (1.0 + want[i].abs()) + 1e-18,
                    "frame {}: {got:?} vs mean {want:?}",
                    f.seq
                );
            }
        }
        let last = rows.0[k - 1];
        blurred += usize::from((f.trap_m[0] - last[2]).abs() > 1e-12);
        checked += 1;
    }
    assert!(checked > 20, "{checked} frames");
    assert!(
        blurred > checked / 2,
        "the moving trap is blurred in {blurred} of {checked}"
    );

    let mut bad = RigConfig::default();
    bad.camera.exposure_s = 0.05;
    match SimStation::new(&bad) {
        Err(e) => assert!(e.to_string().contains("camera.exposure_s"), "{e}"),
        Ok(_) => panic!("an exposure longer than a frame was accepted"),
    }
}
