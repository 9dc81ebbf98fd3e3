//! The rig interface shared by simulated and live rigs, and the simulated rig.
//!
//! # Interface
//!
//! A [`Rig`] exchanges *blocks* of frames at its sample rate (default
//! 10 kHz): one [`ActuatorFrame`] per sample goes out (Pantograph force x, y
//! in N; Haptuator drive in V) and one [`SensorFrame`] per sample comes back
//! (handle position x, y in m; fingertip acceleration x, y, z in m/s²),
//! stamped with the device's sequence number. Command `i` of a block is
//! applied during sample `first_seq + i`; sensor frame `i` is read at the
//! end of that sample. Identity, status and faults are queried separately.
//!
//! How live backends fit the same calls without change:
//! * **Serial DAQ at 10 kHz.** Frames carry the device's sequence number;
//!   a gap in the numbers is filled with placeholder frames flagged
//!   [`FrameFlags::LOST`] (last good values held), counted in
//!   [`BlockReport::lost_frames`] and reported as [`RigFault::LostFrames`].
//! * **Audio interface via a cpal callback.** The callback thread owns the
//!   device; `process_block` only moves frames through lock-free SPSC rings,
//!   so it neither locks nor allocates; callback under-runs surface as
//!   [`RigFault::Overrun`] and lost frames.
//! * **Device watchdog.** A device that zeroes its outputs after missing
//!   commands reports [`RigFault::WatchdogTripped`]; the rig enters
//!   [`RigState::Faulted`] until `start` is called again.
//! * **Disconnects.** `process_block` returns [`RigError::Disconnected`] and
//!   the state becomes [`RigState::Disconnected`].
//!
//! `process_block` must not allocate, lock or panic in any implementation;
//! faults are queued in a fixed-capacity ring ([`FaultQueue`]).
//!
//! # Simulated rig
//!
//! [`SimRig`] runs the [`DualStagePlant`], the [`Accelerometer`] and encoder
//! quantisation, either as fast as possible ([`Pacing::Batch`]: tests,
//! calibration) or paced by a wall [`Clock`] ([`Pacing::WallClock`]: GUI).
//! Pacing derives the deadline of every block from a clock anchor and the
//! sample count — deadline = t_anchor + (seq_end − seq_anchor)/f_s — never by
//! accumulating sleeps, so after a stall the following blocks run without
//! sleeping until the simulation has caught up; a stall longer than
//! `max_lag_s` re-anchors (the lost time is reported as an overrun).

use crate::accel::Accelerometer;
use crate::config::RigConfig;
use crate::error::RigError;
use crate::lti::Integrator;
use crate::plant::{DualStagePlant, PlantFastOutput, PlantInput, PlantOutput};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// One sample of actuator commands (host → device).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ActuatorFrame {
    /// Pantograph force command (x, y), N.
    pub force_n: [f64; 2],
    /// Haptuator drive, V.
    pub haptuator_v: f64,
}

/// Per-frame flags (bit set).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct FrameFlags(pub u8);

impl FrameFlags {
    /// Placeholder for a frame the device did not deliver (values held).
    pub const LOST: u8 = 1;
    /// The accelerometer hit its range on some axis.
    pub const CLIPPED: u8 = 2;
    /// A command was clamped to the actuator limits.
    pub const LIMITED: u8 = 4;
    /// The Haptuator magnet was on an end stop.
    pub const END_STOP: u8 = 8;
    /// A non-finite command was replaced by zero.
    pub const NONFINITE_COMMAND: u8 = 16;

    /// Is `bit` set?
    pub fn has(self, bit: u8) -> bool {
        self.0 & bit != 0
    }
}

/// One sample of sensor data (device → host).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SensorFrame {
    /// Device sequence number of the sample.
    pub seq: u64,
    /// Handle position (x, y), m (encoders on the motors).
    pub handle_m: [f64; 2],
    /// Fingertip acceleration (x, y, z), m/s².
    pub accel_m_s2: [f64; 3],
    /// Flags.
    pub flags: FrameFlags,
}

