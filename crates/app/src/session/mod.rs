//! Study sessions from the app: a real-time **session thread** that owns a
//! [`SessionRunner`] on the simulated station, independent of egui (the
//! Study page is a thin layer over [`SessionHandle`]).
//!
//! # Architecture
//!
//! ```text
//!  GUI thread                                   session thread
//!  ──────────                                   ──────────────
//!  SessionHandle ── hand position (rtrb, 256) ─▶ MouseParticipant.hand_m (latest wins)
//!                ── SessionCommand (rtrb, 64) ▶ start / pause / resume / abort / note /
//!                                                emergency stop / stop
//!                ◀─ SessionEvent (rtrb, 8192) ─ state, trial started/ended, committed rows,
//!                                                telemetry (decimated), health, errors
//! ```
//!
//! One loop iteration = one block of `block` samples (default 10 = 1 ms at
//! 10 kHz): drain commands, [`SessionRunner::advance`], publish telemetry,
//! then — only when the runner asks for it (`needs_service`, i.e. a trial
//! ended) — [`SessionRunner::service`] commits the row (append + fsync)
//! and begins the next trial (journal + fsync). Row I/O therefore happens
//! between trials, never inside the sample loop.
//!
//! **Pacing** reuses the engine's [`Pacer`]: block k is due at
//! t_a + (k+1)·N/f_s (anchor t_a, N samples per block), so the simulated
//! sample position follows the wall clock; late blocks are caught up by the
//! next ones (they run without sleeping), a block finishing more than
//! 2 ms late counts as a deadline miss, and a stall beyond 50 ms re-anchors
//! the schedule (an *overrun*). The schedule is re-anchored after every
//! trial boundary and pause. [`Speed::Fast`] (simulated participant only)
//! never sleeps: dry runs and tests run as fast as the CPU allows.
//!
//! **Telemetry** is what the participant sees: the runner's camera frame
//! ([`VisualFrame`], at the operator model's frame rate and latency,
//! `None` in the blind task), plus the handle position, the force rendered
//! at the handle and live estimates of the running trial's metrics
//! ([`LiveMetrics`]). It is pushed at most every `telemetry_every` samples
//! of session time and every 10 ms of wall time; a full queue drops it
//! (counted), never blocks. Events that must not be lost (state changes,
//! committed rows, errors) are kept in an overflow list on the session
//! thread and sent as soon as there is room.
//!
//! **One participant per sitting.** The study crate runs trials in plan
//! order (participant by participant: training block, then the sessions in
//! the counterbalanced order). A sitting is restricted to one participant
//! ([`SessionOptions::only_participant`]): it must be the participant of
//! the folder's next pending trial, and the sitting ends paused at that
//! participant's last trial (journal: `pause`, reason "participant … finished")
//! so the next participant resumes the same folder. The last participant's
//! last row closes the study (summaries written).
//!
//! **Crash safety** is the study crate's: a killed sitting (process killed,
//! [`SessionHandle`] dropped, [`SessionCommand::Stop`]) leaves the trial in
//! progress open in the journal; reopening the folder
//! ([`StudyStore::open_existing`]) reports it in the [`Recovery`] and the
//! runner runs it again from its seeds, so a resumed study holds exactly
//! the rows of an uninterrupted one.
//!
//! **Emergency stop** ([`SessionCommand::EmergencyStop`]): the running
//! trial is aborted at once (no further sample is computed, so the
//! simulated station's outputs stop), its row is committed with
//! `reject_reason = aborted`, the event is journaled as a note and the
//! session stays paused until the experimenter resumes (also between
//! trials: a held trial does not begin).
//!
//! **Participant screens** ([`SessionOptions::screens`], the Study page's
//! participant view): the runner holds every next trial
//! ([`RunnerState::Waiting`]); which routine runs is
//! [`kilotouch_study::screens::gate`] of the last and the next trial.
//! Within a block the protocol's inter-trial interval (`screens.iti_s`,
//! wall clock) elapses here, then the trial begins by itself; a new block
//! (first trial of the sitting, a new session or training condition)
//! waits for [`SessionCommand::Proceed`], sent by the GUI when the
//! participant leaves the ready screen. The sitting ends cleanly
//! (`session_done` in the journal) when its participant is done or the
//! experimenter stops it; only a crash or kill leaves it unclosed.

