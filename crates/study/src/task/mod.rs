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
//! equations: `docs/STUDY.md` §11 and `docs/THEORY.md` (study tasks).
//!
//! Units: SI inside (m, s, N); the exported columns carry their unit in
//! their name (µm, pN, deg).

pub mod blind;
pub mod circling;
pub mod sim_station;
pub mod station;

use std::f64::consts::PI;

use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::Rng;

use crate::protocol::{Condition, Protocol, Task};

pub use blind::{BlindAccumulator, BlindMetrics, BlindParams, blind_metrics};
pub use circling::{CirclingAccumulator, CirclingMetrics, CirclingParams, circling_metrics};

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

/// How a trial ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrialEnd {
    /// Circling: the requested number of turns was completed.
    Completed,
    /// Blind navigation: the bead moved the retreat distance away from the
    /// contact point.
    Retreated,
    /// The bead left the trap.
    Escaped,
    /// The time-out was reached.
    Timeout,
    /// The experimenter aborted the trial.
    Aborted,
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

/// The fixed obstacle and the bead sizes (sample plane, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// Obstacle centre, m.
    pub obstacle_m: [f64; 2],
    /// Obstacle radius R_o, m.
    pub obstacle_radius_m: f64,
    /// Manipulated bead radius R_b, m.
    pub bead_radius_m: f64,
}

impl Geometry {
    /// Radius of the contact circle R_c = R_o + R_b (bead centre positions
    /// at which the surfaces touch), m.
    pub fn contact_radius_m(&self) -> f64 {
        self.obstacle_radius_m + self.bead_radius_m
    }

    /// Vector from the obstacle centre to `p`, m.
    #[inline]
    pub fn rel(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] - self.obstacle_m[0], p[1] - self.obstacle_m[1]]
    }

    /// Surface gap g = |p − c| − R_c of a bead centred at `p`, m (negative
    /// = overlap).
    #[inline]
    pub fn gap_m(&self, p: [f64; 2]) -> f64 {
        norm(self.rel(p)) - self.contact_radius_m()
    }

    /// Outward unit normal of the obstacle at the direction of `p` (the
    /// x axis when `p` is the centre).
    #[inline]
    pub fn normal(&self, p: [f64; 2]) -> [f64; 2] {
        let r = self.rel(p);
        let d = norm(r);
        if d > 0.0 && d.is_finite() {
            [r[0] / d, r[1] / d]
        } else {
            [1.0, 0.0]
        }
    }
}

/// The layout of one trial: geometry, where the bead starts and (blind
/// task) the heading the participant is told to move along. Drawn from the
/// trial's task generator ([`crate::seeds::STREAM_TASK`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// Obstacle and bead sizes.
    pub geometry: Geometry,
    /// Bead (= trap) position at the start, m.
    pub start_m: [f64; 2],
    /// Unit vector of the instructed initial direction (blind task; for
    /// circling the direction towards the obstacle).
    pub heading: [f64; 2],
}

/// Surface gap between the bead and the obstacle at the start of a
/// circling trial, m (the participant first approaches the obstacle).
pub const CIRCLING_START_GAP_M: f64 = 2.0e-6;

/// Fraction of the widest heading cone that still hits the obstacle from
/// which blind-navigation headings are drawn (so that a straight movement
/// along the instructed heading collides).
pub const BLIND_HEADING_CONE_FRACTION: f64 = 0.6;

/// Uniform in [0, 1) from 53 random bits.
#[inline]
pub fn unit_uniform(rng: &mut ChaCha20Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1_u64 << 53) as f64
}

