//! Participants: the [`Participant`] interface the session runner drives,
//! what a participant observes ([`Observation`]) and is told
//! ([`TrialBrief`]), and the GUI's participant ([`MouseParticipant`]). The
//! simulated operator, the other implementation, is in [`crate::operator`].
//!
//! # What a participant gets
//!
//! Every `act` call (1 kHz by default) carries only what a person has:
//!
//! * the **visual frame** — trap, bead and obstacle positions as the camera
//!   saw them, at the camera frame rate and after its latency (`None` in the
//!   blind task);
//! * the **force at the handle** as the rig renders it (the Pantograph
//!   command, N; zero in V), sample by sample since the last call;
//! * the **fingertip acceleration** as the rig's accelerometer senses it
//!   (m/s²), sample by sample;
//! * the handle position (proprioception).
//!
//! The condition label is never passed: V, P and D differ for a participant
//! only through these signals.
//!

use rand_chacha::ChaCha20Rng;

use crate::export::TaskKind;
use kilotouch_rig::coupling::HandMapping;

/// One camera frame as displayed to the participant: the rig crate's type,
/// which the host also sends to a device with a participant at its handle.
pub use kilotouch_rig::device::VisualFrame;

/// What a participant observes at one `act` call.
#[derive(Debug, Clone, Copy)]
pub struct Observation<'a> {
    /// Time since the trial start, s.
    pub t_s: f64,
    /// Sample period of the slices below, s.
    pub dt_s: f64,
    /// Latest displayed camera frame (`None` before the first one and in
    /// the blind task).
    pub frame: Option<VisualFrame>,
    /// Force rendered at the handle by the Pantograph for every sample
    /// since the last call, N (zero in V).
    pub force_n: &'a [[f64; 2]],
    /// Fingertip acceleration sensed by the rig for every sample since the
    /// last call, m/s² (x, y, z).
    pub accel_m_s2: &'a [[f64; 3]],
    /// Handle position, m.
    pub handle_m: [f64; 2],
}

/// What a participant is told before a trial.
#[derive(Debug, Clone)]
pub struct TrialBrief {
    /// 0-based participant index (who is at the handle).
    pub participant: u32,
    /// The task.
    pub task: TaskKind,
    /// Hand → trap mapping (learned in training).
    pub mapping: HandMapping,
    /// Trap position at the start, m.
    pub start_trap_m: [f64; 2],
    /// Blind task: the instructed initial direction (unit vector).
    pub heading: [f64; 2],
    /// Blind task: how far to retreat, m.
    pub retreat_distance_m: f64,
    /// The trial's participant generator ([`crate::seeds::STREAM_PARTICIPANT`]).
    pub rng: ChaCha20Rng,
    /// Time on task at the trial's start, s: how long the participant has
    /// been at the task since the block began (after a break or the
    /// instructions); 0 for the first trial of a block. A simulated study
    /// gives the nominal value ([`crate::operator::nominal_time_on_task_s`]).
    pub time_on_task_s: f64,
}

/// A participant: a person at the GUI, a recorded trajectory, or the
/// simulated operator.
pub trait Participant {
    /// A trial starts.
    fn begin_trial(&mut self, brief: &TrialBrief) {
        let _ = brief;
    }
    /// Where the hand goes next (m, handle coordinates). Called every
    /// control period; must not allocate in real-time use.
    fn act(&mut self, obs: &Observation<'_>) -> [f64; 2];
}

/// The GUI's participant: the hand follows the mouse (set `hand_m`
/// between runner calls).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MouseParticipant {
    /// Current mouse position mapped to handle coordinates, m.
    pub hand_m: [f64; 2],
}

impl Participant for MouseParticipant {
    fn act(&mut self, _obs: &Observation<'_>) -> [f64; 2] {
        self.hand_m
    }
}

/// The participant's control period: asked for a hand target every
/// `every` samples with what happened since (the force and acceleration of
/// each sample, the handle), the hand moving linearly from the previous
/// target to the new one over the period. One schedule for every place a
/// participant drives a hand: the trial runner, and a device hosting the
/// simulated participant at its handle (hardware in the loop).
/// Allocation-free after construction.
#[derive(Debug, Clone)]
pub struct ControlPeriod {
    every: u64,
    prev: [f64; 2],
    next: [f64; 2],
    force: Vec<[f64; 2]>,
    accel: Vec<[f64; 3]>,
    handle: [f64; 2],
}

impl ControlPeriod {
    /// A schedule whose periods hold at most `capacity` samples.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            every: capacity as u64,
            prev: [0.0; 2],
            next: [0.0; 2],
            force: Vec::with_capacity(capacity),
            accel: Vec::with_capacity(capacity),
            handle: [0.0; 2],
        }
    }

    /// Start over with periods of `every` samples (at most the capacity),
    /// the hand resting at `rest_m` (m).
    pub fn start(&mut self, every: u64, rest_m: [f64; 2]) {
        self.every = every.clamp(1, self.force.capacity().max(1) as u64);
        self.prev = rest_m;
        self.next = rest_m;
        self.force.clear();
        self.accel.clear();
        self.handle = [0.0; 2];
    }

    /// Samples per period.
    pub fn every(&self) -> u64 {
        self.every
    }

    /// Asks `participant` for the target of the next period at trial time
    /// `t_s` (s; sample period `dt_s`), showing it `frame`, with what
    /// happened since the last call; a non-finite target keeps the previous
    /// one.
    #[inline]
    pub fn ask<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
        t_s: f64,
        dt_s: f64,
        frame: Option<VisualFrame>,
    ) {
        let obs = Observation {
            t_s,
            dt_s,
            frame,
            force_n: &self.force,
            accel_m_s2: &self.accel,
            handle_m: self.handle,
        };
        let target = participant.act(&obs);
        self.force.clear();
        self.accel.clear();
        self.prev = self.next;
        if target.iter().all(|v| v.is_finite()) {
            self.next = target;
        }
    }

    /// The hand at sample `phase` (0-based) of the period: linear from the
    /// previous target to the next, m.
    #[inline]
    pub fn hand_at(&self, phase: u64) -> [f64; 2] {
        let a = (phase + 1) as f64 / self.every as f64;
        [
            self.prev[0] + a * (self.next[0] - self.prev[0]),
            self.prev[1] + a * (self.next[1] - self.prev[1]),
        ]
    }

    /// What a sample gave: the Pantograph force (N), the fingertip
    /// acceleration (m/s²) and the handle (m) at its end.
    #[inline]
    pub fn record(&mut self, force_n: [f64; 2], accel_m_s2: [f64; 3], handle_m: [f64; 2]) {
        self.handle = handle_m;
        if self.force.len() < self.force.capacity() {
            self.force.push(force_n);
            self.accel.push(accel_m_s2);
        }
    }
}
