//! [`SessionRunner`]: the session state machine over a [`StudyStore`] (see
//! the [`super`] module documentation).

use std::fmt;

use crate::error::RunError;
use crate::export::{StudyStore, SummaryFiles, TrialRow, TrialTicket, UtcTime};
use crate::participant::Participant;
use crate::protocol::Protocol;
use crate::rawsig::NpyWriter;
use crate::seeds::{Phase, TrialKey};
use crate::task::TrialEnd;
use crate::task::station::Station;

use super::config::RunnerConfig;
use super::engine::TrialEngine;
use super::raw::{raw_layout, with_scene};

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

#[derive(Debug)]
struct Active {
    ticket: TrialTicket,
    raw: Option<NpyWriter>,
}

/// The session state machine (see the [`super`] module documentation).
#[derive(Debug)]
pub struct SessionRunner<S: Station> {
    store: Option<StudyStore>,
    protocol: Protocol,
    engine: TrialEngine<S>,
    state: RunnerState,
    before_pause: Option<RunnerState>,
    active: Option<Active>,
    summaries: Option<SummaryFiles>,
    hold: bool,
}

impl<S: Station> SessionRunner<S> {
    /// A runner over an open store (new or resumed) and a station.
    ///
    /// # Errors
    /// Those of [`TrialEngine::new`].
    pub fn new(store: StudyStore, station: S, cfg: RunnerConfig) -> Result<Self, RunError> {
        let protocol = store.protocol().clone();
        Ok(Self {
            store: Some(store),
            protocol,
            engine: TrialEngine::new(station, cfg)?,
            state: RunnerState::Idle,
            before_pause: None,
            active: None,
            summaries: None,
            hold: false,
        })
    }

    /// Hold before every trial (`true`): [`SessionRunner::start`], a
    /// committed trial and the end of a pause between trials go to
    /// [`RunnerState::Waiting`] instead of beginning the next trial, so
    /// that the participant's screens (instructions, ready, inter-trial
    /// interval, break) run first; [`SessionRunner::proceed`] begins it.
    /// Default `false` (headless runs go straight on).
    pub fn set_hold(&mut self, hold: bool) {
        self.hold = hold;
    }