impl Scene {
    /// Draws the scene of a trial around the start position `start_m`
    /// (the trap position of the handle's rest position).
    ///
    /// * Circling: the obstacle centre at distance R_c + 2 µm from the start
    ///   in a uniformly random direction.
    /// * Blind navigation: the obstacle centre at distance
    ///   R_c + `start_distance` in a uniformly random direction φ; the
    ///   heading points from the start to the centre, rotated by an angle
    ///   uniform in ±0.6·asin(R_c / (R_c + start_distance)) so that the
    ///   straight line along it hits the contact circle.
    pub fn draw(task: &Task, start_m: [f64; 2], rng: &mut ChaCha20Rng) -> Self {
        let phi = 2.0 * PI * unit_uniform(rng);
        let u = [phi.cos(), phi.sin()];
        match task {
            Task::Circling(t) => {
                let geometry = Geometry {
                    obstacle_m: [0.0; 2],
                    obstacle_radius_m: t.obstacle_radius_um * UM,
                    bead_radius_m: t.bead_radius_um * UM,
                };
                let d = geometry.contact_radius_m() + CIRCLING_START_GAP_M;
                Self {
                    geometry: Geometry {
                        obstacle_m: [start_m[0] + d * u[0], start_m[1] + d * u[1]],
                        ..geometry
                    },
                    start_m,
                    heading: u,
                }
            }
            Task::BlindNavigation(t) => {
                let rc = (t.obstacle_radius_um + t.bead_radius_um) * UM;
                let d = rc + t.start_distance_um * UM;
                let cone = BLIND_HEADING_CONE_FRACTION * (rc / d).asin();
                let off = cone * (2.0 * unit_uniform(rng) - 1.0);
                let h = phi + off;
                Self {
                    geometry: Geometry {
                        obstacle_m: [start_m[0] + d * u[0], start_m[1] + d * u[1]],
                        obstacle_radius_m: t.obstacle_radius_um * UM,
                        bead_radius_m: t.bead_radius_um * UM,
                    },
                    start_m,
                    heading: [h.cos(), h.sin()],
                }
            }
        }
    }
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

/// Whether the bead of sample `s` has escaped: the tweezer lost it, its
/// separation from the trap centre is NaN (non-finite position), or that
/// separation exceeds `escape_distance_m` (m).
#[inline]
pub(crate) fn bead_escaped(s: &TaskSample, escape_distance_m: f64) -> bool {
    let sep = norm([s.bead_m[0] - s.trap_m[0], s.bead_m[1] - s.trap_m[1]]);
    !s.trapped || sep.is_nan() || sep > escape_distance_m
}

/// How a trial ends, as both tasks' accumulators decide it: samples after
/// the end are ignored, and at each sample the end conditions are checked
/// in the same order — the bead escaped ([`bead_escaped`]), then the
/// task's own end, then the time-out.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct EndState {
    end: Option<TrialEnd>,
    t_last: f64,
    escaped: bool,
}

impl EndState {
    /// Starts sample `s`: records its time and returns true, or returns
    /// false once the trial has ended (the sample is ignored).
    #[inline]
    pub(crate) fn begin(&mut self, s: &TaskSample) -> bool {
        if self.end.is_some() {
            return false;
        }
        self.t_last = s.t_s;
        true
    }

    /// Ends the trial at sample `s` when an end condition is met: the bead
    /// escaped (`escape_distance_m`, m), else `task_end` (called only then)
    /// gives an end, else `t_s ≥ timeout_s` (s). Returns the end.
    #[inline]
    pub(crate) fn decide(
        &mut self,
        s: &TaskSample,
        escape_distance_m: f64,
        timeout_s: f64,
        task_end: impl FnOnce() -> Option<TrialEnd>,
    ) -> Option<TrialEnd> {
        let end = if bead_escaped(s, escape_distance_m) {
            self.escaped = true;
            Some(TrialEnd::Escaped)
        } else if let Some(e) = task_end() {
            Some(e)
        } else if s.t_s >= timeout_s {
            Some(TrialEnd::Timeout)
        } else {
            None
        };
        self.end = end;
        end
    }

    /// Ends the trial now unless already ended.
    pub(crate) fn force_end(&mut self, end: TrialEnd) {
        if self.end.is_none() {
            self.end = Some(end);
        }
    }