/// What happened during one `process_block` call.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct BlockReport {
    /// Sequence number of the first frame.
    pub first_seq: u64,
    /// Frames exchanged.
    pub frames: usize,
    /// Frames the device failed to deliver (filled with placeholders).
    pub lost_frames: u32,
    /// Samples of wall time skipped because of a stall longer than the
    /// tolerated lag (paced rigs only).
    pub skipped_samples: u64,
    /// How far the block ended behind its wall-clock deadline, s (0 when on
    /// time or when not paced).
    pub lag_s: f64,
}

/// Kind of rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RigKind {
    /// The embedded simulation.
    Simulated,
    /// A DAQ over a serial link.
    SerialDaq,
    /// An audio interface.
    Audio,
}

/// Identity of a rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigIdentity {
    /// Kind.
    pub kind: RigKind,
    /// Human-readable name.
    pub name: String,
    /// Serial number / port / device id.
    pub serial: String,
    /// Firmware or model version.
    pub firmware: String,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Pantograph force limit per axis, N.
    pub force_max_n: f64,
    /// Haptuator drive limit, V.
    pub haptuator_max_v: f64,
    /// Accelerometer range, ±m/s².
    pub accel_range_m_s2: f64,
}

/// Life-cycle state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RigState {
    /// Not exchanging frames; actuators at zero.
    Idle,
    /// Exchanging frames.
    Running,
    /// Stopped by a device fault (e.g. watchdog); `start` to resume.
    Faulted,
    /// Device gone.
    Disconnected,
}

/// Counters and state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigStatus {
    /// State.
    pub state: RigState,
    /// Frames exchanged since creation.
    pub frames: u64,
    /// Frames lost.
    pub lost_frames: u64,
    /// Samples skipped after long stalls.
    pub skipped_samples: u64,
    /// Frames with the accelerometer clipped.
    pub clipped_frames: u64,
    /// Frames with a command clamped to the limits.
    pub limited_frames: u64,
    /// Frames with the Haptuator magnet on an end stop.
    pub end_stop_frames: u64,
    /// Frames with a non-finite command.
    pub nonfinite_commands: u64,
    /// Faults waiting in the queue.
    pub faults_pending: usize,
    /// Faults dropped because the queue was full.
    pub faults_dropped: u64,
}

/// A fault or notable event reported by a rig.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum RigFault {
    /// Frames missing from the device stream.
    LostFrames {
        /// First missing sequence number.
        first_seq: u64,
        /// How many.
        count: u32,
    },
    /// Wall-clock stall beyond the tolerated lag; samples skipped.
    Overrun {
        /// Sequence number at which the stall was detected.
        seq: u64,
        /// Samples skipped.
        skipped: u64,
    },
    /// A non-finite command was replaced by zero.
    NonFiniteCommand {
        /// Sequence number.
        seq: u64,
    },
    /// A command exceeded an actuator limit and was clamped.
    ActuatorLimited {
        /// Sequence number.
        seq: u64,
    },
    /// The accelerometer clipped.
    SensorClipped {
        /// Sequence number.
        seq: u64,
    },
    /// The Haptuator magnet hit an end stop.
    EndStop {
        /// Sequence number.
        seq: u64,
    },
    /// The device watchdog zeroed the outputs.
    WatchdogTripped {
        /// Sequence number.
        seq: u64,
    },
    /// The device disconnected.
    Disconnected,
}

/// Fixed-capacity FIFO of faults (no allocation after creation; the oldest
/// entry is dropped when full).
#[derive(Debug, Clone)]
pub struct FaultQueue {
    buf: [Option<RigFault>; Self::CAPACITY],
    head: usize,
    len: usize,
    dropped: u64,
}

impl Default for FaultQueue {
    fn default() -> Self {
        Self {
            buf: [None; Self::CAPACITY],
            head: 0,
            len: 0,
            dropped: 0,
        }
    }
}

impl FaultQueue {
    /// Capacity.
    pub const CAPACITY: usize = 64;

    /// Append (dropping the oldest when full).
    pub fn push(&mut self, f: RigFault) {
        if self.len == Self::CAPACITY {
            self.head = (self.head + 1) % Self::CAPACITY;
            self.len -= 1;
            self.dropped += 1;
        }
        let tail = (self.head + self.len) % Self::CAPACITY;
        self.buf[tail] = Some(f);
        self.len += 1;
    }

