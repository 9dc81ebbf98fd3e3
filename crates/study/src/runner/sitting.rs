//! [`SittingCore`]: the store side of a session — the state machine
//! `Idle → Training/Trial → … → Done` with pauses, waits and aborts, and
//! the trial-boundary I/O (journal, raw file, committed row) — apart from
//! where trials run. It never runs a sample: it says which trial to begin
//! ([`Next::Begin`]) and takes each finished trial's outcome
//! ([`SittingCore::commit`]).
//!
//! Two drivers: [`super::SessionRunner`] runs the trials inline on a
//! station it owns (headless runs, `study simulate`'s reference), and the
//! app's sitting runs this core on a worker thread while the trials run
//! on the real-time engine's loop. Either way a trial is the same function
//! of its key and a row is committed (append + fsync) before the next
//! trial begins.

use kilotouch_rig::coupling::HandMapping;

use crate::error::RunError;
use crate::export::{StudyStore, SummaryFiles, TrialRow, TrialTicket, UtcTime};
use crate::protocol::Protocol;
use crate::rawsig::{Dtype, NpyWriter};
use crate::seeds::{Phase, TrialKey};

use super::raw::{raw_layout, with_scene};
use super::setup::TrialSetup;
use super::state::RunnerState;
use super::trial::TrialOutcome;

/// What the trial side must do next.
#[derive(Debug)]
pub enum Next {
    /// Begin this trial (its beginning is journaled; its raw file, if any,
    /// is open in the core).
    Begin(Box<TrialSetup>),
    /// Hold: the next trial (this key) waits for the participant
    /// ([`SittingCore::set_hold`]).
    Wait(TrialKey),
    /// Every trial has its row; the store is closed and the summaries
    /// written.
    Done,
}

/// What ending a pause means for the trial side.
#[derive(Debug)]
pub enum Resumed {
    /// The trial that was paused goes on.
    Continue,
    /// The pause came between trials: this comes next.
    Next(Next),
}

/// Where a station's trials start (what a [`TrialSetup`] needs of it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StationFrame {
    /// The station's sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Trap position with the handle at its origin, m.
    pub rest_trap_m: [f64; 2],
    /// The hand ↔ trap mapping.
    pub mapping: HandMapping,
}

#[derive(Debug)]
struct Active {
    ticket: TrialTicket,
    raw: Option<NpyWriter>,
}

/// The store side of a session (module docs).
#[derive(Debug)]
pub struct SittingCore {
    store: Option<StudyStore>,
    protocol: Protocol,
    frame: StationFrame,
    raw: Option<Dtype>,
    state: RunnerState,
    before_pause: Option<RunnerState>,
    active: Option<Active>,
    summaries: Option<SummaryFiles>,
    hold: bool,
}

impl SittingCore {
    /// A core over an open store (new or resumed) for trials on a station
    /// described by `frame`, with raw files of type `raw` (`None`: none).
    pub fn new(store: StudyStore, frame: StationFrame, raw: Option<Dtype>) -> Self {
        let protocol = store.protocol().clone();
        Self {
            store: Some(store),
            protocol,
            frame,
            raw,
            state: RunnerState::Idle,
            before_pause: None,
            active: None,
            summaries: None,
            hold: false,
        }
    }

    /// Hold before every trial (`true`): [`Self::start`], a committed trial
    /// and the end of a pause between trials give [`Next::Wait`] instead of
    /// beginning the next trial, so that the participant's screens run
    /// first; [`Self::proceed`] begins it. Default `false`.
    pub fn set_hold(&mut self, hold: bool) {
        self.hold = hold;
    }

    /// Current state.
    pub fn state(&self) -> RunnerState {
        self.state
    }

    /// The store (`None` once closed).
    pub fn store(&self) -> Option<&StudyStore> {
        self.store.as_ref()
    }

    /// The protocol.
    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    /// Summaries written when the session closed.
    pub fn summaries(&self) -> Option<&SummaryFiles> {
        self.summaries.as_ref()
    }

    /// The raw file of the running trial, if raw files are on.
    pub fn raw_mut(&mut self) -> Option<&mut NpyWriter> {
        self.active.as_mut().and_then(|a| a.raw.as_mut())
    }

    /// Is a trial running or paused in (begun and not yet committed)?
    pub fn has_active_trial(&self) -> bool {
        self.active.is_some()
    }

    fn store_mut(&mut self) -> Result<&mut StudyStore, RunError> {
        self.store
            .as_mut()
            .ok_or_else(|| RunError::State("the session is closed".into()))
    }

    /// The setup of trial `key` on this core's station.
    pub fn setup(&self, key: TrialKey) -> TrialSetup {
        TrialSetup::new(
            &self.protocol,
            key,
            self.frame.rest_trap_m,
            self.frame.mapping,
        )
    }

    /// What comes first. Valid in `Idle`.
    ///
    /// # Errors
    /// [`RunError::State`] outside `Idle`; storage errors.
    pub fn start(&mut self) -> Result<Next, RunError> {
        if self.state != RunnerState::Idle {
            return Err(RunError::State(format!(
                "cannot start while {}",
                self.state
            )));
        }
        self.next_or_wait()
    }

