//! The two micro-bead tasks of the paper (§4.2, §4.3): scene geometry, the
//! per-sample record the metrics are computed from, the metrics themselves
//! and the feedback each condition delivers.
//!
//! * [`circling`]: keep the manipulated bead in contact with a fixed
//!   obstacle while going once around it (§4.3, Figs. 11–12).
//! * [`blind`]: without vision, move until a collision is felt, then move
//!   away along the surface normal (§4.2, Fig. 10).
//!
//! Metrics are *pure functions* of a sequence of [`TaskSample`]s: each task
//! has an accumulator (`push` one sample, allocation-free, returns the end
//! of the trial when an end condition is met) and a function folding a slice
//! through it ([`circling::circling_metrics`], [`blind::blind_metrics`]). The
//! session runner feeds the accumulator online, so nothing is stored per
//! sample; the unit tests feed hand-built trajectories. Definitions and
//! equations: `docs/STUDY.md` §11 and `docs/theory/simulated-participant.md`.
//!
//! Files: `scene.rs` (obstacle, bead sizes, start and heading), `end.rs`
//! (how a trial ends, shared by both tasks), `vec2.rs` (plane-vector
//! helpers), `station.rs` (the station interface a trial runs on) and
//! `sim_station.rs` (the simulated station); this file holds what ties them
//! together (the per-sample record, the task parameters, accumulators and
//! metrics of both tasks, the feedback of a condition).
//!
//! Units: SI inside (m, s, N); the exported columns carry their unit in
//! their name (µm, pN, deg).

pub mod blind;
pub mod circling;
mod end;
mod scene;
pub mod sim_station;
pub mod station;
pub mod trial_kit;
mod vec2;

use crate::protocol::{Condition, Protocol, Task};

pub use blind::{BlindAccumulator, BlindMetrics, BlindParams, blind_metrics};
pub use circling::{CirclingAccumulator, CirclingMetrics, CirclingParams, circling_metrics};
pub use end::TrialEnd;
pub(crate) use end::{EndState, ForceSums, push_until_end};
pub use scene::{BLIND_HEADING_CONE_FRACTION, CIRCLING_START_GAP_M, Geometry, Scene, unit_uniform};
pub use vec2::{angle_between, norm, wrap_pi};

/// µm → m.
pub const UM: f64 = 1e-6;

/// What a condition delivers to the participant (paper §4.3). Everything
/// condition-specific in a trial is here; the participant model never sees
/// the condition label.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Feedback {
    /// The condition the coupling renders (V: no force at the handle).
    pub condition: Condition,
    /// Camera frames are shown (false in the blind task).
    pub vision: bool,
}

impl Feedback {
    /// Feedback of `condition` in `task`: V → no haptics, P → Pantograph
    /// only, D → dual stage; vision unless the task is blind navigation.
    pub fn of(condition: Condition, task: &Task) -> Self {
        Self {
            condition,
            vision: matches!(task, Task::Circling(_)),
        }
    }
}

/// One sample of a trial, as the metrics need it (positions in the sample
/// plane, m; forces in N; time in s from the trial start, at the *end* of
/// the sample, so the k-th sample (1-based) has `t_s = k/f_s`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TaskSample {
    /// Time since the trial start, s.
    pub t_s: f64,
    /// Manipulated bead centre, m.
    pub bead_m: [f64; 2],
    /// Trap centre, m.
    pub trap_m: [f64; 2],
    /// Optical force on the bead κ(trap − bead), N (0 while lost).
    pub force_bead_n: [f64; 2],
    /// Force rendered at the hand, N (0 in V).
    pub force_hand_n: [f64; 2],
    /// The tweezer reports the bead held by the trap.
    pub trapped: bool,
}

/// Task parameters in SI units, from a protocol.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TaskParams {
    /// Circling.
    Circling(CirclingParams),
    /// Blind navigation.
    Blind(BlindParams),
}

impl TaskParams {
    /// Parameters of the protocol's task (thresholds from the task table,
    /// the contact tolerance from `[tolerances]`).
    pub fn from_protocol(p: &Protocol) -> Self {
        let contact_gap_m = p.tolerances.contact_gap_um * UM;
        match &p.task {
            Task::Circling(t) => TaskParams::Circling(CirclingParams {
                contact_gap_m,
                escape_distance_m: t.escape_distance_um * UM,
                min_contact_fraction: t.min_contact_fraction,
                revolutions: t.revolutions,
                timeout_s: t.timeout_s,
            }),
            Task::BlindNavigation(t) => TaskParams::Blind(BlindParams {
                contact_gap_m,
                escape_distance_m: t.escape_distance_um * UM,
                retreat_distance_m: t.retreat_distance_um * UM,
                success_angle_deg: t.success_angle_deg,
                timeout_s: t.timeout_s,
            }),
        }
    }

