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

/// One camera frame as displayed to the participant (sample plane, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisualFrame {
    /// Frame number within the trial (0, 1, …).
    pub seq: u64,
    /// Capture time, s since the trial start.
    pub captured_s: f64,
    /// Manipulated bead centre, m.
    pub bead_m: [f64; 2],
    /// Trap centre (cross-hair), m.
    pub trap_m: [f64; 2],
    /// Obstacle centre, m.
    pub obstacle_m: [f64; 2],
    /// Obstacle radius, m.
    pub obstacle_radius_m: f64,
    /// Bead radius, m.
    pub bead_radius_m: f64,
}

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
