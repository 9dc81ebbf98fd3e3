//! The study's simulated participant at a device's handle: hardware in the
//! loop on one machine (`kilotouch emulate daq --pty --participant
//! operator:SEED`). The emulated DAQ hosts this [`HandAgent`]; the host's
//! sitting runs its trials on the live rig as it would with a person, and
//! tells the device what a person would be told and shown (the host's
//! information frames, [`HostInfo`]).
//!
//! The participant is the same seeded operator as `kilotouch study
//! simulate` ([`SimCohort`], the participant's traits from the study seed,
//! each trial's random stream from its key) under the same control period
//! ([`ControlPeriod`]): every `act_every` samples it is asked for a hand
//! target with what it felt (the Pantograph force the device applied, the
//! fingertip acceleration it sensed, the handle) and saw (the camera frame
//! the host's screen shows, as the device last heard of it — the link's
//! delay adds to the camera's latency). Between trials the hand rests where
//! it is. What differs from `study simulate` is what the live loop adds
//! (the link's and the block's delay, and the device's own noise) and the
//! time on task that drives the attention lapses ([`crate::lapse`]): here
//! the time the block's trials really took, there a nominal one.

use kilotouch_rig::device::{
    ActuatorFrame, HandAgent, HostInfo, PhaseCode, SensorFrame, TaskCode, TrialInfo,
};

use crate::export::TaskKind;
use crate::operator::SimCohort;
use crate::participant::{ControlPeriod, Participant, TrialBrief, VisualFrame};
use crate::protocol::Condition;
use crate::seeds::{Phase, STREAM_PARTICIPANT, TrialKey};

/// The simulated participant at a device's handle (module docs).
#[derive(Debug)]
pub struct DeviceParticipant {
    cohort: SimCohort,
    study_seed: u64,
    control: ControlPeriod,
    act_every: u64,
    dt_s: f64,
    active: bool,
    vision: bool,
    k: u64,
    frame: Option<VisualFrame>,
    /// The block of the latest trial (participant, phase, condition) and
    /// the time spent in its trials so far, s: the time on task.
    block: Option<(u32, Phase, Condition)>,
    block_trials_s: f64,
}

impl DeviceParticipant {
    /// The participants of study seed `study_seed` on a device at
    /// `sample_rate_hz`, asked every `act_every` samples (the runner's
    /// default is 10: 1 kHz at 10 kHz).
    pub fn new(study_seed: u64, sample_rate_hz: f64, act_every: usize) -> Self {
        let every = act_every.max(1);
        Self {
            cohort: SimCohort::new(study_seed, sample_rate_hz / every as f64, sample_rate_hz),
            study_seed,
            control: ControlPeriod::new(every),
            act_every: every as u64,
            dt_s: 1.0 / sample_rate_hz,
            active: false,
            vision: true,
            k: 0,
            frame: None,
            block: None,
            block_trials_s: 0.0,
        }
    }

    /// Is a trial running (the participant acting)?
    pub fn in_trial(&self) -> bool {
        self.active
    }

    /// Why the operator of the current participant could not be built, if
    /// so (the hand then stays still).
    pub fn error(&self) -> Option<&str> {
        self.cohort.error()
    }

    fn begin(&mut self, t: &TrialInfo) {
        let key = TrialKey {
            participant: t.participant,
            phase: match t.phase {
                PhaseCode::Practice => Phase::Practice,
                PhaseCode::Test => Phase::Test,
            },
            condition: t.condition,
            trial: t.index,
        };
        let task = match t.task {
            TaskCode::Circling => TaskKind::Circling,
            TaskCode::BlindNavigation => TaskKind::BlindNavigation,
        };
        // Time on task: the trials run since this block began (a new
        // block follows a break or the instructions).
        let block = (key.participant, key.phase, key.condition);
        if self.block != Some(block) {
            self.block = Some(block);
            self.block_trials_s = 0.0;
        }
        let brief = TrialBrief {
            participant: t.participant,
            task,
            mapping: t.mapping,
            start_trap_m: t.start_trap_m,
            heading: t.heading,
            retreat_distance_m: t.retreat_distance_m,
            rng: key.rng(self.study_seed, STREAM_PARTICIPANT),
            time_on_task_s: self.block_trials_s,
        };
        self.cohort.begin_trial(&brief);
        self.control
            .start(self.act_every, t.mapping.to_hand(t.start_trap_m));
        self.vision = task != TaskKind::BlindNavigation;
        self.frame = None;
        self.k = 0;
        self.active = true;
    }
}

impl HandAgent for DeviceParticipant {
    fn info(&mut self, info: &HostInfo) {
        match info {
            HostInfo::TrialBegin(t) => self.begin(t),
            HostInfo::TrialEnd => {
                if self.active {
                    self.block_trials_s += self.k as f64 * self.dt_s;
                }
                self.active = false;
            }
            HostInfo::View(v) => {
                self.frame = Some(*v);
            }
        }
    }

    fn hand(&mut self) -> Option<[f64; 2]> {
        if !self.active {
            return None;
        }
        let phase = self.k % self.act_every;
        if phase == 0 {
            let frame = if self.vision { self.frame } else { None };
            self.control.ask(
                &mut self.cohort,
                self.k as f64 * self.dt_s,
                self.dt_s,
                frame,
            );
        }
        self.k += 1;
        Some(self.control.hand_at(phase))
    }

    fn observe(&mut self, applied: &ActuatorFrame, sensors: &SensorFrame) {
        if self.active {
            self.control
                .record(applied.force_n, sensors.accel_m_s2, sensors.handle_m);
        }
    }
}
