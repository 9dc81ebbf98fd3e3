//! Typed errors of the calibration procedure.

use super::step::Step;
use kilotouch_dsp::DspError;
use thiserror::Error;

/// Every fallible operation of [`crate::calibration`] returns this error.
///
/// The messages are written for the person running the calibration: they
/// say which step failed, what was measured and what to try.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum CalibrationError {
    /// The cancel flag was raised; the procedure stopped at `step`.
    #[error("calibration cancelled during step `{}`", .step.name())]
    Cancelled {
        /// Step that was running when the cancellation was seen.
        step: Step,
    },
    /// The check step (sensor alive and in range, rig responding, safety
    /// armed) failed.
    #[error("rig check failed: {}", .problems.join("; "))]
    CheckFailed {
        /// One sentence per failed item.
        problems: Vec<String>,
    },
    /// The rig returned unusable data or is unusable for calibration.
    #[error("rig error: {0}")]
    Rig(String),
    /// The rig (or its configuration) reported an error.
    #[error(transparent)]
    Device(#[from] crate::error::RigError),
    /// A configuration value is out of range.
    #[error("invalid calibration setting `{field}` = {value}: {reason}")]
    InvalidConfig {
        /// Dotted field name, e.g. `low.order`.
        field: String,
        /// Offending value, as written.
        value: String,
        /// What is expected.
        reason: String,
    },
    /// A measurement did not allow the step to conclude (e.g. no flat band,
    /// no coherent band to fit).
    #[error("step `{}` failed: {message}", .step.name())]
    Measurement {
        /// Step that failed.
        step: Step,
        /// What was found.
        message: String,
    },
    /// A numerical routine of the dsp crate failed.
    #[error("{context}: {source}")]
    Dsp {
        /// What was being computed.
        context: String,
        /// The dsp error.
        #[source]
        source: DspError,
    },
    /// A calibration file could not be parsed or is incomplete (TOML syntax,
    /// missing or unknown field, wrong format version).
    #[error("calibration file {origin}: {message}")]
    File {
        /// File name or `<string>`.
        origin: String,
        /// Parser message (with line and column when known).
        message: String,
    },
    /// A calibration file's checksum does not match its contents.
    #[error(
        "calibration file {origin} is corrupted: checksum {found} does not match its contents \
         ({computed}); re-run the calibration"
    )]
    Corrupted {
        /// File name or `<string>`.
        origin: String,
        /// Checksum stored in the file.
        found: String,
        /// Checksum of the contents as read.
        computed: String,
    },
    /// A calibration file was made for another rig (name, serial or
    /// configuration hash differ, or another sample rate).
    #[error(
        "calibration file {origin} was made for another rig: file has {found}, this rig is \
         {expected}; re-run the calibration on this rig"
    )]
    WrongRig {
        /// File name or `<string>`.
        origin: String,
        /// Identity of the rig in use.
        expected: String,
        /// Identity stored in the file.
        found: String,
    },
    /// A calibration file is well formed but its contents are unusable
    /// (unstable compensator, non-finite gain, …).
    #[error("calibration file {origin} is invalid: {message}")]
    InvalidFile {
        /// File name or `<string>`.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// Reading or writing a file failed.
    #[error("cannot {action} {path}: {source}")]
    Io {
        /// "read" or "write".
        action: &'static str,
        /// Path involved.
        path: String,
        /// Underlying error.
        #[source]
        source: std::io::Error,
    },
}

impl CalibrationError {
    /// Wrap a dsp error with a context sentence.
    pub fn dsp(context: impl Into<String>, source: DspError) -> Self {
        Self::Dsp {
            context: context.into(),
            source,
        }
    }

    /// Shorthand for [`CalibrationError::InvalidConfig`].
    pub fn config(field: &str, value: impl std::fmt::Display, reason: impl Into<String>) -> Self {
        Self::InvalidConfig {
            field: field.to_owned(),
            value: value.to_string(),
            reason: reason.into(),
        }
    }

    /// Shorthand for [`CalibrationError::Measurement`].
    pub fn measurement(step: Step, message: impl Into<String>) -> Self {
        Self::Measurement {
            step,
            message: message.into(),
        }
    }
}

/// Result alias of the calibration module.
pub type Result<T> = std::result::Result<T, CalibrationError>;
