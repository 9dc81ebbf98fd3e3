//! Device emulator logic, independent of the transport: the reference
//! behaviour of a device speaking `docs/PROTOCOL.md`.
//!
//! [`Emulator`] is fed the bytes that arrive from the host
//! ([`Emulator::receive`]) and the wall time ([`Emulator::advance`]); it
//! queues the bytes to send ([`Emulator::output`]). Behind it sits an
//! [`Instrument`]: the simulated DAQ ([`DaqInstrument`], a batch
//! [`SimRig`]: the same plant, accelerometer and encoders as the simulated
//! rig) or the simulated tweezer ([`super::tweezer_link::TweezerInstrument`]).
//!
//! # Timing
//!
//! Sample t is due at t_anchor + (t − seq_anchor + 1)/f_s (its sensor frame
//! is read at the end of the sample period); the sample position is derived
//! from the clock, never from accumulated sleeps, so the emulator catches
//! up after a stall. Sample t is executed once it is due **and** the host's
//! command for t has arrived: the emulated device waits for late commands
//! (simulated time stands still), which a physical device cannot do — its
//! firmware holds the previous command instead and flags the sample
//! `CMD_LATE` (`docs/PROTOCOL.md`, "Timing"). Samples are sent in frames of
//! up to `batch` samples; a partial frame is sent as soon as the device has
//! to wait for commands, followed by a STATUS frame (repeated every 10 ms
//! while waiting) that carries the next sequence number, so that the host
//! can tell lost frames from frames not yet produced.
//!
//! # Watchdog
//!
//! When the device has run out of commands and no valid host frame has
//! arrived for `watchdog` (counted from the later of the last valid host
//! frame and the moment the commands ran out: commands the host sent ahead
//! are played out, at most [`COMMAND_RING`] samples), the outputs are set to the instrument's safe command (DAQ: all zero), a FAULT
//! (watchdog) and a STATUS (tripped) frame are sent, and the device stops
//! streaming until the next START.
//!
//! # Fault injection
//!
//! Every outgoing byte is dropped with probability `drop_rate`, else XORed
//! with a random non-zero byte with probability `corrupt_rate`; after
//! `stall_after` the device neither reads nor writes (a hung firmware), for
//! `stall_for` or for ever;
//! after `disconnect_after` [`Emulator::advance`] returns
//! [`Next::Disconnect`] (the transport then closes: an unplugged cable).

use super::frame::{
    self, Caps, DaqCaps, DaqCommand, DaqSample, Decoder, DeviceState, FaultReport, Hello,
    PROTOCOL_VERSION, Status, WireItem, fault, flag,
};
use crate::config::RigConfig;
use crate::device::{ActuatorFrame, HandAgent, HostInfo, Rig, SensorFrame};
use crate::error::RigError;
use crate::sim::SimRig;
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::time::Duration;

/// What the emulator serves: one sample per command.
pub trait Instrument: Send {
    /// Per-sample command (host → device).
    type Command: WireItem;
    /// Per-sample data (device → host).
    type Sample: WireItem;
    /// Frame type of command blocks.
    const COMMAND_TYPE: u8;
    /// Frame type of sample blocks.
    const SAMPLE_TYPE: u8;
    /// Handshake answer (version, rate, capabilities, identity).
    fn hello(&self) -> Hello;
    /// Execute one sample period with `cmd` applied; `extra_flags` are the
    /// device's own flags for the sample ([`flag::CMD_LATE`],
    /// [`flag::WATCHDOG`]).
    fn step(&mut self, cmd: &Self::Command, extra_flags: u8) -> Self::Sample;
    /// The command that puts the outputs in their safe state, given the
    /// command applied last (DAQ: zero; tweezer: hold the trap).
    fn safe_command(&self, last: &Self::Command) -> Self::Command;
    /// Reset the instrument's state to `cmd` (frame type RESET).
    fn reset(&mut self, cmd: &Self::Command);
    /// The host's information about the experiment (frame type INFO);
    /// an instrument without a participant ignores it (the default).
    fn info(&mut self, info: &HostInfo) {
        let _ = info;
    }
    /// The scene a tweezer serves on SCENE_REQ (`docs/PROTOCOL.md` §6.5);
    /// `None` (the default): the request is answered FAULT `BAD_FRAME`.
    fn scene(&self) -> Option<frame::Scene> {
        None
    }
}

