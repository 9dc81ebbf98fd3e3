//! The simulated operator: behaviour depends only on what the observation
//! carries, never on the condition label; structural effects of V/P/D.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_study::operator::{OperatorParams, SimCohort};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::runner::{NoRaw, RawSink, RunnerConfig, TrialEngine, TrialOutcome};
use kilotouch_study::seeds::{Phase, TrialKey};
use kilotouch_study::task::sim_station::SimStation;
use kilotouch_study::task::{Feedback, TaskMetrics};

fn protocol(task: &str) -> Protocol {
    let text = format!(
        "name = \"op\"\nparticipants = 2\nconditions = [\"P\", \"D\"]\ntrials_per_session = 1\n\
         [training]\npractice_trials = 0\n{task}\n[seeds]\nstudy = 99\n"
    );
    Protocol::from_toml_str(&text, "<test>").unwrap()
}

fn circling() -> Protocol {
    protocol("[task.circling]\ntimeout_s = 30.0\n")
}

fn engine() -> TrialEngine<SimStation> {
    let cfg = RunnerConfig {
        raw: None,
        ..Default::default()
    };
    TrialEngine::new(SimStation::new(&RigConfig::default()).unwrap(), cfg).unwrap()
}

/// Records every raw row (the full observable record of a trial).
#[derive(Default)]
struct Rows(Vec<Vec<f64>>);

impl RawSink for Rows {
    fn push(&mut self, row: &[f64]) -> Result<(), kilotouch_study::export::ExportError> {
        self.0.push(row.to_vec());
        Ok(())
    }
}

fn run(
    e: &mut TrialEngine<SimStation>,
    p: &Protocol,
    setup: &kilotouch_study::runner::TrialSetup,
) -> (TrialOutcome, Rows) {
    let mut cohort = SimCohort::new(p.seeds.study, 1000.0, 10_000.0);
    let mut rows = Rows::default();
    let o = e.run_trial(setup, &mut cohort, &mut rows).unwrap();
    (o, rows)
}

/// The participant never sees the condition: relabelling a trial while
/// delivering the same feedback (and the same seeds) reproduces it sample
/// for sample; changing only the feedback changes it.
#[test]
fn swapping_the_label_with_identical_feedback_changes_nothing() {
    let p = circling();
    let mut e = engine();
    let key_d = TrialKey::new(1, Condition::D, Phase::Test, 1);
    let setup_d = e.setup(&p, key_d);
    let (o_d, rows_d) = run(&mut e, &p, &setup_d);
    for label in [Condition::V, Condition::P] {
        let mut relabelled = setup_d.clone();
        relabelled.key.condition = label;
        let (o, rows) = run(&mut e, &p, &relabelled);
        assert_eq!(o.metrics, o_d.metrics);
        assert_eq!(o.trajectory, o_d.trajectory);
        assert!(rows.0 == rows_d.0, "raw signals differ under label {label}");
    }
    // Same label, other feedback: different behaviour (the test can fail).
    for fb in [
        Feedback {
            condition: Condition::V,
            vision: true,
        },
        Feedback {
            condition: Condition::P,
            vision: true,
        },
    ] {
        let mut other = setup_d.clone();
        other.feedback = fb;
        let (o, rows) = run(&mut e, &p, &other);
        assert!(rows.0 != rows_d.0);
        assert_ne!(o.trajectory, o_d.trajectory);
    }
}

/// A trial depends only on its setup: running others in between, or a
/// fresh engine, gives the same outcome.
#[test]
fn trials_are_history_free() {
    let p = circling();
    let key = TrialKey::new(0, Condition::P, Phase::Test, 1);
    let mut e1 = engine();
    let s = e1.setup(&p, key);
    let (a, _) = run(&mut e1, &p, &s);
    let other = e1.setup(&p, TrialKey::new(1, Condition::D, Phase::Test, 1));
    run(&mut e1, &p, &other);
    let (b, _) = run(&mut e1, &p, &s);
    let mut e2 = engine();
    let (c, _) = run(&mut e2, &p, &s);
    assert_eq!(a, b);
    assert_eq!(a, c);
}

/// Structural differences between conditions, which the model guarantees
/// whatever its parameters: V renders no force and no Haptuator drive, P no
/// Haptuator drive, D drives both channels; the operator's individual
/// traits depend on (study seed, participant) only.
#[test]
fn conditions_differ_only_in_the_delivered_feedback() {
    let p = circling();
    let mut e = engine();
    let mut by_condition = Vec::new();
    for c in Condition::ALL {
        let key = TrialKey::new(0, c, Phase::Test, 1);
        let s = e.setup(&p, key);
        assert_eq!(s.feedback, Feedback::of(c, &p.task));
        let (o, rows) = run(&mut e, &p, &s);
        let max_abs = |col: usize| rows.0.iter().map(|r| r[col].abs()).fold(0.0, f64::max);
        let (out_low, out_high, hand_force) = (max_abs(10), max_abs(11), max_abs(8));
        match c {
            Condition::V => {
                assert_eq!((out_low, out_high, hand_force), (0.0, 0.0, 0.0));
                let TaskMetrics::Circling(m) = o.metrics else {
                    panic!()
                };
                assert_eq!(m.force_mean_n, m.force_mean_n.map(|_| 0.0));
            }
            Condition::P => {
                assert!(out_low > 0.0 && hand_force > 0.0);
                assert_eq!(out_high, 0.0);
            }
            Condition::D => assert!(out_low > 0.0 && out_high > 0.0),
        }
        by_condition.push(o);
    }
    assert_eq!(
        OperatorParams::for_participant(99, 3),
        OperatorParams::for_participant(99, 3)
    );
    assert_ne!(
        OperatorParams::for_participant(99, 3),
        OperatorParams::for_participant(99, 4)
    );
}

/// Blind navigation: no camera frame ever reaches the participant, and with
/// haptic feedback the simulated operator finds the obstacle and leaves it.
#[test]
fn blind_task_has_no_vision_and_is_solvable_by_touch() {
    let p = protocol("[task.blind_navigation]\nstart_distance_um = 6.0\ntimeout_s = 40.0\n");
    let mut e = engine();
    let mut collided = 0;
    for t in 1..=4 {
        let key = TrialKey::new(0, Condition::D, Phase::Test, t);
        let s = e.setup(&p, key);
        assert!(!s.feedback.vision);
        let mut seen = FrameSpy::default();
        e.run_trial(&s, &mut seen, &mut NoRaw).unwrap();
        assert_eq!(seen.frames, 0, "a frame reached the blind participant");
        let (o, _) = run(&mut e, &p, &s);
        let TaskMetrics::Blind(m) = o.metrics else {
            panic!()
        };
        collided += usize::from(m.time_to_collision_s.is_some());
        // The trajectory starts at the start position (Fig. 10).
        assert_eq!(o.trajectory[0], s.scene.start_m);
    }
    assert!(
        collided >= 3,
        "only {collided} of 4 trials found the obstacle"
    );
}

#[derive(Default)]
struct FrameSpy {
    frames: usize,
}

impl kilotouch_study::participant::Participant for FrameSpy {
    fn act(&mut self, obs: &kilotouch_study::participant::Observation<'_>) -> [f64; 2] {
        self.frames += usize::from(obs.frame.is_some());
        obs.handle_m
    }
}
