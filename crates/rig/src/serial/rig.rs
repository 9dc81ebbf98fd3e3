//! Host side of the serial protocol: the link ([`Link`]: port, handshake,
//! sequence tracking) and the serial DAQ rig ([`SerialRig`]: [`Rig`]).
//!
//! `process_block` sends the block's commands (COMMANDS frames, sequence
//! numbers `first_seq + i`), then reads device frames until every sample
//! `first_seq .. first_seq + n` is accounted for: received, or lost — a gap
//! in the sequence numbers of SAMPLES frames, or samples a STATUS frame
//! says were executed but never arrived. Lost samples become placeholder
//! frames flagged [`FrameFlags::LOST`] holding the last good values. If the
//! sample stream does not advance for [`SerialConfig::timeout`], or too few
//! new samples arrive for the device's rate ([`super::watch`]) — whatever
//! valid frames the device keeps sending instead — the rig commands the
//! outputs to zero (STOP), enters [`RigState::Disconnected`] and returns
//! [`RigError::Disconnected`] naming what the device sent; an I/O error or
//! end of file on the port
//! (device unplugged, emulator killed) does the same at once.
//! [`SerialRig::reconnect`] reopens the port.
//!
//! After `start` nothing is allocated: the receive buffer, the decoder and
//! the transmit buffer are sized when the port is opened, commands are
//! converted to codes in a fixed array.

use super::emulator::value_to_code;
use super::frame::{
    self, Caps, DaqCaps, DaqCommand, DaqSample, Decoder, DeviceKind, DeviceState, Hello,
    PROTOCOL_VERSION, WireItem, fault, flag,
};
use super::watch::{Activity, RateWindow, Stall};
use crate::device::{
    ActuatorFrame, BlockReport, FrameFlags, HostInfo, Rig, RigFault, RigIdentity, RigKind,
    RigState, RigStatus, SensorFrame, StatusCounters, open_block,
};
use crate::error::RigError;
use serialport::{ClearBuffer, SerialPort};
use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

/// Settings of a serial link (from `--rig serial:PATH[,baud=N]…`, see
/// [`super::spec::RigSpec`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SerialConfig {
    /// Port, e.g. `/dev/ttyACM0` or a pty `/dev/pts/N`.
    pub path: String,
    /// Baud rate (ignored by USB CDC and ptys; a UART needs ≥ 2 Mbaud for
    /// 10 kHz, `docs/PROTOCOL.md`).
    pub baud: u32,
    /// No new sample for this long while waiting → the device is declared
    /// stalled/gone (valid frames that do not advance the sample stream do
    /// not count, [`super::watch`]).
    pub timeout: Duration,
    /// Handshake and START answers must arrive within this.
    pub handshake_timeout: Duration,
    /// Restart the device automatically when its watchdog tripped while the
    /// host was between blocks (no sample owed, nothing lost), e.g. during
    /// the computations between calibration runs. Off: the trip is reported
    /// as an error and the rig stays faulted until `start`.
    pub rearm_after_idle_trip: bool,
    /// How far ahead of the samples it waits for the host sends commands
    /// ([`CommandLead`]). [`SerialConfig::new`] is block-synchronous
    /// (`Blocks(0)`: each block's sensor frames are those of its own
    /// commands, the [`crate::Rig`] contract); a `--rig serial:…`
    /// specification leads automatically unless it says `lead=N`.
    pub lead: CommandLead,
    /// The host watchdog's least rate, as a fraction of the device's
    /// nominal rate ([`super::watch`]; `min-rate=PERCENT` in the spec; 0
    /// turns the rate check off, e.g. for the firmware under QEMU, whose
    /// clock is not real time).
    pub min_rate_fraction: f64,
}

use super::lead::Pipeline;
pub use super::lead::{CommandLead, MAX_LEAD_SAMPLES};

/// How far past the block being waited for a device's sample may lie and
/// still be one of the stream's (kept for the next block): the largest
/// command lead plus one frame's items. Beyond it a sample number is stray.
const MAX_AHEAD_SAMPLES: u64 = MAX_LEAD_SAMPLES + 256;

/// Round trips timed at connection (HELLO request → HELLO).
const RTT_PROBES: usize = 4;

impl SerialConfig {
    /// Default baud rate.
    pub const DEFAULT_BAUD: u32 = 2_000_000;
    /// Default stall timeout.
    pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(100);

    /// Defaults for the port `path`.
    pub fn new(path: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            baud: Self::DEFAULT_BAUD,
            timeout: Self::DEFAULT_TIMEOUT,
            handshake_timeout: Duration::from_secs(2),
            rearm_after_idle_trip: false,
            lead: CommandLead::Blocks(0),
            min_rate_fraction: super::watch::MIN_RATE_FRACTION,
        }
    }
}

/// Counters of a link (cumulative over reconnects).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Valid device frames decoded.
    pub frames: u64,
    /// Samples received.
    pub samples: u64,
    /// Samples lost (placeholders).
    pub lost: u64,
    /// Candidate frames with a bad CRC.
    pub crc_errors: u64,
    /// Headers with an impossible length.
    pub bad_lengths: u64,
    /// Bytes skipped while resynchronising.
    pub bytes_skipped: u64,
    /// Samples the device executed with a held (late) command.
    pub late_commands: u64,
    /// Samples the device flagged as run with its watchdog's safe outputs.
    pub watchdog_samples: u64,
    /// FAULT frames received.
    pub device_faults: u64,
    /// Samples whose numbers fit no block: further ahead than any command
    /// lead lets a device run (ignored). Samples of later blocks in a frame
    /// that crosses a block boundary are kept for them, not stray.
    pub stray_samples: u64,
}

/// How an exchange ended badly.
#[derive(Debug)]
pub(crate) enum LinkErr {
    /// The sample stream stalled (no progress, too slow, or past the
    /// caller's deadline).
    Stalled(Stall),
    /// I/O error or end of file.
    Io(std::io::Error),
    /// The device tripped: its watchdog or its emergency stop zeroed the
    /// outputs (or it rejected commands as idle).
    Tripped {
        seq: u64,
        /// Samples of the block received before.
        received: bool,
        /// What tripped it.
        cause: Trip,
    },
}

