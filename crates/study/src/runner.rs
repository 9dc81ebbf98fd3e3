//! The session runner: a GUI-independent state machine that runs a study's
//! trials on a [`Station`] with a [`Participant`] and stores every finished
//! trial crash-safely in a [`StudyStore`].
//!
//! # Two layers
//!
//! * [`TrialEngine`] runs one trial sample by sample: every
//!   `act_every` samples it asks the participant for a hand position (with
//!   the [`Observation`] of what happened since), interpolates the hand
//!   linearly over the samples, steps the station, feeds the task's metric
//!   accumulator, the camera, and the raw-signal sink. The per-sample path
//!   allocates nothing (buffers are sized when the engine is built) and
//!   performs no I/O except [`RawSink::push`].
//! * [`SessionRunner`] is the state machine
//!   `Idle → Training(trial) → … → Trial(trial) → … → Done`, with
//!   `Paused` and experimenter notes and aborts. [`SessionRunner::advance`]
//!   runs at most `n` samples and never touches the disk (except the raw
//!   sink); when a trial ends it reports [`RunnerEvents::needs_service`]
//!   and [`SessionRunner::service`] does the trial-boundary I/O: finish the
//!   raw file, commit the row (append + fsync), begin the next trial
//!   (journal + fsync). [`SessionRunner::run_to_end`] alternates both for
//!   headless use.
//!
//! A GUI engine thread calls `advance` with a block size of its choice and
//! `service` when asked (≈ 1 ms of fsyncs between trials, while the hand
//! is idle). For a live 10 kHz loop, give the runner a [`RawSink`] that
//! hands rows to a logging thread instead of the NPY writer (which makes a
//! `write` system call every 64 KiB).

use std::fmt;

pub use crate::error::RunError;
use crate::export::{ExportError, StudyStore, TaskKind, TrialRow, TrialTicket, UtcTime};
use crate::operator::{Observation, Participant, TrialBrief, VisualFrame};
use crate::protocol::{Protocol, Task};
use crate::rawsig::{Channel, Dtype, NpyWriter, RawLayout, standard_channels};
use crate::seeds::{Phase, STREAM_PARTICIPANT, STREAM_RIG, STREAM_TASK, TrialKey};
use crate::task::station::Station;
use crate::task::{
    Feedback, Geometry, Scene, TaskAccumulator, TaskMetrics, TaskParams, TaskSample, TrialEnd,
};

/// Camera and control timing of the runner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunnerConfig {
    /// Samples between two participant `act` calls (10 → 1 kHz at 10 kHz).
    pub act_every: usize,
    /// Camera frame rate, Hz.
    pub camera_fps: f64,
    /// Camera-to-display latency, s.
    pub camera_latency_s: f64,
    /// Raw-signal sample type (`None`: no raw files).
    pub raw: Option<Dtype>,
    /// Decimation of the kept trajectory (samples per point).
    pub trajectory_every: usize,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            act_every: 10,
            camera_fps: 25.0,
            camera_latency_s: 0.04,
            raw: Some(Dtype::F32),
            trajectory_every: 100,
        }
    }
}

/// Event codes of the raw `event` channel.
pub mod event {
    /// The bead entered the tweezer's contact zone.
    pub const CONTACT_START: f64 = 1.0;
    /// The bead left it.
    pub const CONTACT_END: f64 = 2.0;
    /// The bead escaped the trap.
    pub const ESCAPED: f64 = 3.0;
    /// A lost bead was recaptured.
    pub const RECAPTURED: f64 = 4.0;
    /// A camera frame was captured.
    pub const FRAME: f64 = 5.0;
    /// The trial ended at this sample.
    pub const END: f64 = 9.0;
}

/// Channels of a trial's raw file: the standard 17
/// ([`standard_channels`]) plus the participant's hand target.
pub fn raw_channels() -> Vec<Channel> {
    let mut c = standard_channels();
    c.push(Channel::new(
        "hand_x",
        "m",
        "participant's hand position (input), x",
    ));
    c.push(Channel::new(
        "hand_y",
        "m",
        "participant's hand position (input), y",
    ));
    c
}

/// Number of raw channels.
pub const RAW_CHANNELS: usize = 19;

