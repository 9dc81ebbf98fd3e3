//! [`TrialCore`]: runs one trial sample by sample on a station it is
//! handed block by block (see the [`super`] module documentation);
//! [`TrialOutcome`]: what a finished trial gives.
//!
//! The core owns no station: [`super::TrialEngine`] pairs it with a
//! simulated station it prepares itself, and the app's real-time engine
//! hands it the engine's own closed loop at every block. Starting and
//! running a trial allocate nothing (the trajectory buffer comes in with
//! [`TrialCore::start`] and leaves with [`TrialCore::take_outcome`]).

use kilotouch_rig::config::CameraConfig;
use kilotouch_rig::tweezer::{TweezerEvents, TweezerSample};

use crate::error::RunError;
use crate::participant::{ControlPeriod, Participant, VisualFrame};
use crate::seeds::TrialKey;
use crate::task::station::{MAX_STATION_BLOCK, Station, StationSample};
use crate::task::{Geometry, Scene, TaskAccumulator, TaskMetrics, TaskSample, TrialEnd};

use super::config::RunnerConfig;
use super::event;
use super::raw::{RAW_CHANNELS, RawSink};
use super::setup::TrialSetup;

/// The result of a finished trial.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    /// The trial.
    pub key: TrialKey,
    /// Its metrics.
    pub metrics: TaskMetrics,
    /// Samples run (at `sample_rate_hz`).
    pub samples: u64,
    /// The trial's sample rate, Hz (the station's rate divided by the
    /// trial's decimation, [`Station::trial_decimation`]).
    pub sample_rate_hz: f64,
    /// Bead trajectory decimated by `trajectory_every`, m (Fig. 10).
    pub trajectory: Vec<[f64; 2]>,
    /// The scene.
    pub scene: Scene,
}

const FRAME_RING: usize = 64;

/// Runs one trial sample by sample (module docs).
#[derive(Debug)]
pub struct TrialCore {
    cfg: RunnerConfig,
    camera: CameraConfig,
    // The station's rate, Hz.
    station_fs: f64,
    // The current trial's rate (the station's / its decimation), Hz, and
    // its timing in samples of that rate.
    fs: f64,
    act_every: u64,
    trajectory_every: u64,
    frame_every: u64,
    latency_samples: u64,
    // Samples of a frame's exposure (0: instantaneous) and the sums of
    // the bead and trap positions over the current exposure, m.
    exposure_samples: u64,
    exposure_sum: [[f64; 2]; 2],
    exposure_n: u64,
    // Trial state.
    key: Option<TrialKey>,
    acc: Option<TaskAccumulator>,
    scene: Option<Scene>,
    geometry: Geometry,
    contact_gap_m: f64,
    vision: bool,
    k: u64,
    control: ControlPeriod,
    frames: [Option<(u64, VisualFrame)>; FRAME_RING],
    // A lower bound of the earliest display time (sample) among `frames`
    // (u64::MAX: none pending): the ring is scanned once it is reached,
    // not every sample.
    next_due: u64,
    frame_seq: u64,
    shown: Option<VisualFrame>,
    trajectory: Vec<[f64; 2]>,
    trajectory_cap: usize,
    row: [f64; RAW_CHANNELS],
    end: Option<TrialEnd>,
    // A trial that ended on a sample with its own event: the end code is
    // written on the next sample, then the trial reports its end.
    pending_end: Option<TrialEnd>,
    // The station's hand input and output of the current chunk.
    hands: [[f64; 2]; MAX_STATION_BLOCK],
    samples: [StationSample; MAX_STATION_BLOCK],
}

