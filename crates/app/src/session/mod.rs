//! Study sittings from the app: the study's trials run on the one
//! real-time engine ([`crate::engine`]) that Explore uses — its rig
//! (simulated or live), its pacing, its telemetry, its safety layer and its
//! emergency stop — while the store side runs on a worker thread. The Study
//! page and `kilotouch study run` are thin layers over [`SessionHandle`].
//!
//! # Architecture
//!
//! ```text
//!  GUI / CLI thread               worker thread "kilotouch-sitting"     engine thread
//!  ────────────────               ─────────────────────────────────     ─────────────
//!  SessionHandle ── SessionCommand (mpsc) ─▶ SittingCore (journal,       SittingDriver
//!                ◀─ SessionEvent  (mpsc) ──  rows, raw files, states)    (BlockDriver):
//!                                            builds each trial's parts   TrialCore on the
//!                                            ── Begin(slot) (rtrb) ────▶ engine's loop
//!                                            ◀─ Ended(slot), stop … ───  (LoopStation)
//!                                            ◀─ raw rows (rtrb) ───────
//!                ◀─ Telemetry (rtrb) ────────────────────────────────────
//!  EngineHandle ── hand, emergency stop (the engine's own) ────────────▶
//! ```
//!
//! **One loop.** The engine's block loop is the only real-time loop: the
//! trial side ([`driver::SittingDriver`]) runs inside it as its driver and
//! steps the study's [`kilotouch_study::runner::TrialCore`] on the
//! engine's closed loop, so pacing, deadline misses, telemetry, the safety
//! layer and the emergency stop are the engine's. A trial's parts (a fresh
//! simulated rig, the scene's tweezer, a fresh safety layer) are built by
//! the worker — the same builder as `study simulate`'s station, so a trial
//! on the simulated rig is the same function of its key — and swapped in by
//! the driver; the old parts travel back to be dropped on the worker.
//! Journal writes, fsyncs and raw-file writes happen on the worker, never
//! on the engine thread.
//!
//! **Live rigs.** On a live rig the hand at the handle is real (a person,
//! or the device's own simulated participant): the sitting observes and
//! records it ([`ParticipantKind::Handle`]). Each trial starts wherever the
//! handle is (the hand mapping is re-centred on it); the device is told
//! what the participant's screen shows ([`kilotouch_rig::device::HostInfo`]).
//! Between trials the loop keeps running with the outputs at zero.
//!
//! **One participant per sitting.** Trials run in plan order (participant
//! by participant: training block, then the sessions in the
//! counterbalanced order). A sitting restricted to one participant
//! ([`SessionOptions::only_participant`]) must be the participant of the
//! folder's next pending trial and ends paused after that participant's
//! last trial, so the next participant resumes the same folder. The last
//! participant's last row closes the study (summaries written).
//!
//! **Crash safety** is the study crate's: a killed sitting leaves the trial
//! in progress open in the journal; reopening the folder reports it and
//! the trial runs again from its seeds. A rig that fails during a trial
//! ends the sitting with the device's error: the trial in progress is
//! journaled as aborted (no row) and runs again on resume.
//!
//! **Emergency stop.** The engine's one stop ([`SessionHandle::send`] with
//! [`SessionCommand::EmergencyStop`] presses it, as Esc and the red button
//! do): the outputs go to zero at the next block, the running trial is
//! aborted (its row committed with `reject_reason = aborted`), the stop is
//! journaled and the sitting pauses; no trial begins while the stop is
//! latched.
//!
//! **Participant screens** ([`SessionOptions::screens`]): the worker holds
//! every next trial ([`RunnerState::Waiting`]); the protocol's inter-trial
//! interval elapses there, a new block waits for
//! [`SessionCommand::Proceed`] (the participant leaving the ready screen;
//! the host's simulated participant "reads" for [`SIM_READ_S`]).

mod driver;
mod participant;
mod size;
mod worker;

pub use participant::{LiveMetrics, ParticipantId, validate_participant_id};
pub use size::{estimate_size, space_refusal};

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::{Arc, mpsc};
use std::thread::JoinHandle;