/// The raw layout of trials (sample rate, dtype, channels, event legend).
pub fn raw_layout(sample_rate_hz: f64, dtype: Dtype) -> RawLayout {
    let mut attrs = serde_json::Map::new();
    attrs.insert(
        "event_legend".into(),
        serde_json::json!({
            "1": "contact_start", "2": "contact_end", "3": "escaped",
            "4": "recaptured", "5": "camera_frame", "9": "trial_end"
        }),
    );
    RawLayout {
        sample_rate_hz,
        dtype,
        channels: raw_channels(),
        attrs,
    }
}

/// Where a trial's full-rate rows go.
pub trait RawSink {
    /// One row of [`RAW_CHANNELS`] values.
    ///
    /// # Errors
    /// I/O errors.
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError>;
}

impl RawSink for NpyWriter {
    #[inline]
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError> {
        NpyWriter::push(self, row)
    }
}

/// A sink that drops everything.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoRaw;

impl RawSink for NoRaw {
    #[inline]
    fn push(&mut self, _row: &[f64]) -> Result<(), ExportError> {
        Ok(())
    }
}

impl<S: RawSink + ?Sized> RawSink for Option<&mut S> {
    #[inline]
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError> {
        match self {
            Some(s) => s.push(row),
            None => Ok(()),
        }
    }
}

/// Everything that defines one trial (all randomness drawn from its key).
#[derive(Debug, Clone)]
pub struct TrialSetup {
    /// The trial.
    pub key: TrialKey,
    /// Feedback of its condition.
    pub feedback: Feedback,
    /// Task thresholds.
    pub params: TaskParams,
    /// The scene.
    pub scene: Scene,
    /// What the participant is told.
    pub brief: TrialBrief,
    /// The rig generator.
    pub rig_rng: rand_chacha::ChaCha20Rng,
}

impl TrialSetup {
    /// The setup of trial `key` of `protocol` on a station whose rest trap
    /// position is `start_m`: scene from the task stream, rig noise from
    /// the rig stream, the participant's stream in the brief.
    pub fn new(
        protocol: &Protocol,
        key: TrialKey,
        start_m: [f64; 2],
        mapping: kilotouch_rig::coupling::HandMapping,
    ) -> Self {
        let seed = protocol.seeds.study;
        let mut task_rng = key.rng(seed, STREAM_TASK);
        let scene = Scene::draw(&protocol.task, start_m, &mut task_rng);
        let params = TaskParams::from_protocol(protocol);
        let retreat = match &protocol.task {
            Task::BlindNavigation(t) => t.retreat_distance_um * crate::task::UM,
            Task::Circling(_) => 0.0,
        };
        Self {
            key,
            feedback: Feedback::of(key.condition, &protocol.task),
            params,
            scene,
            brief: TrialBrief {
                participant: key.participant,
                task: TaskKind::of(&protocol.task),
                mapping,
                start_trap_m: start_m,
                heading: scene.heading,
                retreat_distance_m: retreat,
                rng: key.rng(seed, STREAM_PARTICIPANT),
            },
            rig_rng: key.rng(seed, STREAM_RIG),
        }
    }
}

/// The result of a finished trial.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    /// The trial.
    pub key: TrialKey,
    /// Its metrics.
    pub metrics: TaskMetrics,
    /// Samples run.
    pub samples: u64,
    /// Bead trajectory decimated by `trajectory_every`, m (Fig. 10).
    pub trajectory: Vec<[f64; 2]>,
    /// The scene.
    pub scene: Scene,
}

const FRAME_RING: usize = 64;

/// Runs one trial sample by sample (module docs).
#[derive(Debug)]
pub struct TrialEngine<S: Station> {
    station: S,
    cfg: RunnerConfig,
    fs: f64,
    frame_every: u64,
    latency_samples: u64,
    // Trial state.
    key: Option<TrialKey>,
    acc: Option<TaskAccumulator>,
    scene: Option<Scene>,
    geometry: Geometry,
    contact_gap_m: f64,
    vision: bool,
    k: u64,
    hand_prev: [f64; 2],
    hand_next: [f64; 2],
    force_buf: Vec<[f64; 2]>,
    accel_buf: Vec<[f64; 3]>,
    frames: [Option<(u64, VisualFrame)>; FRAME_RING],
    // A lower bound of the earliest display time (sample) among `frames`
    // (u64::MAX: none pending): the ring is scanned once it is reached,
    // not every sample.
    next_due: u64,
    frame_seq: u64,
    shown: Option<VisualFrame>,
    trajectory: Vec<[f64; 2]>,
    trajectory_cap: usize,
    handle: [f64; 2],
    row: [f64; RAW_CHANNELS],
    end: Option<TrialEnd>,
}