impl TrialCore {
    /// A core for a station running at `station_fs` Hz whose participant
    /// watches `camera` (the rig file's `[camera]`).
    ///
    /// # Errors
    /// [`RunError::Config`] for a zero control period or a camera setting
    /// out of range ([`CameraConfig::issues`]).
    pub fn new(station_fs: f64, cfg: RunnerConfig, camera: CameraConfig) -> Result<Self, RunError> {
        if cfg.act_every == 0 || cfg.trajectory_every == 0 {
            return Err(RunError::Config(
                "act_every and trajectory_every must be ≥ 1".into(),
            ));
        }
        if let Some((key, why)) = camera.issues(station_fs).into_iter().next() {
            return Err(RunError::Config(format!("camera.{key} {why}")));
        }
        if !(station_fs.is_finite() && station_fs > 0.0) {
            return Err(RunError::Config(format!(
                "the station's sample rate must be finite and > 0 Hz, got {station_fs}"
            )));
        }
        let fs = station_fs;
        let mut engine = Self {
            cfg,
            camera,
            station_fs: fs,
            fs,
            act_every: 1,
            trajectory_every: 1,
            frame_every: 1,
            latency_samples: 0,
            exposure_samples: 0,
            exposure_sum: [[0.0; 2]; 2],
            exposure_n: 0,
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
            control: ControlPeriod::new(cfg.act_every),
            frames: [None; FRAME_RING],
            next_due: u64::MAX,
            frame_seq: 0,
            shown: None,
            trajectory: Vec::new(),
            trajectory_cap: 0,
            row: [0.0; RAW_CHANNELS],
            end: None,
            pending_end: None,
            hands: [[0.0; 2]; MAX_STATION_BLOCK],
            samples: [StationSample::default(); MAX_STATION_BLOCK],
        };
        engine.set_decimation(1);
        Ok(engine)
    }

    /// The largest rate divisor a trial may run at: none (1) with raw
    /// files, else one that keeps the control period and the trajectory's
    /// decimation whole numbers of samples.
    pub fn max_decimation(&self) -> u32 {
        if self.cfg.raw.is_some() {
            return 1;
        }
        let (mut a, mut b) = (self.cfg.act_every, self.cfg.trajectory_every);
        while b != 0 {
            (a, b) = (b, a % b);
        }
        u32::try_from(a).unwrap_or(1).max(1)
    }

    /// The trial's timing at the station's rate divided by `d` (a divisor
    /// of [`Self::max_decimation`]): the control period, trajectory
    /// decimation, camera period and latency keep their durations.
    fn set_decimation(&mut self, d: u32) {
        let d = u64::from(d.max(1));
        self.fs = self.station_fs / d as f64;
        self.act_every = (self.cfg.act_every as u64 / d).max(1);
        self.trajectory_every = (self.cfg.trajectory_every as u64 / d).max(1);
        let cam = &self.camera;
        self.frame_every = ((self.fs / cam.frame_rate_hz).round() as u64).max(1);
        self.latency_samples = (cam.latency_s * self.fs).round() as u64;
        self.exposure_samples = ((cam.exposure_s * self.fs).round() as u64).min(self.frame_every);
    }

    /// Configuration.
    pub fn config(&self) -> &RunnerConfig {
        &self.cfg
    }

    /// The camera the participant watches.
    pub fn camera(&self) -> &CameraConfig {
        &self.camera
    }

    /// The station's sample rate, Hz (a trial may run at a divisor of it:
    /// [`TrialOutcome::sample_rate_hz`]).
    pub fn sample_rate_hz(&self) -> f64 {
        self.station_fs
    }

    /// The sample rate of the current trial, Hz.
    pub fn trial_sample_rate_hz(&self) -> f64 {
        self.fs
    }

    /// The capacity of the trajectory buffer [`Self::start`] takes for
    /// `setup` at rate divisor `decimation` ([`trajectory_capacity`]).
    ///
    /// # Errors
    /// A time-out that is not a representable number of samples.
    pub fn trajectory_capacity(
        &self,
        setup: &TrialSetup,
        decimation: u32,
    ) -> Result<usize, RunError> {
        trajectory_capacity(&self.cfg, self.station_fs, setup, decimation)
    }