/// What tripped a device, from the FAULT frame that reported it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Trip {
    /// FAULT `WATCHDOG` (or `NOT_RUNNING`: it stopped without the host).
    Watchdog,
    /// FAULT `ESTOP`: the emergency-stop input was engaged.
    EmergencyStop,
    /// STATUS `tripped` without a FAULT naming the cause (it was lost).
    Unknown,
}

impl LinkErr {
    /// The kind of failure, as a tweezer or an engine reports it.
    pub(crate) fn kind(&self) -> LinkErrorKind {
        match self {
            LinkErr::Tripped {
                cause: Trip::EmergencyStop,
                ..
            } => LinkErrorKind::EmergencyStop,
            LinkErr::Tripped { .. } => LinkErrorKind::Watchdog,
            LinkErr::Stalled(_) | LinkErr::Io(_) => LinkErrorKind::Disconnected,
        }
    }
}

/// A `wait_for` filter taking the frames of type `t`.
fn is(t: u8) -> impl Fn(u8, &[u8]) -> bool {
    move |ty, _| ty == t
}

/// Outcome of one exchange.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Exchange {
    /// Samples of the block lost.
    pub lost: u32,
    /// The first of them.
    pub first_lost: Option<u64>,
}

/// The host end of a serial link: port, decoder, handshake, sequence
/// tracking. Shared by [`SerialRig`] and
/// [`super::tweezer_link::LinkTweezer`].
pub struct Link {
    cfg: SerialConfig,
    /// `None` only while reopening.
    port: Option<Box<dyn SerialPort>>,
    decoder: Decoder,
    rx: Box<[u8]>,
    pub(crate) tx: Vec<u8>,
    hello: Hello,
    stats: LinkStats,
    decoder_base: frame::DecoderStats,
    rate: RateWindow,
    deadline: Option<Instant>,
    round_trip: Option<Duration>,
    /// A sample frame whose tail lies past the block last waited for (a
    /// device with commands ahead — the command lead — whose frames do not
    /// line up with the host's blocks): its payload, and the index of the
    /// first item not yet taken. The next exchange takes them first.
    carry: Carry,
}

/// See [`Link::carry`]: at most one frame's payload
/// ([`frame::MAX_PAYLOAD`] bytes, allocated once).
#[derive(Debug)]
struct Carry {
    ty: u8,
    payload: Vec<u8>,
    from: usize,
}

impl Carry {
    fn new() -> Self {
        Self {
            ty: 0,
            payload: Vec::with_capacity(frame::MAX_PAYLOAD),
            from: 0,
        }
    }

    fn clear(&mut self) {
        self.payload.clear();
        self.from = 0;
    }

    /// Keep `payload` from item `from` on (no allocation: it fits the
    /// capacity reserved).
    fn keep(&mut self, ty: u8, payload: &[u8], from: usize) {
        self.ty = ty;
        self.payload.clear();
        self.payload.extend_from_slice(payload);
        self.from = from;
    }
}

impl std::fmt::Debug for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Link")
            .field("path", &self.cfg.path)
            .field("hello", &self.hello)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

fn open_port(cfg: &SerialConfig) -> Result<Box<dyn SerialPort>, RigError> {
    let port = serialport::new(&cfg.path, cfg.baud)
        .timeout(Duration::from_millis(10))
        .open()
        .map_err(|e| {
            RigError::Disconnected(format!("cannot open serial port {}: {e}", cfg.path))
        })?;
    Ok(port)
}

impl Link {
    /// Open the port, handshake and check that the device is of `kind`.
    pub fn open(cfg: &SerialConfig, kind: DeviceKind) -> Result<Self, RigError> {
        let port = open_port(cfg)?;
        let mut link = Self {
            cfg: cfg.clone(),
            port: Some(port),
            decoder: Decoder::new(),
            rx: vec![0u8; frame::MAX_FRAME].into_boxed_slice(),
            tx: Vec::with_capacity(1 << 16),
            hello: Hello {
                version: 0,
                sample_rate_hz: 0,
                watchdog_ms: 0,
                batch: 0,
                caps: Caps::Tweezer(frame::TweezerCaps {
                    stiffness_n_per_m: 0.0,
                }),
                name: String::new(),
                serial: String::new(),
                firmware: String::new(),
            },
            stats: LinkStats::default(),
            decoder_base: frame::DecoderStats::default(),
            rate: RateWindow::default(),
            deadline: None,
            round_trip: None,
            carry: Carry::new(),
        };
        link.handshake(kind)?;
        link.measure_round_trip();
        Ok(link)
    }

    /// Reopen the port (after a disconnect) and handshake again.
    pub fn reopen(&mut self, kind: DeviceKind) -> Result<(), RigError> {
        // Close first: the port is opened with an exclusive lock.
        self.port = None;
        self.port = Some(open_port(&self.cfg)?);
        self.decoder_base = self.decoder_stats_total();
        self.decoder = Decoder::new();
        self.carry.clear();
        self.handshake(kind)?;
        self.measure_round_trip();
        Ok(())
    }

    /// Time [`RTT_PROBES`] HELLO request → HELLO round trips and keep the
    /// longest (a device answers HELLO at once, and a HELLO is about as
    /// long as a SAMPLES frame): the link's round trip, which sizes the
    /// automatic command lead. A probe without an answer within 250 ms is
    /// not counted.
    fn measure_round_trip(&mut self) {
        let mut worst: Option<Duration> = None;
        let mut buf = [0u8; frame::MAX_PAYLOAD];
        for _ in 0..RTT_PROBES {
            frame::write_frame(&mut self.tx, frame::ty::HELLO_REQ, |o| {
                o.extend_from_slice(&PROTOCOL_VERSION.to_le_bytes())
            });
            let t0 = Instant::now();
            if self.flush_tx().is_err() {
                break;
            }
            let deadline = t0 + Duration::from_millis(250);
            if self
                .wait_for(frame::ty::HELLO, is(frame::ty::HELLO), &mut buf, deadline)
                .is_ok()
            {
                let rtt = t0.elapsed();
                worst = Some(worst.map_or(rtt, |w| w.max(rtt)));
            }
        }
        self.round_trip = worst;
    }