    /// Remove the oldest.
    pub fn pop(&mut self) -> Option<RigFault> {
        if self.len == 0 {
            return None;
        }
        let f = self.buf[self.head].take();
        self.head = (self.head + 1) % Self::CAPACITY;
        self.len -= 1;
        f
    }

    /// Entries waiting.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Entries dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// The counters and the fault queue behind [`Rig::status`] and
/// [`Rig::pop_fault`], shared by the simulated and the live rigs. Fixed
/// size: nothing here allocates, locks or panics.
#[derive(Debug, Clone)]
pub(crate) struct StatusCounters {
    /// Counters (frame counts in frames, samples in samples); `state` and
    /// the `faults_*` fields are filled in by [`Self::status`].
    pub(crate) counts: RigStatus,
    /// Faults waiting for [`Rig::pop_fault`].
    pub(crate) faults: FaultQueue,
}

impl Default for StatusCounters {
    fn default() -> Self {
        Self {
            counts: RigStatus {
                state: RigState::Idle,
                frames: 0,
                lost_frames: 0,
                skipped_samples: 0,
                clipped_frames: 0,
                limited_frames: 0,
                end_stop_frames: 0,
                nonfinite_commands: 0,
                faults_pending: 0,
                faults_dropped: 0,
            },
            faults: FaultQueue::default(),
        }
    }
}

impl StatusCounters {
    /// The counters with the rig's `state` and the queue's occupancy.
    pub(crate) fn status(&self, state: RigState) -> RigStatus {
        RigStatus {
            state,
            faults_pending: self.faults.len(),
            faults_dropped: self.faults.dropped(),
            ..self.counts
        }
    }

    /// Queue a fault (the oldest is dropped when the queue is full).
    #[inline]
    pub(crate) fn push(&mut self, f: RigFault) {
        self.faults.push(f);
    }

    /// Oldest queued fault, if any.
    pub(crate) fn pop_fault(&mut self) -> Option<RigFault> {
        self.faults.pop()
    }