    /// Starts trial `setup` on a station already prepared for it, running
    /// at its rate divided by `decimation` (a divisor of
    /// [`Self::max_decimation`]). `trajectory` is the buffer the kept
    /// trajectory goes to (cleared; it should have
    /// [`Self::trajectory_capacity`], else it grows here). Allocation-free
    /// given that buffer and a participant whose `begin_trial` is.
    ///
    /// # Errors
    /// A decimation that does not divide the largest allowed one; a
    /// time-out that is not a representable number of samples.
    pub fn start<P: Participant + ?Sized>(
        &mut self,
        setup: &TrialSetup,
        decimation: u32,
        participant: &mut P,
        mut trajectory: Vec<[f64; 2]>,
    ) -> Result<(), RunError> {
        let d = decimation;
        let max_decimation = self.max_decimation();
        if d == 0 || !max_decimation.is_multiple_of(d) {
            return Err(RunError::State(format!(
                "the station chose a rate divisor of {d}, not a divisor of {max_decimation}"
            )));
        }
        let cap = self.trajectory_capacity(setup, d)?;
        self.set_decimation(d);
        self.key = Some(setup.key);
        self.acc = Some(TaskAccumulator::new(&setup.params, setup.scene.geometry));
        self.scene = Some(setup.scene);
        self.geometry = setup.scene.geometry;
        self.contact_gap_m = setup.params.contact_gap_m();
        self.vision = setup.feedback.vision;
        self.k = 0;
        let rest = setup.brief.mapping.to_hand(setup.scene.start_m);
        self.control.start(self.act_every, rest);
        self.frames = [None; FRAME_RING];
        self.next_due = u64::MAX;
        self.frame_seq = 0;
        self.exposure_sum = [[0.0; 2]; 2];
        self.exposure_n = 0;
        self.shown = None;
        self.trajectory_cap = cap;
        trajectory.clear();
        trajectory.reserve(cap);
        self.trajectory = trajectory;
        self.trajectory.push(setup.scene.start_m);
        self.end = None;
        self.pending_end = None;
        participant.begin_trial(&setup.brief);
        Ok(())
    }

    /// The camera frame the participant's screen shows now (`None`: none
    /// yet, or blind).
    pub fn shown_frame(&self) -> Option<VisualFrame> {
        if self.vision { self.shown } else { None }
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
        if let Some(e) = self.pending_end.take() {
            self.end = Some(e);
            return;
        }
        if let Some(acc) = &mut self.acc
            && self.end.is_none()
        {
            acc.abort();
            self.end = Some(TrialEnd::Aborted);
        }
    }

    /// Runs up to `n` samples of the current trial on `station` (prepared
    /// for it); returns the end when the trial ended within them. The
    /// station advances in chunks that end at the participant's control
    /// periods (at most [`MAX_STATION_BLOCK`] samples): a chunk in which the
    /// trial ends is run to its end by the station, the trial's rows stop
    /// at its end. Allocation-free.
    ///
    /// # Errors
    /// Station and raw-sink errors; [`RunError::State`] without a trial.
    pub fn run<S: Station + ?Sized, P: Participant + ?Sized, W: RawSink + ?Sized>(
        &mut self,
        station: &mut S,
        participant: &mut P,
        raw: &mut W,
        n: usize,
    ) -> Result<Option<TrialEnd>, RunError> {
        if self.end.is_some() {
            return Ok(self.end);
        }
        if self.acc.is_none() {
            return Err(RunError::State("no trial started".into()));
        }
        let every = self.act_every;
        let dt = 1.0 / self.fs;
        let real_hand = station.hand_is_real();
        let mut left = n;
        while left > 0 {
            let phase = self.k % every;
            if phase == 0 {
                let frame = if self.vision { self.shown } else { None };
                self.control.ask(participant, self.k as f64 * dt, dt, frame);
            }
            let until_act = usize::try_from(every - phase).unwrap_or(usize::MAX);
            let chunk = left.min(until_act).min(MAX_STATION_BLOCK);
            for i in 0..chunk {
                self.hands[i] = self.control.hand_at(phase + i as u64);
            }
            station.step_block(&self.hands[..chunk], &mut self.samples[..chunk])?;
            left -= chunk;
            for i in 0..chunk {
                let ss = self.samples[i];
                let hand = if real_hand {
                    ss.sensors.handle_m
                } else {
                    self.hands[i]
                };
                if let Some(e) = self.sample(&ss, hand, dt, raw)? {
                    return Ok(Some(e));
                }
            }
        }
        Ok(None)
    }