mod participant;

pub use participant::{LiveMetrics, ParticipantId, validate_participant_id};

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use kilotouch_rig::RigConfig;
use kilotouch_rig::device::SystemClock;
use kilotouch_study::export::{
    PlannedTrial, Recovery, SESSION_FILE, StudyStore, TRIALS_FILE, TrialRow, plan, read_session,
    read_trials,
};
use kilotouch_study::operator::SimCohort;
use kilotouch_study::participant::VisualFrame;
use kilotouch_study::participant::{MouseParticipant, Observation, Participant, TrialBrief};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::runner::{RunError, RunnerConfig, RunnerEvents, RunnerState, SessionRunner};
use kilotouch_study::seeds::TrialKey;
use kilotouch_study::simulate::sim_meta;
use kilotouch_study::task::sim_station::SimStation;
use kilotouch_study::task::station::{HandMapping, Station};
use kilotouch_study::task::{Scene, TaskParams, TrialEnd};
use thiserror::Error;

use crate::engine::pacing::Pacer;
use participant::Tap;

/// Errors of opening or driving a session.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum SessionError {
    /// Runner, station or storage error.
    #[error("{0}")]
    Run(#[from] RunError),
    /// Storage error while opening the folder.
    #[error("{0}")]
    Export(#[from] kilotouch_study::export::ExportError),
    /// Invalid options or a request that does not fit the folder.
    #[error("{0}")]
    Invalid(String),
    /// The session thread could not be started.
    #[error("cannot start the session thread: {0}")]
    Thread(String),
}

/// Who is at the handle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ParticipantKind {
    /// A person: the hand follows the mouse in the participant view.
    #[default]
    Mouse,
    /// The seeded simulated operator of the study crate (dry runs, tests):
    /// the same [`SimCohort`] as `kilotouch study simulate`.
    Simulated,
}

/// Pacing of the session thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Speed {
    /// One simulated second per wall-clock second (module docs).
    #[default]
    RealTime,
    /// As fast as possible (simulated participant only).
    Fast,
}

/// What the session thread is started with.
#[derive(Debug, Clone)]
pub struct SessionOptions {
    /// Output folder.
    pub out: PathBuf,
    /// The protocol of a new folder; `None` resumes the folder's own
    /// (`session.json`) via [`StudyStore::open_existing`].
    pub protocol: Option<Protocol>,
    /// Rig configuration of the simulated station.
    pub rig: RigConfig,
    /// Who is at the handle.
    pub participant: ParticipantKind,
    /// Pacing ([`Speed::Fast`] requires the simulated participant).
    pub speed: Speed,
    /// Restrict the sitting to this 0-based participant (module docs);
    /// `None` runs every pending trial of the plan.
    pub only_participant: Option<u32>,
    /// Runner timing (camera, control period, raw files).
    pub runner: RunnerConfig,
    /// Samples per block (≥ 1; 10 = 1 ms at 10 kHz).
    pub block: usize,
    /// Samples of session time between two telemetry events (≥ 1).
    pub telemetry_every: usize,
    /// Calibration whose (force-normalised) chain D runs; recorded with its
    /// SHA-256 in `session.json` and the journal. `None`: the model's
    /// as-designed chain, recorded as uncalibrated.
    pub calibration: Option<PathBuf>,
    /// The trap calibration applied on the Rig page, recorded in
    /// `session.json` (`trap_calibration`); `None`: none applied.
    pub trap_calibration: Option<kilotouch_rig::tweezer::TrapCalibrationRecord>,
    /// Run the participant's screens (module docs, "Participant screens"):
    /// every block waits for [`SessionCommand::Proceed`] (the participant's
    /// key or click on the ready screen; the simulated participant "reads"
    /// for [`SIM_READ_S`] in real time), and trials within a block are
    /// separated by the protocol's inter-trial interval. Default `false`
    /// (trials follow one another at once).
    pub screens: bool,
}

/// How long the simulated participant takes on an instructions / ready
/// screen in real time, s (0 at [`Speed::Fast`]).
pub const SIM_READ_S: f64 = 1.5;

