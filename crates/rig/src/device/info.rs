//! What the host tells a device about the experiment it is part of
//! ([`HostInfo`]): the trial that begins, its end, and what the
//! participant's screen shows. A physical DAQ ignores it; a device with a
//! participant at its handle — the emulator hosting the simulated
//! participant (hardware in the loop) — needs it to act as a person in
//! front of the screen would. On the serial link these are the optional
//! information frames of docs/PROTOCOL.md.

use crate::condition::Condition;
use crate::coupling::mapping::HandMapping;

/// The task of a trial, as a participant is told.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TaskCode {
    /// Circling an obstacle bead with the manipulated bead.
    Circling,
    /// Blind navigation: move along a heading until contact, then retreat.
    BlindNavigation,
}

/// Which block a trial belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PhaseCode {
    /// A practice trial (training block).
    Practice,
    /// A test trial.
    Test,
}

/// A trial that begins (everything a participant is told, and the key the
/// device's own participant derives its random stream from).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrialInfo {
    /// 0-based participant index.
    pub participant: u32,
    /// The condition (a participant is not told it; it keys the trial).
    pub condition: Condition,
    /// Practice or test.
    pub phase: PhaseCode,
    /// 1-based trial number within its (participant, condition, phase), as
    /// in `trials.csv`.
    pub index: u32,
    /// The task.
    pub task: TaskCode,
    /// Hand → trap mapping of this trial (its handle origin is where the
    /// handle was when the trial began), m.
    pub mapping: HandMapping,
    /// Trap position at the start, m.
    pub start_trap_m: [f64; 2],
    /// Blind task: instructed initial direction (unit vector).
    pub heading: [f64; 2],
    /// Blind task: how far to retreat after contact, m.
    pub retreat_distance_m: f64,
    /// Sequence number of the trial's first sample.
    pub first_seq: u64,
}

/// One camera frame as the participant's screen shows it (sample plane, m):
/// what a participant sees (`kilotouch_study::participant`) and what the host
/// tells a device with a participant at its handle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisualFrame {
    /// Frame number within the trial (0, 1, …).
    pub seq: u64,
    /// Capture time, s since the trial start.
    pub captured_s: f64,
    /// Manipulated bead centre, m.
    pub bead_m: [f64; 2],
    /// Trap centre, m.
    pub trap_m: [f64; 2],
    /// Obstacle centre, m.
    pub obstacle_m: [f64; 2],
    /// Obstacle radius, m.
    pub obstacle_radius_m: f64,
    /// Bead radius, m.
    pub bead_radius_m: f64,
}

/// What the host tells the device (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HostInfo {
    /// A trial begins.
    TrialBegin(TrialInfo),
    /// The trial ended (the participant stops acting until the next one).
    TrialEnd,
    /// The participant's screen now shows this frame.
    View(VisualFrame),
}

/// A participant at a device's handle: what an emulated device hosts for
/// hardware-in-the-loop runs (`kilotouch emulate daq --participant`). It
/// hears what the host tells the device ([`HostInfo`]), feels what the
/// device renders and moves the handle. Called on the device's thread,
/// once per sample.
pub trait HandAgent: Send + std::fmt::Debug {
    /// The host told the device something.
    fn info(&mut self, info: &HostInfo);
    /// Where the hand is during the next sample (m; `None`: where it was).
    fn hand(&mut self) -> Option<[f64; 2]>;
    /// The sample ran with `applied` (Pantograph force N, Haptuator drive
    /// V); `sensors` is what the device read at its end.
    fn observe(
        &mut self,
        applied: &crate::device::ActuatorFrame,
        sensors: &crate::device::SensorFrame,
    );
}
