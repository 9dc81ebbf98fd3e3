//! The device state machine of `docs/PROTOCOL.md` on a sample clock.
//!
//! [`Device::tick`] runs once per sample period (the 10 kHz timer
//! interrupt); [`Device::handle`] acts on each valid host frame (the link
//! task, after its decoder found one). Both write whole frames to an
//! [`Outbox`] (the transmit queue of the USART or USB link). Behind the
//! device is a [`Frontend`]: the board's DAC, encoders and ADC, or the plant
//! model of the QEMU build.
//!
//! # Sample periods (§7)
//!
//! Sample t occupies the period [t₀ + (t − t_s)/f_s, t₀ + (t − t_s + 1)/f_s)
//! after START (t₀ its tick, t_s the `next_seq` it reported). What happens
//! when the command for t is missing depends on the [`LatePolicy`]:
//!
//! * [`LatePolicy::Hold`] (a physical device): every tick ends one period
//!   and begins the next. The end reads the sensors into the sample, the
//!   beginning applies the command for the new period, or holds the one
//!   applied before and flags the sample `CMD_LATE`. The first period after
//!   START begins at START itself, before any command can have arrived.
//! * [`LatePolicy::Wait`] (a simulated plant, the emulator's semantics):
//!   sample t runs once it is due and its command is here — simulated time
//!   stands still until then, and the device catches up afterwards, at most
//!   [`MAX_CATCH_UP`] samples per tick. While it waits it sends the partial
//!   batch and a STATUS, repeated every [`STATUS_PERIOD_TICKS`]. It also
//!   stands still while the transmit queue lacks room for two frames, so
//!   that it never drops a frame (a board, holding, drops the frame whole).
//!
//! # Watchdog (§8)
//!
//! When the device has run out of commands (Wait: it is waiting; Hold: it
//! is holding) and no valid host frame has arrived for the window — counted
//! from the later of the last valid host frame and the moment the commands
//! ran out — it zeroes the outputs, sends FAULT `WATCHDOG` and STATUS
//! `tripped`, and refuses commands until START.
//!
//! # Clamps and flags
//!
//! A command code of −32768 counts as −32767, a code beyond the board's
//! [`Config::max_code`] is clamped to it; either sets `LIMITED` on the
//! sample. The frontend adds the sensor flags (`CLIPPED`, `END_STOP`,
//! `NONFINITE`).

use crate::ring::{CommandRing, RING};
use kilotouch_proto::frame::{MAX_FRAME, encode_payload};
use kilotouch_proto::testing::{self, Ack, Profile};
use kilotouch_proto::{
    Caps, DaqCaps, DaqCommand, DaqSample, DeviceState, FaultReport, Hello, PROTOCOL_VERSION,
    Status, WireItem, block_header, block_item, encode_block, fault, flag, ty, unwrap_seq,
};

/// Samples per sample interrupt at most while catching up (Wait policy).
pub const MAX_CATCH_UP: usize = 64;
/// Samples per SAMPLES frame at most.
pub const MAX_BATCH: usize = 32;
/// Ticks between STATUS frames while waiting for commands (10 ms at 10 kHz).
pub const STATUS_PERIOD_TICKS: u64 = 100;

/// What a missing command means (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LatePolicy {
    /// Hold the previous command, flag the sample `CMD_LATE`.
    Hold,
    /// Wait for the command (simulated plant only).
    Wait,
}