    /// Begins the trial a [`RunnerState::Waiting`] state holds.
    ///
    /// # Errors
    /// [`RunError::State`] when not waiting; storage errors.
    pub fn proceed(&mut self) -> Result<Next, RunError> {
        if !matches!(self.state, RunnerState::Waiting(_)) {
            return Err(RunError::State(format!(
                "nothing waits to begin while {}",
                self.state
            )));
        }
        self.begin_next()
    }

    /// [`Next::Wait`] for the next pending trial when holding and one is
    /// left; otherwise begins it (or closes the study).
    fn next_or_wait(&mut self) -> Result<Next, RunError> {
        if self.hold
            && let Some(key) = self.store_mut()?.next_pending().map(|p| p.key)
        {
            self.state = RunnerState::Waiting(key);
            return Ok(Next::Wait(key));
        }
        self.begin_next()
    }

    fn begin_next(&mut self) -> Result<Next, RunError> {
        let next = self.store_mut()?.next_pending().map(|p| p.key);
        let Some(key) = next else {
            if let Some(store) = self.store.take() {
                self.summaries = Some(store.close()?);
            }
            self.state = RunnerState::Done;
            return Ok(Next::Done);
        };
        let setup = self.setup(key);
        let fs = self.frame.sample_rate_hz;
        let dtype = self.raw;
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
        self.active = Some(Active { ticket, raw });
        self.state = match key.phase {
            Phase::Practice => RunnerState::Training(key),
            Phase::Test => RunnerState::Trial(key),
        };
        Ok(Next::Begin(Box::new(setup)))
    }

    /// The trial side could not begin the trial [`Next::Begin`] gave:
    /// its beginning is journaled as aborted with `why` (no row; it runs
    /// again on resume) and the session pauses between trials.
    ///
    /// # Errors
    /// I/O errors.
    pub fn begin_failed(&mut self, why: &str) -> Result<(), RunError> {
        if let Some(active) = self.active.take() {
            self.store_mut()?.abort_trial(active.ticket, why)?;
        }
        if !matches!(self.state, RunnerState::Done) {
            self.store_mut()?.pause(why)?;
            self.before_pause = None;
            self.state = RunnerState::Paused(None);
        }
        Ok(())
    }

    /// Commits the finished trial `outcome` (its raw file finished, its row
    /// appended and fsynced) and says what comes next: `None` while paused
    /// (the session stays paused between trials), else the next step.
    /// `Ok(None)` also when no trial is active.
    ///
    /// # Errors
    /// Storage errors.
    pub fn commit(
        &mut self,
        outcome: &TrialOutcome,
    ) -> Result<Option<(TrialRow, Option<Next>)>, RunError> {
        let Some(active) = self.active.take() else {
            return Ok(None);
        };
        let mut row = active.ticket.row();
        outcome.metrics.fill_row(&mut row);
        if let Some(w) = active.raw {
            w.finish()?;
        }
        self.store_mut()?.commit_trial(active.ticket, &row)?;
        let next = match self.state {
            RunnerState::Paused(_) => {
                self.state = RunnerState::Paused(None);
                None
            }
            _ => Some(self.next_or_wait()?),
        };
        Ok(Some((row, next)))
    }

    /// Pauses the session (journaled); a running trial waits.
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

    /// Ends a pause (journaled): the waiting trial goes on, or the next one
    /// comes when the pause came between trials.
    ///
    /// # Errors
    /// [`RunError::State`] when not paused; storage errors.
    pub fn resume(&mut self) -> Result<Resumed, RunError> {
        let RunnerState::Paused(trial) = self.state else {
            return Err(RunError::State(format!(
                "cannot resume while {}",
                self.state
            )));
        };
        self.store_mut()?.resume()?;
        match trial {
            Some(_) => {
                self.state = self.before_pause.take().unwrap_or(RunnerState::Idle);
                Ok(Resumed::Continue)
            }
            None => {
                self.before_pause = None;
                Ok(Resumed::Next(self.next_or_wait()?))
            }
        }
    }

    /// May the running trial be aborted now (one is running or paused in)?
    ///
    /// # Errors
    /// [`RunError::State`] naming the state otherwise.
    pub fn check_abort(&self) -> Result<(), RunError> {
        match self.state {
            RunnerState::Training(_) | RunnerState::Trial(_) | RunnerState::Paused(Some(_)) => {
                Ok(())
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

    /// The timing verdict the sitting's `session_done` records (the store's
    /// [`StudyStore::set_timing`]); nothing once the store is closed.
    pub fn set_timing(&mut self, t: Option<crate::export::SittingTiming>) {
        if let Some(store) = self.store.as_mut() {
            store.set_timing(t);
        }
    }

    /// Ends this sitting cleanly without closing the study (the next
    /// participant, or a later sitting, resumes the folder): a trial in
    /// progress is journaled as aborted with `reason` (no row; it runs
    /// again on resume) and the sitting's `session_done` is written. The
    /// core is closed afterwards (no store).
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
}
