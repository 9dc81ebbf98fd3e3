//! The participant as a sitting sees it: who is at the handle ([`Who`]), a
//! [`Tap`] around them that records what they observe (for telemetry and
//! live metrics, allocation-free), and the validation of pseudonymous IDs.

use kilotouch_study::operator::SimCohort;
use kilotouch_study::participant::{
    MouseParticipant, Observation, Participant, TrialBrief, VisualFrame,
};
use kilotouch_study::protocol::AssignmentTable;
use kilotouch_study::seeds::TrialKey;

use super::Telemetry;

/// Live estimates of the running trial's metrics, from what the tap sees:
/// camera frames (the rig file's `[camera]`: 25 Hz, displayed 40 ms late by default) for the geometry,
/// every sample's handle force for the force. The committed row holds the
/// exact per-sample values (study crate, `task::circling`).
///
/// With c the obstacle centre, R_c = R_o + R_b and b_j the bead centre in
/// frame j, the gap is g_j = |b_j − c| − R_c; the phase starts at the
/// first frame with g_j < `contact_gap`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LiveMetrics {
    /// Time since the trial start, s.
    pub t_s: f64,
    /// Frames in contact / frames since the first contact (`None` before
    /// any contact or without vision).
    pub contact_fraction: Option<f64>,
    /// Mean |g_j| over the frames since the first contact, µm.
    pub disp_err_mean_um: Option<f64>,
    /// Mean |F_hand| over the samples since the first contact (since the
    /// start without vision), N.
    pub force_mean_n: Option<f64>,
    /// Peak |F_hand| since the trial start, N.
    pub force_peak_n: f64,
}

/// Who is at the handle during a sitting.
#[derive(Debug)]
pub(crate) enum Who {
    /// A person at the GUI: the hand follows the mouse (simulated rig).
    Mouse(MouseParticipant),
    /// The study crate's seeded simulated operator (simulated rig).
    Sim(Box<SimCohort>),
    /// A live rig: a real hand (a person, or the device's own simulated
    /// participant) moves the handle; the sitting observes and records it.
    Handle,
}

impl Participant for Who {
    fn begin_trial(&mut self, brief: &TrialBrief) {
        match self {
            Who::Mouse(m) => m.begin_trial(brief),
            Who::Sim(s) => s.begin_trial(brief),
            Who::Handle => {}
        }
    }

    fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
        match self {
            Who::Mouse(m) => m.act(obs),
            Who::Sim(s) => s.act(obs),
            Who::Handle => obs.handle_m,
        }
    }
}

/// Wraps a participant and records its observations (module docs).
#[derive(Debug)]
pub(crate) struct Tap<P> {
    pub(crate) inner: P,
    contact_gap_m: f64,
    vision: bool,
    t_s: f64,
    frame: Option<VisualFrame>,
    last_seq: Option<u64>,
    handle_m: [f64; 2],
    hand_m: [f64; 2],
    force_n: [f64; 2],
    in_phase: bool,
    frames_phase: u64,
    frames_contact: u64,
    sum_gap_m: f64,
    force_sum: f64,
    force_n_samples: u64,
    force_peak: f64,
}

impl<P: Participant> Tap<P> {
    pub(crate) fn new(inner: P, contact_gap_m: f64) -> Self {
        Self {
            inner,
            contact_gap_m,
            vision: true,
            t_s: 0.0,
            frame: None,
            last_seq: None,
            handle_m: [0.0; 2],
            hand_m: [0.0; 2],
            force_n: [0.0; 2],
            in_phase: false,
            frames_phase: 0,
            frames_contact: 0,
            sum_gap_m: 0.0,
            force_sum: 0.0,
            force_n_samples: 0,
            force_peak: 0.0,
        }
    }

    /// Forgets the previous trial.
    fn reset(&mut self) {
        self.t_s = 0.0;
        self.frame = None;
        self.last_seq = None;
        self.handle_m = [0.0; 2];
        self.force_n = [0.0; 2];
        self.in_phase = false;
        self.frames_phase = 0;
        self.frames_contact = 0;
        self.sum_gap_m = 0.0;
        self.force_sum = 0.0;
        self.force_n_samples = 0;
        self.force_peak = 0.0;
    }

    /// The live metrics so far.
    pub(crate) fn live(&self) -> LiveMetrics {
        let frac = |a: f64, n: u64| (n > 0).then(|| a / n as f64);
        LiveMetrics {
            t_s: self.t_s,
            contact_fraction: frac(self.frames_contact as f64, self.frames_phase),
            disp_err_mean_um: frac(self.sum_gap_m * 1e6, self.frames_phase),
            force_mean_n: frac(self.force_sum, self.force_n_samples),
            force_peak_n: self.force_peak,
        }
    }