/// A device that keeps the link busy with valid frames but never advances
/// the sample stream once started (what the host's progress watchdog,
/// [`super::watch`], must catch). It executes no command and trips no
/// watchdog of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Misbehaviour {
    /// Only STATUS frames ("running", the sequence number never moving).
    StatusOnly,
    /// Only frames of a type the protocol does not define.
    UnknownFrames,
    /// SAMPLES frames whose sequence numbers are never the ones owed
    /// (alternately long past and far ahead).
    StraySequence,
}

impl Misbehaviour {
    /// Period of the misbehaving frames.
    pub const PERIOD: Duration = Duration::from_millis(1);
}

/// Fault injection on the device → host stream (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FaultInjection {
    /// Probability that an outgoing byte is corrupted, in [0, 1].
    pub corrupt_rate: f64,
    /// Probability that an outgoing byte is dropped, in [0, 1].
    pub drop_rate: f64,
    /// Hang (no input, no output) this long after creation…
    pub stall_after: Option<Duration>,
    /// …for this long (`None`: for ever). Input arriving during the stall
    /// is lost; afterwards the watchdog has tripped.
    pub stall_for: Option<Duration>,
    /// Disconnect this long after creation.
    pub disconnect_after: Option<Duration>,
    /// Seed of the fault generator.
    pub seed: u64,
    /// Stream valid frames that never advance the sample stream.
    pub misbehave: Option<Misbehaviour>,
    /// Flag bits ([`flag`]) set on every sample: a device that reports a
    /// fault (or a late command, or its watchdog) on everything it sends.
    pub sample_flags: u8,
}

/// Emulator settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmulatorConfig {
    /// Watchdog window: outputs safe when no valid host frame arrives
    /// within it.
    pub watchdog: Duration,
    /// Samples per device frame at most (1 ..= 64).
    pub batch: usize,
    /// Run like a physical device: every sample at its time, a missing
    /// command replaced by the previous one and flagged `CMD_LATE`
    /// (`false`: wait for the command, simulated time standing still).
    pub free_running: bool,
    /// Clock speed: simulated seconds per wall-clock second (1 = real
    /// time, the device's rate; 4 serves 40 000 samples per wall second
    /// from a 10 kHz rig). The HELLO still announces the rig's rate, so a
    /// host's loop, delays and time-outs in samples are those of the real
    /// device; for benchmarks that need many sittings (`kilotouch bench
    /// --hil`). Range 0.1 ..= 20.
    pub speed: f64,
    /// Fault injection.
    pub faults: FaultInjection,
}

impl Default for EmulatorConfig {
    fn default() -> Self {
        Self {
            watchdog: Duration::from_millis(100),
            batch: 10,
            free_running: false,
            speed: 1.0,
            faults: FaultInjection::default(),
        }
    }
}

impl EmulatorConfig {
    /// Check the ranges.
    pub fn validate(&self) -> Result<(), RigError> {
        let p = |name: &'static str, v: f64| {
            if (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(RigError::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be a probability in [0, 1]".into(),
                })
            }
        };
        p("corrupt_rate", self.faults.corrupt_rate)?;
        p("drop_rate", self.faults.drop_rate)?;
        if !(0.1..=20.0).contains(&self.speed) {
            return Err(RigError::InvalidParameter {
                name: "speed",
                value: self.speed,
                reason: "the emulator's clock speed must be in 0.1 ..= 20 (1 = real time)".into(),
            });
        }
        let wd = self.watchdog.as_secs_f64();
        if !(0.001..=60.0).contains(&wd) {
            return Err(RigError::InvalidParameter {
                name: "watchdog_ms",
                value: wd * 1e3,
                reason: "must be in 1 ..= 60000 ms".into(),
            });
        }
        if !(1..=64).contains(&self.batch) {
            return Err(RigError::InvalidParameter {
                name: "batch",
                value: self.batch as f64,
                reason: "must be in 1 ..= 64".into(),
            });
        }
        Ok(())
    }
}

