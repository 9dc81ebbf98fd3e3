//! [`SessionRunner`]: a session run inline — the store side
//! ([`SittingCore`]) and the trials on a station the runner owns (see the
//! [`super`] module documentation).

use std::fmt;

use crate::error::RunError;
use crate::export::{StudyStore, SummaryFiles, TrialRow};
use crate::participant::Participant;
use crate::protocol::Protocol;
use crate::seeds::TrialKey;
use crate::task::TrialEnd;
use crate::task::station::PrepareStation;

use super::config::RunnerConfig;
use super::engine::TrialEngine;
use super::sitting::{Next, Resumed, SittingCore, StationFrame};

/// States of a session (see the [`super`] module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunnerState {
    /// Created; [`SessionRunner::start`] begins the first pending trial.
    Idle,
    /// A practice trial (training block) is running.
    Training(TrialKey),
    /// A test trial is running.
    Trial(TrialKey),
    /// Paused by the experimenter (the trial in progress, if any, waits).
    Paused(Option<TrialKey>),
    /// Between two trials, the next one (this key) waits for the
    /// participant: inter-trial interval, break, instructions or ready
    /// screen ([`SessionRunner::set_hold`]); [`SessionRunner::proceed`]
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

/// What one `advance` / `service` call did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunnerEvents {
    /// Samples run.
    pub samples: usize,
    /// A trial began.
    pub started: Option<TrialKey>,
    /// The running trial ended (its row is not yet committed).
    pub ended: Option<(TrialKey, TrialEnd)>,
    /// A row was committed (on disk, fsynced).
    pub committed: Option<TrialRow>,
    /// Call [`SessionRunner::service`] (trial-boundary I/O is due).
    pub needs_service: bool,
    /// The session is done.
    pub done: bool,
}

/// A session run inline (module docs).
#[derive(Debug)]
pub struct SessionRunner<S: PrepareStation> {
    core: SittingCore,
    engine: TrialEngine<S>,
}

impl<S: PrepareStation> SessionRunner<S> {
    /// A runner over an open store (new or resumed) and a station.
    ///
    /// # Errors
    /// Those of [`TrialEngine::new`].
    pub fn new(store: StudyStore, station: S, cfg: RunnerConfig) -> Result<Self, RunError> {
        let frame = StationFrame {
            sample_rate_hz: station.sample_rate_hz(),
            rest_trap_m: station.rest_trap_m(),
            mapping: station.mapping(),
        };
        Ok(Self {
            core: SittingCore::new(store, frame, cfg.raw),
            engine: TrialEngine::new(station, cfg)?,
        })
    }

    /// Hold before every trial ([`SittingCore::set_hold`]): the runner goes
    /// to [`RunnerState::Waiting`] instead of beginning the next trial;
    /// [`SessionRunner::proceed`] begins it. Default `false` (headless runs
    /// go straight on).
    pub fn set_hold(&mut self, hold: bool) {
        self.core.set_hold(hold);
    }

    /// Carries out what the store side says comes next.
    fn apply<P: Participant + ?Sized>(
        &mut self,
        next: Next,
        participant: &mut P,
        ev: &mut RunnerEvents,
    ) -> Result<(), RunError> {
        match next {
            Next::Begin(setup) => {
                if let Err(e) = self.engine.start(&setup, participant) {
                    self.core.begin_failed("station error at trial start")?;
                    return Err(e);
                }
                ev.started = Some(setup.key);
            }
            Next::Wait(_) => {}
            Next::Done => ev.done = true,
        }
        Ok(())
    }