impl<S: Station> TrialEngine<S> {
    /// An engine on `station`.
    ///
    /// # Errors
    /// [`RunError::Config`] for a zero control period or a non-positive
    /// frame rate / negative latency.
    pub fn new(station: S, cfg: RunnerConfig) -> Result<Self, RunError> {
        if cfg.act_every == 0 || cfg.trajectory_every == 0 {
            return Err(RunError::Config(
                "act_every and trajectory_every must be ≥ 1".into(),
            ));
        }
        let fps_ok = cfg.camera_fps.is_finite() && cfg.camera_fps > 0.0;
        let latency_ok = cfg.camera_latency_s.is_finite() && cfg.camera_latency_s >= 0.0;
        if !(fps_ok && latency_ok) {
            return Err(RunError::Config(format!(
                "camera_fps must be > 0 and camera_latency_s ≥ 0, got {} and {}",
                cfg.camera_fps, cfg.camera_latency_s
            )));
        }
        let fs = station.sample_rate_hz();
        let frame_every = ((fs / cfg.camera_fps).round() as u64).max(1);
        let latency_samples = (cfg.camera_latency_s * fs).round() as u64;
        Ok(Self {
            station,
            cfg,
            fs,
            frame_every,
            latency_samples,
            key: None,
            acc: None,
            scene: None,
            geometry: Geometry {
                obstacle_m: [0.0; 2],
                obstacle_radius_m: 0.0,
                bead_radius_m: 0.0,
            },
            contact_gap_m: 0.0,
            vision: true,
            k: 0,
            hand_prev: [0.0; 2],
            hand_next: [0.0; 2],
            force_buf: Vec::with_capacity(cfg.act_every),
            accel_buf: Vec::with_capacity(cfg.act_every),
            frames: [None; FRAME_RING],
            next_due: u64::MAX,
            frame_seq: 0,
            shown: None,
            trajectory: Vec::new(),
            trajectory_cap: 0,
            handle: [0.0; 2],
            row: [0.0; RAW_CHANNELS],
            end: None,
        })
    }

    /// The station.
    pub fn station(&self) -> &S {
        &self.station
    }

    /// Configuration.
    pub fn config(&self) -> &RunnerConfig {
        &self.cfg
    }

    /// Sample rate, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    /// The setup of trial `key` of `protocol` on this engine's station.
    pub fn setup(&self, protocol: &Protocol, key: TrialKey) -> TrialSetup {
        TrialSetup::new(
            protocol,
            key,
            self.station.rest_trap_m(),
            self.station.mapping(),
        )
    }

    /// Starts a trial (allocates the trajectory buffer; not real-time).
    ///
    /// # Errors
    /// Station preparation errors.
    pub fn start<P: Participant + ?Sized>(
        &mut self,
        setup: &TrialSetup,
        participant: &mut P,
    ) -> Result<(), RunError> {
        let mut rng = setup.rig_rng.clone();
        self.station.prepare(
            &setup.scene,
            setup.feedback.condition,
            setup.params.escape_distance_m(),
            &mut rng,
        )?;
        self.key = Some(setup.key);
        self.acc = Some(TaskAccumulator::new(&setup.params, setup.scene.geometry));
        self.scene = Some(setup.scene);
        self.geometry = setup.scene.geometry;
        self.contact_gap_m = setup.params.contact_gap_m();
        self.vision = setup.feedback.vision;
        self.k = 0;
        let rest = setup.brief.mapping.to_hand(setup.scene.start_m);
        self.hand_prev = rest;
        self.hand_next = rest;
        self.force_buf.clear();
        self.accel_buf.clear();
        self.frames = [None; FRAME_RING];
        self.next_due = u64::MAX;
        self.frame_seq = 0;
        self.shown = None;
        self.trajectory_cap =
            (setup.params.timeout_s() * self.fs / self.cfg.trajectory_every as f64) as usize + 2;
        self.trajectory = Vec::with_capacity(self.trajectory_cap);
        self.trajectory.push(setup.scene.start_m);
        self.handle = [0.0; 2];
        self.end = None;
        participant.begin_trial(&setup.brief);
        Ok(())
    }