/// Counters of an emulator.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EmulatorStats {
    /// Samples executed.
    pub samples: u64,
    /// Valid host frames.
    pub host_frames: u64,
    /// Samples executed with a held command.
    pub late_commands: u64,
    /// Commands that arrived for samples already executed.
    pub stale_commands: u64,
    /// Commands rejected because they were too far ahead.
    pub overflow_commands: u64,
    /// Watchdog trips.
    pub watchdog_trips: u64,
    /// Outgoing bytes corrupted by fault injection.
    pub bytes_corrupted: u64,
    /// Outgoing bytes dropped by fault injection.
    pub bytes_dropped: u64,
    /// Outgoing bytes discarded because the transport did not take them.
    pub bytes_overflowed: u64,
}

/// What the transport should do next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Call [`Emulator::advance`] again at this time (or when bytes arrive).
    WakeAt(Duration),
    /// Close the transport (injected disconnect).
    Disconnect,
}

/// Commands buffered ahead of execution, samples.
pub const COMMAND_RING: usize = 8192;
/// Pending output kept when the transport is slow, bytes.
pub const MAX_PENDING_OUTPUT: usize = 1 << 20;
/// Period of STATUS frames while waiting for commands.
pub const STATUS_PERIOD: Duration = Duration::from_millis(10);

/// The device emulator (module docs).
#[derive(Debug)]
pub struct Emulator<I: Instrument> {
    inst: I,
    cfg: EmulatorConfig,
    hello: Hello,
    fs: f64,
    decoder: Decoder,
    state: DeviceState,
    next_seq: u64,
    anchor_time: Duration,
    anchor_seq: u64,
    ring: Vec<Option<(u64, I::Command)>>,
    applied: I::Command,
    batch: Vec<I::Sample>,
    batch_seq: u64,
    last_host: Duration,
    waiting_status_at: Option<Duration>,
    waiting_since: Option<Duration>,
    created: Duration,
    out: Vec<u8>,
    scratch: Vec<u8>,
    rng: Xoshiro256PlusPlus,
    stats: EmulatorStats,
}

impl<I: Instrument> Emulator<I> {
    /// Emulator around `inst`, created at wall time `now`.
    pub fn new(inst: I, cfg: EmulatorConfig, now: Duration) -> Result<Self, RigError> {
        cfg.validate()?;
        let mut hello = inst.hello();
        hello.watchdog_ms = cfg.watchdog.as_millis().min(u128::from(u16::MAX)) as u16;
        hello.batch = cfg.batch as u8;
        let fs = f64::from(hello.sample_rate_hz);
        if fs.is_nan() || fs <= 0.0 {
            return Err(RigError::InvalidParameter {
                name: "sample_rate_hz",
                value: fs,
                reason: "must be > 0".into(),
            });
        }
        Ok(Self {
            fs,
            applied: I::Command::default(),
            batch: Vec::with_capacity(cfg.batch),
            rng: Xoshiro256PlusPlus::seed_from_u64(cfg.faults.seed),
            inst,
            cfg,
            hello,
            decoder: Decoder::new(),
            state: DeviceState::Idle,
            next_seq: 0,
            anchor_time: now,
            anchor_seq: 0,
            ring: vec![None; COMMAND_RING],
            batch_seq: 0,
            last_host: now,
            waiting_status_at: None,
            waiting_since: None,
            created: now,
            out: Vec::with_capacity(1 << 16),
            scratch: Vec::with_capacity(4096),
            stats: EmulatorStats::default(),
        })
    }

