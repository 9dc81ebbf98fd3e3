//! How a trial ends, as both tasks decide it ([`EndState`]: escape, the
//! task's own end, the time-out), and the force sums both tasks average.

use super::TaskSample;
use super::vec2::norm;

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

/// Whether the bead of sample `s` has escaped: the tweezer lost it, its
/// separation from the trap centre is NaN (non-finite position), or that
/// separation exceeds `escape_distance_m` (m).
#[inline]
pub(crate) fn bead_escaped(s: &TaskSample, escape_distance_m: f64) -> bool {
    let sep = norm([s.bead_m[0] - s.trap_m[0], s.bead_m[1] - s.trap_m[1]]);
    !s.trapped || sep.is_nan() || sep > escape_distance_m
}

/// How a trial ends, as both tasks' accumulators decide it (and when the
/// bead first touched the obstacle, where both tasks' phases begin): samples
/// after the end are ignored, and at each sample the end conditions are checked
/// in the same order — the bead escaped ([`bead_escaped`]), then the
/// task's own end, then the time-out.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct EndState {
    end: Option<TrialEnd>,
    t_last: f64,
    escaped: bool,
    first_contact_s: Option<f64>,
}

impl EndState {
    /// Starts sample `s`: records its time and returns `Some`, or returns
    /// `None` once the trial has ended (the sample is ignored).
    #[inline]
    pub(crate) fn begin(&mut self, s: &TaskSample) -> Option<()> {
        if self.end.is_some() {
            return None;
        }
        self.t_last = s.t_s;
        Some(())
    }

    /// Notes whether sample `s` is in contact with the obstacle; returns
    /// true at the first contact of the trial (its time is then kept).
    #[inline]
    pub(crate) fn note_contact(&mut self, s: &TaskSample, in_contact: bool) -> bool {
        let first = in_contact && self.first_contact_s.is_none();
        if first {
            self.first_contact_s = Some(s.t_s);
        }
        first
    }

    /// Time of the first contact, s (`None`: no contact yet).
    pub(crate) fn first_contact_s(&self) -> Option<f64> {
        self.first_contact_s
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