    /// The trial in progress (or just ended).
    pub fn key(&self) -> Option<TrialKey> {
        self.key
    }

    /// How the trial ended, once it has.
    pub fn end(&self) -> Option<TrialEnd> {
        self.end
    }

    /// Samples run in the current trial.
    pub fn samples(&self) -> u64 {
        self.k
    }

    /// Ends the current trial as aborted (its metrics so far are kept).
    pub fn abort(&mut self) {
        if let Some(acc) = &mut self.acc
            && self.end.is_none()
        {
            acc.abort();
            self.end = Some(TrialEnd::Aborted);
        }
    }

    /// Runs up to `n` samples of the current trial; returns the end when the
    /// trial ended within them. Allocation-free.
    ///
    /// # Errors
    /// Station and raw-sink errors; [`RunError::State`] without a trial.
    pub fn run<P: Participant + ?Sized, W: RawSink + ?Sized>(
        &mut self,
        participant: &mut P,
        raw: &mut W,
        n: usize,
    ) -> Result<Option<TrialEnd>, RunError> {
        if self.end.is_some() {
            return Ok(self.end);
        }
        let Some(acc) = self.acc.as_mut() else {
            return Err(RunError::State("no trial started".into()));
        };
        let every = self.cfg.act_every as u64;
        let dt = 1.0 / self.fs;
        for _ in 0..n {
            let phase = self.k % every;
            if phase == 0 {
                let obs = Observation {
                    t_s: self.k as f64 * dt,
                    dt_s: dt,
                    frame: if self.vision { self.shown } else { None },
                    force_n: &self.force_buf,
                    accel_m_s2: &self.accel_buf,
                    handle_m: self.handle,
                };
                let target = participant.act(&obs);
                self.force_buf.clear();
                self.accel_buf.clear();
                self.hand_prev = self.hand_next;
                if target.iter().all(|v| v.is_finite()) {
                    self.hand_next = target;
                }
            }
            let a = (phase + 1) as f64 / every as f64;
            let hand = [
                self.hand_prev[0] + a * (self.hand_next[0] - self.hand_prev[0]),
                self.hand_prev[1] + a * (self.hand_next[1] - self.hand_prev[1]),
            ];
            self.station.set_hand(hand);
            let ss = self.station.step()?;
            self.k += 1;
            let t = self.k as f64 * dt;
            let tw = &ss.tweezer;
            let sample = TaskSample {
                t_s: t,
                bead_m: tw.bead_m,
                trap_m: tw.trap_m,
                force_bead_n: tw.force_n,
                force_hand_n: ss.force_hand_n,
                trapped: tw.trapped,
            };
            self.handle = ss.sensors.handle_m;
            if self.force_buf.len() < self.force_buf.capacity() {
                self.force_buf.push(ss.command.force_n);
                self.accel_buf.push(ss.sensors.accel_m_s2);
            }
            // Camera: capture every frame period, display after the latency.
            let mut ev = 0.0;
            if self.k.is_multiple_of(self.frame_every) {
                let geometry = self.geometry;
                let f = VisualFrame {
                    seq: self.frame_seq,
                    captured_s: t,
                    bead_m: tw.bead_m,
                    trap_m: tw.trap_m,
                    obstacle_m: geometry.obstacle_m,
                    obstacle_radius_m: geometry.obstacle_radius_m,
                    bead_radius_m: geometry.bead_radius_m,
                };
                let due = self.k + self.latency_samples;
                self.frames[(self.frame_seq as usize) % FRAME_RING] = Some((due, f));
                self.next_due = self.next_due.min(due);
                self.frame_seq += 1;
                ev = event::FRAME;
            }
            if self.k >= self.next_due {
                let mut next = u64::MAX;
                for slot in &mut self.frames {
                    match *slot {
                        Some((due, f)) if due <= self.k => {
                            if self.shown.is_none_or(|s| s.seq < f.seq) {
                                self.shown = Some(f);
                            }
                            *slot = None;
                        }
                        Some((due, _)) => next = next.min(due),
                        None => {}
                    }
                }
                self.next_due = next;
            }
            if tw.events.contact_start {
                ev = event::CONTACT_START;
            }
            if tw.events.contact_end {
                ev = event::CONTACT_END;
            }
            if tw.events.recaptured {
                ev = event::RECAPTURED;
            }
            if tw.events.escaped {
                ev = event::ESCAPED;
            }
            let end = acc.push(&sample);
            if end.is_some() {
                ev = event::END;
            }
            if self.k.is_multiple_of(self.cfg.trajectory_every as u64)
                && self.trajectory.len() < self.trajectory_cap
            {
                self.trajectory.push(tw.bead_m);
            }
            let r = &mut self.row;
            r[0] = ss.sensors.handle_m[0];
            r[1] = ss.sensors.handle_m[1];
            r[2] = tw.trap_m[0];
            r[3] = tw.trap_m[1];
            r[4] = tw.bead_m[0];
            r[5] = tw.bead_m[1];
            r[6] = tw.force_n[0];
            r[7] = tw.force_n[1];
            r[8] = ss.force_hand_n[0];
            r[9] = ss.force_hand_n[1];
            r[10] = ss.command.force_n[0];
            r[11] = ss.command.haptuator_v;
            r[12] = ss.sensors.accel_m_s2[0];
            r[13] = ss.sensors.accel_m_s2[1];
            r[14] = ss.sensors.accel_m_s2[2];
            r[15] = f64::from(u8::from(
                self.geometry.gap_m(tw.bead_m) < self.contact_gap_m,
            ));
            r[16] = ev;
            r[17] = hand[0];
            r[18] = hand[1];
            raw.push(&self.row)?;
            if let Some(e) = end {
                if self.trajectory.len() < self.trajectory_cap {
                    self.trajectory.push(tw.bead_m);
                }
                self.end = Some(e);
                return Ok(Some(e));
            }
        }
        Ok(None)
    }