    /// The bookkeeping of one sample the station ran: metrics, camera, raw
    /// row, trajectory; the end when the trial ended at it.
    #[inline]
    fn sample<W: RawSink + ?Sized>(
        &mut self,
        ss: &StationSample,
        hand: [f64; 2],
        dt: f64,
        raw: &mut W,
    ) -> Result<Option<TrialEnd>, RunError> {
        self.k += 1;
        let t = self.k as f64 * dt;
        let tw = &ss.tweezer;
        self.control.record(
            ss.command.force_n,
            ss.sensors.accel_m_s2,
            ss.sensors.handle_m,
        );
        let captured = self.capture_frame(t, tw);
        self.display_due_frames();
        let sample = TaskSample {
            t_s: t,
            bead_m: tw.bead_m,
            trap_m: tw.trap_m,
            force_bead_n: tw.force_n,
            force_hand_n: ss.force_hand_n,
            trapped: tw.trapped,
        };
        if let Some(e) = self.pending_end.take() {
            // The sample after an event that ended the trial carries
            // the end code (the event keeps its own sample).
            self.fill_row(ss, hand, event::END);
            raw.push(&self.row)?;
            self.end = Some(e);
            return Ok(Some(e));
        }
        let end = self.acc.as_mut().and_then(|acc| acc.push(&sample));
        if self.k.is_multiple_of(self.trajectory_every) {
            self.keep_trajectory_point(tw.bead_m);
        }
        let code = event_code(&tw.events, captured);
        let end_here = end.is_some() && (code == 0.0 || code == event::FRAME);
        self.fill_row(ss, hand, if end_here { event::END } else { code });
        raw.push(&self.row)?;
        if let Some(e) = end {
            self.keep_trajectory_point(tw.bead_m);
            if end_here {
                self.end = Some(e);
                return Ok(Some(e));
            }
            self.pending_end = Some(e);
        }
        Ok(None)
    }

    /// Camera capture: every frame period, a frame of the scene at time `t`
    /// (s) is queued for display `latency_samples` later; with an exposure,
    /// its positions are the means over the exposure's samples ending at
    /// the capture (motion blur). Returns whether a frame was captured at
    /// this sample.
    #[inline]
    fn capture_frame(&mut self, t: f64, tw: &TweezerSample) -> bool {
        let n = self.exposure_samples;
        if n > 0 {
            // Samples to the next capture (0: this one).
            let fe = self.frame_every;
            let ahead = (fe - self.k % fe) % fe;
            if ahead < n {
                for (sum, p) in self.exposure_sum.iter_mut().zip([tw.bead_m, tw.trap_m]) {
                    sum[0] += p[0];
                    sum[1] += p[1];
                }
                self.exposure_n += 1;
            }
        }
        if !self.k.is_multiple_of(self.frame_every) {
            return false;
        }
        let (bead_m, trap_m) = if self.exposure_n > 0 {
            let w = 1.0 / self.exposure_n as f64;
            let [b, p] = self.exposure_sum;
            self.exposure_sum = [[0.0; 2]; 2];
            self.exposure_n = 0;
            ([b[0] * w, b[1] * w], [p[0] * w, p[1] * w])
        } else {
            (tw.bead_m, tw.trap_m)
        };
        let geometry = self.geometry;
        let f = VisualFrame {
            seq: self.frame_seq,
            captured_s: t,
            bead_m,
            trap_m,
            obstacle_m: geometry.obstacle_m,
            obstacle_radius_m: geometry.obstacle_radius_m,
            bead_radius_m: geometry.bead_radius_m,
        };
        let due = self.k + self.latency_samples;
        self.frames[(self.frame_seq as usize) % FRAME_RING] = Some((due, f));
        self.next_due = self.next_due.min(due);
        self.frame_seq += 1;
        true
    }

