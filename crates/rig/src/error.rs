//! Typed errors of the rig crate.

use kilotouch_dsp::DspError;
use thiserror::Error;

/// Every fallible operation in `kilotouch-rig` returns this error.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum RigError {
    /// A rig file could not be parsed or failed validation. `line`/`column`
    /// are 1-based and point at the offending key when it could be located.
    #[error("{origin}{}: `{field}`: {message}", fmt_pos(*line, *column))]
    Config {
        /// File name (or `<default>` / `<string>`) the text came from.
        origin: String,
        /// 1-based line of the offending key, if known.
        line: Option<usize>,
        /// 1-based column of the offending key, if known.
        column: Option<usize>,
        /// Dotted field path, e.g. `plant.m_h`.
        field: String,
        /// What is wrong and what is expected.
        message: String,
    },
    /// A rig file could not be read.
    #[error("cannot read rig file {path}: {source}")]
    Io {
        /// Path that was being read.
        path: String,
        /// Underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A scalar argument is outside its valid range.
    #[error("invalid parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// Parameter name as the user sees it.
        name: &'static str,
        /// Offending value.
        value: f64,
        /// Why it is invalid.
        reason: String,
    },
    /// Input data are unusable (empty, mismatched lengths, non-finite).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A numerical routine failed (singular matrix, non-convergence).
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// An integrator or model is unstable at the requested step.
    #[error("unstable: {0}")]
    Unstable(String),
    /// Error from the dsp crate.
    #[error(transparent)]
    Dsp(#[from] DspError),
    /// The rig is not in a state that allows the operation (e.g. not started).
    #[error("rig not ready: {0}")]
    NotReady(String),
    /// The device went away (live rigs: USB unplugged, audio device lost).
    #[error("rig disconnected: {0}")]
    Disconnected(String),
    /// The closed loop's stability margins are below the configured minimum
    /// (the message names the margin and the largest safe force scale).
    #[error("{0}")]
    LoopNotSafe(String),
    /// The device reported an unrecoverable fault.
    #[error("rig fault: {0}")]
    Device(String),
    /// An error of one part of a larger operation, with what that part was
    /// (which axis of a record; what a failing link reported).
    #[error("{context}: {source}")]
    In {
        /// The part, or the error the part saw first.
        context: String,
        /// The error underneath.
        #[source]
        source: Box<RigError>,
    },
}

fn fmt_pos(line: Option<usize>, column: Option<usize>) -> String {
    match (line, column) {
        (Some(l), Some(c)) => format!(":{l}:{c}"),
        (Some(l), None) => format!(":{l}"),
        _ => String::new(),
    }
}

impl RigError {
    /// `Ok` when `value` is finite and > 0, else
    /// [`RigError::InvalidParameter`] naming the parameter.
    pub fn require_positive(name: &'static str, value: f64) -> Result<(), RigError> {
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(RigError::InvalidParameter {
                name,
                value,
                reason: "must be finite and > 0".into(),
            })
        }
    }
}