/// The analog side of the device.
pub trait Frontend {
    /// Apply `cmd` (clamped codes) from now on: the command of the period
    /// that begins.
    fn apply(&mut self, cmd: &DaqCommand);
    /// The sensors at the end of the current period: encoder counts,
    /// accelerometer codes and the sensor flags (`CLIPPED`, `END_STOP`,
    /// `NONFINITE`).
    fn read(&mut self) -> DaqSample;
    /// Outputs to zero at once (watchdog, emergency stop, STOP).
    fn safe(&mut self);
    /// The command the outputs carry now (after [`safe`](Self::safe): zero).
    fn outputs(&self) -> DaqCommand;
    /// Capabilities announced in HELLO (they may change with a loaded plant).
    fn caps(&self) -> DaqCaps;
    /// A test operation this frontend implements (the plant model's);
    /// `Err(result)` with a [`testing::result`] code otherwise.
    fn test(&mut self, op: u8, args: &[u8], idle: bool) -> Result<u32, u8> {
        let _ = (op, args, idle);
        Err(testing::result::UNSUPPORTED)
    }
}

/// The transmit queue of the link.
pub trait Outbox {
    /// Free bytes.
    fn free(&self) -> usize;
    /// Append `bytes` (the caller checked [`free`](Self::free)).
    fn write(&mut self, bytes: &[u8]);
}

/// Fixed settings of a device.
#[derive(Debug, Clone, Copy)]
pub struct Config {
    /// Sample rate, Hz (the tick rate).
    pub sample_rate_hz: u32,
    /// Watchdog window, ms.
    pub watchdog_ms: u16,
    /// Samples per SAMPLES frame (1 ..= [`MAX_BATCH`]).
    pub batch: u8,
    /// Late-command policy at reset.
    pub policy: LatePolicy,
    /// Largest output code magnitude (≤ 32767): the board's clamp.
    pub max_code: i16,
    /// Act on TEST frames (the QEMU build); otherwise FAULT BAD_FRAME.
    pub test_frames: bool,
    /// HELLO name.
    pub name: &'static str,
    /// HELLO firmware string (version and build hash).
    pub firmware: &'static str,
}

/// Counters of a device.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Valid host frames.
    pub host_frames: u32,
    /// Host frames rejected for their CRC (the link's decoder).
    pub host_crc_errors: u32,
    /// Samples executed with a held command.
    pub late_commands: u32,
    /// Watchdog trips.
    pub watchdog_trips: u32,
    /// Frames dropped because the transmit queue was full.
    pub tx_dropped: u32,
}

/// Device → host fault injection (test frames): per-byte probabilities in
/// parts per million, xorshift32 generator.
#[derive(Debug, Clone, Copy, Default)]
struct Faults {
    corrupt_ppm: u32,
    drop_ppm: u32,
    rng: u32,
}

impl Faults {
    fn next(&mut self) -> u32 {
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.rng = x;
        x
    }
    fn draw_ppm(&mut self) -> u32 {
        self.next() % 1_000_000
    }
}

/// The device (module docs).
#[derive(Debug)]
pub struct Device<F: Frontend, O: Outbox> {
    cfg: Config,
    serial: [u8; 24],
    fe: F,
    out: O,
    policy: LatePolicy,
    state: DeviceState,
    now: u64,
    next_seq: u64,
    /// First sample whose command may still be stored (Hold: the period
    /// after the one in progress).
    open_seq: u64,
    anchor_tick: u64,
    anchor_seq: u64,
    ring: CommandRing,
    applied: DaqCommand,
    period_flags: u8,
    batch: [DaqSample; MAX_BATCH],
    batch_len: usize,
    batch_seq: u64,
    last_host: u64,
    waiting_since: Option<u64>,
    status_at: Option<u64>,
    estop: bool,
    counters: Counters,
    faults: Faults,
    profile: Profile,
    scratch: [u8; MAX_FRAME],
}