use kilotouch_rig::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_study::export::{
    DeviceRecord, PlannedTrial, Recovery, SESSION_FILE, StudyStore, TRIALS_FILE, TrialRow,
    TweezerDeviceRecord, plan_with_rows, read_session, read_trials,
};
use kilotouch_study::operator::SimCohort;
use kilotouch_study::participant::{MouseParticipant, VisualFrame};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::runner::{
    RunError, RunnerConfig, RunnerState, SittingCore, StationFrame, TrialCore,
};
use kilotouch_study::seeds::TrialKey;
use kilotouch_study::simulate::sim_meta;
use kilotouch_study::task::station::HandMapping;
use kilotouch_study::task::trial_kit::KitBuilder;
use kilotouch_study::task::{Scene, TaskParams, TrialEnd};
use thiserror::Error;

use crate::engine::{EngineHandle, EstopTrigger, Health};
use participant::{Tap, Who};

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
    /// The worker thread could not be started.
    #[error("cannot start the sitting's worker thread: {0}")]
    Thread(String),
    /// The engine refused the sitting (a chain whose margins at the rig's
    /// loop delay are below the minimum; a full command queue).
    #[error("{0}")]
    Engine(#[from] crate::engine::EngineError),
}

/// Who is at the handle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ParticipantKind {
    /// A person on the simulated rig: the hand follows the mouse in the
    /// participant view.
    #[default]
    Mouse,
    /// The seeded simulated operator of the study crate on the simulated
    /// rig (dry runs, tests): the same [`SimCohort`] as `kilotouch study
    /// simulate`.
    Simulated,
    /// A live rig: the hand at the handle is real — a person, or the
    /// device's own simulated participant (`kilotouch emulate daq
    /// --participant`); the sitting observes and records the handle.
    Handle,
}

/// Pacing of a sitting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Speed {
    /// One second of trial per wall-clock second (the engine's pacing).
    #[default]
    RealTime,
    /// As fast as possible (the simulated participant on the simulated rig
    /// only: the engine stops sleeping for the sitting).
    Fast,
}