    /// Count the command and sensor flags of frame `seq` (non-finite
    /// command, limited, clipped, end stop) and queue each kind of fault
    /// once per block: `noted` collects the [`FrameFlags`] bits already
    /// queued in this block (start each block at 0).
    #[inline]
    pub(crate) fn note_flags(&mut self, ff: FrameFlags, seq: u64, noted: &mut u8) {
        const COUNTED: u8 = FrameFlags::NONFINITE_COMMAND
            | FrameFlags::LIMITED
            | FrameFlags::CLIPPED
            | FrameFlags::END_STOP;
        if ff.0 & COUNTED == 0 {
            return;
        }
        let kinds = [
            (
                FrameFlags::NONFINITE_COMMAND,
                RigFault::NonFiniteCommand { seq },
            ),
            (FrameFlags::LIMITED, RigFault::ActuatorLimited { seq }),
            (FrameFlags::CLIPPED, RigFault::SensorClipped { seq }),
            (FrameFlags::END_STOP, RigFault::EndStop { seq }),
        ];
        for (bit, fault) in kinds {
            if ff.has(bit) {
                let c = &mut self.counts;
                match bit {
                    FrameFlags::NONFINITE_COMMAND => c.nonfinite_commands += 1,
                    FrameFlags::LIMITED => c.limited_frames += 1,
                    FrameFlags::CLIPPED => c.clipped_frames += 1,
                    _ => c.end_stop_frames += 1,
                }
                if *noted & bit == 0 {
                    self.faults.push(fault);
                    *noted |= bit;
                }
            }
        }
    }
}

/// The block-length contract of [`Rig::process_block`], shared by every
/// implementation: one sensor frame per command.
pub fn check_block_lengths(
    commands: &[ActuatorFrame],
    sensors: &[SensorFrame],
) -> Result<(), RigError> {
    if commands.len() == sensors.len() {
        Ok(())
    } else {
        Err(RigError::InvalidInput(format!(
            "{} commands but {} sensor frames",
            commands.len(),
            sensors.len()
        )))
    }
}

/// A haptic rig, simulated or live (module docs).
pub trait Rig: Send {
    /// Identity.
    fn identity(&self) -> &RigIdentity;
    /// Sample rate, Hz.
    fn sample_rate_hz(&self) -> f64 {
        self.identity().sample_rate_hz
    }
    /// Start exchanging frames (anchors the clock of paced rigs).
    fn start(&mut self) -> Result<(), RigError>;
    /// Stop; actuators go to zero.
    fn stop(&mut self) -> Result<(), RigError>;
    /// Exchange one block: `commands.len()` must equal `sensors.len()`.
    /// Paced and live rigs block until the block's frames are due; batch
    /// rigs return at once. Must not allocate, lock or panic.
    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError>;
    /// Exchange a block of one frame: exactly
    /// `process_block(&[*command], &mut [*sensors])` (the default
    /// implementation), which a rig may override with a cheaper path for the
    /// sample-by-sample [`ClosedLoop`](crate::coupling::ClosedLoop) (the
    /// batch [`SimRig`] does). `sensors` is written only on success. Must not
    /// allocate, lock or panic.
    #[inline]
    fn process_frame(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        frame_as_block(self, command, sensors)
    }
    /// Current counters and state.
    fn status(&self) -> RigStatus;
    /// Oldest queued fault, if any.
    fn pop_fault(&mut self) -> Option<RigFault>;
}

/// One frame exchanged as a one-frame block: the default
/// [`Rig::process_frame`], also the fallback of rigs that override it.
/// `sensors` is written only on success.
#[inline]
pub fn frame_as_block<R: Rig + ?Sized>(
    rig: &mut R,
    command: &ActuatorFrame,
    sensors: &mut SensorFrame,
) -> Result<BlockReport, RigError> {
    let mut out = [*sensors];
    let r = rig.process_block(std::slice::from_ref(command), &mut out)?;
    *sensors = out[0];
    Ok(r)
}

/// Time source for paced rigs.
pub trait Clock: Send {
    /// Time since an arbitrary fixed origin.
    fn now(&self) -> Duration;
    /// Block until `now() ≥ t` (returns at once if already past).
    fn sleep_until(&self, t: Duration);
}

/// The monotonic system clock.
#[derive(Debug, Clone)]
pub struct SystemClock {
    origin: Instant,
}

impl Default for SystemClock {
    fn default() -> Self {
        Self {
            origin: Instant::now(),
        }
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }
    fn sleep_until(&self, t: Duration) {
        let now = self.now();
        if t > now {
            std::thread::sleep(t - now);
        }
    }
}

/// A clock advanced by hand (tests): `sleep_until` jumps forward; another
/// handle can advance time to simulate a stall.
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    nanos: Arc<AtomicU64>,
    sleeps: Arc<AtomicU64>,
}

impl ManualClock {
    /// Advance by `d`.
    pub fn advance(&self, d: Duration) {
        self.nanos.fetch_add(d.as_nanos() as u64, Ordering::SeqCst);
    }
    /// Number of `sleep_until` calls that actually waited.
    pub fn sleeps(&self) -> u64 {
        self.sleeps.load(Ordering::SeqCst)
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        Duration::from_nanos(self.nanos.load(Ordering::SeqCst))
    }
    fn sleep_until(&self, t: Duration) {
        let target = t.as_nanos() as u64;
        let prev = self.nanos.fetch_max(target, Ordering::SeqCst);
        if prev < target {
            self.sleeps.fetch_add(1, Ordering::SeqCst);
        }
    }
}

/// How a simulated rig uses time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Pacing {
    /// As fast as possible (tests, calibration, batch runs).
    Batch,
    /// Paced by the wall clock (GUI); stalls longer than `max_lag_s` are
    /// skipped rather than caught up.
    WallClock {
        /// Largest lag caught up by running without sleeping, s.
        max_lag_s: f64,
    },
}

/// The simulated dual-stage rig (module docs).
#[derive(Debug)]
pub struct SimRig<C: Clock = SystemClock> {
    identity: RigIdentity,
    fs: f64,
    plant: DualStagePlant,
    accel: Accelerometer,
    encoder_res: f64,
    force_max: f64,
    drive_max: f64,
    hand_prev: [f64; 2],
    hand_target: [f64; 2],
    truth: PlantFastOutput,
    seq: u64,
    state: RigState,
    pacing: Pacing,
    clock: C,
    anchor_time: Duration,
    anchor_seq: u64,
    counters: StatusCounters,
}