    pub(crate) fn telemetry(&self, key: TrialKey) -> Telemetry {
        Telemetry {
            key,
            t_s: self.t_s,
            frame: self.frame,
            handle_m: self.handle_m,
            hand_m: self.hand_m,
            force_n: self.force_n,
            live: self.live(),
        }
    }
}

impl<P: Participant> Participant for Tap<P> {
    fn begin_trial(&mut self, brief: &TrialBrief) {
        self.reset();
        self.vision = brief.task != kilotouch_study::export::TaskKind::BlindNavigation;
        self.hand_m = brief.mapping.to_hand(brief.start_trap_m);
        self.inner.begin_trial(brief);
    }

    fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
        self.t_s = obs.t_s;
        self.handle_m = obs.handle_m;
        if let Some(f) = obs.frame
            && self.last_seq != Some(f.seq)
        {
            self.last_seq = Some(f.seq);
            self.frame = Some(f);
            let d = [f.bead_m[0] - f.obstacle_m[0], f.bead_m[1] - f.obstacle_m[1]];
            let gap = d[0].hypot(d[1]) - (f.obstacle_radius_m + f.bead_radius_m);
            if gap.is_finite() {
                let contact = gap < self.contact_gap_m;
                self.in_phase |= contact;
                if self.in_phase {
                    self.frames_phase += 1;
                    self.frames_contact += u64::from(contact);
                    self.sum_gap_m += gap.abs();
                }
            }
        }
        let counting = self.in_phase || !self.vision;
        for f in obs.force_n {
            let m = f[0].hypot(f[1]);
            if !m.is_finite() {
                continue;
            }
            self.force_peak = self.force_peak.max(m);
            if counting {
                self.force_sum += m;
                self.force_n_samples += 1;
            }
        }
        if let Some(f) = obs.force_n.last() {
            self.force_n = *f;
        }
        let h = self.inner.act(obs);
        if h.iter().all(|v| v.is_finite()) {
            self.hand_m = h;
        }
        h
    }
}

/// A validated pseudonymous participant ID and its 0-based index.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParticipantId {
    /// The protocol's display ID (`P01`, …), the `participant` column.
    pub id: String,
    /// 0-based index (seed derivation, order table row).
    pub index: u32,
}

/// Validates what the experimenter typed as participant ID and maps it to
/// the protocol's participant: `P03`, `p3`, `3` or `03` → `P03` (index 2).
/// Only pseudonyms are accepted: anything that looks like a name or an
/// e-mail address (letters beyond a short prefix, `@`, spaces) is refused
/// so that no identifying data reaches the output folder.
///
/// # Errors
/// A message for the page (empty, not a pseudonym, out of range).
pub fn validate_participant_id(
    text: &str,
    table: &AssignmentTable,
) -> Result<ParticipantId, String> {
    let t = text.trim();
    if t.is_empty() {
        return Err("enter the participant's pseudonymous ID (e.g. P01)".into());
    }
    if t.contains('@') || t.contains(char::is_whitespace) {
        return Err(
            "this looks like a name or an e-mail address: enter the pseudonymous ID (e.g. P01), \
             never identifying data"
                .into(),
        );
    }
    let digits_at = t.find(|c: char| c.is_ascii_digit());
    let (prefix, number) = match digits_at {
        Some(i) => t.split_at(i),
        None => (t, ""),
    };
    let prefix_ok = prefix.is_empty() || prefix.eq_ignore_ascii_case("p");
    let number_ok =
        !number.is_empty() && number.len() <= 6 && number.chars().all(|c| c.is_ascii_digit());
    if !(prefix_ok && number_ok) {
        return Err(format!(
            "`{t}` is not a pseudonymous ID: use P followed by the participant number \
             (P01 … P{:02}); names or other identifying text are not accepted",
            table.participants.len()
        ));
    }
    let n: usize = number
        .parse()
        .map_err(|_| format!("`{t}`: participant number out of range"))?;
    match table.participants.iter().find(|p| p.participant + 1 == n) {
        Some(p) => Ok(ParticipantId {
            id: p.id.clone(),
            index: u32::try_from(p.participant)
                .map_err(|_| "participant index too large".to_owned())?,
        }),
        None => Err(format!(
            "`{t}`: the protocol has participants P01 … P{:02}",
            table.participants.len()
        )),
    }
}
