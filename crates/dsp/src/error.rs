//! Typed errors of the dsp crate.

use thiserror::Error;

/// Every fallible operation in `kilotouch-dsp` returns this error.
///
/// Variants name the offending parameter so that callers (CLI, calibration
/// wizard) can report *what* was wrong without guessing.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum DspError {
    /// A scalar parameter is outside its valid range.
    #[error("invalid parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// Parameter name as the user sees it (e.g. `fc`, `nperseg`).
        name: &'static str,
        /// Offending value (converted to f64 for reporting).
        value: f64,
        /// Why it is invalid, e.g. "must be in (0, fs/2)".
        reason: String,
    },
    /// Input data are unusable (empty, too short, non-finite, mismatched lengths).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A polynomial or transfer function is degenerate (zero leading coefficient, empty, …).
    #[error("degenerate polynomial or transfer function: {0}")]
    Degenerate(String),
    /// A numerical routine failed to converge or met a singular system.
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// A transfer function cannot be inverted safely because it has zeros in
    /// the right half plane (non-minimum phase). The minimum-phase reflection
    /// is offered in `minimum_phase` (numerator and denominator, descending
    /// powers of s).
    #[error(
        "cannot invert: {count} zero(s) in the right half plane at {zeros:?} rad/s; \
         use the minimum-phase reflection instead"
    )]
    RightHalfPlaneZeros {
        /// Number of zeros with positive real part.
        count: usize,
        /// The offending zeros, formatted as strings `re±im j`.
        zeros: Vec<String>,
        /// Minimum-phase reflection of the model (same magnitude response).
        minimum_phase: Box<crate::tf::Tf>,
    },
    /// A transfer function is improper (more zeros than poles) where a proper
    /// one is required.
    #[error(
        "transfer function is not proper: numerator degree {num_degree} > denominator degree {den_degree}"
    )]
    NotProper {
        /// Degree of the numerator polynomial.
        num_degree: usize,
        /// Degree of the denominator polynomial.
        den_degree: usize,
    },
    /// A system is unstable where a stable one is required.
    #[error("unstable system: {0}")]
    Unstable(String),
}

impl DspError {
    /// Shorthand for [`DspError::InvalidParameter`].
    pub fn param(name: &'static str, value: f64, reason: impl Into<String>) -> Self {
        Self::InvalidParameter {
            name,
            value,
            reason: reason.into(),
        }
    }
}

/// `value` must be finite and > 0; otherwise `InvalidParameter` naming
/// `name`.
pub(crate) fn check_positive(name: &'static str, value: f64) -> crate::Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(DspError::param(name, value, "must be finite and > 0"))
    }
}

/// `value` must be finite and ≥ 0; otherwise `InvalidParameter` naming
/// `name`.
pub(crate) fn check_non_negative(name: &'static str, value: f64) -> crate::Result<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(DspError::param(name, value, "must be finite and ≥ 0"))
    }
}

/// A sample rate must be finite and positive (hertz).
pub(crate) fn check_fs(fs: f64) -> crate::Result<()> {
    if fs.is_finite() && fs > 0.0 {
        Ok(())
    } else {
        Err(DspError::param(
            "fs",
            fs,
            "sample rate must be finite and > 0",
        ))
    }
}