    /// Begins the trial a [`RunnerState::Waiting`] state holds.
    ///
    /// # Errors
    /// [`RunError::State`] when not waiting; storage and station errors.
    pub fn proceed<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
    ) -> Result<RunnerEvents, RunError> {
        if !matches!(self.state, RunnerState::Waiting(_)) {
            return Err(RunError::State(format!(
                "nothing waits to begin while {}",
                self.state
            )));
        }
        let mut ev = RunnerEvents::default();
        self.begin_next(participant, &mut ev)?;
        Ok(ev)
    }

    /// Goes to [`RunnerState::Waiting`] for the next pending trial when
    /// holding and one is left; otherwise begins it (or closes the study).
    fn next_or_wait<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
        ev: &mut RunnerEvents,
    ) -> Result<(), RunError> {
        if self.hold
            && let Some(key) = self.store_mut()?.next_pending().map(|p| p.key)
        {
            self.state = RunnerState::Waiting(key);
            return Ok(());
        }
        self.begin_next(participant, ev)
    }

    /// Ends this sitting cleanly without closing the study (the next
    /// participant, or a later sitting, resumes the folder): a trial in
    /// progress is journaled as aborted with `reason` (no row; it runs
    /// again on resume) and the sitting's `session_done` is written, so the
    /// next opening does not report an unclosed sitting. The runner is
    /// closed afterwards (no store).
    ///
    /// # Errors
    /// I/O errors.
    pub fn end_sitting(&mut self, reason: &str) -> Result<(), RunError> {
        if let Some(active) = self.active.take() {
            self.store_mut()?.abort_trial(active.ticket, reason)?;
        }
        if let Some(store) = self.store.take() {
            store.end_sitting()?;
        }
        Ok(())
    }

    /// Current state.
    pub fn state(&self) -> RunnerState {
        self.state
    }

    /// The store (`None` once closed).
    pub fn store(&self) -> Option<&StudyStore> {
        self.store.as_ref()
    }

    /// The protocol the runner runs.
    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    /// The trial engine (station, current trial).
    pub fn engine(&self) -> &TrialEngine<S> {
        &self.engine
    }

    /// Summaries written when the session closed.
    pub fn summaries(&self) -> Option<&SummaryFiles> {
        self.summaries.as_ref()
    }

    fn store_mut(&mut self) -> Result<&mut StudyStore, RunError> {
        self.store
            .as_mut()
            .ok_or_else(|| RunError::State("the session is closed".into()))
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
        if self.state != RunnerState::Idle {
            return Err(RunError::State(format!(
                "cannot start while {}",
                self.state
            )));
        }
        let mut ev = RunnerEvents::default();
        self.next_or_wait(participant, &mut ev)?;
        Ok(ev)
    }

    fn begin_next<P: Participant + ?Sized>(
        &mut self,
        participant: &mut P,
        ev: &mut RunnerEvents,
    ) -> Result<(), RunError> {
        let next = self.store_mut()?.next_pending().map(|p| p.key);
        let Some(key) = next else {
            if let Some(store) = self.store.take() {
                self.summaries = Some(store.close()?);
            }
            self.state = RunnerState::Done;
            ev.done = true;
            return Ok(());
        };
        let setup = self.engine.setup(&self.protocol, key);
        let fs = self.engine.sample_rate_hz();
        let dtype = self.engine.config().raw;
        let store = self.store_mut()?;
        let mut ticket = store.begin_trial(key, UtcTime::now())?;
        let raw = match dtype {
            Some(d) => {
                match store.raw_writer(&mut ticket, with_scene(raw_layout(fs, d), &setup.scene)) {
                    Ok(w) => Some(w),
                    Err(e) => {
                        store.abort_trial(ticket, "raw file could not be created")?;
                        return Err(e.into());
                    }
                }
            }
            None => None,
        };
        if let Err(e) = self.engine.start(&setup, participant) {
            self.store_mut()?
                .abort_trial(ticket, "station error at trial start")?;
            return Err(e);
        }
        self.active = Some(Active { ticket, raw });
        self.state = match key.phase {
            Phase::Practice => RunnerState::Training(key),
            Phase::Test => RunnerState::Trial(key),
        };
        ev.started = Some(key);
        Ok(())
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
        if !matches!(self.state, RunnerState::Training(_) | RunnerState::Trial(_)) {
            return Ok(ev);
        }
        if self.engine.end().is_some() {
            ev.needs_service = true;
            return Ok(ev);
        }
        let Some(active) = self.active.as_mut() else {
            return Err(RunError::State("no active trial".into()));
        };
        let before = self.engine.samples();
        let mut sink = active.raw.as_mut();
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
        if self.engine.end().is_some()
            && let Some(active) = self.active.take()
        {
            let outcome = self.engine.outcome()?;
            let mut row = active.ticket.row();
            outcome.metrics.fill_row(&mut row);
            if let Some(w) = active.raw {
                w.finish()?;
            }
            self.store_mut()?.commit_trial(active.ticket, &row)?;
            ev.committed = Some(row);
            match self.state {
                RunnerState::Paused(_) => self.state = RunnerState::Paused(None),
                _ => self.next_or_wait(participant, &mut ev)?,
            }
        }
        Ok(ev)
    }

    /// Pauses the session (journaled); the running trial waits.
    ///
    /// # Errors
    /// [`RunError::State`] when idle, done or already paused; I/O errors.
    pub fn pause(&mut self, reason: &str) -> Result<(), RunError> {
        let trial = match self.state {
            RunnerState::Training(k) | RunnerState::Trial(k) => Some(k),
            RunnerState::Waiting(_) => None,
            s => return Err(RunError::State(format!("cannot pause while {s}"))),
        };
        self.store_mut()?.pause(reason)?;
        self.before_pause = Some(self.state);
        self.state = RunnerState::Paused(trial);
        Ok(())
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
        let RunnerState::Paused(trial) = self.state else {
            return Err(RunError::State(format!(
                "cannot resume while {}",
                self.state
            )));
        };
        self.store_mut()?.resume()?;
        let mut ev = RunnerEvents::default();
        match trial {
            Some(_) => {
                self.state = self.before_pause.take().unwrap_or(RunnerState::Idle);
                ev.needs_service = self.engine.end().is_some();
            }
            None => {
                self.before_pause = None;
                self.next_or_wait(participant, &mut ev)?;
            }
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
        match self.state {
            RunnerState::Training(_) | RunnerState::Trial(_) | RunnerState::Paused(Some(_)) => {
                self.engine.abort();
                let mut ev = RunnerEvents::default();
                if let (Some(k), Some(e)) = (self.engine.key(), self.engine.end()) {
                    ev.ended = Some((k, e));
                }
                ev.needs_service = true;
                Ok(ev)
            }
            s => Err(RunError::State(format!("no trial to abort while {s}"))),
        }
    }

    /// Journals an experimenter note.
    ///
    /// # Errors
    /// After the session closed; I/O errors.
    pub fn note(&mut self, text: &str) -> Result<(), RunError> {
        self.store_mut()?.note(text)?;
        Ok(())
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
        let (mut completed, planned) = match &self.store {
            Some(s) => (s.completed_count(), s.plan().len()),
            None => return Ok(()),
        };
        if self.state == RunnerState::Idle {
            self.start(participant)?;
        }
        let block = block.max(1);
        loop {
            match self.state {
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