    /// The link's round trip measured at connection (the longest of
    /// [`RTT_PROBES`]).
    pub fn round_trip(&self) -> Option<Duration> {
        self.round_trip
    }

    /// Settings.
    pub fn config(&self) -> &SerialConfig {
        &self.cfg
    }

    /// The device's handshake answer.
    pub fn hello(&self) -> &Hello {
        &self.hello
    }

    fn decoder_stats_total(&self) -> frame::DecoderStats {
        let d = self.decoder.stats();
        let b = self.decoder_base;
        frame::DecoderStats {
            frames: b.frames + d.frames,
            crc_errors: b.crc_errors + d.crc_errors,
            bad_lengths: b.bad_lengths + d.bad_lengths,
            bytes_skipped: b.bytes_skipped + d.bytes_skipped,
        }
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        let d = self.decoder_stats_total();
        LinkStats {
            frames: d.frames,
            crc_errors: d.crc_errors,
            bad_lengths: d.bad_lengths,
            bytes_skipped: d.bytes_skipped + self.stats.bytes_skipped,
            ..self.stats
        }
    }

    fn disconnected(&self, why: &str) -> RigError {
        RigError::Disconnected(format!("{}: {why}", self.cfg.path))
    }

    /// The error of a failed exchange, naming the port and what happened.
    pub(crate) fn map_err(&self, e: &LinkErr) -> RigError {
        match e {
            LinkErr::Stalled(why) => {
                self.disconnected(&format!("{why}; outputs commanded to zero"))
            }
            LinkErr::Io(e) => self.disconnected(&format!("the device vanished ({e})")),
            LinkErr::Tripped {
                seq,
                cause: Trip::Watchdog,
                ..
            } => RigError::Device(format!(
                "{}: the device watchdog tripped at sample {seq} (no host frame within {} ms); \
                 outputs are zero, call start() to resume",
                self.cfg.path, self.hello.watchdog_ms
            )),
            LinkErr::Tripped {
                seq,
                cause: Trip::EmergencyStop,
                ..
            } => RigError::Device(format!(
                "{}: the emergency stop was engaged at sample {seq}; outputs are zero, \
                 release the emergency stop, then call start() to resume",
                self.cfg.path
            )),
            LinkErr::Tripped {
                seq,
                cause: Trip::Unknown,
                ..
            } => RigError::Device(format!(
                "{}: the device tripped at sample {seq} (its watchdog or its emergency stop; \
                 the FAULT frame naming which was lost); outputs are zero, call start() to resume",
                self.cfg.path
            )),
        }
    }

    /// Send the bytes in `tx` and clear it.
    pub(crate) fn flush_tx(&mut self) -> Result<(), RigError> {
        let Some(port) = self.port.as_mut() else {
            self.tx.clear();
            return Err(self.disconnected("the port is closed"));
        };
        let _ = port.set_timeout(self.cfg.timeout.max(Duration::from_millis(10)));
        let r = port.write_all(&self.tx);
        self.tx.clear();
        r.map_err(|e| self.disconnected(&format!("write failed, the device vanished ({e})")))
    }

    /// Read whatever arrives within `wait` into the decoder. `Ok(false)`:
    /// nothing arrived.
    fn read_some(&mut self, wait: Duration) -> Result<bool, LinkErr> {
        let Some(port) = self.port.as_mut() else {
            return Err(LinkErr::Io(std::io::Error::new(
                ErrorKind::NotConnected,
                "the port is closed",
            )));
        };
        let _ = port.set_timeout(wait);
        match port.read(&mut self.rx) {
            Ok(0) => Err(LinkErr::Io(std::io::Error::new(
                ErrorKind::UnexpectedEof,
                "end of file on the port",
            ))),
            Ok(n) => {
                // At most MAX_FRAME bytes are read, and the decoder always
                // has room for that once next_frame has returned None.
                let taken = self.decoder.push(&self.rx[..n]);
                self.stats.bytes_skipped += (n - taken) as u64;
                Ok(true)
            }
            Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => Ok(false),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(false),
            Err(e) => Err(LinkErr::Io(e)),
        }
    }

    /// Wait for the first frame that `accept(type, payload)` takes (others
    /// skipped) and return its type and its payload copied into `out`
    /// (length); `want` is the frame type asked for (START's STATUS makes a
    /// FAULT `ESTOP` a refusal).
    fn wait_for(
        &mut self,
        want: u8,
        accept: impl Fn(u8, &[u8]) -> bool,
        out: &mut [u8; frame::MAX_PAYLOAD],
        deadline: Instant,
    ) -> Result<(u8, usize), RigError> {
        let corrupted_before = self.decoder.stats().crc_errors + self.decoder.stats().bad_lengths;
        loop {
            while let Some(f) = self.decoder.next_frame() {
                if accept(f.ty, f.payload) {
                    let n = f.payload.len();
                    out[..n].copy_from_slice(f.payload);
                    return Ok((f.ty, n));
                }
                if f.ty == frame::ty::FAULT
                    && let Some(fr) = frame::parse_fault(f.payload)
                {
                    if fr.code == fault::VERSION {
                        return Err(RigError::Device(format!(
                            "{}: the device does not speak protocol version {PROTOCOL_VERSION}",
                            self.cfg.path
                        )));
                    }
                    // START refused: the device stays tripped.
                    if fr.code == fault::ESTOP && want == frame::ty::STATUS {
                        return Err(RigError::Device(format!(
                            "{}: the device refuses to start: its emergency stop is engaged \
                             (release it, then start again)",
                            self.cfg.path
                        )));
                    }
                }
            }
            let now = Instant::now();
            if now >= deadline {
                let d = self.decoder.stats();
                let corrupted = d.crc_errors + d.bad_lengths - corrupted_before;
                return Err(self.disconnected(&if corrupted > 0 {
                    format!(
                        "no valid answer from the device within {} ms: {corrupted} corrupted \
                         frame(s) arrived instead (check the cable, the baud rate and \
                         interference)",
                        self.cfg.handshake_timeout.as_millis()
                    )
                } else {
                    format!(
                        "no answer from the device within {} ms (is it a kilotouch device, and \
                         is the emulator running?)",
                        self.cfg.handshake_timeout.as_millis()
                    )
                }));
            }
            self.read_some((deadline - now).min(Duration::from_millis(50)))
                .map_err(|e| self.map_err(&e))?;
        }
    }

