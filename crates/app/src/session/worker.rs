//! The store side of a sitting on its own thread (`kilotouch-sitting`):
//! the study crate's [`SittingCore`] (journal, raw files, committed rows,
//! the state machine), the building of each trial's parts
//! ([`TrialSlot`], off the real-time path) and the participant's screens'
//! timing. It paces nothing: it waits on the GUI's commands with a short
//! time-out and, in between, drains the engine driver's messages and the
//! raw rows. Events to the GUI go through an unbounded channel (nothing the
//! experimenter must see is dropped).

use std::sync::mpsc;
use std::time::{Duration, Instant};

use kilotouch_rig::AnyTweezer;
use kilotouch_rig::tweezer::{DetectedTweezer, DetectorConfig};
use kilotouch_study::runner::{
    Next, RAW_CHANNELS, Resumed, RunError, RunnerConfig, RunnerState, SittingCore, TrialSetup,
    trajectory_capacity,
};
use kilotouch_study::seeds::TrialKey;
use kilotouch_study::task::Scene;
use kilotouch_study::task::trial_kit::KitBuilder;

use super::driver::{FromDriver, ToDriver, TrialSlot};
use super::{FinishReason, SIM_READ_S, SessionCommand, SessionEvent, Speed};

/// How often the worker looks at the driver's queues and the raw rows
/// while no command arrives.
const POLL: Duration = Duration::from_millis(2);

/// Longest wait for the driver to hand back the trial in progress when the
/// sitting stops (the engine runs a block every millisecond; a stopped
/// engine never answers).
const DETACH_WAIT: Duration = Duration::from_secs(2);

/// Who is at the handle, as the screens' timing needs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Reader {
    /// A person (or a device's own participant): the ready screen waits for
    /// the GUI's [`SessionCommand::Proceed`].
    Person,
    /// The host's simulated participant: it "reads" for [`SIM_READ_S`].
    Simulated,
}

/// The worker's state (module docs).
pub(crate) struct Worker {
    pub core: SittingCore,
    pub kits: KitBuilder,
    pub detector: DetectorConfig,
    pub runner: RunnerConfig,
    pub fs: f64,
    pub to_driver: rtrb::Producer<ToDriver>,
    pub from_driver: rtrb::Consumer<FromDriver>,
    pub raw_rx: rtrb::Consumer<[f64; RAW_CHANNELS]>,
    pub cmd_rx: mpsc::Receiver<SessionCommand>,
    pub ev_tx: mpsc::Sender<SessionEvent>,
    pub only_participant: Option<u32>,
    pub screens: bool,
    pub speed: Speed,
    pub reader: Reader,
    /// The scene of the trial sent to the driver.
    pub scene: Option<(TrialKey, Scene)>,
    pub last_ended: Option<TrialKey>,
    pub waiting_since: Option<Instant>,
    pub last_state: Option<RunnerState>,
    /// A live tweezer's obstacle (the one the protocol's scene uses), in
    /// the instrument's frame, m: each trial's frame is placed so that it
    /// sits where the trial's scene puts the obstacle.
    pub live_obstacle_m: Option<[f64; 2]>,
    /// What the driver counts (the timing verdict's inputs).
    pub counters: std::sync::Arc<super::driver::SittingCounters>,
    /// Samples per engine block.
    pub block_len: u64,
    /// The rig file's `sitting_max_late_fraction`.
    pub max_late_fraction: f64,
}

impl std::fmt::Debug for Worker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Worker")
            .field("state", &self.core.state())
            .finish_non_exhaustive()
    }
}

impl Worker {
    fn emit(&self, e: SessionEvent) {
        // The GUI side may be gone (dropped handle): nothing to tell then.
        let _ = self.ev_tx.send(e);
    }

    fn emit_state(&mut self) {
        let s = self.core.state();
        if self.last_state != Some(s) {
            self.last_state = Some(s);
            self.emit(SessionEvent::State(s));
        }
    }

    fn tell(&mut self, m: ToDriver) -> Result<(), RunError> {
        self.to_driver
            .push(m)
            .map_err(|_| RunError::State("the engine does not take commands (queue full)".into()))
    }