    /// The outcome of the current trial (metrics so far if not ended).
    ///
    /// # Errors
    /// [`RunError::State`] without a trial.
    pub fn outcome(&self) -> Result<TrialOutcome, RunError> {
        match (&self.acc, self.key, self.scene) {
            (Some(acc), Some(key), Some(scene)) => Ok(TrialOutcome {
                key,
                metrics: acc.metrics(),
                samples: self.k,
                trajectory: self.trajectory.clone(),
                scene,
            }),
            _ => Err(RunError::State("no trial started".into())),
        }
    }

    /// Runs a whole trial (start, run to its end) and returns its outcome.
    ///
    /// # Errors
    /// Those of [`TrialEngine::start`] and [`TrialEngine::run`].
    pub fn run_trial<P: Participant + ?Sized, W: RawSink + ?Sized>(
        &mut self,
        setup: &TrialSetup,
        participant: &mut P,
        raw: &mut W,
    ) -> Result<TrialOutcome, RunError> {
        self.start(setup, participant)?;
        let limit = (setup.params.timeout_s() * self.fs).ceil() as u64 + 1;
        while self.end.is_none() {
            self.run(participant, raw, 10_000)?;
            if self.k > limit {
                return Err(RunError::State(format!(
                    "trial {} did not end by its time-out",
                    setup.key
                )));
            }
        }
        self.outcome()
    }
}

/// States of a session (module docs).
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

/// The session state machine (module docs).
#[derive(Debug)]
pub struct SessionRunner<S: Station> {
    store: Option<StudyStore>,
    protocol: Protocol,
    engine: TrialEngine<S>,
    state: RunnerState,
    before_pause: Option<RunnerState>,
    active: Option<Active>,
    summaries: Option<crate::export::SummaryFiles>,
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
        })
    }

    /// Current state.
    pub fn state(&self) -> RunnerState {
        self.state
    }

    /// The store (`None` once closed).
    pub fn store(&self) -> Option<&StudyStore> {
        self.store.as_ref()
    }

    /// The trial engine (station, current trial).
    pub fn engine(&self) -> &TrialEngine<S> {
        &self.engine
    }

    /// Summaries written when the session closed.
    pub fn summaries(&self) -> Option<&crate::export::SummaryFiles> {
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
        self.begin_next(participant, &mut ev)?;
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
            Some(d) => match store.raw_writer(&mut ticket, raw_layout(fs, d)) {
                Ok(w) => Some(w),
                Err(e) => {
                    store.abort_trial(ticket, "raw file could not be created")?;
                    return Err(e.into());
                }
            },
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
                _ => self.begin_next(participant, &mut ev)?,
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
                self.begin_next(participant, &mut ev)?;
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
