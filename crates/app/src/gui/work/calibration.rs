//! The calibration procedure on a background thread, for the wizard.
//!
//! [`CalibrationRun::start`] builds the simulated rig of a [`RigConfig`]
//! ([`RigAdapter::sim`], the accelerometer noise seeded) and runs
//! [`kilotouch_rig::calibration::calibrate`] (steps 1–6; the wizard saves,
//! step 7, on the user's request) on a thread of its own. The procedure's
//! [`Progress`](kilotouch_rig::calibration::Progress) reports travel to the
//! UI thread through an `mpsc` channel; the UI drains it with the
//! non-blocking [`CalibrationRun::poll`] once per frame and never waits for
//! the worker. Cancel raises the procedure's own cancel flag (checked
//! before every rig run), so a cancel takes effect within one rig run
//! (≤ one MLS record, well under a second on the simulated rig). A panic in
//! the worker is caught and reported as a failure; dropping the run raises
//! the cancel flag and detaches the thread.

use kilotouch_rig::RigConfig;
use kilotouch_rig::calibration::{
    CalibrationConfig, CalibrationError, CalibrationOutcome, RigAdapter, Step, calibrate,
};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Progress of the seven steps as the UI shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct StepProgress {
    /// Fraction done of each step of [`Step::ALL`], in [0, 1].
    pub fractions: [f64; 7],
    /// Step reported last.
    pub current: Option<Step>,
    /// Message of the last report.
    pub message: String,
}

impl Default for StepProgress {
    fn default() -> Self {
        Self {
            fractions: [0.0; 7],
            current: None,
            message: String::new(),
        }
    }
}

impl StepProgress {
    /// Record a report: `step` at `fraction` (clamped to [0, 1]; non-finite
    /// counts as 0); the steps before it are complete (the procedure runs
    /// them in order).
    pub fn apply(&mut self, step: Step, fraction: f64, message: &str) {
        let f = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let i = step.index();
        for done in &mut self.fractions[..i] {
            *done = 1.0;
        }
        self.fractions[i] = self.fractions[i].max(f);
        self.current = Some(step);
        message.clone_into(&mut self.message);
    }

    /// Whole procedure done, in [0, 1] (steps weighted equally, as
    /// [`Step::overall`]).
    pub fn overall(&self) -> f64 {
        self.fractions.iter().sum::<f64>() / self.fractions.len() as f64
    }
}

/// How a run ended.
#[derive(Debug)]
pub enum RunEnd {
    /// Steps 1–6 completed.
    Finished(Box<CalibrationOutcome>),
    /// The cancel flag stopped the procedure during this step.
    Cancelled(Step),
    /// The procedure failed (message for the user).
    Failed(String),
}

enum Msg {
    Progress(Step, f64, String),
    End(RunEnd),
}

/// A calibration running on a background thread (module documentation).
#[derive(Debug)]
pub struct CalibrationRun {
    cancel: Arc<AtomicBool>,
    rx: Option<Receiver<Msg>>,
    handle: Option<JoinHandle<()>>,
    progress: StepProgress,
    started: Instant,
    finished_after: Option<Duration>,
    pending_end: Option<RunEnd>,
}

impl std::fmt::Debug for Msg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Msg::Progress(s, x, m) => write!(f, "Progress({}, {x}, {m})", s.name()),
            Msg::End(e) => write!(f, "End({e:?})"),
        }
    }
}

fn end_of(result: Result<CalibrationOutcome, CalibrationError>) -> RunEnd {
    match result {
        Ok(o) => RunEnd::Finished(Box::new(o)),
        Err(CalibrationError::Cancelled { step }) => RunEnd::Cancelled(step),
        Err(e) => RunEnd::Failed(e.to_string()),
    }
}

impl CalibrationRun {
    /// Start calibrating the simulated rig of `rig` with `cfg`, the
    /// accelerometer noise seeded with `seed`. `repaint` (the UI's context)
    /// is asked to repaint at every progress report so that the bars move
    /// without user input.
    pub fn start(
        rig: &RigConfig,
        seed: Option<u64>,
        cfg: CalibrationConfig,
        repaint: Option<egui::Context>,
    ) -> Self {
        let cancel = Arc::new(AtomicBool::new(false));
        let (tx, rx) = mpsc::channel::<Msg>();
        let rig = rig.clone();
        let flag = Arc::clone(&cancel);
        let worker_tx = tx.clone();
        let spawned = std::thread::Builder::new()
            .name("kilotouch-calibration".into())
            .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
            .spawn(move || {
                let tx = worker_tx;
                let ctx = repaint;
                let body = std::panic::AssertUnwindSafe(|| {
                    let mut report = |step: Step, fraction: f64, message: &str| {
                        let _ = tx.send(Msg::Progress(step, fraction, message.to_owned()));
                        if let Some(c) = &ctx {
                            c.request_repaint();
                        }
                    };
                    let result = RigAdapter::sim(&rig, seed)
                        .and_then(|mut r| calibrate(&mut r, &cfg, None, &mut report, &flag));
                    end_of(result)
                });
                let end = std::panic::catch_unwind(body).unwrap_or_else(|p| {
                    let what = p
                        .downcast_ref::<&str>()
                        .map(|s| (*s).to_owned())
                        .or_else(|| p.downcast_ref::<String>().cloned())
                        .unwrap_or_else(|| "unknown panic".into());
                    RunEnd::Failed(format!("the calibration worker crashed: {what}"))
                });
                let _ = tx.send(Msg::End(end));
                if let Some(c) = &ctx {
                    c.request_repaint();
                }
            });
        let (handle, pending_end) = match spawned {
            Ok(h) => (Some(h), None),
            Err(e) => (
                None,
                Some(RunEnd::Failed(format!(
                    "cannot start the calibration thread: {e}"
                ))),
            ),
        };
        drop(tx);
        Self {
            cancel,
            rx: Some(rx),
            handle,
            progress: StepProgress::default(),
            started: Instant::now(),
            finished_after: None,
            pending_end,
        }
    }

