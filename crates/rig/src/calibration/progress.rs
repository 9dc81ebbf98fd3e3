//! Progress reporting and cancellation of the calibration steps.
//!
//! The GUI wizard and the command line observe the same procedure through
//! [`Progress`] (step, fraction of that step done, message) and stop it with
//! an [`AtomicBool`] cancel flag, checked before every rig run.

use super::error::{CalibrationError, Result};
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};

/// The seven steps of the procedure (paper §3; issue 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    /// Sensor alive and in range, rig responding, safety armed.
    Check,
    /// Low channel (Pantograph on, Haptuator off): MLS, H1, G0_L, flat band.
    IdentifyLow,
    /// High channel (Pantograph off, Haptuator on): MLS, H1, reliable band, Ĝ_H fit.
    IdentifyHigh,
    /// Crossover frequency selection.
    Crossover,
    /// K_sys, C_L = K_sys/G0_L and C_H = K_sys·F/Ĝ_H.
    Design,
    /// Stepped sines through the full chain at third-octave centres.
    Verify,
    /// Calibration file written.
    Save,
}

impl Step {
    /// All steps in procedure order.
    pub const ALL: [Step; 7] = [
        Step::Check,
        Step::IdentifyLow,
        Step::IdentifyHigh,
        Step::Crossover,
        Step::Design,
        Step::Verify,
        Step::Save,
    ];

    /// Short name, e.g. `identify-low`.
    pub fn name(self) -> &'static str {
        match self {
            Step::Check => "check",
            Step::IdentifyLow => "identify-low",
            Step::IdentifyHigh => "identify-high",
            Step::Crossover => "crossover",
            Step::Design => "design",
            Step::Verify => "verify",
            Step::Save => "save",
        }
    }

    /// Position in [`Step::ALL`] (0-based).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Fraction of the whole procedure done when this step is `fraction`
    /// done (steps weighted equally), in [0, 1].
    pub fn overall(self, fraction: f64) -> f64 {
        let f = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        (self.index() as f64 + f) / Step::ALL.len() as f64
    }
}

/// Observer of the procedure's progress.
///
/// `fraction` ∈ [0, 1] is the part of `step` done; it never decreases within
/// a step, and each step ends with a report at 1.0. `message` is a short
/// human-readable line (e.g. "low channel: run 2, amplitude 2.5 N").
pub trait Progress {
    /// Called at the start of each step, after each rig run and at the end.
    fn report(&mut self, step: Step, fraction: f64, message: &str);
}

impl<F: FnMut(Step, f64, &str)> Progress for F {
    fn report(&mut self, step: Step, fraction: f64, message: &str) {
        self(step, fraction, message);
    }
}

/// A [`Progress`] that ignores every report.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn report(&mut self, _step: Step, _fraction: f64, _message: &str) {}
}

/// What every step receives besides the rig: the progress observer and the
/// cancel flag.
pub struct StepContext<'a> {
    progress: &'a mut dyn Progress,
    cancel: &'a AtomicBool,
}

impl std::fmt::Debug for StepContext<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepContext")
            .field("cancelled", &self.cancel.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

impl<'a> StepContext<'a> {
    /// Context from an observer and a cancel flag (raise the flag from any
    /// thread to stop the procedure before its next rig run).
    pub fn new(progress: &'a mut dyn Progress, cancel: &'a AtomicBool) -> Self {
        Self { progress, cancel }
    }

    /// Report progress of `step`.
    pub fn report(&mut self, step: Step, fraction: f64, message: &str) {
        self.progress
            .report(step, fraction.clamp(0.0, 1.0), message);
    }

    /// `Err(Cancelled { step })` once the cancel flag is raised.
    pub fn check_cancel(&self, step: Step) -> Result<()> {
        if self.cancel.load(Ordering::Relaxed) {
            Err(CalibrationError::Cancelled { step })
        } else {
            Ok(())
        }
    }
}