impl SimRig<SystemClock> {
    /// Batch (as-fast-as-possible) simulated rig from a configuration.
    pub fn new(cfg: &RigConfig) -> Result<Self, RigError> {
        Self::with_clock(cfg, Integrator::Zoh, Pacing::Batch, SystemClock::default())
    }

    /// Paced by the system clock.
    pub fn paced(cfg: &RigConfig, max_lag_s: f64) -> Result<Self, RigError> {
        Self::with_clock(
            cfg,
            Integrator::Zoh,
            Pacing::WallClock { max_lag_s },
            SystemClock::default(),
        )
    }
}

impl<C: Clock> SimRig<C> {
    /// Full constructor: integrator, pacing and clock.
    pub fn with_clock(
        cfg: &RigConfig,
        integrator: Integrator,
        pacing: Pacing,
        clock: C,
    ) -> Result<Self, RigError> {
        cfg.validate()?;
        if let Pacing::WallClock { max_lag_s } = pacing
            && !(max_lag_s.is_finite() && max_lag_s > 0.0)
        {
            return Err(RigError::InvalidParameter {
                name: "max_lag_s",
                value: max_lag_s,
                reason: "must be finite and > 0".into(),
            });
        }
        let fs = cfg.rig.sample_rate_hz;
        let plant = DualStagePlant::new(cfg, integrator)?;
        let accel = Accelerometer::new(&cfg.accelerometer, fs)?;
        let identity = RigIdentity {
            kind: RigKind::Simulated,
            name: cfg.rig.name.clone(),
            serial: format!("sim-{}", integrator.name()),
            firmware: concat!("kilotouch-rig ", env!("CARGO_PKG_VERSION")).to_string(),
            sample_rate_hz: fs,
            force_max_n: cfg.limits.pantograph_force_max_n,
            haptuator_max_v: cfg.limits.haptuator_drive_max_v,
            accel_range_m_s2: accel.range_m_s2(),
        };
        Ok(Self {
            identity,
            fs,
            plant,
            accel,
            encoder_res: cfg.rig.encoder_resolution_m,
            force_max: cfg.limits.pantograph_force_max_n,
            drive_max: cfg.limits.haptuator_drive_max_v,
            hand_prev: [0.0; 2],
            hand_target: [0.0; 2],
            truth: PlantFastOutput::default(),
            seq: 0,
            state: RigState::Idle,
            pacing,
            clock,
            anchor_time: Duration::ZERO,
            anchor_seq: 0,
            counters: StatusCounters::default(),
        })
    }

    /// Move the hand (the mouse, or a recorded trajectory) to `pos` (m): it
    /// travels linearly to `pos` over the next block. Non-finite → ignored.
    pub fn set_hand(&mut self, pos: [f64; 2]) {
        if pos.iter().all(|v| v.is_finite()) {
            self.hand_target = pos;
        }
    }

    /// True plant outputs of the last sample (tip acceleration without the
    /// sensor, positions, stroke) — the "ground truth" for validation.
    /// The tip position is computed on demand from the plant's state
    /// ([`DualStagePlant::tip_m`], bit-identical to what the step would have
    /// returned), so the per-sample path skips it.
    pub fn truth(&self) -> PlantOutput {
        PlantOutput {
            accel_m_s2: self.truth.accel_m_s2,
            tip_m: self.plant.tip_m(),
            motor_m: self.truth.motor_m,
            stroke_m: self.truth.stroke_m,
        }
    }

    /// The plant (for inspection).
    pub fn plant(&self) -> &DualStagePlant {
        &self.plant
    }

    /// The accelerometer (its response, for calibration).
    pub fn accelerometer(&self) -> &Accelerometer {
        &self.accel
    }

    /// Samples due now according to the wall clock and not yet simulated
    /// (paced rigs; 0 for batch).
    pub fn frames_due(&self) -> u64 {
        match (self.pacing, self.state) {
            (Pacing::WallClock { .. }, RigState::Running) => {
                let elapsed = self
                    .clock
                    .now()
                    .saturating_sub(self.anchor_time)
                    .as_secs_f64();
                let pos = self.anchor_seq + (elapsed * self.fs).floor() as u64;
                pos.saturating_sub(self.seq)
            }
            _ => 0,
        }
    }