    /// Ask the procedure to stop before its next rig run.
    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }

    /// True once [`CalibrationRun::cancel`] was called.
    pub fn cancel_requested(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }

    /// Progress so far.
    pub fn progress(&self) -> &StepProgress {
        &self.progress
    }

    /// Time since the start (frozen at the end), s.
    pub fn elapsed(&self) -> Duration {
        self.finished_after
            .unwrap_or_else(|| self.started.elapsed())
    }

    /// Drain the worker's messages without blocking; returns how the run
    /// ended, once, when it has.
    pub fn poll(&mut self) -> Option<RunEnd> {
        if let Some(end) = self.pending_end.take() {
            self.finish();
            return Some(end);
        }
        let rx = self.rx.as_ref()?;
        loop {
            match rx.try_recv() {
                // The procedure ends with "not saved" (no output file):
                // step 7 is the wizard's Save button, not the worker's.
                Ok(Msg::Progress(Step::Save, _, _)) => {}
                Ok(Msg::Progress(step, f, m)) => self.progress.apply(step, f, &m),
                Ok(Msg::End(end)) => {
                    self.finish();
                    return Some(end);
                }
                Err(TryRecvError::Empty) => return None,
                Err(TryRecvError::Disconnected) => {
                    self.finish();
                    return Some(RunEnd::Failed(
                        "the calibration worker stopped without a result".into(),
                    ));
                }
            }
        }
    }

    fn finish(&mut self) {
        self.rx = None;
        self.finished_after = Some(self.started.elapsed());
        // The worker has sent its last message: it ends at once, so the
        // join is immediate; a still-running thread is left detached.
        if let Some(h) = self.handle.take()
            && h.is_finished()
        {
            let _ = h.join();
        }
    }

    /// True until [`CalibrationRun::poll`] has returned the end.
    pub fn is_running(&self) -> bool {
        self.rx.is_some() || self.pending_end.is_some()
    }
}

impl Drop for CalibrationRun {
    fn drop(&mut self) {
        self.cancel();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Poll (as the UI does, never blocking) until the run ends.
    fn wait_end(run: &mut CalibrationRun) -> RunEnd {
        let t0 = Instant::now();
        loop {
            if let Some(e) = run.poll() {
                return e;
            }
            assert!(t0.elapsed() < Duration::from_secs(60), "no end");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn progress_marks_earlier_steps_done_and_never_decreases() {
        let mut p = StepProgress::default();
        p.apply(Step::IdentifyHigh, 0.5, "high run 1");
        assert_eq!(&p.fractions[..3], &[1.0, 1.0, 0.5]);
        assert_eq!(p.current, Some(Step::IdentifyHigh));
        p.apply(Step::IdentifyHigh, 0.25, "late report");
        assert_eq!(p.fractions[2], 0.5);
        p.apply(Step::Verify, f64::NAN, "bad fraction");
        assert_eq!(p.fractions[5], 0.0);
        p.apply(Step::Verify, 7.0, "over");
        assert_eq!(p.fractions[5], 1.0);
        // Equal weights: the same as Step::overall at the current step.
        assert!((p.overall() - Step::Verify.overall(1.0)).abs() < 1e-15);
        assert_eq!(p.message, "over");
    }

    #[test]
    fn an_invalid_configuration_ends_the_run_with_its_error() {
        let mut cfg = CalibrationConfig::default();
        cfg.low.order = 2; // outside 4..=20
        let mut run = CalibrationRun::start(&RigConfig::default(), Some(1), cfg, None);
        let end = wait_end(&mut run);
        match end {
            RunEnd::Failed(m) => assert!(m.contains("low.order"), "{m}"),
            other => panic!("expected a failure, got {other:?}"),
        }
        assert!(!run.is_running());
        assert!(run.poll().is_none());
    }

    #[test]
    fn cancel_stops_a_long_run_within_one_record() {
        // Records of 2¹⁸ − 1 samples × 16 periods per channel: the whole
        // procedure would take minutes; the flag is checked before every
        // rig run, so the stop comes after at most one record.
        let mut cfg = CalibrationConfig::default();
        for exc in [&mut cfg.low, &mut cfg.high] {
            exc.order = 18;
            exc.periods = 16;
        }
        let mut run = CalibrationRun::start(&RigConfig::default(), Some(1), cfg, None);
        run.cancel();
        assert!(run.cancel_requested());
        let end = wait_end(&mut run);
        match end {
            RunEnd::Cancelled(step) => assert!(step.index() <= Step::IdentifyHigh.index()),
            other => panic!("expected a cancellation, got {other:?}"),
        }
    }
}