    fn handshake(&mut self, kind: DeviceKind) -> Result<(), RigError> {
        if let Some(p) = self.port.as_mut() {
            let _ = p.clear(ClearBuffer::Input);
        }
        self.decoder.clear();
        let deadline = Instant::now() + self.cfg.handshake_timeout;
        let mut buf = [0u8; frame::MAX_PAYLOAD];
        let hello = loop {
            frame::write_frame(&mut self.tx, frame::ty::HELLO_REQ, |o| {
                o.extend_from_slice(&PROTOCOL_VERSION.to_le_bytes())
            });
            self.flush_tx()?;
            let step = (Instant::now() + Duration::from_millis(250)).min(deadline);
            match self.wait_for(frame::ty::HELLO, is(frame::ty::HELLO), &mut buf, step) {
                Ok((_, n)) => match frame::parse_hello(&buf[..n]) {
                    Some(h) => break h,
                    None => {
                        return Err(RigError::Device(format!(
                            "{}: malformed HELLO from the device",
                            self.cfg.path
                        )));
                    }
                },
                Err(RigError::Disconnected(_)) if Instant::now() < deadline => continue,
                Err(e) => return Err(e),
            }
        };
        if hello.version != PROTOCOL_VERSION {
            return Err(RigError::Device(format!(
                "{}: device speaks protocol version {}, this host {PROTOCOL_VERSION}",
                self.cfg.path, hello.version
            )));
        }
        if hello.kind() != kind {
            return Err(RigError::Device(format!(
                "{}: expected a {kind:?} device, found a {:?} (`{}`)",
                self.cfg.path,
                hello.kind(),
                hello.name
            )));
        }
        super::announce::check_hello(&self.cfg.path, &hello)?;
        self.hello = Hello {
            name: crate::text::printable(&hello.name, 64),
            serial: crate::text::printable(&hello.serial, 64),
            firmware: crate::text::printable(&hello.firmware, 64),
            ..hello
        };
        Ok(())
    }

    /// A hard time bound for every exchange (e.g. the end of `rig check
    /// --duration`): past it, waiting for samples ends as a stall.
    pub fn set_deadline(&mut self, deadline: Option<Instant>) {
        self.deadline = deadline;
    }

    /// Send START and wait for the device to run; returns the device's next
    /// sequence number.
    pub fn start(&mut self) -> Result<u64, RigError> {
        frame::write_frame(&mut self.tx, frame::ty::START, |_| {});
        self.flush_tx()?;
        let deadline = Instant::now() + self.cfg.handshake_timeout;
        self.await_running(deadline)
    }

    /// Wait for the device's STATUS `running` (the answer to START);
    /// returns its next sequence number.
    fn await_running(&mut self, deadline: Instant) -> Result<u64, RigError> {
        let mut buf = [0u8; frame::MAX_PAYLOAD];
        let running = |t: u8, p: &[u8]| {
            t == frame::ty::STATUS
                && frame::parse_status(p).is_some_and(|s| s.state == DeviceState::Running)
        };
        let (_, n) = self.wait_for(frame::ty::STATUS, running, &mut buf, deadline)?;
        let st = frame::parse_status(&buf[..n])
            .ok_or_else(|| RigError::Device("malformed STATUS".into()))?;
        self.rate.reset();
        self.carry.clear();
        Ok(u64::from(st.next_seq))
    }

    /// Begin a new run of a running device: STOP, the frames `between`
    /// queues (e.g. a RESET), START; returns the new run's first sample.
    /// Frames of the old run still in flight are told apart by the STATUS
    /// `idle` that answers the STOP: only the STATUS `running` after it
    /// starts the new run.
    pub fn restart(&mut self, between: impl FnOnce(&mut Vec<u8>)) -> Result<u64, RigError> {
        self.tx.clear();
        frame::write_frame(&mut self.tx, frame::ty::STOP, |_| {});
        between(&mut self.tx);
        frame::write_frame(&mut self.tx, frame::ty::START, |_| {});
        self.flush_tx()?;
        let deadline = Instant::now() + self.cfg.handshake_timeout;
        let mut buf = [0u8; frame::MAX_PAYLOAD];
        let idle = |t: u8, p: &[u8]| {
            t == frame::ty::STATUS
                && frame::parse_status(p).is_some_and(|s| s.state != DeviceState::Running)
        };
        self.wait_for(frame::ty::STATUS, idle, &mut buf, deadline)?;
        self.await_running(deadline)
    }

    /// Ask the device with a frame of type `req` (no payload) for a frame
    /// of type `want`: its payload copied into `out` (length), or `None`
    /// when the device answers FAULT `BAD_FRAME` (it does not know the
    /// request). Waits up to the handshake time-out.
    pub fn query(
        &mut self,
        req: u8,
        want: u8,
        out: &mut [u8; frame::MAX_PAYLOAD],
    ) -> Result<Option<usize>, RigError> {
        frame::write_frame(&mut self.tx, req, |_| {});
        self.flush_tx()?;
        let deadline = Instant::now() + self.cfg.handshake_timeout;
        let refused = |t: u8, p: &[u8]| {
            t == frame::ty::FAULT
                && frame::parse_fault(p).is_some_and(|f| f.code == fault::BAD_FRAME)
        };
        let (t, n) = self.wait_for(want, |t, p| t == want || refused(t, p), out, deadline)?;
        Ok((t == want).then_some(n))
    }