    /// Next sequence number.
    pub fn seq(&self) -> u64 {
        self.seq
    }

    fn deadline(&self, seq: u64) -> Duration {
        self.anchor_time + Duration::from_secs_f64((seq - self.anchor_seq) as f64 / self.fs)
    }

    /// Simulate one sample: sanitise and limit the command, step the
    /// plant, read the accelerometer and the encoders. Allocation-free; the
    /// flags of the frame tell what happened (counted by [`Self::note_flags`]).
    #[inline(always)]
    fn frame(&mut self, cmd: &ActuatorFrame, hand: [f64; 2], hv: [f64; 2]) -> SensorFrame {
        // Common case: within the limits (hence finite), nothing to change.
        let (f, v, mut flags) = if cmd.force_n[0].abs() <= self.force_max
            && cmd.force_n[1].abs() <= self.force_max
            && cmd.haptuator_v.abs() <= self.drive_max
        {
            (cmd.force_n, cmd.haptuator_v, 0u8)
        } else {
            self.sanitise(cmd)
        };
        let in_stop_before = self.plant.x.end_stop_steps();
        let o = self.plant.step_fast(&PlantInput {
            force_n: f,
            drive_v: v,
            hand_m: hand,
            hand_vel_m_s: hv,
        });
        if self.plant.x.end_stop_steps() != in_stop_before {
            flags |= FrameFlags::END_STOP;
        }
        let r = self.accel.sample([o.accel_m_s2[0], o.accel_m_s2[1], 0.0]);
        if r.clipped {
            flags |= FrameFlags::CLIPPED;
        }
        self.truth = o;
        SensorFrame {
            seq: self.seq,
            handle_m: [self.quantise(o.motor_m[0]), self.quantise(o.motor_m[1])],
            accel_m_s2: r.m_s2,
            flags: FrameFlags(flags),
        }
    }

    /// A command outside the limits or non-finite: non-finite components
    /// become 0 ([`FrameFlags::NONFINITE_COMMAND`]), others are clamped to
    /// the limits ([`FrameFlags::LIMITED`]). Returns (force, drive, flags).
    #[cold]
    #[inline(never)]
    fn sanitise(&self, cmd: &ActuatorFrame) -> ([f64; 2], f64, u8) {
        let mut flags = 0u8;
        let mut f = cmd.force_n;
        let mut v = cmd.haptuator_v;
        for x in f.iter_mut() {
            if !x.is_finite() {
                *x = 0.0;
                flags |= FrameFlags::NONFINITE_COMMAND;
            } else if x.abs() > self.force_max {
                *x = self.force_max.copysign(*x);
                flags |= FrameFlags::LIMITED;
            }
        }
        if !v.is_finite() {
            v = 0.0;
            flags |= FrameFlags::NONFINITE_COMMAND;
        } else if v.abs() > self.drive_max {
            v = self.drive_max.copysign(v);
            flags |= FrameFlags::LIMITED;
        }
        (f, v, flags)
    }

    /// Count a frame's flags and queue each kind of fault once per block
    /// (`noted` collects the kinds already queued in this block).
    #[cold]
    #[inline(never)]
    fn note_flags(&mut self, ff: FrameFlags, noted: &mut u8) {
        self.counters.note_flags(ff, self.seq, noted);
    }

    /// [`Rig::process_frame`] through the block path (paced or not running).
    #[cold]
    #[inline(never)]
    fn process_frame_slow(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        frame_as_block(self, command, sensors)
    }

    fn quantise(&self, x: f64) -> f64 {
        if self.encoder_res > 0.0 {
            crate::round_half_away(x / self.encoder_res) * self.encoder_res
        } else {
            x
        }
    }
}

impl<C: Clock> Rig for SimRig<C> {
    fn identity(&self) -> &RigIdentity {
        &self.identity
    }

    fn start(&mut self) -> Result<(), RigError> {
        self.state = RigState::Running;
        self.anchor_time = self.clock.now();
        self.anchor_seq = self.seq;
        Ok(())
    }