impl SessionOptions {
    /// Defaults: mouse participant, real time, blocks of 10 samples,
    /// telemetry every 20 samples (2 ms at 10 kHz), the study crate's
    /// [`RunnerConfig::default`] (25 Hz camera, 40 ms latency, f32 raw files).
    pub fn new(out: &Path, protocol: Option<Protocol>, rig: RigConfig) -> Self {
        Self {
            out: out.to_path_buf(),
            protocol,
            rig,
            participant: ParticipantKind::Mouse,
            speed: Speed::RealTime,
            only_participant: None,
            runner: RunnerConfig::default(),
            block: 10,
            telemetry_every: 20,
            calibration: None,
            trap_calibration: None,
            screens: false,
        }
    }
}

/// Commands from the GUI.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionCommand {
    /// Begin the first pending trial (valid once, when idle).
    Start,
    /// Pause (the running trial waits; journaled).
    Pause,
    /// End a pause.
    Resume,
    /// Abort the running trial (row with `reject_reason = aborted`).
    AbortTrial,
    /// Journal an experimenter note.
    Note(String),
    /// Emergency stop (module docs).
    EmergencyStop,
    /// The participant is ready: begin the trial the runner holds
    /// ([`RunnerState::Waiting`]); ignored otherwise.
    Proceed,
    /// End the sitting now: the trial in progress is journaled as aborted
    /// (no row; it runs again on resume) and the sitting closes cleanly.
    Stop,
}

/// One telemetry event (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Telemetry {
    /// The trial.
    pub key: TrialKey,
    /// Time since the trial start, s.
    pub t_s: f64,
    /// Camera frame shown to the participant (`None`: none yet, or blind).
    pub frame: Option<VisualFrame>,
    /// Handle position, m.
    pub handle_m: [f64; 2],
    /// Hand target given to the station, m.
    pub hand_m: [f64; 2],
    /// Force rendered at the handle by the Pantograph at the last sample, N.
    pub force_n: [f64; 2],
    /// Live estimates of the trial's metrics.
    pub live: LiveMetrics,
}

/// Timing health of the session thread.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SessionHealth {
    /// Blocks late by more than the tolerated latency (real time only).
    pub deadline_misses: u64,
    /// Re-anchors after stalls.
    pub overruns: u64,
    /// Worst lateness, s (real time only; −∞ before the first block).
    pub worst_lateness_s: f64,
    /// Busy time / wall time over the last report window.
    pub load: f64,
    /// Telemetry events dropped because the GUI did not drain the queue.
    pub telemetry_dropped: u64,
    /// Simulated time run in this sitting, s.
    pub simulated_s: f64,
}

/// Events to the GUI.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionEvent {
    /// The runner's state changed.
    State(RunnerState),
    /// A trial began.
    TrialStarted {
        /// The trial.
        key: TrialKey,
        /// Its scene (obstacle, start, heading).
        scene: Scene,
    },
    /// The running trial ended (row not yet committed).
    TrialEnded(TrialKey, TrialEnd),
    /// A row was committed (fsynced).
    Committed(Box<TrialRow>),
    /// Decimated telemetry.
    Telemetry(Telemetry),
    /// Timing health (every 100 ms of wall time).
    Health(SessionHealth),
    /// A note was journaled.
    Noted(String),
    /// A command was refused or a step failed (the session goes on when
    /// it can).
    Error(String),
    /// The session thread ended: why.
    Finished(FinishReason),
}

/// Why the session thread ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FinishReason {
    /// Every trial of the plan has its row; the summaries are written.
    StudyDone,
    /// The participant of this sitting has finished all their trials.
    ParticipantDone(String),
    /// The experimenter stopped the sitting.
    Stopped,
    /// An error ended it.
    Failed(String),
}

/// What the GUI knows at once after opening.
#[derive(Debug, Clone)]
pub struct SessionInfo {
    /// The protocol in use.
    pub protocol: Protocol,
    /// Folder recovery report (resumed, torn tails, interrupted trials).
    pub recovery: Recovery,
    /// Recovery as text.
    pub recovery_text: String,
    /// Rows already in `trials.csv` (all participants).
    pub rows: Vec<TrialRow>,
    /// Trials completed / planned.
    pub completed: usize,
    /// Trials planned.
    pub planned: usize,
    /// The first pending trial (where the sitting starts).
    pub next: Option<PlannedTrial>,
    /// Hand → trap mapping of the station.
    pub mapping: HandMapping,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// The runner configuration (camera rate and latency).
    pub runner: RunnerConfig,
}