    /// Send STOP (best effort: errors ignored, short timeout).
    pub fn stop(&mut self) {
        self.tx.clear();
        frame::write_frame(&mut self.tx, frame::ty::STOP, |_| {});
        if let Some(p) = self.port.as_mut() {
            let _ = p.set_timeout(Duration::from_millis(20));
            let _ = p.write_all(&self.tx);
        }
        self.tx.clear();
    }

    /// Wait until samples `first .. first + n` (frame type `sample_ty`) are
    /// accounted for; `sink(i, Some(sample))` for each received sample,
    /// `sink(i, None)` for each lost one, in order of i.
    pub(crate) fn exchange<S: WireItem>(
        &mut self,
        sample_ty: u8,
        first: u64,
        n: usize,
        sink: impl FnMut(usize, Option<&S>),
    ) -> Result<Exchange, LinkErr> {
        let mut block = Block::new(first, n, sink);
        let mut clock = StallClock::new();
        let crc_base = self.decoder.stats().crc_errors;
        let rate_hz = self.hello.sample_rate_hz;
        let Self {
            decoder,
            stats,
            cfg,
            port,
            rx,
            rate,
            deadline,
            carry,
            ..
        } = self;
        // What the previous exchange kept: samples of this block first.
        if !carry.payload.is_empty() {
            if carry.ty == sample_ty {
                match block.take(&carry.payload, carry.from, stats) {
                    Some(i) => carry.from = i,
                    None => carry.clear(),
                }
            } else {
                carry.clear();
            }
        }
        loop {
            let before = block.expected;
            while block.expected < block.end {
                let Some(f) = decoder.next_frame() else {
                    break;
                };
                block.on_frame(f.ty, f.payload, sample_ty, stats, carry)?;
            }
            block.seen.crc_errors = decoder.stats().crc_errors - crc_base;
            let progressed = block.expected > before;
            let Some(wait) = clock.next_wait(&block, progressed, rate, cfg, rate_hz, *deadline)?
            else {
                return Ok(block.ex);
            };
            read_into(port, rx, decoder, stats, wait)?;
        }
    }
}

/// The block one [`Link::exchange`] fills: samples `first .. end`, those
/// accounted for so far (below `expected`, received or lost, each passed to
/// the sink once, in order), and what the device sent meanwhile.
struct Block<S, F> {
    first: u64,
    end: u64,
    expected: u64,
    ex: Exchange,
    seen: Activity,
    sink: F,
    item: std::marker::PhantomData<fn(&S)>,
}

impl<S: WireItem, F: FnMut(usize, Option<&S>)> Block<S, F> {
    fn new(first: u64, n: usize, sink: F) -> Self {
        Self {
            first,
            end: first + n as u64,
            expected: first,
            ex: Exchange::default(),
            seen: Activity::default(),
            sink,
            item: std::marker::PhantomData,
        }
    }

    /// Samples `expected .. to` lost (none when `to` ≤ `expected`).
    fn lose_until(&mut self, to: u64, stats: &mut LinkStats) {
        let from = self.expected;
        for q in from..to {
            (self.sink)((q - self.first) as usize, None);
        }
        if to > from {
            self.ex.lost += (to - from) as u32;
            self.ex.first_lost.get_or_insert(from);
            stats.lost += to - from;
            self.expected = to;
        }
    }

    /// The items of a sample frame from index `from` on: those of this
    /// block go to the sink (gaps before them lost); returns the index of
    /// the first item past the block, if any (kept for the next exchange).
    fn take(&mut self, payload: &[u8], from: usize, stats: &mut LinkStats) -> Option<usize> {
        let (seq32, cnt) = frame::block_header::<S>(payload)?;
        let base = frame::unwrap_seq(seq32, self.expected);
        for i in from..cnt {
            let q = base + i as u64;
            if q < self.expected {
                self.seen.stray_samples += 1;
                continue;
            }
            if q >= self.end + MAX_AHEAD_SAMPLES {
                // Further ahead than any command lead lets a device run:
                // not a sample of this stream.
                self.seen.stray_samples += 1;
                stats.stray_samples += 1;
                continue;
            }
            if q >= self.end {
                // Frames arrive in order: what this block still lacks was
                // lost.
                self.lose_until(self.end, stats);
                return Some(i);
            }
            self.lose_until(q, stats);
            let s = frame::block_item::<S>(payload, i);
            (self.sink)((q - self.first) as usize, Some(&s));
            stats.samples += 1;
            self.seen.new_samples += 1;
            self.expected = q + 1;
        }
        None
    }

    /// One decoded frame: samples, a STATUS (samples the device reports
    /// sent but the host never saw are lost; a tripped device ends the
    /// exchange), a FAULT (a trip ends it), or a frame not expected here.
    fn on_frame(
        &mut self,
        ty: u8,
        payload: &[u8],
        sample_ty: u8,
        stats: &mut LinkStats,
        carry: &mut Carry,
    ) -> Result<(), LinkErr> {
        self.seen.frames += 1;
        match ty {
            t if t == sample_ty => {
                if frame::block_header::<S>(payload).is_none() {
                    self.seen.unknown += 1;
                } else if let Some(i) = self.take(payload, 0, stats) {
                    // The frame's tail belongs to later blocks.
                    carry.keep(t, payload, i);
                }
            }
            frame::ty::STATUS => {
                self.seen.status += 1;
                let Some(st) = frame::parse_status(payload) else {
                    return Ok(());
                };
                let next = frame::unwrap_seq(st.next_seq, self.expected);
                match st.state {
                    DeviceState::Running if next > self.expected => {
                        self.lose_until(next.min(self.end), stats);
                    }
                    DeviceState::Tripped if next >= self.expected => {
                        return Err(LinkErr::Tripped {
                            seq: next,
                            received: self.expected > self.first,
                            cause: Trip::Unknown,
                        });
                    }
                    _ => {}
                }
            }
            frame::ty::FAULT => {
                self.seen.faults += 1;
                stats.device_faults += 1;
                if let Some((seq, cause)) = trip_fault(payload, self.expected) {
                    return Err(LinkErr::Tripped {
                        seq,
                        received: self.expected > self.first,
                        cause,
                    });
                }
            }
            _ => self.seen.unknown += 1,
        }
        Ok(())
    }
}