    /// Camera display: once the earliest queued frame is due, shows the
    /// newest due frame and drops every due one from the ring.
    #[inline]
    fn display_due_frames(&mut self) {
        if self.k < self.next_due {
            return;
        }
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

    /// Appends a bead position to the kept trajectory, up to its capacity.
    #[inline]
    fn keep_trajectory_point(&mut self, bead_m: [f64; 2]) {
        if self.trajectory.len() < self.trajectory_cap {
            self.trajectory.push(bead_m);
        }
    }

    /// Fills the raw row of the sample ([`super::raw_channels`] order).
    #[inline]
    fn fill_row(&mut self, ss: &StationSample, hand: [f64; 2], event: f64) {
        let tw = &ss.tweezer;
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
        r[16] = event;
        r[17] = hand[0];
        r[18] = hand[1];
    }

    /// The outcome of the current trial (metrics so far if not ended).
    ///
    /// # Errors
    /// [`RunError::State`] without a trial.
    pub fn outcome(&self) -> Result<TrialOutcome, RunError> {
        let mut o = self.outcome_without_trajectory()?;
        o.trajectory = self.trajectory.clone();
        Ok(o)
    }

    /// The outcome of the trial that ended, its trajectory moved out (the
    /// allocation-free form of [`Self::outcome`]; the core keeps an empty
    /// trajectory).
    ///
    /// # Errors
    /// [`RunError::State`] without a trial.
    pub fn take_outcome(&mut self) -> Result<TrialOutcome, RunError> {
        let mut o = self.outcome_without_trajectory()?;
        o.trajectory = std::mem::take(&mut self.trajectory);
        Ok(o)
    }

    fn outcome_without_trajectory(&self) -> Result<TrialOutcome, RunError> {
        match (&self.acc, self.key, self.scene) {
            (Some(acc), Some(key), Some(scene)) => Ok(TrialOutcome {
                key,
                metrics: acc.metrics(),
                samples: self.k,
                sample_rate_hz: self.fs,
                trajectory: Vec::new(),
                scene,
            }),
            _ => Err(RunError::State("no trial started".into())),
        }
    }

    /// The time-out of the current trial in samples, plus one (a trial that
    /// runs past it is a bug).
    pub(super) fn sample_limit(&self, timeout_s: f64) -> Result<u64, RunError> {
        kilotouch_rig::checked_count((timeout_s * self.fs).ceil())
            .map(|n| n + 1)
            .ok_or_else(|| timeout_error(timeout_s, self.fs))
    }
}

/// Points of trajectory a trial of `setup` keeps on a station running at
/// `station_fs` Hz with rate divisor `decimation`: its time-out over the
/// decimation of the kept trajectory, plus the start and end points. What
/// [`TrialCore::start`]'s buffer should hold (build it off the real-time
/// path).
///
/// # Errors
/// A time-out that is not a representable number of samples.
pub fn trajectory_capacity(
    cfg: &RunnerConfig,
    station_fs: f64,
    setup: &TrialSetup,
    decimation: u32,
) -> Result<usize, RunError> {
    let d = u64::from(decimation.max(1));
    let fs = station_fs / d as f64;
    let every = (cfg.trajectory_every as u64 / d).max(1);
    let cap = (setup.params.timeout_s() * fs / every as f64).floor();
    kilotouch_rig::checked_count(cap)
        .and_then(|c| usize::try_from(c).ok())
        .and_then(|c| c.checked_add(2))
        .ok_or_else(|| timeout_error(setup.params.timeout_s(), fs))
}

/// The `event` channel's code at a sample: its most significant event —
/// escape, recapture, contact end, contact start, camera frame — or 0 for
/// none ([`event`]). The trial-end code goes on the sample where the trial
/// ends when nothing but a camera frame happened there, else on the next
/// sample (so an escape that ends a trial keeps its code 3).
#[inline]
fn event_code(events: &TweezerEvents, frame_captured: bool) -> f64 {
    if events.escaped {
        event::ESCAPED
    } else if events.recaptured {
        event::RECAPTURED
    } else if events.contact_end {
        event::CONTACT_END
    } else if events.contact_start {
        event::CONTACT_START
    } else if frame_captured {
        event::FRAME
    } else {
        0.0
    }
}

/// The error of a trial time-out whose sample count cannot be represented
/// (the protocol's bounds keep `timeout_s` far below this).
fn timeout_error(timeout_s: f64, fs: f64) -> RunError {
    RunError::Config(format!(
        "task timeout_s = {timeout_s} s at {fs} Hz is not a representable number of samples \
         (at most {} s)",
        crate::protocol::MAX_TIMEOUT_S
    ))
}