/// The GUI side of a running session.
#[derive(Debug)]
pub struct SessionHandle {
    info: SessionInfo,
    hand_tx: rtrb::Producer<[f64; 2]>,
    cmd_tx: rtrb::Producer<SessionCommand>,
    ev_rx: rtrb::Consumer<SessionEvent>,
    thread: Option<JoinHandle<()>>,
    finished: Option<FinishReason>,
}

/// Read-only look at an output folder (no journal entry, no repair).
#[derive(Debug, Clone, PartialEq)]
pub enum FolderStatus {
    /// No `session.json`: a new study would be created there.
    Empty,
    /// A study folder.
    Study {
        /// Protocol name.
        protocol: String,
        /// Rows in `trials.csv`.
        completed: usize,
        /// Planned trials.
        planned: usize,
        /// First pending trial in plan order (`None`: complete).
        next: Option<PlannedTrial>,
    },
    /// Unreadable or not a study folder.
    Unreadable(String),
}

/// Looks at `dir` without modifying it: `session.json` and `trials.csv`
/// (a torn tail is ignored, as a reopen would cut it).
pub fn inspect_folder(dir: &Path) -> FolderStatus {
    let session = dir.join(SESSION_FILE);
    if !session.exists() {
        return FolderStatus::Empty;
    }
    let info = match read_session(&session) {
        Ok(i) => i,
        Err(e) => return FolderStatus::Unreadable(e.to_string()),
    };
    let rows = match read_trials(&dir.join(TRIALS_FILE)) {
        Ok(r) => r.rows,
        Err(e) => return FolderStatus::Unreadable(e.to_string()),
    };
    let planned = plan(&info.protocol, &info.order_table);
    let done: std::collections::HashSet<TrialKey> = rows
        .iter()
        .filter_map(|r| {
            info.order_table
                .iter()
                .find(|o| o.participant == r.participant)
                .map(|o| r.key(o.index))
        })
        .collect();
    FolderStatus::Study {
        protocol: info.protocol.name.clone(),
        completed: rows.len(),
        planned: planned.len(),
        next: planned.into_iter().find(|p| !done.contains(&p.key)),
    }
}

