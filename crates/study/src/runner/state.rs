//! [`RunnerState`]: where a sitting is, shared by the store side
//! ([`super::SittingCore`]) and the runners that drive it.

use std::fmt;

use crate::seeds::TrialKey;

/// States of a session (see the [`super`] module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunnerState {
    /// Created; [`super::SessionRunner::start`] begins the first pending trial.
    Idle,
    /// A practice trial (training block) is running.
    Training(TrialKey),
    /// A test trial is running.
    Trial(TrialKey),
    /// Paused by the experimenter (the trial in progress, if any, waits).
    Paused(Option<TrialKey>),
    /// Between two trials, the next one (this key) waits for the
    /// participant: inter-trial interval, break, instructions or ready
    /// screen ([`super::SessionRunner::set_hold`]); [`super::SessionRunner::proceed`]
    /// begins it. Not journaled (no pause).
    Waiting(TrialKey),
    /// Every trial of the plan has its row; the store is closed.
    Done,
}

impl fmt::Display for RunnerState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RunnerState::Idle => f.write_str("idle"),
            RunnerState::Training(k) => write!(f, "training {k}"),
            RunnerState::Trial(k) => write!(f, "trial {k}"),
            RunnerState::Paused(Some(k)) => write!(f, "paused in {k}"),
            RunnerState::Paused(None) => f.write_str("paused between trials"),
            RunnerState::Waiting(k) => write!(f, "waiting for the participant before {k}"),
            RunnerState::Done => f.write_str("done"),
        }
    }
}