    /// Begins the trial a [`RunnerState::Waiting`] state holds.
    ///
    /// # Errors
    /// [`RunError::State`] when not waiting; storage and station errors.
    pub fn proceed<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
    ) -> Result<RunnerEvents, RunError> {
        let next = self.core.proceed()?;
        let mut ev = RunnerEvents::default();
        self.apply(next, participant, &mut ev)?;
        Ok(ev)
    }

    /// Ends this sitting cleanly without closing the study
    /// ([`SittingCore::end_sitting`]).
    ///
    /// # Errors
    /// I/O errors.
    pub fn end_sitting(&mut self, reason: &str) -> Result<(), RunError> {
        self.core.end_sitting(reason)
    }

    /// Current state.
    pub fn state(&self) -> RunnerState {
        self.core.state()
    }

    /// The store (`None` once closed).
    pub fn store(&self) -> Option<&StudyStore> {
        self.core.store()
    }

    /// The protocol the runner runs.
    pub fn protocol(&self) -> &Protocol {
        self.core.protocol()
    }

    /// The trial engine (station, current trial).
    pub fn engine(&self) -> &TrialEngine<S> {
        &self.engine
    }

    /// Summaries written when the session closed.
    pub fn summaries(&self) -> Option<&SummaryFiles> {
        self.core.summaries()
    }

    /// Begins the first pending trial (or closes the session when none is
    /// left). Valid in `Idle`.
    ///
    /// # Errors
    /// [`RunError::State`] outside `Idle`; storage and station errors.
    pub fn start<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
    ) -> Result<RunnerEvents, RunError> {
        let next = self.core.start()?;
        let mut ev = RunnerEvents::default();
        self.apply(next, participant, &mut ev)?;
        Ok(ev)
    }

    /// Runs up to `n` samples of the current trial. No file I/O other than
    /// the raw sink; does nothing while idle, paused, done or when the
    /// trial has ended and awaits [`SessionRunner::service`].
    ///
    /// # Errors
    /// Station and raw-file errors.
    pub fn advance<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
        n: usize,
    ) -> Result<RunnerEvents, RunError> {
        let mut ev = RunnerEvents::default();
        if !matches!(
            self.core.state(),
            RunnerState::Training(_) | RunnerState::Trial(_)
        ) {
            return Ok(ev);
        }
        if self.engine.end().is_some() {
            ev.needs_service = true;
            return Ok(ev);
        }
        if !self.core.has_active_trial() {
            return Err(RunError::State("no active trial".into()));
        }
        let before = self.engine.samples();
        let mut sink = self.core.raw_mut();
        let end = self.engine.run(participant, &mut sink, n)?;
        ev.samples = (self.engine.samples() - before) as usize;
        if let (Some(e), Some(k)) = (end, self.engine.key()) {
            ev.ended = Some((k, e));
            ev.needs_service = true;
        }
        Ok(ev)
    }

    /// Trial-boundary I/O: when the current trial has ended, finishes its
    /// raw file and commits its row (append + fsync); then, unless paused,
    /// begins the next pending trial (or closes the session).
    ///
    /// # Errors
    /// Storage and station errors.
    pub fn service<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
    ) -> Result<RunnerEvents, RunError> {
        let mut ev = RunnerEvents::default();
        if self.engine.end().is_none() {
            return Ok(ev);
        }
        let outcome = self.engine.outcome()?;
        if let Some((row, next)) = self.core.commit(&outcome)? {
            ev.committed = Some(row);
            if let Some(next) = next {
                self.apply(next, participant, &mut ev)?;
            }
        }
        Ok(ev)
    }

    /// Pauses the session (journaled); the running trial waits.
    ///
    /// # Errors
    /// [`RunError::State`] when idle, done or already paused; I/O errors.
    pub fn pause(&mut self, reason: &str) -> Result<(), RunError> {
        self.core.pause(reason)
    }

    /// Ends a pause (journaled): continues the waiting trial, or begins the
    /// next one when the pause came between trials.
    ///
    /// # Errors
    /// [`RunError::State`] when not paused; storage and station errors.
    pub fn resume<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
    ) -> Result<RunnerEvents, RunError> {
        let mut ev = RunnerEvents::default();
        match self.core.resume()? {
            Resumed::Continue => ev.needs_service = self.engine.end().is_some(),
            Resumed::Next(next) => self.apply(next, participant, &mut ev)?,
        }
        Ok(ev)
    }

    /// Aborts the running trial: it ends now and its row is committed by the
    /// next [`SessionRunner::service`] with `reject_reason = aborted` (the
    /// metrics recorded so far are kept). Nothing is lost.
    ///
    /// # Errors
    /// [`RunError::State`] without a running trial.
    pub fn abort_trial(&mut self) -> Result<RunnerEvents, RunError> {
        self.core.check_abort()?;
        self.engine.abort();
        let mut ev = RunnerEvents::default();
        if let (Some(k), Some(e)) = (self.engine.key(), self.engine.end()) {
            ev.ended = Some((k, e));
        }
        ev.needs_service = true;
        Ok(ev)
    }

    /// Journals an experimenter note.
    ///
    /// # Errors
    /// After the session closed; I/O errors.
    pub fn note(&mut self, text: &str) -> Result<(), RunError> {
        self.core.note(text)
    }

    /// Runs the whole remaining session headless: start (if idle), then
    /// `advance` in blocks of `block` samples and `service` at every trial
    /// boundary until done. `progress(completed, planned)` is called after
    /// every commit.
    ///
    /// # Errors
    /// Those of the steps; [`RunError::State`] when paused.
    pub fn run_to_end<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
        block: usize,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<(), RunError> {
        let (mut completed, planned) = match self.core.store() {
            Some(s) => (s.completed_count(), s.plan().len()),
            None => return Ok(()),
        };
        if self.core.state() == RunnerState::Idle {
            self.start(participant)?;
        }
        let block = block.max(1);
        loop {
            match self.core.state() {
                RunnerState::Done => return Ok(()),
                RunnerState::Paused(_) => {
                    return Err(RunError::State("paused: resume before run_to_end".into()));
                }
                RunnerState::Waiting(_) => {
                    self.proceed(participant)?;
                }
                _ => {}
            }
            let ev = self.advance(participant, block)?;
            if ev.needs_service && self.service(participant)?.committed.is_some() {
                completed += 1;
                progress(completed, planned);
            }
        }
    }
}