impl SessionHandle {
    /// Opens the output folder (new or resumed: the study crate repairs and
    /// reconciles it) and starts the session thread, idle until
    /// [`SessionCommand::Start`].
    ///
    /// # Errors
    /// Invalid options ([`Speed::Fast`] with a person, a participant who is
    /// not next in the plan, a done study), storage and station errors.
    pub fn spawn(opts: SessionOptions) -> Result<Self, SessionError> {
        if opts.block == 0 || opts.telemetry_every == 0 {
            return Err(SessionError::Invalid(
                "block and telemetry_every must be ≥ 1".into(),
            ));
        }
        if opts.speed == Speed::Fast && opts.participant == ParticipantKind::Mouse {
            return Err(SessionError::Invalid(
                "\"as fast as possible\" is for the simulated participant only".into(),
            ));
        }
        let (mut meta, chain) = sim_meta(
            &opts.rig,
            opts.calibration.as_deref(),
            opts.runner.raw.is_some(),
            None,
        )?;
        meta.trap_calibration.clone_from(&opts.trap_calibration);
        if opts.protocol.is_some() && opts.out.join(SESSION_FILE).exists() {
            // The folder's own protocol decides; a different one is refused by
            // the store (ProtocolMismatch) — say so before touching anything.
            if let (FolderStatus::Study { protocol, .. }, Some(p)) =
                (inspect_folder(&opts.out), &opts.protocol)
                && protocol != p.name
            {
                return Err(SessionError::Invalid(format!(
                    "{} holds the study `{protocol}`, not `{}`: resume it or choose another folder",
                    opts.out.display(),
                    p.name
                )));
            }
        }
        let store = match &opts.protocol {
            Some(p) => StudyStore::open(&opts.out, p, &meta)?,
            None => StudyStore::open_existing(&opts.out, &meta)?,
        };
        let next = store.next_pending().cloned();
        if let (Some(p), Some(n)) = (opts.only_participant, &next)
            && n.key.participant != p
        {
            return Err(SessionError::Invalid(format!(
                "the next pending trial of this folder is {} ({}): trials run in plan order, \
                 so the participant of this sitting must be {}",
                n.key, n.participant, n.participant
            )));
        }
        if next.is_none() {
            return Err(SessionError::Invalid(format!(
                "{} is complete: every planned trial has its row",
                opts.out.display()
            )));
        }
        let recovery = store.recovery().clone();
        let rows = read_trials(&opts.out.join(TRIALS_FILE))?.rows;
        let station = SimStation::with_chain(&opts.rig, chain)?;
        let info = SessionInfo {
            protocol: store.protocol().clone(),
            recovery_text: recovery.to_string(),
            recovery,
            rows,
            completed: store.completed_count(),
            planned: store.plan().len(),
            next,
            mapping: station.mapping(),
            sample_rate_hz: station.sample_rate_hz(),
            runner: opts.runner,
        };
        let fs = station.sample_rate_hz();
        let runner = SessionRunner::new(store, station, opts.runner)?;
        let participant = match opts.participant {
            ParticipantKind::Mouse => Who::Mouse(MouseParticipant::default()),
            ParticipantKind::Simulated => Who::Sim(Box::new(SimCohort::new(
                info.protocol.seeds.study,
                fs / opts.runner.act_every as f64,
                fs,
            ))),
        };
        let contact_gap_m = TaskParams::from_protocol(&info.protocol).contact_gap_m();
        let (hand_tx, hand_rx) = rtrb::RingBuffer::new(256);
        let (cmd_tx, cmd_rx) = rtrb::RingBuffer::new(64);
        let (ev_tx, ev_rx) = rtrb::RingBuffer::new(8192);
        let thread = SessionThread {
            runner,
            tap: Tap::new(participant, contact_gap_m),
            hand_rx,
            cmd_rx,
            ev_tx,
            overflow: VecDeque::new(),
            opts,
            fs,
            health: SessionHealth {
                worst_lateness_s: f64::NEG_INFINITY,
                ..Default::default()
            },
            last_ended: None,
        };
        let handle = std::thread::Builder::new()
            .name("kilotouch-session".into())
            .spawn(move || thread.run())
            .map_err(|e| SessionError::Thread(e.to_string()))?;
        Ok(Self {
            info,
            hand_tx,
            cmd_tx,
            ev_rx,
            thread: Some(handle),
            finished: None,
        })
    }

    /// What was known at opening.
    pub fn info(&self) -> &SessionInfo {
        &self.info
    }

    /// Sends a command (`false`: queue full or thread ended; try again).
    pub fn send(&mut self, cmd: SessionCommand) -> bool {
        self.cmd_tx.push(cmd).is_ok()
    }

    /// Sets the hand position for a mouse participant, m (handle
    /// coordinates); `false` when the queue is full (the thread keeps the
    /// latest it has). Non-finite values are ignored by the runner.
    pub fn set_hand(&mut self, hand_m: [f64; 2]) -> bool {
        self.hand_tx.push(hand_m).is_ok()
    }

    /// Drains the events (call every frame).
    pub fn poll(&mut self) -> Vec<SessionEvent> {
        let mut out = Vec::with_capacity(self.ev_rx.slots());
        while let Ok(e) = self.ev_rx.pop() {
            if let SessionEvent::Finished(r) = &e {
                self.finished = Some(r.clone());
            }
            out.push(e);
        }
        out
    }

    /// Why the thread ended, once it has reported it.
    pub fn finished(&self) -> Option<&FinishReason> {
        self.finished.as_ref()
    }

