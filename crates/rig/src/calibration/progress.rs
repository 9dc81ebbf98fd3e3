//! Progress reporting and cancellation of the calibration steps.
//!
//! The GUI wizard and the command line observe the same procedure through
//! [`Progress`] (step, fraction of that step done, message) and stop it with
//! an [`AtomicBool`] cancel flag, checked before every rig run.

use super::error::{CalibrationError, Result};
pub use super::step::Step;
use std::sync::atomic::{AtomicBool, Ordering};

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

    /// A step begins: `Err(Cancelled { step })` once the cancel flag is
    /// raised, else `message` is reported at fraction 0.
    pub fn begin(&mut self, step: Step, message: &str) -> Result<()> {
        self.check_cancel(step)?;
        self.report(step, 0.0, message);
        Ok(())
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
