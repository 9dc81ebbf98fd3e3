//! Circling (paper §4.3): keep the manipulated bead in contact with a fixed
//! spherical obstacle while going around it.
//!
//! Definitions (c obstacle centre, R_c = R_o + R_b, b_k bead centre, t_k
//! trap centre, sample k at time t_k = k/f_s):
//!
//! * gap g_k = |b_k − c| − R_c; **contact** when g_k < `contact_gap`
//!   (protocol `tolerances.contact_gap_um`).
//! * The **circling phase** starts at the first sample in contact (k₀) and
//!   ends at the end sample K. Metrics are means over k₀ ≤ k ≤ K.
//! * **Turn angle**: θ_k = atan2 of b_k − c, unwrapped: Θ = Σ_{k>k₀}
//!   wrap(θ_k − θ_{k−1}) with wrap to (−π, π]. Either direction counts.
//! * **End**: escape (trap lost: tweezer flag or |b_k − t_k| >
//!   `escape_distance`), else |Θ| ≥ 2π·`revolutions` (completed), else
//!   t_k ≥ `timeout` — checked in that order at every sample.
//! * **time_s** = t_K, the manipulation time from the trial start.
//! * **contact_fraction** = (samples in contact) / (samples of the phase).
//! * **disp_err_mean_um** = mean |g_k| (distance of the bead centre from the
//!   contact circle), µm.
//! * **force_mean_pn** = mean |κ(t_k − b_k)| (optical force on the bead), pN;
//!   **force_mean_n** = mean |F_hand,k| (force rendered at the hand), N.
//! * **Rejection**: escaped → `escaped`; time-out → `timeout`; completed
//!   with contact_fraction < `min_contact_fraction` → `low_contact`;
//!   experimenter abort → `aborted`.

use std::f64::consts::PI;

use super::{EndState, ForceSums, Geometry, TaskSample, TrialEnd, push_until_end, wrap_pi};

/// Thresholds of the circling task (SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CirclingParams {
    /// Contact when the surface gap is below this, m.
    pub contact_gap_m: f64,
    /// Escape when the bead is further than this from the trap centre, m.
    pub escape_distance_m: f64,
    /// Minimum contact fraction of a successful trial (0–1).
    pub min_contact_fraction: f64,
    /// Turns that complete the trial.
    pub revolutions: f64,
    /// Time-out, s.
    pub timeout_s: f64,
}

/// Result of a circling trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CirclingMetrics {
    /// How the trial ended (`None`: no end condition met yet).
    pub end: Option<TrialEnd>,
    /// Time of the last sample processed, s (the manipulation time once
    /// ended).
    pub time_s: f64,
    /// Time of the first contact, s.
    pub first_contact_s: Option<f64>,
    /// Fraction of the circling phase in contact (0 without contact).
    pub contact_fraction: f64,
    /// Mean |gap| over the circling phase, µm.
    pub disp_err_mean_um: Option<f64>,
    /// Mean optical force magnitude over the circling phase, pN.
    pub force_mean_pn: Option<f64>,
    /// Mean magnitude of the force rendered at the hand, N.
    pub force_mean_n: Option<f64>,
    /// The bead escaped the trap.
    pub escaped: bool,
    /// Signed turns Θ/2π since the first contact.
    pub turns: f64,
    /// Samples of the circling phase.
    pub phase_samples: u64,
    /// The threshold the reject rule uses.
    pub min_contact_fraction: f64,
}

impl CirclingMetrics {
    /// Reject reason, `None` for a successful trial.
    pub fn reject_reason(&self) -> Option<&'static str> {
        match self.end {
            None => Some("incomplete"),
            Some(TrialEnd::Escaped) => Some("escaped"),
            Some(TrialEnd::Timeout) => Some("timeout"),
            Some(TrialEnd::Aborted) => Some("aborted"),
            Some(TrialEnd::Completed | TrialEnd::Retreated) => {
                (self.contact_fraction < self.min_contact_fraction).then_some("low_contact")
            }
        }
    }
}

/// Online circling metrics (module docs). Allocation-free.
#[derive(Debug, Clone)]
pub struct CirclingAccumulator {
    p: CirclingParams,
    g: Geometry,
    state: EndState,
    prev_angle: f64,
    turned: f64,
    n_phase: u64,
    n_contact: u64,
    sum_disp: f64,
    forces: ForceSums,
}

impl CirclingAccumulator {
    /// Fresh accumulator.
    pub fn new(p: CirclingParams, g: Geometry) -> Self {
        Self {
            p,
            g,
            state: EndState::default(),
            prev_angle: 0.0,
            turned: 0.0,
            n_phase: 0,
            n_contact: 0,
            sum_disp: 0.0,
            forces: ForceSums::default(),
        }
    }

    /// Time of the first contact, s.
    pub fn first_contact_s(&self) -> Option<f64> {
        self.state.first_contact_s()
    }

    /// Adds one sample; returns the end once an end condition is met (and
    /// ignores samples after it).
    #[inline]
    pub fn push(&mut self, s: &TaskSample) -> Option<TrialEnd> {
        self.state.begin(s)?;
        let gap = self.g.gap_m(s.bead_m);
        let in_contact = gap < self.p.contact_gap_m;
        let rel = self.g.rel(s.bead_m);
        let angle = rel[1].atan2(rel[0]);
        if self.state.note_contact(s, in_contact) {
            self.prev_angle = angle;
        }
        if self.state.first_contact_s().is_some() {
            self.n_phase += 1;
            self.n_contact += u64::from(in_contact);
            if gap.is_finite() {
                self.sum_disp += gap.abs();
            }
            self.forces.add(s);
            self.turned += wrap_pi(angle - self.prev_angle);
            self.prev_angle = angle;
        }
        let completed = self.turned.abs() >= 2.0 * PI * self.p.revolutions;
        self.state
            .decide(s, self.p.escape_distance_m, self.p.timeout_s, || {
                completed.then_some(TrialEnd::Completed)
            })
    }

    /// Ends the trial now (e.g. experimenter abort) unless already ended.
    pub fn force_end(&mut self, end: TrialEnd) {
        self.state.force_end(end);
    }

    /// Metrics so far.
    pub fn metrics(&self) -> CirclingMetrics {
        let n = self.n_phase as f64;
        let (force_mean_pn, force_mean_n) = self.forces.means(self.n_phase);
        CirclingMetrics {
            end: self.state.end(),
            time_s: self.state.t_last(),
            first_contact_s: self.state.first_contact_s(),
            contact_fraction: if self.n_phase > 0 {
                self.n_contact as f64 / n
            } else {
                0.0
            },
            disp_err_mean_um: (self.n_phase > 0).then(|| self.sum_disp / n * 1e6),
            force_mean_pn,
            force_mean_n,
            escaped: self.state.escaped(),
            turns: self.turned / (2.0 * PI),
            phase_samples: self.n_phase,
            min_contact_fraction: self.p.min_contact_fraction,
        }
    }
}

/// Circling metrics of a recorded trial: the samples are pushed in order
/// until an end condition is met (later samples are ignored).
pub fn circling_metrics(
    samples: &[TaskSample],
    params: CirclingParams,
    geometry: Geometry,
) -> CirclingMetrics {
    let mut acc = CirclingAccumulator::new(params, geometry);
    push_until_end(samples, |s| acc.push(s));
    acc.metrics()
}
