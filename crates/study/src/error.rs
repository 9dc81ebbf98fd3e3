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
}