    /// The instrument.
    pub fn instrument(&self) -> &I {
        &self.inst
    }

    /// State.
    pub fn state(&self) -> DeviceState {
        self.state
    }

    /// The command applied during the last executed sample (after a
    /// watchdog trip: the safe command).
    pub fn applied(&self) -> &I::Command {
        &self.applied
    }

    /// Next sample to execute.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Counters.
    pub fn stats(&self) -> EmulatorStats {
        self.stats
    }

    /// The handshake answer.
    pub fn hello(&self) -> &Hello {
        &self.hello
    }

    fn stalled(&self, now: Duration) -> bool {
        let t = now.saturating_sub(self.created);
        let f = self.cfg.faults;
        f.stall_after
            .is_some_and(|s| t >= s && f.stall_for.is_none_or(|d| t < s + d))
    }

    /// Bytes waiting to be sent.
    pub fn output(&self) -> &[u8] {
        &self.out
    }

    /// The transport sent the first `n` bytes of [`output`](Self::output).
    pub fn consume_output(&mut self, n: usize) {
        let n = n.min(self.out.len());
        self.out.drain(..n);
    }

    /// Move the scratch frame(s) to the output through fault injection.
    fn emit(&mut self) {
        let f = self.cfg.faults;
        if f.corrupt_rate > 0.0 || f.drop_rate > 0.0 {
            for i in 0..self.scratch.len() {
                let b = self.scratch[i];
                if f.drop_rate > 0.0 && self.rng.random::<f64>() < f.drop_rate {
                    self.stats.bytes_dropped += 1;
                } else if f.corrupt_rate > 0.0 && self.rng.random::<f64>() < f.corrupt_rate {
                    let x = self.rng.random_range(1..=255u8);
                    self.out.push(b ^ x);
                    self.stats.bytes_corrupted += 1;
                } else {
                    self.out.push(b);
                }
            }
        } else {
            self.out.extend_from_slice(&self.scratch);
        }
        self.scratch.clear();
        if self.out.len() > MAX_PENDING_OUTPUT {
            let excess = self.out.len() - MAX_PENDING_OUTPUT;
            self.stats.bytes_overflowed += excess as u64;
            self.out.drain(..excess);
        }
    }

    fn status(&self) -> Status {
        let d = self.decoder.stats();
        Status {
            next_seq: self.next_seq as u32,
            state: self.state,
            host_frames: self.stats.host_frames as u32,
            host_crc_errors: d.crc_errors as u32,
            late_commands: self.stats.late_commands as u32,
        }
    }

    fn send_status(&mut self) {
        let s = self.status();
        frame::write_status(&mut self.scratch, &s);
        self.emit();
    }

    fn send_fault(&mut self, code: u8) {
        let f = FaultReport {
            code,
            seq: self.next_seq as u32,
        };
        frame::write_fault(&mut self.scratch, &f);
        self.emit();
    }

    fn flush_batch(&mut self) {
        if self.batch.is_empty() {
            return;
        }
        frame::write_block(
            &mut self.scratch,
            I::SAMPLE_TYPE,
            self.batch_seq as u32,
            &self.batch,
        );
        self.batch.clear();
        self.emit();
    }

    /// Bytes from the host arrived at wall time `now`.
    pub fn receive(&mut self, mut data: &[u8], now: Duration) {
        if self.stalled(now) {
            return;
        }
        while !data.is_empty() {
            let n = self.decoder.push(data);
            data = &data[n..];
            while let Some(f) = self.decoder.next_frame() {
                let (ty, len) = (f.ty, f.payload.len());
                let mut payload = [0u8; frame::MAX_PAYLOAD];
                payload[..len].copy_from_slice(f.payload);
                self.handle(ty, &payload[..len], now);
            }
        }
    }