/// The time side of one exchange: when the stream last advanced, the rate
/// window's last tick, and whether the one grace look past the timeout
/// was used; the device's activity at the last progress and tick.
struct StallClock {
    last_progress: Instant,
    last_tick: Instant,
    grace_used: bool,
    at_progress: Activity,
    at_tick: Activity,
}

impl StallClock {
    fn new() -> Self {
        let now = Instant::now();
        Self {
            last_progress: now,
            last_tick: now,
            grace_used: false,
            at_progress: Activity::default(),
            at_tick: Activity::default(),
        }
    }

    /// After draining the decoder: `None` when the block is complete,
    /// otherwise how long to wait for the device, or the stall (too slow
    /// over the rate window, past `deadline`, or no progress for the
    /// timeout plus one grace look: the host itself may have been
    /// descheduled while the device's frames were arriving).
    fn next_wait<S, F>(
        &mut self,
        block: &Block<S, F>,
        progressed: bool,
        rate: &mut RateWindow,
        cfg: &SerialConfig,
        rate_hz: u32,
        deadline: Option<Instant>,
    ) -> Result<Option<Duration>, LinkErr> {
        let now = Instant::now();
        let seen = block.seen;
        if progressed {
            self.last_progress = now;
            self.at_progress = seen;
        }
        // The rate check on the time spent waiting for the device.
        rate.add(
            now - self.last_tick,
            &seen.since(&self.at_tick),
            rate_hz,
            cfg.min_rate_fraction,
        )
        .map_err(LinkErr::Stalled)?;
        (self.last_tick, self.at_tick) = (now, seen);
        if block.expected >= block.end {
            return Ok(None);
        }
        if deadline.is_some_and(|d| now >= d) {
            return Err(LinkErr::Stalled(Stall::Deadline {
                activity: seen.since(&self.at_progress),
            }));
        }
        let idle = now - self.last_progress;
        let wait = if idle >= cfg.timeout {
            if self.grace_used {
                return Err(LinkErr::Stalled(Stall::NoProgress {
                    waited_ms: u64::try_from(idle.as_millis()).unwrap_or(u64::MAX),
                    expected_seq: block.expected,
                    activity: seen.since(&self.at_progress),
                }));
            }
            self.grace_used = true;
            Duration::from_millis(1)
        } else {
            self.grace_used = false;
            (cfg.timeout - idle).min(Duration::from_millis(20))
        };
        Ok(Some(match deadline {
            Some(d) => wait
                .min(d.saturating_duration_since(now))
                .max(Duration::from_millis(1)),
            None => wait,
        }))
    }
}

/// The sequence number and cause of a FAULT frame that means the device
/// stopped: its watchdog or its emergency stop tripped it at or after
/// `expected`, or it is not running.
fn trip_fault(payload: &[u8], expected: u64) -> Option<(u64, Trip)> {
    let fr = frame::parse_fault(payload)?;
    let seq = frame::unwrap_seq(fr.seq, expected);
    match fr.code {
        fault::WATCHDOG if seq >= expected => Some((seq, Trip::Watchdog)),
        fault::ESTOP if seq >= expected => Some((seq, Trip::EmergencyStop)),
        fault::NOT_RUNNING => Some((seq, Trip::Watchdog)),
        _ => None,
    }
}

/// Wait up to `wait` for bytes on the port and feed them to the decoder
/// (counting the bytes it skips). A time-out is not an error; end of file
/// and I/O errors are.
fn read_into(
    port: &mut Option<Box<dyn SerialPort>>,
    rx: &mut [u8],
    decoder: &mut Decoder,
    stats: &mut LinkStats,
    wait: Duration,
) -> Result<(), LinkErr> {
    let Some(port) = port.as_mut() else {
        return Err(LinkErr::Io(std::io::Error::new(
            ErrorKind::NotConnected,
            "the port is closed",
        )));
    };
    let _ = port.set_timeout(wait);
    match port.read(rx) {
        Ok(0) => Err(LinkErr::Io(std::io::Error::new(
            ErrorKind::UnexpectedEof,
            "end of file on the port",
        ))),
        Ok(k) => {
            // rx holds MAX_FRAME bytes, which always fit (module docs).
            let taken = decoder.push(&rx[..k]);
            stats.bytes_skipped += (k - taken) as u64;
            Ok(())
        }
        Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => Ok(()),
        Err(e) if e.kind() == ErrorKind::Interrupted => Ok(()),
        Err(e) => Err(LinkErr::Io(e)),
    }
}

impl Link {
    /// The command lead, samples, for blocks of `n` samples of this link
    /// ([`super::lead::lead_samples`] with its `lead`, the device's rate and
    /// the round trip measured at connection).
    pub fn lead_samples(&self, n: usize) -> u64 {
        super::lead::lead_samples(
            self.cfg.lead,
            f64::from(self.hello.sample_rate_hz),
            self.round_trip.map(|d| d.as_secs_f64()),
            n,
        )
    }

    /// Queue (in the transmit buffer, sent by the next flush) the commands
    /// of samples `first .. first + n` as block frames of type `ty` of at
    /// most `per_frame` items (and at most what fits a frame): item `i` is
    /// `item(i)`. Allocates nothing once the transmit buffer has grown to a
    /// block's frames.
    pub(crate) fn queue_items<C: WireItem>(
        &mut self,
        ty: u8,
        first: u64,
        n: usize,
        per_frame: usize,
        mut item: impl FnMut(usize) -> C,
    ) {
        let per = per_frame.clamp(1, frame::max_items::<C>());
        let mut i = 0;
        while i < n {
            let k = (n - i).min(per);
            let seq = (first + i as u64) as u32;
            frame::write_frame(&mut self.tx, ty, |o| {
                o.extend_from_slice(&seq.to_le_bytes());
                o.push(k as u8);
                for j in i..i + k {
                    frame::put_item(o, &item(j));
                }
            });
            i += k;
        }
    }
}

pub use crate::device::LinkErrorKind;