    fn stop(&mut self) -> Result<(), RigError> {
        self.state = RigState::Idle;
        Ok(())
    }

    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError> {
        if self.state != RigState::Running {
            return Err(RigError::NotReady(
                "call start() before process_block()".into(),
            ));
        }
        check_block_lengths(commands, sensors)?;
        let n = commands.len();
        let mut report = BlockReport {
            first_seq: self.seq,
            frames: n,
            ..Default::default()
        };
        if n == 0 {
            return Ok(report);
        }
        // Long stall: skip the lost wall time instead of catching it up.
        if let Pacing::WallClock { max_lag_s } = self.pacing {
            let now = self.clock.now();
            let due = self.deadline(self.seq);
            if now > due && (now - due).as_secs_f64() > max_lag_s {
                let skipped = ((now - due).as_secs_f64() * self.fs).floor() as u64;
                self.anchor_time = now;
                self.anchor_seq = self.seq;
                report.skipped_samples = skipped;
                self.counters.counts.skipped_samples += skipped;
                self.counters.push(RigFault::Overrun {
                    seq: self.seq,
                    skipped,
                });
            }
        }
        // The hand moves linearly from its previous target to the new one
        // over the block: velocity Δ·f_s/n, position after frame i at
        // prev + (i + 1)/n·Δ.
        let dh = [
            self.hand_target[0] - self.hand_prev[0],
            self.hand_target[1] - self.hand_prev[1],
        ];
        let rate = self.fs / n as f64;
        let hv = [dh[0] * rate, dh[1] * rate];
        let inv_n = 1.0 / n as f64;
        let mut noted = 0u8;
        for (i, (cmd, out)) in commands.iter().zip(sensors.iter_mut()).enumerate() {
            let a = (i + 1) as f64 * inv_n;
            let hand = [self.hand_prev[0] + a * dh[0], self.hand_prev[1] + a * dh[1]];
            *out = self.frame(cmd, hand, hv);
            if out.flags.0 != 0 {
                self.note_flags(out.flags, &mut noted);
            }
            self.seq += 1;
        }
        self.hand_prev = self.hand_target;
        self.counters.counts.frames += n as u64;
        if let Pacing::WallClock { .. } = self.pacing {
            let deadline = self.deadline(self.seq);
            let now = self.clock.now();
            if now < deadline {
                self.clock.sleep_until(deadline);
            } else {
                report.lag_s = (now - deadline).as_secs_f64();
            }
        }
        Ok(report)
    }

    /// The block of one frame without the block machinery in the batch,
    /// running case (bit-identical to `process_block` with one frame: the
    /// hand moves by Δ = target − prev at velocity Δ·f_s); everything else
    /// (paced, not started) goes through `process_block`.
    #[inline]
    fn process_frame(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        if self.state != RigState::Running || !matches!(self.pacing, Pacing::Batch) {
            return self.process_frame_slow(command, sensors);
        }
        let first_seq = self.seq;
        let dh = [
            self.hand_target[0] - self.hand_prev[0],
            self.hand_target[1] - self.hand_prev[1],
        ];
        let hand = [self.hand_prev[0] + dh[0], self.hand_prev[1] + dh[1]];
        let hv = [dh[0] * self.fs, dh[1] * self.fs];
        let out = self.frame(command, hand, hv);
        if out.flags.0 != 0 {
            self.note_flags(out.flags, &mut 0);
        }
        *sensors = out;
        self.seq += 1;
        self.hand_prev = self.hand_target;
        self.counters.counts.frames += 1;
        Ok(BlockReport {
            first_seq,
            frames: 1,
            ..Default::default()
        })
    }

    fn status(&self) -> RigStatus {
        self.counters.status(self.state)
    }

    fn pop_fault(&mut self) -> Option<RigFault> {
        self.counters.pop_fault()
    }
}

#[cfg(test)]
mod process_frame_tests {
    use super::*;

    /// A rig that only has `process_block` (the trait's default
    /// `process_frame`).
    struct BlockOnly(SimRig);