impl<F: Frontend, O: Outbox> Device<F, O> {
    /// A device in state idle; `serial` is the HELLO serial number (e.g.
    /// the MCU's unique ID in hex, at most 24 bytes).
    pub fn new(cfg: Config, serial: &[u8], fe: F, out: O) -> Self {
        let mut s = [0u8; 24];
        let n = serial.len().min(24);
        s[..n].copy_from_slice(&serial[..n]);
        Self {
            policy: cfg.policy,
            cfg: Config {
                batch: cfg.batch.clamp(1, MAX_BATCH as u8),
                max_code: cfg.max_code.clamp(0, 32767),
                ..cfg
            },
            serial: s,
            fe,
            out,
            state: DeviceState::Idle,
            now: 0,
            next_seq: 0,
            open_seq: 0,
            anchor_tick: 0,
            anchor_seq: 0,
            ring: CommandRing::new(),
            applied: DaqCommand::default(),
            period_flags: 0,
            batch: [DaqSample::default(); MAX_BATCH],
            batch_len: 0,
            batch_seq: 0,
            last_host: 0,
            waiting_since: None,
            status_at: None,
            estop: false,
            counters: Counters::default(),
            faults: Faults::default(),
            profile: Profile::default(),
            scratch: [0u8; MAX_FRAME],
        }
    }

    /// State.
    pub fn state(&self) -> DeviceState {
        self.state
    }

    /// Next sample to be sent (the STATUS `next_seq`).
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// The command applied to the outputs now.
    pub fn applied(&self) -> DaqCommand {
        self.applied
    }

    /// Counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Late-command policy in force.
    pub fn policy(&self) -> LatePolicy {
        self.policy
    }

    /// The frontend.
    pub fn frontend(&self) -> &F {
        &self.fe
    }

    /// The frontend, mutable (the board reads its cost counters).
    pub fn frontend_mut(&mut self) -> &mut F {
        &mut self.fe
    }

    /// The transmit queue.
    pub fn outbox(&mut self) -> &mut O {
        &mut self.out
    }

    /// Sample periods since reset.
    pub fn ticks(&self) -> u64 {
        self.now
    }

    /// The link's decoder count of host frames rejected for their CRC
    /// (reported in STATUS).
    pub fn set_host_crc_errors(&mut self, n: u64) {
        self.counters.host_crc_errors = n.min(u64::from(u32::MAX)) as u32;
    }

    /// Record the cost of one sample interrupt (`total`) and of the plant
    /// model inside it (`plant`), in cycle-counter counts.
    pub fn record_cost(&mut self, total: u32, plant: u32) {
        let p = &mut self.profile;
        p.ticks = p.ticks.wrapping_add(1);
        p.max = p.max.max(total);
        p.sum = p.sum.wrapping_add(u64::from(total));
        p.plant_max = p.plant_max.max(plant);
        p.plant_sum = p.plant_sum.wrapping_add(u64::from(plant));
    }