/// What a sitting is started with.
#[derive(Debug, Clone)]
pub struct SessionOptions {
    /// Output folder.
    pub out: PathBuf,
    /// The protocol of a new folder; `None` resumes the folder's own
    /// (`session.json`) via [`StudyStore::open_existing`].
    pub protocol: Option<Protocol>,
    /// The rig file the engine runs (its content hash is recorded and
    /// checked on resume; a simulated trial's rig is built from it).
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
    /// Defaults: mouse participant, real time, telemetry every 20 samples
    /// (2 ms at 10 kHz), the study crate's
    /// [`RunnerConfig::default`] (1 kHz control, f32 raw files); the
    /// camera is the rig file's.
    pub fn new(out: &Path, protocol: Option<Protocol>, rig: RigConfig) -> Self {
        Self {
            out: out.to_path_buf(),
            protocol,
            rig,
            participant: ParticipantKind::Mouse,
            speed: Speed::RealTime,
            only_participant: None,
            runner: RunnerConfig::default(),
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

/// Timing health of a sitting: the engine's, since the sitting began.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SessionHealth {
    /// Blocks late by more than the tolerated latency (real time only).
    pub deadline_misses: u64,
    /// Re-anchors after stalls.
    pub overruns: u64,
    /// Worst lateness, s (real time only; −∞ before the first block).
    pub worst_lateness_s: f64,
    /// Busy time / wall time over the engine's last report window.
    pub load: f64,
    /// Participant-view telemetry events the GUI did not drain in time.
    pub telemetry_dropped: u64,
    /// Trial time the sitting's trials ran, s.
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
    /// The plan grew to this many trials: an unsuccessful practice row
    /// earned an extra practice trial (`training.practice_retries`).
    /// Follows that row's [`SessionEvent::Committed`].
    Replanned(usize),
    /// Decimated telemetry.
    Telemetry(Telemetry),
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
    /// The rig the sitting runs on (`sim`, `serial:PATH`, …).
    pub rig: String,
    /// The live device's record (name, loop delay); `None`: simulated.
    pub device: Option<DeviceRecord>,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// The runner configuration (camera rate and latency).
    pub runner: RunnerConfig,
}

/// The GUI side of a running sitting.
#[derive(Debug)]
pub struct SessionHandle {
    info: SessionInfo,
    cmd_tx: mpsc::Sender<SessionCommand>,
    ev_rx: mpsc::Receiver<SessionEvent>,
    telemetry: rtrb::Consumer<Telemetry>,
    estop: EstopTrigger,
    thread: Option<JoinHandle<()>>,
    finished: Option<FinishReason>,
    /// The engine's chain before the sitting (restored by [`Self::close`]).
    restore_chain: Option<(LoopChain, Clearance)>,
    fast: bool,
    /// Engine health when the sitting began (misses are counted from it).
    health0: Option<Health>,
    counters: Arc<driver::SittingCounters>,
    /// Samples per engine block and the rig file's late limit (the timing
    /// verdict's).
    timing_params: (u64, f64),
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
    let planned = plan_with_rows(&info.protocol, &info.order_table, &rows);
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

/// Queue capacities of a sitting: commands to the driver, its messages,
/// the participant's telemetry.
const TO_DRIVER: usize = 16;
const FROM_DRIVER: usize = 64;
const TELEMETRY: usize = 4096;

impl SessionHandle {
    /// Opens the output folder (new or resumed: the study crate repairs and
    /// reconciles it), installs the sitting as the engine's driver and
    /// starts the worker, idle until [`SessionCommand::Start`]. The engine
    /// runs the sitting's chain (the one `opts.calibration` names) from now
    /// on, cleared at the engine's loop delay.
    ///
    /// # Errors
    /// Invalid options (a participant kind the rig cannot have,
    /// [`Speed::Fast`] with a person or on a live rig, a participant who is
    /// not next in the plan, a done study), a chain whose margins at the
    /// rig's loop delay are below the minimum, storage errors.
    pub fn spawn(opts: SessionOptions, engine: &mut EngineHandle) -> Result<Self, SessionError> {
        check_options(&opts, engine.is_live(), engine.live_tweezer().is_some())?;
        let (mut meta, chain) = sim_meta(
            &opts.rig,
            opts.calibration.as_deref(),
            opts.runner.raw.is_some(),
            None,
        )?;
        meta.trap_calibration.clone_from(&opts.trap_calibration);
        let device = device_record(engine);
        if let Some(d) = &device {
            meta.rig = format!("{} ({})", d.name, d.spec);
        }
        meta.device.clone_from(&device);
        let store = open_store(&opts, &meta)?;
        let restore_chain = use_chain(engine, &chain)?;
        let fs = engine.sample_rate_hz();
        let mapping = HandMapping::from_config(&engine.config().coupling);
        let info = session_info(&opts, engine, &store, mapping, device)?;
        let live_obstacle_m = live_obstacle(engine, &info.protocol)?;
        let timing_params = (
            engine.block_len() as u64,
            opts.rig.safety.sitting_max_late_fraction,
        );
        let (to_driver, inbox) = rtrb::RingBuffer::new(TO_DRIVER);
        let (outbox, from_driver) = rtrb::RingBuffer::new(FROM_DRIVER);
        let (raw_tx, raw_rx) = rtrb::RingBuffer::new(driver::RAW_QUEUE_ROWS);
        let (tel_tx, telemetry) = rtrb::RingBuffer::new(TELEMETRY);
        let who = participant_of(&opts, &info.protocol, fs);
        let counters = Arc::new(driver::SittingCounters::default());
        let contact_gap_m = TaskParams::from_protocol(&info.protocol).contact_gap_m();
        let d = driver::SittingDriver::new(driver::DriverParts {
            core: TrialCore::new(fs, opts.runner, opts.rig.camera)?,
            who: Tap::new(who, contact_gap_m),
            inbox,
            outbox,
            raw: raw_tx,
            raw_on: opts.runner.raw.is_some(),
            telemetry: tel_tx,
            telemetry_every: opts.telemetry_every as u64,
            counters: counters.clone(),
            fs,
            mapping,
            free: engine.free_exploration_driver(),
        });
        let kits = if engine.is_live() {
            KitBuilder::live(&opts.rig, engine.identity())
        } else {
            KitBuilder::new(&opts.rig)
        };
        let frame = StationFrame {
            sample_rate_hz: fs,
            rest_trap_m: mapping.rest_trap_m(),
            mapping,
        };
        let (cmd_tx, cmd_rx) = mpsc::channel();
        let (ev_tx, ev_rx) = mpsc::channel();
        let fast = opts.speed == Speed::Fast;
        let w = worker::Worker {
            core: SittingCore::new(store, frame, opts.runner.raw),
            kits,
            detector: opts.rig.tweezer.detector.clone(),
            runner: opts.runner,
            fs,
            to_driver,
            from_driver,
            raw_rx,
            cmd_rx,
            ev_tx,
            only_participant: opts.only_participant,
            screens: opts.screens,
            speed: opts.speed,
            reader: match opts.participant {
                ParticipantKind::Simulated => worker::Reader::Simulated,
                _ => worker::Reader::Person,
            },
            scene: None,
            last_ended: None,
            waiting_since: None,
            last_state: None,
            live_obstacle_m,
            counters: counters.clone(),
            block_len: timing_params.0,
            max_late_fraction: timing_params.1,
        };
        if !engine.set_driver(Box::new(d)) {
            return Err(SessionError::Invalid(
                "the engine's command queue is full: try again".into(),
            ));
        }
        if fast {
            engine.set_paced(false);
        }
        let thread = std::thread::Builder::new()
            .name("kilotouch-sitting".into())
            .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
            .spawn(move || w.run())
            .map_err(|e| SessionError::Thread(e.to_string()))?;
        Ok(Self {
            info,
            cmd_tx,
            ev_rx,
            telemetry,
            estop: engine.estop_trigger(),
            thread: Some(thread),
            finished: None,
            restore_chain,
            fast,
            health0: engine.health().copied(),
            counters,
            timing_params,
        })
    }

    /// The sitting's timing verdict so far (what `session.json` records
    /// when it ends): late blocks and late device commands against the rig
    /// file's `sitting_max_late_fraction`.
    pub fn timing(&self) -> kilotouch_study::export::SittingTiming {
        self.counters
            .timing(self.timing_params.0, self.timing_params.1)
    }

    /// What was known at opening.
    pub fn info(&self) -> &SessionInfo {
        &self.info
    }

    /// Sends a command (`false`: the sitting has ended). An emergency stop
    /// presses the engine's own stop at once (it never waits on a queue).
    pub fn send(&mut self, cmd: SessionCommand) -> bool {
        if cmd == SessionCommand::EmergencyStop {
            self.estop.fire();
        }
        self.cmd_tx.send(cmd).is_ok()
    }

    /// Drains the events, the participant's telemetry among them (call
    /// every frame).
    pub fn poll(&mut self) -> Vec<SessionEvent> {
        let mut out = Vec::new();
        while let Ok(t) = self.telemetry.pop() {
            out.push(SessionEvent::Telemetry(t));
        }
        while let Ok(e) = self.ev_rx.try_recv() {
            if let SessionEvent::Finished(r) = &e {
                self.finished = Some(r.clone());
            }
            out.push(e);
        }
        out
    }

    /// The sitting's timing health: the engine's (deadline misses and
    /// overruns counted from the start of the sitting when the engine had
    /// reported before it), the trial time the sitting ran.
    pub fn health(&self, engine: &EngineHandle) -> SessionHealth {
        let samples = self.counters.samples.load(Ordering::Relaxed);
        let dropped = self.counters.telemetry_dropped.load(Ordering::Relaxed);
        let simulated_s = samples as f64 / engine.sample_rate_hz();
        let Some(h) = engine.health() else {
            return SessionHealth {
                worst_lateness_s: f64::NEG_INFINITY,
                telemetry_dropped: dropped,
                simulated_s,
                ..SessionHealth::default()
            };
        };
        let base = |f: fn(&Health) -> u64| self.health0.as_ref().map_or(0, f);
        SessionHealth {
            deadline_misses: h
                .deadline_misses
                .saturating_sub(base(|h| h.deadline_misses)),
            overruns: h.overruns.saturating_sub(base(|h| h.overruns)),
            worst_lateness_s: h.worst_lateness_total_s,
            load: h.load,
            telemetry_dropped: dropped,
            simulated_s,
        }
    }

    /// Why the sitting ended, once it has reported it.
    pub fn finished(&self) -> Option<&FinishReason> {
        self.finished.as_ref()
    }

    /// Is the worker still running?
    pub fn is_alive(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }

    /// Waits for the worker to end (after a `Stop`, or when done); the
    /// remaining events are returned.
    pub fn join(mut self) -> Vec<SessionEvent> {
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.poll()
    }

    /// Ends the sitting (a `Stop` if it still runs), waits for the worker
    /// and gives the engine back to free exploration, stopped: its driver,
    /// its pacing and the chain it ran before. The remaining events are
    /// returned.
    pub fn close(mut self, engine: &mut EngineHandle) -> Vec<SessionEvent> {
        if self.is_alive() {
            let _ = self.cmd_tx.send(SessionCommand::Stop);
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        engine.free_exploration();
        // Free exploration takes the loop back stopped: nothing arms itself
        // after a sitting (Resume on the Rig page starts it).
        let _ = engine.send(crate::engine::Command::Stop);
        if self.fast {
            engine.set_paced(true);
        }
        if let Some((chain, clearance)) = self.restore_chain.take() {
            let _ = engine.apply_chain(&chain, &clearance);
        }
        self.poll()
    }
}

impl Drop for SessionHandle {
    fn drop(&mut self) {
        // Dropping the handle ends the sitting like `Stop` (the trial in
        // progress stays open and runs again on resume); the engine's
        // driver, detached, goes on as free exploration.
        let _ = self.cmd_tx.send(SessionCommand::Stop);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Refuses option sets that do not fit the rig.
fn check_options(
    opts: &SessionOptions,
    live: bool,
    live_tweezer: bool,
) -> Result<(), SessionError> {
    if opts.telemetry_every == 0 {
        return Err(SessionError::Invalid("telemetry_every must be ≥ 1".into()));
    }
    match (opts.participant, live) {
        (ParticipantKind::Handle, false) => {
            return Err(SessionError::Invalid(
                "the participant at the handle needs a live rig: on the simulated rig choose a \
                 person at the mouse or the simulated participant"
                    .into(),
            ));
        }
        (ParticipantKind::Mouse | ParticipantKind::Simulated, true) => {
            return Err(SessionError::Invalid(
                "on a live rig the hand at the handle is real (a person, or the emulator's \
                 simulated participant): choose the participant at the handle"
                    .into(),
            ));
        }
        _ => {}
    }
    if opts.speed == Speed::Fast && opts.participant != ParticipantKind::Simulated {
        return Err(SessionError::Invalid(
            "\"as fast as possible\" is for the simulated participant on the simulated rig only"
                .into(),
        ));
    }
    if opts.speed == Speed::Fast && live_tweezer {
        return Err(SessionError::Invalid(
            "\"as fast as possible\" needs the simulated tweezer: a live tweezer streams at its \
             own rate"
                .into(),
        ));
    }
    Ok(())
}

/// Largest relative difference between a live tweezer's obstacle radius
/// and the protocol's for the scene to be that obstacle.
const OBSTACLE_RADIUS_TOLERANCE: f64 = 0.05;

/// A live tweezer's obstacle for the protocol's scene (instrument frame,
/// m): the one whose radius is the protocol's (within
/// [`OBSTACLE_RADIUS_TOLERANCE`]); `None` with the simulated tweezer.
fn live_obstacle(
    engine: &EngineHandle,
    protocol: &kilotouch_study::protocol::Protocol,
) -> Result<Option<[f64; 2]>, SessionError> {
    let Some(t) = engine.live_tweezer() else {
        return Ok(None);
    };
    let want = kilotouch_study::task::Geometry::of_protocol(&protocol.task).obstacle_radius_m;
    let near = |r: f64| (r - want).abs() <= OBSTACLE_RADIUS_TOLERANCE * want;
    if let Some(o) = t.obstacles.iter().find(|o| near(o.radius_m)) {
        return Ok(Some(o.centre_m));
    }
    let seen = if t.obstacles.is_empty() {
        "reports no obstacle".to_owned()
    } else {
        let radii: Vec<String> = t
            .obstacles
            .iter()
            .map(|o| format!("{:.2} µm", o.radius_m * 1e6))
            .collect();
        format!("reports obstacles of radius {}", radii.join(", "))
    };
    Err(SessionError::Invalid(format!(
        "the tweezer {} {seen}, the protocol `{}` needs one of radius {:.2} µm: the task's \
         contacts, gaps and metrics are computed from that obstacle",
        t.spec.describe(),
        protocol.name,
        want * 1e6
    )))
}

/// What the page shows of a sitting about to start: the folder's protocol,
/// recovery, rows and plan, and the rig it runs on.
fn session_info(
    opts: &SessionOptions,
    engine: &EngineHandle,
    store: &StudyStore,
    mapping: HandMapping,
    device: Option<DeviceRecord>,
) -> Result<SessionInfo, SessionError> {
    Ok(SessionInfo {
        protocol: store.protocol().clone(),
        recovery_text: store.recovery().to_string(),
        recovery: store.recovery().clone(),
        rows: read_trials(&opts.out.join(TRIALS_FILE))?.rows,
        completed: store.completed_count(),
        planned: store.plan().len(),
        next: store.next_pending().cloned(),
        mapping,
        sample_rate_hz: engine.sample_rate_hz(),
        runner: opts.runner,
        rig: engine.spec().describe(),
        device,
    })
}

/// The live device's record for `session.json` (`None`: the simulated rig).
fn device_record(engine: &EngineHandle) -> Option<DeviceRecord> {
    let tweezer = engine.live_tweezer();
    if !engine.is_live() && tweezer.is_none() {
        return None;
    }
    let id = engine.identity();
    let fs = id.sample_rate_hz;
    let delay = engine.loop_delay_samples();
    let tweezer = tweezer.map(|t| TweezerDeviceRecord {
        spec: t.spec.describe(),
        name: t.name.clone(),
        serial: t.serial.clone(),
        firmware: t.firmware.clone(),
        lead_samples: t.lead_samples,
        lead_ms: f64::from(t.lead_samples) / fs * 1e3,
        round_trip_ms: t.round_trip_s.map(|s| s * 1e3),
    });
    Some(DeviceRecord {
        spec: engine.spec().describe(),
        kind: format!("{:?}", id.kind),
        name: id.name.clone(),
        serial: id.serial.clone(),
        firmware: id.firmware.clone(),
        sample_rate_hz: fs,
        block_samples: u32::try_from(engine.block_len()).unwrap_or(u32::MAX),
        loop_delay_samples: delay,
        loop_delay_ms: f64::from(delay) / fs * 1e3,
        extra_latency_ms: engine.latency_s() * 1e3,
        round_trip_ms: engine.round_trip_s().map(|s| s * 1e3),
        tweezer,
    })
}

/// Opens the folder (new or resumed) after the checks a sitting needs.
fn open_store(
    opts: &SessionOptions,
    meta: &kilotouch_study::export::StudyMeta,
) -> Result<StudyStore, SessionError> {
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
        Some(p) => StudyStore::open(&opts.out, p, meta)?,
        None => StudyStore::open_existing(&opts.out, meta)?,
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
    Ok(store)
}

/// Makes the engine run `chain` (cleared at the engine's loop delay);
/// returns the chain to restore afterwards when it differed.
fn use_chain(
    engine: &mut EngineHandle,
    chain: &LoopChain,
) -> Result<Option<(LoopChain, Clearance)>, SessionError> {
    if engine.chain_source() == &chain.source {
        return Ok(None);
    }
    let clearance = Clearance::check_with_latency(engine.config(), chain, engine.latency_s())
        .map_err(|e| SessionError::Invalid(format!("the sitting's chain: {e}")))?;
    let before = engine.chain_and_clearance();
    engine.apply_chain(chain, &clearance)?;
    Ok(before)
}

/// The participant at the handle.
fn participant_of(opts: &SessionOptions, protocol: &Protocol, fs: f64) -> Who {
    match opts.participant {
        ParticipantKind::Mouse => Who::Mouse(MouseParticipant::default()),
        ParticipantKind::Handle => Who::Handle,
        ParticipantKind::Simulated => {
            let mut c = SimCohort::new(protocol.seeds.study, fs / opts.runner.act_every as f64, fs);
            // Built here, not at the first trial on the engine thread.
            if let Some(p) = opts.only_participant {
                c.prepare(p);
            }
            Who::Sim(Box::new(c))
        }
    }
}