    /// The thread body: runs until the sitting ends, then reports why.
    pub fn run(mut self) {
        self.core.set_hold(self.screens);
        self.emit_state();
        let mut reason = match self.run_loop() {
            Ok(r) => r,
            Err(e) => FinishReason::Failed(e.to_string()),
        };
        let why = match &reason {
            FinishReason::ParticipantDone(id) => Some(format!("participant {id} finished")),
            FinishReason::Stopped => Some("sitting stopped by the experimenter".to_owned()),
            FinishReason::Failed(e) => Some(format!("sitting ended: {e}")),
            FinishReason::StudyDone => None,
        };
        if let Some(why) = why {
            self.detach();
            self.update_timing();
            if let Err(e) = self.core.end_sitting(&why)
                && !matches!(reason, FinishReason::Failed(_))
            {
                reason = FinishReason::Failed(format!("ending the sitting: {e}"));
            }
        }
        self.emit_state();
        self.emit(SessionEvent::Finished(reason));
    }

    /// Takes the trial in progress back from the driver (unrecorded: it
    /// runs again on resume), waiting a bounded time.
    fn detach(&mut self) {
        if self.tell(ToDriver::Detach).is_err() {
            return;
        }
        let t0 = Instant::now();
        while t0.elapsed() < DETACH_WAIT {
            match self.from_driver.pop() {
                // The trial in progress comes back to be dropped here.
                Ok(FromDriver::Detached(slot)) => {
                    drop(slot);
                    return;
                }
                Ok(FromDriver::DeviceFailed(..)) => return,
                Ok(_) => {}
                Err(_) => std::thread::sleep(POLL),
            }
        }
    }

