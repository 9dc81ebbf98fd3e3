//! [`RunError`], the error of running trials: shared by the stations
//! ([`crate::task::station`]), the session runner ([`crate::runner`], which
//! re-exports it: `kilotouch_study::runner::RunError`) and simulated
//! studies ([`crate::simulate`]).

use kilotouch_rig::RigError;
use thiserror::Error;

use crate::storage::error::ExportError;

/// Errors of running trials.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum RunError {
    /// Rig or tweezer error.
    #[error("rig: {0}")]
    Rig(#[from] RigError),
    /// Storage error.
    #[error("{0}")]
    Export(#[from] ExportError),
    /// Filter design error (operator percepts).
    #[error("dsp: {0}")]
    Dsp(#[from] kilotouch_dsp::DspError),
    /// An operation not allowed in the current state.
    #[error("runner: {0}")]
    State(String),
    /// Invalid runner configuration.
    #[error("runner configuration: {0}")]
    Config(String),
    /// A draft trial's haptic loop at its lower rate would not meet the
    /// minimum stability margins ([`crate::fidelity::Fidelity::Draft`]).
    #[error("draft haptic loop at {rate_hz} Hz (rate divisor {divisor}) refused: {why}")]
    DraftLoopNotSafe {
        /// The draft loop's rate, Hz.
        rate_hz: f64,
        /// The rate divisor from the rig's rate.
        divisor: u32,
        /// The stability analysis' reason, with the margins and minima.
        why: String,
    },
}