/// A DAQ on a serial link as a [`Rig`] (module docs).
#[derive(Debug)]
pub struct SerialRig {
    link: Link,
    identity: RigIdentity,
    caps: DaqCaps,
    state: RigState,
    counters: StatusCounters,
    last: SensorFrame,
    /// Samples waited for, commands sent, the run's lead.
    pipe: Pipeline,
    /// Host-side flags of the commands sent, by sequence number modulo its
    /// length (the sensor frame of a sample carries its command's flags).
    cmd_flags: Box<[u8]>,
}

/// Commands whose host-side flags are remembered (≥ lead + block).
const CMD_FLAG_RING: usize = 4096;

impl SerialRig {
    /// Exchange block `s .. s + n`: each received sample decoded into
    /// `sensors` (encoder counts → m, accelerometer codes → m/s², the
    /// host's flags with the command's own), each lost one as the last
    /// received frame flagged LOST; late commands counted as overruns.
    fn exchange_block(
        &mut self,
        s: u64,
        n: usize,
        sensors: &mut [SensorFrame],
    ) -> Result<Exchange, LinkErr> {
        let caps = self.caps;
        let last = &mut self.last;
        let cmd_flags = &self.cmd_flags;
        let mut late = 0u64;
        let mut watchdog = 0u64;
        let r = self
            .link
            .exchange::<DaqSample>(frame::ty::SAMPLES, s, n, |i, smp| {
                let seq = s + i as u64;
                let local = cmd_flags[(seq % CMD_FLAG_RING as u64) as usize];
                sensors[i] = match smp {
                    Some(d) => {
                        if d.flags & flag::CMD_LATE != 0 {
                            late += 1;
                        }
                        if d.flags & flag::WATCHDOG != 0 {
                            watchdog += 1;
                        }
                        let f = SensorFrame {
                            seq,
                            handle_m: d.enc.map(|e| f64::from(e) / caps.encoder_counts_per_m),
                            accel_m_s2: d.acc.map(|a| f64::from(a) * caps.accel_m_s2_per_code),
                            flags: FrameFlags((d.flags & flag::HOST_MASK) | local),
                        };
                        *last = f;
                        f
                    }
                    None => SensorFrame {
                        seq,
                        flags: FrameFlags(FrameFlags::LOST | local),
                        ..*last
                    },
                };
            });
        self.link.stats.late_commands += late;
        self.link.stats.watchdog_samples += watchdog;
        self.counters.counts.late_commands += late;
        if late > 0 {
            self.counters.push(RigFault::Overrun {
                seq: s,
                skipped: late,
            });
        }
        r
    }

    /// Refuses a block on a disconnected or tripped device (an idle one is
    /// refused by `open_block`).
    fn ready(&self) -> Result<(), RigError> {
        match self.state {
            RigState::Disconnected => Err(RigError::Disconnected(format!(
                "{}: call reconnect() first",
                self.link.config().path
            ))),
            RigState::Faulted => Err(RigError::NotReady(
                "the device tripped (its watchdog or its emergency stop): call start() to resume"
                    .into(),
            )),
            // Idle refuses in `open_block`.
            RigState::Idle | RigState::Running => Ok(()),
        }
    }

    /// Commands per COMMANDS frame.
    pub const FRAME_COMMANDS: usize = 32;

    /// Open the port and handshake with a DAQ.
    pub fn open(cfg: &SerialConfig) -> Result<Self, RigError> {
        let link = Link::open(cfg, DeviceKind::Daq)?;
        let (identity, caps) = Self::identity_of(&link)?;
        Ok(Self {
            link,
            identity,
            caps,
            state: RigState::Idle,
            counters: StatusCounters::default(),
            last: SensorFrame::default(),
            pipe: Pipeline::default(),
            cmd_flags: vec![0u8; CMD_FLAG_RING].into_boxed_slice(),
        })
    }

    /// The command lead, samples, for blocks of `n` samples
    /// ([`CommandLead`], [`Link::lead_samples`]).
    pub fn lead_samples(&self, n: usize) -> u64 {
        self.link.lead_samples(n)
    }

    /// Queue zero commands for samples `s .. s + n` (the lead's first
    /// blocks).
    fn queue_zeros(&mut self, s: u64, n: u64) {
        for q in s..s + n {
            self.cmd_flags[(q % CMD_FLAG_RING as u64) as usize] = 0;
        }
        self.link.queue_items(
            frame::ty::COMMANDS,
            s,
            n as usize,
            Self::FRAME_COMMANDS,
            |_| DaqCommand::default(),
        );
    }

    fn identity_of(link: &Link) -> Result<(RigIdentity, DaqCaps), RigError> {
        let h = link.hello();
        // Every value was checked when the HELLO was accepted (`handshake`).
        let Caps::Daq(caps) = h.caps else {
            return Err(RigError::Device("not a DAQ".into()));
        };
        Ok((
            RigIdentity {
                kind: RigKind::SerialDaq,
                name: h.name.clone(),
                serial: h.serial.clone(),
                firmware: h.firmware.clone(),
                sample_rate_hz: f64::from(h.sample_rate_hz),
                force_max_n: caps.force_max_n,
                haptuator_max_v: caps.drive_max_v,
                accel_range_m_s2: caps.accel_range_m_s2,
            },
            caps,
        ))
    }

    /// Reopen the port after a disconnect (same path) and handshake; the
    /// rig is then idle (`start` to resume).
    pub fn reconnect(&mut self) -> Result<(), RigError> {
        self.link.reopen(DeviceKind::Daq)?;
        let (identity, caps) = Self::identity_of(&self.link)?;
        self.identity = identity;
        self.caps = caps;
        self.state = RigState::Idle;
        Ok(())
    }

    /// A hard time bound for every block ([`Link::set_deadline`]): past
    /// it, `process_block` ends as a stall (outputs commanded to zero).
    pub fn set_deadline(&mut self, deadline: Option<Instant>) {
        self.link.set_deadline(deadline);
    }

    /// Link counters.
    pub fn link_stats(&self) -> LinkStats {
        self.link.stats()
    }

    /// The device's handshake answer.
    pub fn hello(&self) -> &Hello {
        self.link.hello()
    }

