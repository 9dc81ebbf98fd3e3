//! Blind navigation (paper §4.2, Fig. 10): without vision, move the bead
//! until a collision with the obstacle is felt, then move away from the
//! obstacle along the surface normal.
//!
//! Definitions (c obstacle centre, R_c = R_o + R_b, b_k bead, sample k at
//! t_k = k/f_s):
//!
//! * **contact** when g_k = |b_k − c| − R_c < `contact_gap`.
//! * **time_to_collision_s** = t of the first contact sample.
//! * **contact point** p_c = the bead centre at the *last* contact sample
//!   so far; **surface normal** n_c = (p_c − c)/|p_c − c|.
//! * **peak_force_pn** = max |κ(t_k − b_k)| from the first contact to the
//!   end, pN.
//! * **End**: escape (as in circling), else — after a contact, out of
//!   contact — |b_k − p_c| ≥ `retreat_distance` (retreated), else
//!   t_k ≥ `timeout`.
//! * **retreat_angle_err_deg** = ∠(b_K − p_c, n_c) ∈ [0°, 180°], the angle
//!   between the retreat path (chord from the contact point to the end
//!   point) and the outward normal at the contact point.
//! * **force_mean_pn / force_mean_n**: means over the whole trial.
//! * **Rejection**: escaped → `escaped`; time-out without contact →
//!   `no_collision`; time-out after contact → `timeout`; retreat angle >
//!   `success_angle` → `retreat_angle`; abort → `aborted`.

use super::{
    EndState, ForceSums, Geometry, TaskSample, TrialEnd, angle_between, norm, push_until_end,
};

/// Thresholds of the blind-navigation task (SI, degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlindParams {
    /// Contact when the surface gap is below this, m.
    pub contact_gap_m: f64,
    /// Escape distance from the trap centre, m.
    pub escape_distance_m: f64,
    /// Distance from the contact point that ends the trial, m.
    pub retreat_distance_m: f64,
    /// Largest successful retreat-direction error, degrees.
    pub success_angle_deg: f64,
    /// Time-out, s.
    pub timeout_s: f64,
}

/// Result of a blind-navigation trial.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlindMetrics {
    /// How the trial ended (`None`: not yet).
    pub end: Option<TrialEnd>,
    /// Time of the last sample processed, s.
    pub time_s: f64,
    /// Time of the first contact, s.
    pub time_to_collision_s: Option<f64>,
    /// Peak optical force magnitude after the first contact, pN.
    pub peak_force_pn: Option<f64>,
    /// Retreat-direction error, degrees (when retreated).
    pub retreat_angle_err_deg: Option<f64>,
    /// Contact point (last contact sample), m.
    pub contact_point_m: Option<[f64; 2]>,
    /// Outward surface normal at the contact point.
    pub normal: Option<[f64; 2]>,
    /// Mean optical force magnitude over the trial, pN.
    pub force_mean_pn: Option<f64>,
    /// Mean magnitude of the force rendered at the hand, N.
    pub force_mean_n: Option<f64>,
    /// The bead escaped the trap.
    pub escaped: bool,
    /// The success threshold used, degrees.
    pub success_angle_deg: f64,
}

impl BlindMetrics {
    /// Reject reason, `None` for a successful trial.
    pub fn reject_reason(&self) -> Option<&'static str> {
        match self.end {
            None => Some("incomplete"),
            Some(TrialEnd::Escaped) => Some("escaped"),
            Some(TrialEnd::Aborted) => Some("aborted"),
            Some(TrialEnd::Timeout) => Some(if self.time_to_collision_s.is_some() {
                "timeout"
            } else {
                "no_collision"
            }),
            Some(TrialEnd::Retreated | TrialEnd::Completed) => match self.retreat_angle_err_deg {
                Some(a) if a <= self.success_angle_deg => None,
                _ => Some("retreat_angle"),
            },
        }
    }
}

/// Online blind-navigation metrics (module docs). Allocation-free.
#[derive(Debug, Clone)]
pub struct BlindAccumulator {
    p: BlindParams,
    g: Geometry,
    state: EndState,
    contact_point: [f64; 2],
    normal: [f64; 2],
    peak_fb: f64,
    angle_deg: Option<f64>,
    n: u64,
    forces: ForceSums,
}

impl BlindAccumulator {
    /// Fresh accumulator.
    pub fn new(p: BlindParams, g: Geometry) -> Self {
        Self {
            p,
            g,
            state: EndState::default(),
            contact_point: [0.0; 2],
            normal: [1.0, 0.0],
            peak_fb: 0.0,
            angle_deg: None,
            n: 0,
            forces: ForceSums::default(),
        }
    }

    /// Time of the first contact, s.
    pub fn first_contact_s(&self) -> Option<f64> {
        self.state.first_contact_s()
    }

    /// Adds one sample; returns the end once an end condition is met.
    #[inline]
    pub fn push(&mut self, s: &TaskSample) -> Option<TrialEnd> {
        self.state.begin(s)?;
        self.n += 1;
        let fb = self.forces.add(s);
        let in_contact = self.g.gap_m(s.bead_m) < self.p.contact_gap_m;
        self.state.note_contact(s, in_contact);
        if in_contact {
            self.contact_point = s.bead_m;
            self.normal = self.g.normal(s.bead_m);
        }
        let touched = self.state.first_contact_s().is_some();
        if touched && fb.is_finite() {
            self.peak_fb = self.peak_fb.max(fb);
        }
        let d = [
            s.bead_m[0] - self.contact_point[0],
            s.bead_m[1] - self.contact_point[1],
        ];
        self.state
            .decide(s, self.p.escape_distance_m, self.p.timeout_s, || {
                // Retreated: out of contact, the retreat distance away from
                // the contact point.
                if touched && !in_contact && norm(d) >= self.p.retreat_distance_m {
                    self.angle_deg = Some(angle_between(d, self.normal).to_degrees());
                    Some(TrialEnd::Retreated)
                } else {
                    None
                }
            })
    }

    /// Ends the trial now unless already ended.
    pub fn force_end(&mut self, end: TrialEnd) {
        self.state.force_end(end);
    }

    /// Metrics so far.
    pub fn metrics(&self) -> BlindMetrics {
        let touched = self.state.first_contact_s().is_some();
        let (force_mean_pn, force_mean_n) = self.forces.means(self.n);
        BlindMetrics {
            end: self.state.end(),
            time_s: self.state.t_last(),
            time_to_collision_s: self.state.first_contact_s(),
            peak_force_pn: touched.then_some(self.peak_fb * 1e12),
            retreat_angle_err_deg: self.angle_deg,
            contact_point_m: touched.then_some(self.contact_point),
            normal: touched.then_some(self.normal),
            force_mean_pn,
            force_mean_n,
            escaped: self.state.escaped(),
            success_angle_deg: self.p.success_angle_deg,
        }
    }
}

/// Blind-navigation metrics of a recorded trial (samples pushed in order
/// until an end condition is met).
pub fn blind_metrics(
    samples: &[TaskSample],
    params: BlindParams,
    geometry: Geometry,
) -> BlindMetrics {
    let mut acc = BlindAccumulator::new(params, geometry);
    push_until_end(samples, |s| acc.push(s));
    acc.metrics()
}