    fn handle(&mut self, ty: u8, payload: &[u8], now: Duration) {
        self.stats.host_frames += 1;
        self.last_host = now;
        match ty {
            frame::ty::HELLO_REQ => {
                let v = if payload.len() == 2 {
                    u16::from_le_bytes([payload[0], payload[1]])
                } else {
                    0
                };
                if v != PROTOCOL_VERSION {
                    self.send_fault(fault::VERSION);
                }
                let h = self.hello.clone();
                frame::write_hello(&mut self.scratch, &h);
                self.emit();
            }
            frame::ty::START => {
                self.flush_batch();
                self.ring.fill(None);
                self.state = DeviceState::Running;
                self.anchor_time = now;
                self.anchor_seq = self.next_seq;
                self.waiting_status_at = None;
                self.send_status();
            }
            frame::ty::STOP => {
                self.flush_batch();
                self.go_idle(DeviceState::Idle);
                self.send_status();
            }
            frame::ty::HEARTBEAT => {}
            frame::ty::SCENE_REQ => match self.inst.scene() {
                Some(sc) => {
                    frame::write_scene(&mut self.scratch, &sc);
                    self.emit();
                }
                None => self.send_fault(fault::BAD_FRAME),
            },
            frame::ty::INFO => match frame::parse_info(payload) {
                Some(i) => self.inst.info(&i),
                None => self.send_fault(fault::BAD_FRAME),
            },
            frame::ty::RESET => {
                if payload.len() == I::Command::SIZE {
                    let c = I::Command::decode(payload);
                    self.inst.reset(&c);
                    self.applied = c;
                } else {
                    self.send_fault(fault::BAD_FRAME);
                }
            }
            t if t == I::COMMAND_TYPE => {
                let Some((seq32, n)) = frame::block_header::<I::Command>(payload) else {
                    self.send_fault(fault::BAD_FRAME);
                    return;
                };
                if self.state != DeviceState::Running {
                    self.send_fault(fault::NOT_RUNNING);
                    return;
                }
                let first = frame::unwrap_seq(seq32, self.next_seq);
                let (mut stale, mut over) = (false, false);
                for i in 0..n {
                    let q = first + i as u64;
                    if q < self.next_seq {
                        self.stats.stale_commands += 1;
                        stale = true;
                    } else if q >= self.next_seq + COMMAND_RING as u64 {
                        self.stats.overflow_commands += 1;
                        over = true;
                    } else {
                        let c = frame::block_item::<I::Command>(payload, i);
                        self.ring[(q % COMMAND_RING as u64) as usize] = Some((q, c));
                    }
                }
                if stale {
                    self.send_fault(fault::LATE);
                }
                if over {
                    self.send_fault(fault::OVERFLOW);
                }
            }
            _ => self.send_fault(fault::BAD_FRAME),
        }
    }

    fn go_idle(&mut self, state: DeviceState) {
        self.state = state;
        self.applied = self.inst.safe_command(&self.applied);
        self.ring.fill(None);
        self.waiting_status_at = None;
        self.waiting_since = None;
    }

    /// Wall time at which sample `seq` is due (end of its period).
    fn due_time(&self, seq: u64) -> Duration {
        self.anchor_time
            + Duration::from_secs_f64(
                (seq + 1 - self.anchor_seq) as f64 / (self.fs * self.cfg.speed),
            )
    }