    /// Device capabilities.
    pub fn caps(&self) -> DaqCaps {
        self.caps
    }

    /// Queue the commands of a block for samples from `s` on.
    fn queue_commands(&mut self, s: u64, commands: &[ActuatorFrame]) {
        let c = self.caps;
        for (i, a) in commands.iter().enumerate() {
            self.cmd_flags[((s + i as u64) % CMD_FLAG_RING as u64) as usize] = command_flags(a, &c);
        }
        self.link.queue_items(
            frame::ty::COMMANDS,
            s,
            commands.len(),
            Self::FRAME_COMMANDS,
            |i| {
                let a = &commands[i];
                DaqCommand {
                    force: [
                        value_to_code(a.force_n[0], c.force_max_n).0,
                        value_to_code(a.force_n[1], c.force_max_n).0,
                    ],
                    drive: value_to_code(a.haptuator_v, c.drive_max_v).0,
                }
            },
        );
    }

    fn fail(&mut self, e: LinkErr) -> RigError {
        match e {
            LinkErr::Tripped { seq, cause, .. } => {
                self.state = RigState::Faulted;
                self.counters.push(match cause {
                    Trip::EmergencyStop => RigFault::EmergencyStop { seq },
                    Trip::Watchdog | Trip::Unknown => RigFault::WatchdogTripped { seq },
                });
            }
            LinkErr::Stalled(_) | LinkErr::Io(_) => {
                self.link.stop();
                self.state = RigState::Disconnected;
                self.counters.push(RigFault::Disconnected);
            }
        }
        self.link.map_err(&e)
    }
}

/// Host-side flags of a command: non-finite values and clamping.
fn command_flags(a: &ActuatorFrame, c: &DaqCaps) -> u8 {
    let mut f = 0;
    for (v, max) in [
        (a.force_n[0], c.force_max_n),
        (a.force_n[1], c.force_max_n),
        (a.haptuator_v, c.drive_max_v),
    ] {
        if !v.is_finite() {
            f |= FrameFlags::NONFINITE_COMMAND;
        } else if value_to_code(v, max).1 {
            f |= FrameFlags::LIMITED;
        }
    }
    f
}

impl Rig for SerialRig {
    fn identity(&self) -> &RigIdentity {
        &self.identity
    }

    fn start(&mut self) -> Result<(), RigError> {
        if self.state == RigState::Disconnected {
            return Err(RigError::Disconnected(format!(
                "{}: call reconnect() first",
                self.link.config().path
            )));
        }
        match self.link.start() {
            Ok(seq) => {
                self.pipe = Pipeline::start(seq);
                self.state = RigState::Running;
                Ok(())
            }
            Err(e) => {
                if matches!(e, RigError::Disconnected(_)) {
                    self.state = RigState::Disconnected;
                }
                Err(e)
            }
        }
    }

    fn stop(&mut self) -> Result<(), RigError> {
        if self.state != RigState::Disconnected {
            self.link.stop();
            self.state = RigState::Idle;
        }
        Ok(())
    }

    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError> {
        self.ready()?;
        let mut report = open_block(self.state, commands, sensors, self.pipe.next_seq)?;
        let n = report.frames;
        if n == 0 {
            return Ok(report);
        }
        let mut retried = false;
        let ex = loop {
            // The run's first block: the lead's zero commands go first.
            if let Some((first, l)) = self.pipe.open_lead(self.link.lead_samples(n)) {
                self.queue_zeros(first, l);
            }
            let at = self.pipe.queue(n);
            self.queue_commands(at, commands);
            if let Err(e) = self.link.flush_tx() {
                // The write failed: the device vanished (as a failed read
                // does in `fail`).
                self.link.stop();
                self.state = RigState::Disconnected;
                self.counters.push(RigFault::Disconnected);
                return Err(e);
            }
            let s = self.pipe.next_seq;
            report.first_seq = s;
            let r = self.exchange_block(s, n, sensors);
            match r {
                Ok(ex) => break ex,
                Err(LinkErr::Tripped {
                    received: false,
                    cause: Trip::Watchdog | Trip::Unknown,
                    ..
                }) if self.link.config().rearm_after_idle_trip && !retried => {
                    retried = true;
                    self.counters.push(RigFault::WatchdogTripped { seq: s });
                    let seq = self
                        .link
                        .start()
                        .inspect_err(|_| self.state = RigState::Disconnected)?;
                    // A new run: its lead goes first again.
                    self.pipe = Pipeline::start(seq);
                }
                Err(e) => return Err(self.fail(e)),
            }
        };
        self.pipe.received(n);
        report.lost_frames = ex.lost;
        if let Some(first_seq) = ex.first_lost {
            self.counters.push(RigFault::LostFrames {
                first_seq,
                count: ex.lost,
            });
        }
        // Counters and first-of-kind faults, as the simulated rig reports them.
        let mut noted = 0u8;
        for f in sensors.iter() {
            self.counters.note_flags(f.flags, f.seq, &mut noted);
        }
        self.counters.counts.frames += n as u64;
        self.counters.counts.lost_frames += u64::from(ex.lost);
        Ok(report)
    }

    fn status(&self) -> RigStatus {
        self.counters.status(self.state)
    }

    fn pop_fault(&mut self) -> Option<RigFault> {
        self.counters.pop_fault()
    }

    /// The block plus the command lead ([`CommandLead`]).
    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        let n = block_len.max(1);
        let lead = self.pipe.lead_or(|| self.link.lead_samples(n));
        u32::try_from(n as u64 + lead).unwrap_or(u32::MAX)
    }

    fn round_trip_s(&self) -> Option<f64> {
        self.link.round_trip().map(|d| d.as_secs_f64())
    }

    /// Queued with the next block's commands.
    fn send_info(&mut self, info: &HostInfo) -> Result<(), RigError> {
        if self.state == RigState::Running {
            frame::write_info(&mut self.link.tx, info);
        }
        Ok(())
    }
}

impl Drop for SerialRig {
    fn drop(&mut self) {
        if self.state == RigState::Running {
            self.link.stop();
        }
    }
}