    /// Is the session thread still running?
    pub fn is_alive(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Waits for the thread to end (after a `Stop`, or when done); the
    /// remaining events are returned.
    pub fn join(mut self) -> Vec<SessionEvent> {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.poll()
    }
}

impl Drop for SessionHandle {
    fn drop(&mut self) {
        // Dropping the handle ends the sitting like `Stop` (the trial in
        // progress stays open and runs again on resume).
        let _ = self.cmd_tx.push(SessionCommand::Stop);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The participant of the sitting.
#[derive(Debug)]
enum Who {
    Mouse(MouseParticipant),
    Sim(Box<SimCohort>),
}

impl Participant for Who {
    fn begin_trial(&mut self, brief: &TrialBrief) {
        match self {
            Who::Mouse(m) => m.begin_trial(brief),
            Who::Sim(s) => s.begin_trial(brief),
        }
    }

    fn act(&mut self, obs: &Observation<'_>) -> [f64; 2] {
        match self {
            Who::Mouse(m) => m.act(obs),
            Who::Sim(s) => s.act(obs),
        }
    }
}

struct SessionThread {
    runner: SessionRunner<SimStation>,
    tap: Tap<Who>,
    hand_rx: rtrb::Consumer<[f64; 2]>,
    cmd_rx: rtrb::Consumer<SessionCommand>,
    ev_tx: rtrb::Producer<SessionEvent>,
    overflow: VecDeque<SessionEvent>,
    opts: SessionOptions,
    fs: f64,
    health: SessionHealth,
    /// The last trial that ended (what the next one's screens follow).
    last_ended: Option<TrialKey>,
}

/// Slots kept free in the event queue for events that must not be lost.
const RESERVED_SLOTS: usize = 64;

impl SessionThread {
    /// Sends an event that must arrive (kept in order in the overflow list
    /// while the queue is full).
    fn emit(&mut self, e: SessionEvent) {
        self.flush();
        if !self.overflow.is_empty() {
            self.overflow.push_back(e);
            return;
        }
        if let Err(rtrb::PushError::Full(e)) = self.ev_tx.push(e) {
            self.overflow.push_back(e);
        }
    }

    fn flush(&mut self) {
        while let Some(e) = self.overflow.pop_front() {
            if let Err(rtrb::PushError::Full(e)) = self.ev_tx.push(e) {
                self.overflow.push_front(e);
                break;
            }
        }
    }

    /// Sends telemetry if there is room beyond the reserve, else counts it.
    fn emit_telemetry(&mut self, t: Telemetry) {
        if self.overflow.is_empty() && self.ev_tx.slots() > RESERVED_SLOTS {
            let _ = self.ev_tx.push(SessionEvent::Telemetry(t));
        } else {
            self.health.telemetry_dropped += 1;
        }
    }

    fn emit_state(&mut self, last: &mut Option<RunnerState>) {
        let s = self.runner.state();
        if *last != Some(s) {
            *last = Some(s);
            self.emit(SessionEvent::State(s));
        }
    }

    fn report(&mut self, ev: &RunnerEvents) {
        if let Some((k, e)) = ev.ended {
            self.last_ended = Some(k);
            self.emit(SessionEvent::TrialEnded(k, e));
        }
        if let Some(row) = &ev.committed {
            self.emit(SessionEvent::Committed(Box::new(row.clone())));
        }
        if let Some(k) = ev.started {
            if let Ok(o) = self.runner.engine().outcome() {
                self.emit(SessionEvent::TrialStarted {
                    key: k,
                    scene: o.scene,
                });
            }
            if let Who::Sim(s) = &self.tap.inner
                && let Some(e) = s.error()
            {
                let msg = format!("simulated operator: {e}");
                self.emit(SessionEvent::Error(msg));
            }
        }
    }

    /// Is `key` the last pending trial of the sitting's participant while
    /// other participants' trials remain? (Then the sitting ends after it.)
    fn participant_boundary(&self, key: TrialKey) -> bool {
        let Some(p) = self.opts.only_participant else {
            return false;
        };
        let Some(store) = self.runner.store() else {
            return false;
        };
        match store.pending().find(|t| t.key != key) {
            Some(next) => next.key.participant != p,
            None => false,
        }
    }

    fn run(mut self) {
        let mut reason = match self.run_loop() {
            Ok(r) => r,
            Err(e) => FinishReason::Failed(e.to_string()),
        };
        // A participant finished or the experimenter stopped: the sitting
        // ends cleanly (journal `session_done`), so the next opening does
        // not report a crash.
        let why = match &reason {
            FinishReason::ParticipantDone(id) => Some(format!("participant {id} finished")),
            FinishReason::Stopped => Some("sitting stopped by the experimenter".to_owned()),
            _ => None,
        };
        if let Some(why) = why
            && let Err(e) = self.runner.end_sitting(&why)
        {
            reason = FinishReason::Failed(format!("ending the sitting: {e}"));
        }
        self.emit(SessionEvent::Health(self.health));
        self.emit(SessionEvent::Finished(reason));
        // Deliver what is left while the GUI drains (bounded wait).
        let t0 = Instant::now();
        while !self.overflow.is_empty() && t0.elapsed() < Duration::from_secs(2) {
            self.flush();
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    fn run_loop(&mut self) -> Result<FinishReason, RunError> {
        let paced = self.opts.speed == Speed::RealTime;
        let period = self.opts.block as f64 / self.fs;
        let mut pacer = Pacer::new(SystemClock::default(), period, 2e-3, 50e-3, paced);
        let mut last_state = None;
        self.emit_state(&mut last_state);
        let mut since_telemetry = 0usize;
        let mut last_telemetry = Instant::now();
        let mut window_start = Instant::now();
        let mut window_busy = 0.0f64;
        let mut was_running = false;
        let screens = self.opts.screens;
        self.runner.set_hold(screens);
        let iti_s = self.runner.protocol().screens.iti_s;
        let mut waiting_since: Option<Instant> = None;
        loop {
            // Commands.
            while let Ok(cmd) = self.cmd_rx.pop() {
                let r = self.command(cmd);
                match r {
                    Ok(Some(reason)) => return Ok(reason),
                    Ok(None) => {}
                    Err(e) => self.emit(SessionEvent::Error(e.to_string())),
                }
                self.emit_state(&mut last_state);
            }
            while let Ok(h) = self.hand_rx.pop() {
                if let Who::Mouse(m) = &mut self.tap.inner {
                    m.hand_m = h;
                }
            }
            self.flush();
            let state = self.runner.state();
            if state == RunnerState::Done {
                return Ok(FinishReason::StudyDone);
            }
            if let RunnerState::Waiting(next) = state {
                // The participant's screens: the inter-trial interval runs
                // here; a new block waits for the participant (Proceed).
                let since = *waiting_since.get_or_insert_with(Instant::now);
                let fast = !paced;
                let wait_s = match (
                    kilotouch_study::screens::gate(self.last_ended, next),
                    &self.tap.inner,
                ) {
                    _ if fast => Some(0.0),
                    (kilotouch_study::screens::Gate::Iti, _) => Some(iti_s),
                    (_, Who::Sim(_)) => Some(SIM_READ_S),
                    (_, Who::Mouse(_)) => None,
                };
                if wait_s.is_some_and(|w| since.elapsed().as_secs_f64() >= w) {
                    waiting_since = None;
                    let ev = self.runner.proceed(&mut self.tap)?;
                    self.report(&ev);
                    self.emit_state(&mut last_state);
                    continue;
                }
            } else {
                waiting_since = None;
            }
            let running = matches!(state, RunnerState::Training(_) | RunnerState::Trial(_));
            if !running {
                was_running = false;
                std::thread::sleep(Duration::from_millis(2));
                continue;
            }
            if !was_running {
                pacer.reanchor();
                was_running = true;
            }
            pacer.begin_block();
            let ev = self.runner.advance(&mut self.tap, self.opts.block)?;
            self.health.simulated_s += ev.samples as f64 / self.fs;
            since_telemetry += ev.samples;
            let wall_ok = last_telemetry.elapsed() >= Duration::from_millis(10) || paced;
            if since_telemetry >= self.opts.telemetry_every
                && wall_ok
                && let Some(key) = self.runner.engine().key()
            {
                since_telemetry = 0;
                last_telemetry = Instant::now();
                let t = self.tap.telemetry(key);
                self.emit_telemetry(t);
            }
            self.report(&ev);
            if ev.needs_service {
                if let Some((key, _)) = ev.ended
                    && self.participant_boundary(key)
                {
                    let id = self.participant_id(key);
                    self.runner.pause(&format!("participant {id} finished"))?;
                    let sev = self.runner.service(&mut self.tap)?;
                    self.report(&sev);
                    self.emit_state(&mut last_state);
                    return Ok(FinishReason::ParticipantDone(id));
                }
                let sev = self.runner.service(&mut self.tap)?;
                self.report(&sev);
                was_running = false;
            }
            self.emit_state(&mut last_state);
            let timing = pacer.end_block();
            window_busy += timing.busy_s;
            let w = window_start.elapsed().as_secs_f64();
            if w >= 0.1 {
                self.health.deadline_misses = pacer.misses;
                self.health.overruns = pacer.overruns;
                self.health.worst_lateness_s = pacer.worst_lateness_s;
                self.health.load = window_busy / w;
                window_busy = 0.0;
                window_start = Instant::now();
                self.emit(SessionEvent::Health(self.health));
            }
        }
    }

    fn participant_id(&self, key: TrialKey) -> String {
        self.runner
            .store()
            .and_then(|s| s.planned(&key))
            .map(|p| p.participant.clone())
            .unwrap_or_else(|| format!("P{:02}", u64::from(key.participant) + 1))
    }

    /// Applies a command; `Some(reason)` ends the thread.
    fn command(&mut self, cmd: SessionCommand) -> Result<Option<FinishReason>, RunError> {
        match cmd {
            SessionCommand::Start => {
                let ev = self.runner.start(&mut self.tap)?;
                self.report(&ev);
            }
            SessionCommand::Pause => self.runner.pause("experimenter")?,
            SessionCommand::Resume => {
                if self.runner.state() == RunnerState::Paused(None) {
                    // After a pause between trials (or an emergency stop)
                    // the next trial starts a new block: instructions and
                    // the ready screen again, not a bare interval.
                    self.last_ended = None;
                }
                let ev = self.runner.resume(&mut self.tap)?;
                self.report(&ev);
            }
            SessionCommand::AbortTrial => {
                let ev = self.runner.abort_trial()?;
                self.report(&ev);
            }
            SessionCommand::Note(text) => {
                let text = text.trim().to_owned();
                if !text.is_empty() {
                    self.runner.note(&text)?;
                    self.emit(SessionEvent::Noted(text));
                }
            }
            SessionCommand::EmergencyStop => {
                let state = self.runner.state();
                let in_trial = matches!(
                    state,
                    RunnerState::Training(_) | RunnerState::Trial(_) | RunnerState::Paused(Some(_))
                );
                self.runner.note("emergency stop")?;
                self.emit(SessionEvent::Noted("emergency stop".into()));
                if in_trial {
                    let ev = self.runner.abort_trial()?;
                    self.report(&ev);
                    if !matches!(self.runner.state(), RunnerState::Paused(_)) {
                        self.runner.pause("emergency stop")?;
                    }
                    let key = ev.ended.map(|(k, _)| k);
                    let sev = self.runner.service(&mut self.tap)?;
                    self.report(&sev);
                    if let Some(k) = key
                        && self.participant_boundary_after_commit(k)
                    {
                        return Ok(Some(FinishReason::ParticipantDone(self.participant_id(k))));
                    }
                }
                if matches!(self.runner.state(), RunnerState::Waiting(_)) {
                    // Between trials: nothing begins until the experimenter
                    // resumes.
                    self.runner.pause("emergency stop")?;
                }
            }
            SessionCommand::Proceed => {
                if matches!(self.runner.state(), RunnerState::Waiting(_)) {
                    let ev = self.runner.proceed(&mut self.tap)?;
                    self.report(&ev);
                }
            }
            SessionCommand::Stop => return Ok(Some(FinishReason::Stopped)),
        }
        Ok(None)
    }

    /// After `key` was committed: does the sitting's participant have no
    /// pending trial left (while others do)?
    fn participant_boundary_after_commit(&self, key: TrialKey) -> bool {
        let (Some(p), Some(store)) = (self.opts.only_participant, self.runner.store()) else {
            return false;
        };
        let _ = key;
        store.next_pending().is_some_and(|n| n.key.participant != p)
    }
}