    /// Time-out, s.
    pub fn timeout_s(&self) -> f64 {
        match self {
            TaskParams::Circling(c) => c.timeout_s,
            TaskParams::Blind(b) => b.timeout_s,
        }
    }

    /// Contact tolerance (surface gap), m.
    pub fn contact_gap_m(&self) -> f64 {
        match self {
            TaskParams::Circling(c) => c.contact_gap_m,
            TaskParams::Blind(b) => b.contact_gap_m,
        }
    }

    /// Escape distance (bead to trap centre), m.
    pub fn escape_distance_m(&self) -> f64 {
        match self {
            TaskParams::Circling(c) => c.escape_distance_m,
            TaskParams::Blind(b) => b.escape_distance_m,
        }
    }
}

/// Online metrics of either task.
#[derive(Debug, Clone)]
pub enum TaskAccumulator {
    /// Circling.
    Circling(CirclingAccumulator),
    /// Blind navigation.
    Blind(BlindAccumulator),
}

impl TaskAccumulator {
    /// A fresh accumulator for `params` and `geometry`.
    pub fn new(params: &TaskParams, geometry: Geometry) -> Self {
        match params {
            TaskParams::Circling(p) => {
                TaskAccumulator::Circling(CirclingAccumulator::new(*p, geometry))
            }
            TaskParams::Blind(p) => TaskAccumulator::Blind(BlindAccumulator::new(*p, geometry)),
        }
    }

    /// Adds one sample; returns how the trial ended when an end condition
    /// is met (at most once). Allocation-free.
    #[inline]
    pub fn push(&mut self, s: &TaskSample) -> Option<TrialEnd> {
        match self {
            TaskAccumulator::Circling(a) => a.push(s),
            TaskAccumulator::Blind(a) => a.push(s),
        }
    }

    /// Whether the bead has touched the obstacle in this trial.
    pub fn touched(&self) -> bool {
        match self {
            TaskAccumulator::Circling(a) => a.first_contact_s().is_some(),
            TaskAccumulator::Blind(a) => a.first_contact_s().is_some(),
        }
    }

    /// Ends the trial by an experimenter abort.
    pub fn abort(&mut self) {
        match self {
            TaskAccumulator::Circling(a) => a.force_end(TrialEnd::Aborted),
            TaskAccumulator::Blind(a) => a.force_end(TrialEnd::Aborted),
        }
    }

    /// The metrics so far (final once `push` returned an end).
    pub fn metrics(&self) -> TaskMetrics {
        match self {
            TaskAccumulator::Circling(a) => TaskMetrics::Circling(a.metrics()),
            TaskAccumulator::Blind(a) => TaskMetrics::Blind(a.metrics()),
        }
    }
}

/// Metrics of either task.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TaskMetrics {
    /// Circling.
    Circling(CirclingMetrics),
    /// Blind navigation.
    Blind(BlindMetrics),
}

impl TaskMetrics {
    /// Whether the trial is successful (not rejected).
    pub fn success(&self) -> bool {
        self.reject_reason().is_none()
    }

    /// Reject reason (`None` when successful).
    pub fn reject_reason(&self) -> Option<&'static str> {
        match self {
            TaskMetrics::Circling(m) => m.reject_reason(),
            TaskMetrics::Blind(m) => m.reject_reason(),
        }
    }

    /// Fills the result columns of a `trials.csv` row (identity columns
    /// untouched). Undefined metrics stay NA.
    pub fn fill_row(&self, row: &mut crate::export::TrialRow) {
        let finite = |v: f64| v.is_finite().then_some(v);
        row.success = self.success();
        row.reject_reason = self.reject_reason().unwrap_or_default().to_owned();
        match self {
            TaskMetrics::Circling(m) => {
                row.time_s = finite(m.time_s);
                row.force_mean_pn = m.force_mean_pn.and_then(finite);
                row.force_mean_n = m.force_mean_n.and_then(finite);
                row.disp_err_mean_um = m.disp_err_mean_um.and_then(finite);
                row.contact_fraction = Some(m.contact_fraction).and_then(finite);
                row.escaped = Some(m.escaped);
            }
            TaskMetrics::Blind(m) => {
                row.time_s = finite(m.time_s);
                row.force_mean_pn = m.force_mean_pn.and_then(finite);
                row.force_mean_n = m.force_mean_n.and_then(finite);
                row.escaped = Some(m.escaped);
                row.time_to_collision_s = m.time_to_collision_s.and_then(finite);
                row.peak_force_pn = m.peak_force_pn.and_then(finite);
                row.retreat_angle_err_deg = m.retreat_angle_err_deg.and_then(finite);
            }
        }
    }
}
