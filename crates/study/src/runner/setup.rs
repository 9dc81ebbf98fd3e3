//! [`TrialSetup`]: everything that defines one trial, drawn from its key.

use kilotouch_rig::coupling::HandMapping;

use crate::export::TaskKind;
use crate::operator::nominal_time_on_task_s;
use crate::participant::TrialBrief;
use crate::protocol::{Protocol, Task};
use crate::seeds::{STREAM_PARTICIPANT, STREAM_RIG, STREAM_TASK, TrialKey};
use crate::task::{Feedback, Scene, TaskParams, UM};

/// Everything that defines one trial (all randomness drawn from its key).
#[derive(Debug, Clone)]
pub struct TrialSetup {
    /// The trial.
    pub key: TrialKey,
    /// Feedback of its condition.
    pub feedback: Feedback,
    /// Task thresholds.
    pub params: TaskParams,
    /// The scene.
    pub scene: Scene,
    /// What the participant is told.
    pub brief: TrialBrief,
    /// The rig generator.
    pub rig_rng: rand_chacha::ChaCha20Rng,
}

impl TrialSetup {
    /// The setup of trial `key` of `protocol` on a station whose rest trap
    /// position is `start_m`: scene from the task stream, rig noise from
    /// the rig stream, the participant's stream in the brief.
    pub fn new(
        protocol: &Protocol,
        key: TrialKey,
        start_m: [f64; 2],
        mapping: HandMapping,
    ) -> Self {
        let seed = protocol.seeds.study;
        let mut task_rng = key.rng(seed, STREAM_TASK);
        let scene = Scene::draw(&protocol.task, start_m, &mut task_rng);
        let params = TaskParams::from_protocol(protocol);
        let retreat = match &protocol.task {
            Task::BlindNavigation(t) => t.retreat_distance_um * UM,
            Task::Circling(_) => 0.0,
        };
        Self {
            key,
            feedback: Feedback::of(key.condition, &protocol.task),
            params,
            scene,
            brief: TrialBrief {
                participant: key.participant,
                task: TaskKind::of(&protocol.task),
                mapping,
                start_trap_m: start_m,
                heading: scene.heading,
                retreat_distance_m: retreat,
                rng: key.rng(seed, STREAM_PARTICIPANT),
                time_on_task_s: nominal_time_on_task_s(protocol, key),
            },
            rig_rng: key.rng(seed, STREAM_RIG),
        }
    }
}