    /// One frame of a misbehaving device ([`Misbehaviour`]).
    fn misbehave(&mut self, m: Misbehaviour) {
        match m {
            Misbehaviour::StatusOnly => {
                let st = self.status();
                frame::write_status(&mut self.scratch, &st);
            }
            Misbehaviour::UnknownFrames => {
                frame::write_frame(&mut self.scratch, 0x7E, |o| o.extend_from_slice(b"junk"));
            }
            Misbehaviour::StraySequence => {
                self.batch_seq += 1;
                let seq = if self.batch_seq.is_multiple_of(2) {
                    self.next_seq.wrapping_sub(1000)
                } else {
                    self.next_seq.wrapping_add(1 << 20)
                };
                let s = self.inst.step(&self.applied, 0);
                frame::write_block(&mut self.scratch, I::SAMPLE_TYPE, seq as u32, &[s]);
            }
        }
        self.emit();
    }

    /// Run every sample that is due at wall time `now` and whose command
    /// is here; check the watchdog; queue the output. Returns when to call
    /// again.
    pub fn advance(&mut self, now: Duration) -> Next {
        if self
            .cfg
            .faults
            .disconnect_after
            .is_some_and(|d| now.saturating_sub(self.created) >= d)
        {
            return Next::Disconnect;
        }
        if self.stalled(now) {
            return Next::WakeAt(now + Duration::from_millis(50));
        }
        if self.state != DeviceState::Running {
            return Next::WakeAt(now + Duration::from_millis(50));
        }
        if let Some(m) = self.cfg.faults.misbehave {
            self.misbehave(m);
            return Next::WakeAt(now + Misbehaviour::PERIOD);
        }
        let elapsed = now.saturating_sub(self.anchor_time).as_secs_f64();
        let pos = self.anchor_seq + (elapsed * self.fs * self.cfg.speed).floor() as u64;
        let mut waiting = false;
        while self.next_seq < pos {
            let slot = (self.next_seq % COMMAND_RING as u64) as usize;
            let (cmd, late) = match self.ring[slot] {
                Some((q, c)) if q == self.next_seq => {
                    self.ring[slot] = None;
                    (c, 0)
                }
                // A physical device holds the previous command.
                _ if self.cfg.free_running => {
                    if now.saturating_sub(self.last_host) >= self.cfg.watchdog {
                        // Out of commands and the host silent for the
                        // watchdog window: outputs safe.
                        self.flush_batch();
                        self.stats.watchdog_trips += 1;
                        self.go_idle(DeviceState::Tripped);
                        self.send_fault(fault::WATCHDOG);
                        self.send_status();
                        return Next::WakeAt(now + Duration::from_millis(50));
                    }
                    self.stats.late_commands += 1;
                    (self.applied, flag::CMD_LATE)
                }
                _ => {
                    waiting = true;
                    break;
                }
            };
            if self.batch.is_empty() {
                self.batch_seq = self.next_seq;
            }
            let s = self.inst.step(&cmd, late | self.cfg.faults.sample_flags);
            self.applied = cmd;
            self.batch.push(s);
            self.next_seq += 1;
            self.stats.samples += 1;
            self.waiting_status_at = None;
            if self.batch.len() >= self.cfg.batch {
                self.flush_batch();
            }
        }
        if !waiting {
            self.waiting_since = None;
        } else {
            self.flush_batch();
            // The watchdog window runs from the later of the last valid host
            // frame and the moment the device ran out of commands: on its
            // clock (the sample that is due without a command), unless the
            // device is far behind its clock (the emulating process was
            // descheduled: it ran the samples only now, so the host could
            // not have answered them earlier) — then from now.
            let ran_out = self.due_time(self.next_seq);
            let since = *self.waiting_since.get_or_insert(
                if now.saturating_sub(ran_out) > self.cfg.watchdog / 2 {
                    now
                } else {
                    ran_out.min(now)
                },
            );
            let deadline = self.last_host.max(since) + self.cfg.watchdog;
            if now >= deadline {
                // Watchdog: outputs safe, report, stop streaming.
                self.stats.watchdog_trips += 1;
                self.go_idle(DeviceState::Tripped);
                self.send_fault(fault::WATCHDOG);
                self.send_status();
                return Next::WakeAt(now + Duration::from_millis(50));
            }
            if self.waiting_status_at.is_none_or(|t| now >= t) {
                self.send_status();
                self.waiting_status_at = Some(now + STATUS_PERIOD);
            }
        }
        // Wake when the current batch will be full, or while waiting at the
        // next status repeat or the watchdog deadline, whichever comes first.
        let fill = self.next_seq + (self.cfg.batch - self.batch.len()) as u64 - 1;
        let mut wake = self.due_time(fill.max(pos));
        if let (true, Some(since)) = (waiting, self.waiting_since) {
            wake = wake
                .min(self.waiting_status_at.unwrap_or(wake))
                .min(self.last_host.max(since) + self.cfg.watchdog);
        }
        Next::WakeAt(wake.max(now))
    }
}