    /// The HELLO of this device.
    fn hello(&self) -> Hello<'_> {
        let n = self.serial.iter().position(|&b| b == 0).unwrap_or(24);
        Hello {
            name: self.cfg.name.as_bytes(),
            serial: &self.serial[..n],
            firmware: self.cfg.firmware.as_bytes(),
            ..Hello::current(
                Caps::Daq(self.fe.caps()),
                self.cfg.sample_rate_hz,
                self.cfg.watchdog_ms,
                self.cfg.batch,
            )
        }
    }

    fn watchdog_ticks(&self) -> u64 {
        (u64::from(self.cfg.watchdog_ms) * u64::from(self.cfg.sample_rate_hz))
            .div_ceil(1000)
            .max(1)
    }

    /// Queue the frame in `scratch[..n]`, through fault injection; a frame
    /// that does not fit is dropped whole and counted.
    fn emit(&mut self, n: usize) {
        if self.out.free() < n {
            self.counters.tx_dropped = self.counters.tx_dropped.wrapping_add(1);
            return;
        }
        let f = self.faults;
        if f.corrupt_ppm == 0 && f.drop_ppm == 0 {
            self.out.write(&self.scratch[..n]);
            return;
        }
        for i in 0..n {
            let b = self.scratch[i];
            if self.faults.draw_ppm() < f.drop_ppm {
                continue;
            }
            let b = if self.faults.draw_ppm() < f.corrupt_ppm {
                b ^ (1 + (self.faults.next() % 255) as u8)
            } else {
                b
            };
            self.out.write(&[b]);
        }
    }

    fn send(&mut self, frame_ty: u8, payload: &[u8]) {
        if let Ok(n) = encode_payload(&mut self.scratch, frame_ty, payload) {
            self.emit(n);
        }
    }

    fn status(&self) -> Status {
        Status {
            next_seq: self.next_seq as u32,
            state: self.state,
            host_frames: self.counters.host_frames,
            host_crc_errors: self.counters.host_crc_errors,
            late_commands: self.counters.late_commands,
        }
    }

    fn send_status(&mut self) {
        let s = self.status().encode();
        self.send(ty::STATUS, &s);
    }

    fn send_fault(&mut self, code: u8) {
        let f = FaultReport {
            code,
            seq: self.next_seq as u32,
        }
        .encode();
        self.send(ty::FAULT, &f);
    }

    fn send_hello(&mut self) {
        let mut p = [0u8; Hello::MAX_SIZE];
        if let Ok(n) = self.hello().encode(&mut p) {
            self.send(ty::HELLO, &p[..n]);
        }
    }

    fn ack(&mut self, op: u8, r: Result<u32, u8>, data: &[u8]) {
        let (result, value) = match r {
            Ok(v) => (testing::result::OK, v),
            Err(code) => (code, 0),
        };
        let mut p = [0u8; Ack::SIZE + Profile::SIZE];
        p[..Ack::SIZE].copy_from_slice(&Ack { op, result, value }.encode());
        let n = data.len().min(Profile::SIZE);
        p[Ack::SIZE..Ack::SIZE + n].copy_from_slice(&data[..n]);
        self.send(ty::TEST_ACK, &p[..Ack::SIZE + n]);
    }

    fn flush_batch(&mut self) {
        if self.batch_len == 0 {
            return;
        }
        let (seq, n) = (self.batch_seq as u32, self.batch_len);
        self.batch_len = 0;
        let batch = self.batch;
        if let Ok(len) = encode_block(&mut self.scratch, ty::SAMPLES, seq, &batch[..n]) {
            self.emit(len);
        }
    }

    fn push_sample(&mut self, s: DaqSample) {
        if self.batch_len == 0 {
            self.batch_seq = self.next_seq;
        }
        self.batch[self.batch_len] = s;
        self.batch_len += 1;
        self.next_seq += 1;
        if self.batch_len >= usize::from(self.cfg.batch) {
            self.flush_batch();
        }
    }

    /// Clamp a command to the protocol's and the board's range; the
    /// `LIMITED` flag when anything changed.
    fn clamp(&self, c: DaqCommand) -> (DaqCommand, u8) {
        let m = self.cfg.max_code;
        let mut f = 0;
        let mut lim = |v: i16| {
            let x = v.max(-m).min(m);
            if x != v {
                f = flag::LIMITED;
            }
            x
        };
        let out = DaqCommand {
            force: [lim(c.force[0]), lim(c.force[1])],
            drive: lim(c.drive),
        };
        (out, f)
    }

    fn go_idle(&mut self, state: DeviceState) {
        self.state = state;
        self.fe.safe();
        self.applied = DaqCommand::default();
        self.ring.clear();
        self.status_at = None;
        self.waiting_since = None;
    }

    /// Hold policy: begin the period of `next_seq` with its command or the
    /// held one.
    fn begin_period(&mut self) {
        let seq = self.next_seq;
        self.open_seq = seq + 1;
        match self.ring.take(seq) {
            Some(c) => {
                let (c, f) = self.clamp(c);
                self.fe.apply(&c);
                self.applied = c;
                self.period_flags = f;
                self.waiting_since = None;
            }
            None => {
                self.period_flags = flag::CMD_LATE;
                self.counters.late_commands = self.counters.late_commands.wrapping_add(1);
                self.waiting_since.get_or_insert(self.now);
            }
        }
    }

    fn start(&mut self) {
        if self.estop {
            self.send_fault(fault::ESTOP);
            self.send_status();
            return;
        }
        self.flush_batch();
        self.ring.clear();
        self.state = DeviceState::Running;
        self.anchor_tick = self.now;
        self.anchor_seq = self.next_seq;
        self.open_seq = self.next_seq;
        self.status_at = None;
        self.waiting_since = None;
        if self.policy == LatePolicy::Hold {
            self.begin_period();
        }
        self.send_status();
    }

    /// Act on one valid host frame (`docs/PROTOCOL.md` §5).
    pub fn handle(&mut self, frame_ty: u8, payload: &[u8]) {
        self.counters.host_frames = self.counters.host_frames.wrapping_add(1);
        self.last_host = self.now;
        match frame_ty {
            ty::HELLO_REQ => {
                let v = match payload {
                    [a, b] => u16::from_le_bytes([*a, *b]),
                    _ => 0,
                };
                if v != PROTOCOL_VERSION {
                    self.send_fault(fault::VERSION);
                }
                self.send_hello();
            }
            ty::START => self.start(),
            ty::STOP => {
                self.flush_batch();
                self.go_idle(DeviceState::Idle);
                self.send_status();
            }
            // Host information (trial, participant's screen) is for devices
            // with a participant at the handle; a DAQ ignores it (§5.5).
            ty::HEARTBEAT | ty::INFO => {}
            // A tweezer frame: a well-formed one changes nothing on a DAQ.
            ty::RESET if payload.len() == DaqCommand::SIZE => {}
            ty::COMMANDS => self.commands(payload),
            ty::TEST if self.cfg.test_frames => self.test(payload),
            _ => self.send_fault(fault::BAD_FRAME),
        }
    }

    fn commands(&mut self, payload: &[u8]) {
        let Some((seq32, n)) = block_header::<DaqCommand>(payload) else {
            self.send_fault(fault::BAD_FRAME);
            return;
        };
        if self.state != DeviceState::Running {
            self.send_fault(fault::NOT_RUNNING);
            return;
        }
        let first = unwrap_seq(seq32, self.next_seq);
        let (mut stale, mut over) = (false, false);
        for i in 0..n {
            let q = first + i as u64;
            if q < self.open_seq {
                stale = true;
            } else if q >= self.next_seq + RING as u64 {
                over = true;
            } else {
                self.ring.put(q, block_item::<DaqCommand>(payload, i));
            }
        }
        if stale {
            self.send_fault(fault::LATE);
        }
        if over {
            self.send_fault(fault::OVERFLOW);
        }
    }

    fn test(&mut self, payload: &[u8]) {
        let Some((&op, args)) = payload.split_first() else {
            self.send_fault(fault::BAD_FRAME);
            return;
        };
        let idle = self.state != DeviceState::Running;
        let bad = testing::result::BAD_ARGUMENT;
        let r = match (op, args) {
            (testing::op::MODE, [m @ (0 | 1)]) if idle => {
                self.policy = if *m == 0 {
                    LatePolicy::Wait
                } else {
                    LatePolicy::Hold
                };
                Ok(u32::from(*m))
            }
            (testing::op::MODE, [_]) if !idle => Err(testing::result::BUSY),
            (testing::op::ESTOP, [e @ (0 | 1)]) => {
                self.set_estop(*e == 1);
                Ok(u32::from(*e))
            }
            (testing::op::FAULTS, a) if a.len() == 12 => {
                let w = |i: usize| u32::from_le_bytes([a[i], a[i + 1], a[i + 2], a[i + 3]]);
                self.faults = Faults {
                    corrupt_ppm: w(0).min(1_000_000),
                    drop_ppm: w(4).min(1_000_000),
                    rng: w(8) | 1,
                };
                Ok(0)
            }
            (testing::op::PROFILE, [reset @ (0 | 1)]) => {
                let p = Profile {
                    tx_dropped: self.counters.tx_dropped,
                    ..self.profile
                }
                .encode();
                if *reset == 1 {
                    self.profile = Profile::default();
                    self.counters.tx_dropped = 0;
                }
                self.ack(op, Ok(0), &p);
                return;
            }
            (testing::op::OUTPUTS, []) => {
                let mut b = [0u8; DaqCommand::SIZE];
                self.fe.outputs().encode(&mut b);
                self.ack(op, Ok(0), &b);
                return;
            }
            (testing::op::MODE | testing::op::ESTOP | testing::op::FAULTS, _)
            | (testing::op::PROFILE | testing::op::OUTPUTS, _) => Err(bad),
            _ => self.fe.test(op, args, idle),
        };
        self.ack(op, r, &[]);
    }

    /// The emergency-stop input changed. Engaged: outputs zero at once; a
    /// running device trips (FAULT `ESTOP`, STATUS `tripped`) and START is
    /// refused until it is released.
    pub fn set_estop(&mut self, engaged: bool) {
        self.estop = engaged;
        if engaged {
            self.fe.safe();
            if self.state == DeviceState::Running {
                self.flush_batch();
                self.go_idle(DeviceState::Tripped);
                self.send_fault(fault::ESTOP);
                self.send_status();
            }
        }
    }

    /// Whether the emergency stop is engaged.
    pub fn estop(&self) -> bool {
        self.estop
    }

    fn trip(&mut self) {
        self.counters.watchdog_trips = self.counters.watchdog_trips.wrapping_add(1);
        self.flush_batch();
        self.go_idle(DeviceState::Tripped);
        self.send_fault(fault::WATCHDOG);
        self.send_status();
    }

    /// One sample period has passed (the timer interrupt; module docs).
    pub fn tick(&mut self) {
        self.now += 1;
        if self.state != DeviceState::Running {
            return;
        }
        match self.policy {
            LatePolicy::Hold => self.tick_hold(),
            LatePolicy::Wait => self.tick_wait(),
        }
    }

    fn tick_hold(&mut self) {
        let mut s = self.fe.read();
        s.flags |= self.period_flags;
        self.push_sample(s);
        self.begin_period();
        if let Some(since) = self.waiting_since
            && self.now >= self.last_host.max(since) + self.watchdog_ticks()
        {
            self.trip();
        }
    }

    fn tick_wait(&mut self) {
        let pos = self.anchor_seq + (self.now - self.anchor_tick);
        let mut waiting = false;
        let mut done = 0;
        while self.next_seq < pos && done < MAX_CATCH_UP {
            // A simulated device lets time stand still rather than drop a
            // frame when the link is behind (room for a SAMPLES frame and a
            // STATUS).
            if self.out.free() < 2 * MAX_FRAME {
                break;
            }
            let Some(c) = self.ring.take(self.next_seq) else {
                waiting = true;
                break;
            };
            let (c, f) = self.clamp(c);
            self.fe.apply(&c);
            self.applied = c;
            let mut s = self.fe.read();
            s.flags |= f;
            self.open_seq = self.next_seq + 1;
            self.push_sample(s);
            self.status_at = None;
            done += 1;
        }
        if !waiting {
            self.waiting_since = None;
            return;
        }
        self.flush_batch();
        // Sample next_seq became due at the end of its period.
        let due = self.anchor_tick + (self.next_seq + 1 - self.anchor_seq);
        let since = *self.waiting_since.get_or_insert(due.min(self.now));
        if self.now >= self.last_host.max(since) + self.watchdog_ticks() {
            self.trip();
            return;
        }
        if self.status_at.is_none_or(|t| self.now >= t) {
            self.send_status();
            self.status_at = Some(self.now + STATUS_PERIOD_TICKS);
        }
    }
}