    /// How the trial ended (`None`: not yet).
    pub(crate) fn end(&self) -> Option<TrialEnd> {
        self.end
    }

    /// Time of the last sample processed, s.
    pub(crate) fn t_last(&self) -> f64 {
        self.t_last
    }

    /// The bead escaped the trap.
    pub(crate) fn escaped(&self) -> bool {
        self.escaped
    }
}

/// Running sums of the force magnitudes the tasks average: the optical
/// force on the bead |κ(trap − bead)| and the force rendered at the hand,
/// N. Non-finite magnitudes add nothing (they still count as samples).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ForceSums {
    bead_n: f64,
    hand_n: f64,
}

impl ForceSums {
    /// Adds the magnitudes of sample `s`; returns the one on the bead, N
    /// (possibly non-finite).
    #[inline]
    pub(crate) fn add(&mut self, s: &TaskSample) -> f64 {
        let fb = norm(s.force_bead_n);
        if fb.is_finite() {
            self.bead_n += fb;
        }
        let fh = norm(s.force_hand_n);
        if fh.is_finite() {
            self.hand_n += fh;
        }
        fb
    }

    /// Mean magnitudes over `n` samples: (on the bead, pN; at the hand, N);
    /// `None` for no samples.
    pub(crate) fn means(&self, n: u64) -> (Option<f64>, Option<f64>) {
        let k = n as f64;
        (
            (n > 0).then(|| self.bead_n / k * 1e12),
            (n > 0).then(|| self.hand_n / k),
        )
    }
}

/// Pushes `samples` in order through `push` until it reports an end (the
/// later samples are ignored): the recorded-trial drivers of the tasks'
/// online accumulators.
pub(crate) fn push_until_end(
    samples: &[TaskSample],
    mut push: impl FnMut(&TaskSample) -> Option<TrialEnd>,
) {
    for s in samples {
        if push(s).is_some() {
            break;
        }
    }
}

/// Euclidean norm of a 2-vector, √(x² + y²): several times cheaper than
/// `f64::hypot` (a libm call, ≈ 5 % of a simulated study when it was used
/// here). The task's positions (m) and forces (N) are far from the
/// over- and underflow limits of the squares (|x| ≳ 1e154 gives +∞, which
/// every comparison then treats as far or large; |x| ≲ 1e-154 loses relative
/// accuracy but not the comparisons against µm and pN scales).
#[inline]
pub fn norm(v: [f64; 2]) -> f64 {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

/// Wraps an angle difference to (−π, π].
#[inline]
pub fn wrap_pi(mut a: f64) -> f64 {
    if !a.is_finite() {
        return 0.0;
    }
    if a > PI || a <= -PI {
        a = a.rem_euclid(2.0 * PI);
        if a > PI {
            a -= 2.0 * PI;
        }
    }
    a
}

/// Angle between two vectors, radians in [0, π] (atan2 of the cross and dot
/// products: accurate for small and near-π angles). 0 when either vector is
/// zero.
#[inline]
pub fn angle_between(a: [f64; 2], b: [f64; 2]) -> f64 {
    let cross = a[0] * b[1] - a[1] * b[0];
    let dot = a[0] * b[0] + a[1] * b[1];
    if cross == 0.0 && dot == 0.0 {
        0.0
    } else {
        cross.abs().atan2(dot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_and_angles() {
        assert_eq!(wrap_pi(0.25), 0.25);
        assert!((wrap_pi(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_pi(-PI) - PI).abs() < 1e-12);
        assert!((wrap_pi(-1.5 * PI) - 0.5 * PI).abs() < 1e-12);
        assert_eq!(wrap_pi(f64::NAN), 0.0);
        assert!((angle_between([1.0, 0.0], [0.0, 2.0]) - PI / 2.0).abs() < 1e-15);
        assert!((angle_between([1.0, 0.0], [-1.0, 1e-9]) - PI).abs() < 1e-8);
        assert_eq!(angle_between([0.0, 0.0], [1.0, 0.0]), 0.0);
    }
}