/// The simulated DAQ behind the emulator: a batch [`SimRig`] whose sensor
/// frames are converted to encoder counts and accelerometer codes.
#[derive(Debug)]
pub struct DaqInstrument {
    rig: SimRig,
    caps: DaqCaps,
    name: String,
    fs: u32,
    frame: [SensorFrame; 1],
    agent: Option<Box<dyn HandAgent>>,
}

/// A sample rate as the serial protocol carries it: whole Hz, from 1 to
/// `u32::MAX`.
///
/// # Errors
/// [`RigError::InvalidParameter`] (`sample_rate_hz`) for any other rate.
pub(crate) fn wire_rate_hz(fs: f64) -> Result<u32, RigError> {
    if fs.fract() != 0.0 || !(1.0..=f64::from(u32::MAX)).contains(&fs) {
        return Err(RigError::InvalidParameter {
            name: "sample_rate_hz",
            value: fs,
            reason: "the serial protocol carries whole Hz".into(),
        });
    }
    Ok(fs as u32)
}

impl DaqInstrument {
    /// Encoder counts per metre used when the rig file sets no resolution.
    pub const DEFAULT_COUNTS_PER_M: f64 = 1e7;

    /// The simulated rig of `cfg` as a DAQ.
    pub fn new(cfg: &RigConfig) -> Result<Self, RigError> {
        let mut rig = SimRig::new(cfg)?;
        rig.start()?;
        let fs = wire_rate_hz(cfg.rig.sample_rate_hz)?;
        let range = rig.accelerometer().range_m_s2();
        let lsb = rig.accelerometer().lsb_m_s2();
        let res = cfg.rig.encoder_resolution_m;
        let caps = DaqCaps {
            encoder_counts_per_m: if res > 0.0 {
                1.0 / res
            } else {
                Self::DEFAULT_COUNTS_PER_M
            },
            accel_m_s2_per_code: if lsb > 0.0 { lsb } else { range / 32767.0 },
            accel_range_m_s2: range,
            force_max_n: cfg.limits.pantograph_force_max_n,
            drive_max_v: cfg.limits.haptuator_drive_max_v,
        };
        if caps.accel_range_m_s2 / caps.accel_m_s2_per_code > 32767.0 {
            return Err(RigError::InvalidParameter {
                name: "lsb_m_s2",
                value: lsb,
                reason: "the accelerometer range does not fit 16-bit codes".into(),
            });
        }
        Ok(Self {
            rig,
            caps,
            name: cfg.rig.name.clone(),
            fs,
            frame: [SensorFrame::default()],
            agent: None,
        })
    }

    /// The same DAQ with `agent` at its handle (hardware in the loop): it
    /// moves the simulated hand and hears the host's information frames.
    pub fn with_agent(mut self, agent: Box<dyn HandAgent>) -> Self {
        self.agent = Some(agent);
        self
    }

    /// The participant at the handle, if any.
    pub fn agent(&self) -> Option<&dyn HandAgent> {
        self.agent.as_deref()
    }

    /// The simulated rig (ground truth for tests).
    pub fn rig(&self) -> &SimRig {
        &self.rig
    }