    impl Rig for BlockOnly {
        fn identity(&self) -> &RigIdentity {
            self.0.identity()
        }
        fn start(&mut self) -> Result<(), RigError> {
            self.0.start()
        }
        fn stop(&mut self) -> Result<(), RigError> {
            self.0.stop()
        }
        fn process_block(
            &mut self,
            commands: &[ActuatorFrame],
            sensors: &mut [SensorFrame],
        ) -> Result<BlockReport, RigError> {
            self.0.process_block(commands, sensors)
        }
        fn status(&self) -> RigStatus {
            self.0.status()
        }
        fn pop_fault(&mut self) -> Option<RigFault> {
            self.0.pop_fault()
        }
    }

    fn bits(s: &SensorFrame) -> (u64, [u64; 2], [u64; 3], u8) {
        (
            s.seq,
            s.handle_m.map(f64::to_bits),
            s.accel_m_s2.map(f64::to_bits),
            s.flags.0,
        )
    }

    /// `SimRig::process_frame` (its batch fast path) against one-frame
    /// blocks through `process_block` (the default `process_frame`): the
    /// same sensor frames, reports, ground truth, counters and faults, bit
    /// for bit, with a moving hand, commands beyond the limits and
    /// non-finite commands; before `start` both refuse.
    #[test]
    fn frame_path_is_a_one_frame_block() {
        let cfg = RigConfig::default();
        let mut a = SimRig::new(&cfg).unwrap();
        let mut b = BlockOnly(SimRig::new(&cfg).unwrap());
        let cmd = ActuatorFrame::default();
        let mut sa = SensorFrame::default();
        let mut sb = SensorFrame::default();
        assert!(a.process_frame(&cmd, &mut sa).is_err());
        assert!(b.process_frame(&cmd, &mut sb).is_err());
        assert_eq!(sa, SensorFrame::default());
        a.start().unwrap();
        b.start().unwrap();
        let fmax = cfg.limits.pantograph_force_max_n;
        for k in 0..20_000u64 {
            let t = k as f64 * 1e-4;
            if k % 7 == 0 {
                let hand = [3e-3 * (40.0 * t).sin(), 2e-3 * (25.0 * t).cos()];
                a.set_hand(hand);
                b.0.set_hand(hand);
            }
            let mut cmd = ActuatorFrame {
                force_n: [1.5 * fmax * (300.0 * t).sin(), 0.2 * fmax],
                haptuator_v: 3.0 * (900.0 * t).sin(),
            };
            if k % 1001 == 0 {
                cmd.force_n[(k % 2) as usize] = f64::NAN;
                cmd.haptuator_v = f64::INFINITY;
            }
            let ra = a.process_frame(&cmd, &mut sa).unwrap();
            let rb = b.process_frame(&cmd, &mut sb).unwrap();
            assert_eq!(ra, rb);
            assert_eq!(bits(&sa), bits(&sb), "{k}");
            assert_eq!(a.truth(), b.0.truth());
        }
        assert_eq!(a.status(), b.status());
        let sa = a.status();
        assert!(sa.limited_frames > 0 && sa.nonfinite_commands > 0);
        while let Some(f) = a.pop_fault() {
            assert_eq!(Some(f), b.pop_fault());
        }
        assert_eq!(b.pop_fault(), None);
    }

    /// A paced rig takes the block path (deadline, lag, skipped samples).
    #[test]
    fn paced_frame_path_reports_like_a_block() {
        let cfg = RigConfig::default();
        let clock = ManualClock::default();
        let mut a = SimRig::with_clock(
            &cfg,
            Integrator::Zoh,
            Pacing::WallClock { max_lag_s: 0.01 },
            clock.clone(),
        )
        .unwrap();
        a.start().unwrap();
        let mut s = SensorFrame::default();
        let r = a.process_frame(&ActuatorFrame::default(), &mut s).unwrap();
        assert_eq!((r.frames, r.skipped_samples), (1, 0));
        assert_eq!(clock.now(), Duration::from_secs_f64(1e-4));
        clock.advance(Duration::from_millis(50));
        let r = a.process_frame(&ActuatorFrame::default(), &mut s).unwrap();
        assert!(r.skipped_samples > 400, "{r:?}");
        assert_eq!(s.seq, 1);
    }
}