    fn run_loop(&mut self) -> Result<FinishReason, RunError> {
        loop {
            match self.cmd_rx.recv_timeout(POLL) {
                Ok(cmd) => {
                    if let Some(r) = self.command(cmd)? {
                        return Ok(r);
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => return Ok(FinishReason::Stopped),
            }
            self.drain_raw()?;
            while let Ok(m) = self.from_driver.pop() {
                if let Some(r) = self.driver_message(m)? {
                    return Ok(r);
                }
            }
            if let Some(r) = self.screens_timing()? {
                return Ok(r);
            }
            self.emit_state();
        }
    }

    /// Raw rows of the running trial into its file.
    fn drain_raw(&mut self) -> Result<(), RunError> {
        while let Ok(row) = self.raw_rx.pop() {
            if let Some(w) = self.core.raw_mut() {
                w.push(&row)?;
            }
        }
        Ok(())
    }

    /// Carries out what the store side says comes next.
    fn apply(&mut self, next: Next) -> Result<Option<FinishReason>, RunError> {
        match next {
            Next::Begin(setup) => {
                let slot = match self.slot(*setup) {
                    Ok(s) => s,
                    Err(e) => {
                        self.core
                            .begin_failed("the trial's parts could not be built")?;
                        return Err(e);
                    }
                };
                self.scene = Some((slot.setup.key, slot.setup.scene));
                self.tell(ToDriver::Begin(slot))?;
            }
            Next::Wait(_) => self.waiting_since = None,
            Next::Done => return Ok(Some(FinishReason::StudyDone)),
        }
        self.emit_state();
        Ok(None)
    }

    /// A trial's parts (module docs of [`super::driver`]).
    fn slot(&mut self, setup: TrialSetup) -> Result<Box<TrialSlot>, RunError> {
        let mut rng = setup.rig_rng.clone();
        let kit = self.kits.build(
            &setup.scene,
            setup.feedback.condition,
            setup.params.escape_distance_m(),
            1,
            &mut rng,
        )?;
        let tweezer = DetectedTweezer::wrap(kit.tweezer, &self.detector)?;
        let cap = trajectory_capacity(&self.runner, self.fs, &setup, 1)?;
        let c = setup.scene.geometry.obstacle_m;
        let tweezer_origin_m = self
            .live_obstacle_m
            .map_or([0.0; 2], |o| [o[0] - c[0], o[1] - c[1]]);
        Ok(Box::new(TrialSlot {
            setup,
            rig: kit.rig.map(Box::new),
            tweezer: AnyTweezer::Sim(Box::new(tweezer)),
            tweezer_origin_m,
            safety: Box::new(kit.safety),
            trajectory: Vec::with_capacity(cap),
            outcome: None,
            end: None,
            raw_dropped: 0,
        }))
    }

    fn command(&mut self, cmd: SessionCommand) -> Result<Option<FinishReason>, RunError> {
        let r = match cmd {
            SessionCommand::Start => self.core.start().and_then(|n| self.apply(n)),
            SessionCommand::Pause => {
                let running = matches!(
                    self.core.state(),
                    RunnerState::Training(_) | RunnerState::Trial(_)
                );
                self.core.pause("experimenter").and_then(|()| {
                    if running {
                        self.tell(ToDriver::Pause)?;
                    }
                    Ok(None)
                })
            }
            SessionCommand::Resume => {
                if self.core.state() == RunnerState::Paused(None) {
                    // After a pause between trials (or an emergency stop)
                    // the next trial starts a new block: instructions and
                    // the ready screen again, not a bare interval.
                    self.last_ended = None;
                }
                match self.core.resume() {
                    Ok(Resumed::Continue) => self.tell(ToDriver::Resume).map(|()| None),
                    Ok(Resumed::Next(n)) => self.apply(n),
                    Err(e) => Err(e),
                }
            }
            SessionCommand::AbortTrial => self
                .core
                .check_abort()
                .and_then(|()| self.tell(ToDriver::Abort))
                .map(|()| None),
            SessionCommand::Note(text) => {
                let text = text.trim().to_owned();
                if text.is_empty() {
                    Ok(None)
                } else {
                    self.core.note(&text).map(|()| {
                        self.emit(SessionEvent::Noted(text));
                        None
                    })
                }
            }
            // The engine's one emergency stop was pressed by the handle;
            // what it did arrives from the driver.
            SessionCommand::EmergencyStop => Ok(None),
            SessionCommand::Proceed => {
                if matches!(self.core.state(), RunnerState::Waiting(_)) {
                    self.core.proceed().and_then(|n| self.apply(n))
                } else {
                    Ok(None)
                }
            }
            SessionCommand::Stop => return Ok(Some(FinishReason::Stopped)),
        };
        match r {
            Ok(Some(f)) => Ok(Some(f)),
            Ok(None) => {
                self.emit_state();
                Ok(None)
            }
            Err(e) => {
                self.emit(SessionEvent::Error(e.to_string()));
                self.emit_state();
                Ok(None)
            }
        }
    }

    fn driver_message(&mut self, m: FromDriver) -> Result<Option<FinishReason>, RunError> {
        match m {
            FromDriver::Started(key) => {
                if let Some((k, scene)) = self.scene
                    && k == key
                {
                    self.emit(SessionEvent::TrialStarted { key, scene });
                }
                Ok(None)
            }
            FromDriver::Refused(_slot, why) => {
                self.core.begin_failed(why)?;
                self.emit(SessionEvent::Error(format!(
                    "the next trial did not begin: {why}"
                )));
                self.emit_state();
                Ok(None)
            }
            FromDriver::EmergencyStop(trial) => {
                let what = match trial {
                    Some(k) => format!("emergency stop: trial {k} aborted (its row is kept)"),
                    None => "emergency stop (no trial was running)".to_owned(),
                };
                self.core.note(&what)?;
                self.emit(SessionEvent::Noted(what));
                if matches!(
                    self.core.state(),
                    RunnerState::Training(_) | RunnerState::Trial(_) | RunnerState::Waiting(_)
                ) {
                    self.core.pause("emergency stop")?;
                }
                self.emit_state();
                Ok(None)
            }
            FromDriver::Ended(slot) => self.ended(slot),
            FromDriver::DeviceFailed(_slot, why) => Ok(Some(FinishReason::Failed(format!(
                "the rig failed during the sitting: {why}"
            )))),
            FromDriver::Detached(slot) => {
                drop(slot);
                Ok(None)
            }
        }
    }

    /// A trial ended: its rows are on their way, then the row is committed.
    /// The timing verdict so far, for the sitting's `session_done`.
    fn update_timing(&mut self) {
        let t = self.counters.timing(self.block_len, self.max_late_fraction);
        self.core.set_timing(Some(t));
    }

    fn ended(&mut self, mut slot: Box<TrialSlot>) -> Result<Option<FinishReason>, RunError> {
        self.drain_raw()?;
        self.update_timing();
        let Some(outcome) = slot.outcome.take() else {
            return Err(RunError::State(format!(
                "trial {} ended without an outcome",
                slot.setup.key
            )));
        };
        let key = outcome.key;
        self.last_ended = Some(key);
        if let Some(end) = slot.end {
            self.emit(SessionEvent::TrialEnded(key, end));
        }
        if slot.raw_dropped > 0 {
            self.emit(SessionEvent::Error(format!(
                "the raw file of trial {key} lost {} rows (the disk could not keep up)",
                slot.raw_dropped
            )));
        }
        let boundary = self.participant_boundary(key);
        if boundary {
            let id = self.participant_id(key);
            self.core.pause(&format!("participant {id} finished"))?;
        }
        let planned = self.planned();
        let Some((row, next)) = self.core.commit(&outcome)? else {
            return Ok(None);
        };
        self.emit(SessionEvent::Committed(Box::new(row)));
        let now_planned = self.planned();
        if now_planned > planned {
            self.emit(SessionEvent::Replanned(now_planned));
        }
        if boundary {
            return Ok(Some(FinishReason::ParticipantDone(
                self.participant_id(key),
            )));
        }
        match next {
            Some(n) => self.apply(n),
            None => {
                // Paused (an emergency stop or the experimenter): the
                // sitting's participant may have no trial left.
                if self.participant_done_after(key) {
                    return Ok(Some(FinishReason::ParticipantDone(
                        self.participant_id(key),
                    )));
                }
                self.emit_state();
                Ok(None)
            }
        }
    }

    /// Trials in the study's plan now (0 once the store is closed).
    fn planned(&self) -> usize {
        self.core.store().map_or(0, |s| s.plan().len())
    }

    /// Is `key` the last pending trial of the sitting's participant while
    /// other participants' trials remain? (Then the sitting ends after it.)
    fn participant_boundary(&self, key: TrialKey) -> bool {
        let (Some(p), Some(store)) = (self.only_participant, self.core.store()) else {
            return false;
        };
        match store.pending().find(|t| t.key != key) {
            Some(next) => next.key.participant != p,
            None => false,
        }
    }

    /// After `key` was committed: has the sitting's participant no pending
    /// trial left (while others do)?
    fn participant_done_after(&self, _key: TrialKey) -> bool {
        let (Some(p), Some(store)) = (self.only_participant, self.core.store()) else {
            return false;
        };
        store.next_pending().is_some_and(|n| n.key.participant != p)
    }

    fn participant_id(&self, key: TrialKey) -> String {
        self.core
            .store()
            .and_then(|s| s.planned(&key))
            .map(|p| p.participant.clone())
            .unwrap_or_else(|| format!("P{:02}", u64::from(key.participant) + 1))
    }

    /// The participant's screens: the inter-trial interval elapses here; a
    /// new block waits for the participant ([`SessionCommand::Proceed`]),
    /// the simulated participant reads for [`SIM_READ_S`].
    fn screens_timing(&mut self) -> Result<Option<FinishReason>, RunError> {
        let RunnerState::Waiting(next) = self.core.state() else {
            self.waiting_since = None;
            return Ok(None);
        };
        let since = *self.waiting_since.get_or_insert_with(Instant::now);
        let wait_s = match (
            kilotouch_study::screens::gate(self.last_ended, next),
            self.reader,
        ) {
            _ if self.speed == Speed::Fast => Some(0.0),
            (kilotouch_study::screens::Gate::Iti, _) => Some(self.core.protocol().screens.iti_s),
            (_, Reader::Simulated) => Some(SIM_READ_S),
            (_, Reader::Person) => None,
        };
        if wait_s.is_some_and(|w| since.elapsed().as_secs_f64() >= w) {
            self.waiting_since = None;
            let n = self.core.proceed()?;
            return self.apply(n);
        }
        Ok(None)
    }
}