    /// Capabilities.
    pub fn caps(&self) -> DaqCaps {
        self.caps
    }
}

/// Value of an i16 output code with full scale `max`.
pub fn code_to_value(code: i16, max: f64) -> f64 {
    f64::from(code) * max / 32767.0
}

/// i16 output code of `v` with full scale `max` (rounded, saturated;
/// non-finite → 0). Returns (code, clamped?).
pub fn value_to_code(v: f64, max: f64) -> (i16, bool) {
    if !v.is_finite() || max.is_nan() || max <= 0.0 {
        return (0, false);
    }
    let x = crate::round_half_away(v / max * 32767.0);
    if x > 32767.0 {
        (32767, true)
    } else if x < -32767.0 {
        (-32767, true)
    } else {
        (x as i16, false)
    }
}

fn sat_i32(x: f64) -> i32 {
    if x.is_nan() {
        0
    } else {
        x.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }
}

fn sat_i16(x: f64) -> i16 {
    if x.is_nan() {
        0
    } else {
        x.clamp(-32767.0, 32767.0) as i16
    }
}

impl Instrument for DaqInstrument {
    type Command = DaqCommand;
    type Sample = DaqSample;
    const COMMAND_TYPE: u8 = frame::ty::COMMANDS;
    const SAMPLE_TYPE: u8 = frame::ty::SAMPLES;

    fn hello(&self) -> Hello {
        Hello::emulator(
            self.fs,
            Caps::Daq(self.caps),
            &self.name,
            "emulator-0001",
            "daq",
        )
    }

    fn step(&mut self, cmd: &DaqCommand, extra_flags: u8) -> DaqSample {
        let c = self.caps;
        let a = ActuatorFrame {
            force_n: [
                code_to_value(cmd.force[0], c.force_max_n),
                code_to_value(cmd.force[1], c.force_max_n),
            ],
            haptuator_v: code_to_value(cmd.drive, c.drive_max_v),
        };
        if let Some(h) = self.agent.as_mut().and_then(|ag| ag.hand()) {
            self.rig.set_hand(h);
        }
        let flags = match self.rig.process_block(&[a], &mut self.frame) {
            Ok(_) => self.frame[0].flags.0 & flag::HOST_MASK,
            Err(_) => flag::NONFINITE,
        };
        let f = self.frame[0];
        if let Some(ag) = self.agent.as_mut() {
            ag.observe(&a, &f);
        }
        DaqSample {
            enc: [
                sat_i32(crate::round_half_away(
                    f.handle_m[0] * c.encoder_counts_per_m,
                )),
                sat_i32(crate::round_half_away(
                    f.handle_m[1] * c.encoder_counts_per_m,
                )),
            ],
            acc: f
                .accel_m_s2
                .map(|v| sat_i16(crate::round_half_away(v / c.accel_m_s2_per_code))),
            flags: flags | extra_flags,
        }
    }

    fn safe_command(&self, _last: &DaqCommand) -> DaqCommand {
        DaqCommand::default()
    }

    fn reset(&mut self, _cmd: &DaqCommand) {}

    fn info(&mut self, info: &HostInfo) {
        if let Some(ag) = self.agent.as_mut() {
            ag.info(info);
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn output_codes_round_trip_and_saturate() {
        for v in [-5.0, -2.5, 0.0, 1e-3, 4.999, 5.0] {
            let (c, lim) = value_to_code(v, 5.0);
            assert!(!lim);
            assert!((code_to_value(c, 5.0) - v).abs() <= 0.5 * 5.0 / 32767.0 + 1e-15);
        }
        assert_eq!(value_to_code(6.0, 5.0), (32767, true));
        assert_eq!(value_to_code(-1e300, 5.0), (-32767, true));
        assert_eq!(value_to_code(f64::NAN, 5.0), (0, false));
        assert_eq!(value_to_code(f64::INFINITY, 5.0), (0, false));
    }
}
