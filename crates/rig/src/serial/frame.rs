//! Wire format of the live-rig protocol (`docs/PROTOCOL.md`): framing,
//! CRC, message payloads and the resynchronising decoder.
//!
//! Every frame is
//!
//! ```text
//! offset  size  field
//! 0       2     sync marker A5 5A
//! 2       2     LEN: payload length in bytes, u16 little-endian, ≤ MAX_PAYLOAD
//! 4       1     TYPE
//! 5       LEN   payload
//! 5+LEN   2     CRC-16/CCITT-FALSE over bytes 2 .. 5+LEN (LEN, TYPE, payload), LE
//! ```
//!
//! CRC-16/CCITT-FALSE (a.k.a. CRC-16/IBM-3740, AUTOSAR): polynomial 0x1021,
//! initial value 0xFFFF, no reflection, no final XOR; check value 0x29B1
//! for the ASCII string `123456789` (Williams, *A painless guide to CRC
//! error detection algorithms*; the `crc` crate's catalogue). It detects
//! every error burst of ≤ 16 bits, hence every corrupted single byte.
//!
//! The [`Decoder`] keeps the unconsumed bytes in a fixed buffer of
//! 2·[`MAX_FRAME`] bytes (bounded memory, no allocation after creation).
//! It scans for the sync marker, rejects a header whose LEN exceeds
//! [`MAX_PAYLOAD`], and on a CRC mismatch discards only the first sync byte
//! and scans again, so a valid frame that follows garbage or a corrupted
//! frame is always found (resynchronisation on the next valid frame). A
//! header whose (corrupted) LEN runs past the start of a complete valid
//! frame is dropped without waiting for the bytes it claims: otherwise a
//! device that has paused for the host's next commands would leave the
//! host waiting for bytes that never come.

use crc::{CRC_16_IBM_3740, Crc};

/// CRC-16/CCITT-FALSE (= CRC-16/IBM-3740): poly 0x1021, init 0xFFFF.
pub const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// Sync marker opening every frame.
pub const SYNC: [u8; 2] = [0xA5, 0x5A];
/// Bytes before the payload: sync (2), LEN (2), TYPE (1).
pub const HEADER: usize = 5;
/// Bytes after the payload: the CRC.
pub const TRAILER: usize = 2;
/// Largest payload accepted, bytes.
pub const MAX_PAYLOAD: usize = 1024;
/// Largest frame, bytes.
pub const MAX_FRAME: usize = HEADER + MAX_PAYLOAD + TRAILER;
/// Protocol version spoken by this implementation.
pub const PROTOCOL_VERSION: u16 = 2;

/// Frame types (`docs/PROTOCOL.md`, "Frame types"). Host → device types
/// are 0x01–0x3F, device → host types 0x81–0xBF.
pub mod ty {
    /// Host → device: handshake request (payload: host protocol version u16).
    pub const HELLO_REQ: u8 = 0x01;
    /// Host → device: arm and start streaming (no payload).
    pub const START: u8 = 0x02;
    /// Host → device: outputs to zero, stop streaming (no payload).
    pub const STOP: u8 = 0x03;
    /// Host → device: DAQ commands (block of [`super::DaqCommand`]).
    pub const COMMANDS: u8 = 0x04;
    /// Host → device: heartbeat (payload: counter u32).
    pub const HEARTBEAT: u8 = 0x05;
    /// Host → device: tweezer trap positions (block of [`super::TrapCommand`]).
    pub const TRAP: u8 = 0x06;
    /// Host → device: reset the instrument state to one command item
    /// (tweezer: trap and bead at the given position).
    pub const RESET: u8 = 0x07;
    /// Device → host: handshake answer ([`super::Hello`]).
    pub const HELLO: u8 = 0x81;
    /// Device → host: DAQ samples (block of [`super::DaqSample`]).
    pub const SAMPLES: u8 = 0x82;
    /// Device → host: status ([`super::Status`]).
    pub const STATUS: u8 = 0x83;
    /// Device → host: fault ([`super::FaultReport`]).
    pub const FAULT: u8 = 0x84;
    /// Device → host: tweezer samples (block of [`super::TweezerWireSample`]).
    pub const TWEEZER_SAMPLES: u8 = 0x85;
}

/// Per-sample flag bits of device samples. Bits 1–4 equal the host's
/// [`crate::device::FrameFlags`] bits; bit 0 is never sent (the host uses it
/// for lost-frame placeholders).
pub mod flag {
    /// Accelerometer at its range on some axis.
    pub const CLIPPED: u8 = 0x02;
    /// A command was clamped by the device.
    pub const LIMITED: u8 = 0x04;
    /// Haptuator magnet on an end stop (when the device can tell).
    pub const END_STOP: u8 = 0x08;
    /// The device replaced an invalid command by zero.
    pub const NONFINITE: u8 = 0x10;
    /// The command for this sample arrived late (or not at all): the
    /// previous command was held.
    pub const CMD_LATE: u8 = 0x20;
    /// The watchdog had zeroed the outputs during this sample.
    pub const WATCHDOG: u8 = 0x40;
    /// Bits the host copies into [`crate::device::FrameFlags`].
    pub const HOST_MASK: u8 = CLIPPED | LIMITED | END_STOP | NONFINITE;
}

/// Fault codes of [`FaultReport`] (`docs/PROTOCOL.md`, "Faults").
pub mod fault {
    /// No valid host frame within the watchdog window: outputs zeroed,
    /// device idle until the next START.
    pub const WATCHDOG: u8 = 0x01;
    /// A host frame with a valid CRC but an unknown type or a malformed payload.
    pub const BAD_FRAME: u8 = 0x02;
    /// HELLO_REQ with a protocol version the device does not speak.
    pub const VERSION: u8 = 0x03;
    /// A command for a sample too far ahead of the device (buffer full).
    pub const OVERFLOW: u8 = 0x04;
    /// A command for a sample the device had already executed.
    pub const LATE: u8 = 0x05;
    /// Commands received while idle (no START).
    pub const NOT_RUNNING: u8 = 0x06;

    /// Human-readable name of a fault code.
    pub fn name(code: u8) -> &'static str {
        match code {
            WATCHDOG => "watchdog tripped",
            BAD_FRAME => "bad host frame",
            VERSION => "protocol version mismatch",
            OVERFLOW => "command buffer overflow",
            LATE => "late command",
            NOT_RUNNING => "command while idle",
            _ => "unknown fault",
        }
    }
}

/// Kind of device announced in [`Hello`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// Haptic DAQ: encoders, accelerometer, Pantograph and Haptuator outputs.
    Daq,
    /// Optical tweezer: trap positioning, bead tracking.
    Tweezer,
}

impl DeviceKind {
    /// Wire code.
    pub fn code(self) -> u8 {
        match self {
            DeviceKind::Daq => 1,
            DeviceKind::Tweezer => 2,
        }
    }
    /// From the wire code.
    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            1 => Some(DeviceKind::Daq),
            2 => Some(DeviceKind::Tweezer),
            _ => None,
        }
    }
}

/// Capabilities of a DAQ (handshake). Output codes are i16 with full scale
/// ±32767 = ±the limit: value = code · limit / 32767.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DaqCaps {
    /// Encoder counts per metre of handle travel.
    pub encoder_counts_per_m: f64,
    /// Accelerometer scale, (m/s²) per code.
    pub accel_m_s2_per_code: f64,
    /// Accelerometer full scale, ±m/s².
    pub accel_range_m_s2: f64,
    /// Pantograph force limit per axis, N (code ±32767).
    pub force_max_n: f64,
    /// Haptuator drive limit, V (code ±32767).
    pub drive_max_v: f64,
}

/// Capabilities of a tweezer (handshake).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TweezerCaps {
    /// Trap stiffness κ, N/m.
    pub stiffness_n_per_m: f64,
}

/// Kind-specific capabilities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Caps {
    /// DAQ.
    Daq(DaqCaps),
    /// Tweezer.
    Tweezer(TweezerCaps),
}

/// Handshake answer (device → host, [`ty::HELLO`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Hello {
    /// Protocol version of the device.
    pub version: u16,
    /// Sample rate, Hz.
    pub sample_rate_hz: u32,
    /// Watchdog window, ms.
    pub watchdog_ms: u16,
    /// Samples per device frame at most.
    pub batch: u8,
    /// Capabilities (the kind follows from the variant).
    pub caps: Caps,
    /// Device name (UTF-8, ≤ 255 bytes).
    pub name: String,
    /// Serial number.
    pub serial: String,
    /// Firmware version.
    pub firmware: String,
}

impl Hello {
    /// The handshake of one of kilotouch's own emulators (current protocol
    /// version, no device watchdog, no batching): `tool` names it in the
    /// firmware string (`kilotouch emulate daq 0.1.0`).
    pub fn emulator(sample_rate_hz: u32, caps: Caps, name: &str, serial: &str, tool: &str) -> Self {
        Self {
            version: PROTOCOL_VERSION,
            sample_rate_hz,
            watchdog_ms: 0,
            batch: 0,
            caps,
            name: name.to_owned(),
            serial: serial.to_owned(),
            firmware: format!("kilotouch emulate {tool} {}", env!("CARGO_PKG_VERSION")),
        }
    }

    /// Device kind.
    pub fn kind(&self) -> DeviceKind {
        match self.caps {
            Caps::Daq(_) => DeviceKind::Daq,
            Caps::Tweezer(_) => DeviceKind::Tweezer,
        }
    }
}

/// Device state in [`Status`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceState {
    /// Outputs zero, not streaming.
    Idle,
    /// Streaming samples.
    Running,
    /// Stopped by the watchdog (outputs zero) until the next START.
    Tripped,
}

impl DeviceState {
    /// Wire code.
    pub fn code(self) -> u8 {
        match self {
            DeviceState::Idle => 0,
            DeviceState::Running => 1,
            DeviceState::Tripped => 2,
        }
    }
    /// From the wire code.
    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(DeviceState::Idle),
            1 => Some(DeviceState::Running),
            2 => Some(DeviceState::Tripped),
            _ => None,
        }
    }
}

/// Device status ([`ty::STATUS`]): sent on START/STOP, and every 10 ms
/// while the device waits for commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status {
    /// Sequence number of the next sample the device will execute (every
    /// earlier sample has been sent).
    pub next_seq: u32,
    /// State.
    pub state: DeviceState,
    /// Valid host frames received.
    pub host_frames: u32,
    /// Host frames rejected (CRC errors seen by the device's decoder).
    pub host_crc_errors: u32,
    /// Samples executed with a held command (late or missing).
    pub late_commands: u32,
}

/// A fault ([`ty::FAULT`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultReport {
    /// Fault code ([`fault`]).
    pub code: u8,
    /// Sequence number at which it happened.
    pub seq: u32,
}

/// One fixed-size item of a block payload (`seq u32, n u8, n × item`).
pub trait WireItem: Copy + Default + Send + std::fmt::Debug {
    /// Encoded size, bytes.
    const SIZE: usize;
    /// Append the little-endian encoding.
    fn put(&self, out: &mut Vec<u8>);
    /// Decode from exactly `SIZE` bytes.
    fn get(b: &[u8]) -> Self;
}

/// DAQ command of one sample (host → device): output codes, full scale
/// ±32767 = ± the limits of [`DaqCaps`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DaqCommand {
    /// Pantograph force codes (x, y).
    pub force: [i16; 2],
    /// Haptuator drive code.
    pub drive: i16,
}

/// DAQ sample (device → host).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DaqSample {
    /// Encoder counts (x, y).
    pub enc: [i32; 2],
    /// Accelerometer codes (x, y, z).
    pub acc: [i16; 3],
    /// Flags ([`flag`]).
    pub flags: u8,
}

/// Tweezer trap command of one sample (host → device), m.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrapCommand {
    /// Trap centre (x, y), m.
    pub trap_m: [f64; 2],
}

/// Tweezer status bits of [`TweezerWireSample::status`].
pub mod tweezer_status {
    /// Bead held by the trap.
    pub const TRAPPED: u8 = 0x01;
    /// Bead in an obstacle's contact zone.
    pub const IN_CONTACT: u8 = 0x02;
    /// Contact started this sample.
    pub const CONTACT_START: u8 = 0x04;
    /// Contact ended this sample.
    pub const CONTACT_END: u8 = 0x08;
    /// Bead escaped this sample.
    pub const ESCAPED: u8 = 0x10;
    /// Bead recaptured this sample.
    pub const RECAPTURED: u8 = 0x20;
    /// Watchdog: the trap was held (no valid host frame).
    pub const WATCHDOG: u8 = 0x40;
}

/// Tweezer sample (device → host).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TweezerWireSample {
    /// Bead centre (x, y), m.
    pub bead_m: [f64; 2],
    /// Position-detector sum signal, V.
    pub sum_v: f32,
    /// Position-detector difference signals (x, y), V: the raw signal a
    /// trap calibration fits (`crate::tweezer::calibration`).
    pub detector_v: [f32; 2],
    /// Status bits ([`tweezer_status`]).
    pub status: u8,
}

fn rd<const N: usize>(b: &[u8], at: usize) -> [u8; N] {
    let mut a = [0u8; N];
    if let Some(s) = b.get(at..at + N) {
        a.copy_from_slice(s);
    }
    a
}

impl WireItem for DaqCommand {
    const SIZE: usize = 6;
    fn put(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.force[0].to_le_bytes());
        out.extend_from_slice(&self.force[1].to_le_bytes());
        out.extend_from_slice(&self.drive.to_le_bytes());
    }
    fn get(b: &[u8]) -> Self {
        Self {
            force: [i16::from_le_bytes(rd(b, 0)), i16::from_le_bytes(rd(b, 2))],
            drive: i16::from_le_bytes(rd(b, 4)),
        }
    }
}

impl WireItem for DaqSample {
    const SIZE: usize = 15;
    fn put(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.enc[0].to_le_bytes());
        out.extend_from_slice(&self.enc[1].to_le_bytes());
        for a in self.acc {
            out.extend_from_slice(&a.to_le_bytes());
        }
        out.push(self.flags);
    }
    fn get(b: &[u8]) -> Self {
        Self {
            enc: [i32::from_le_bytes(rd(b, 0)), i32::from_le_bytes(rd(b, 4))],
            acc: [
                i16::from_le_bytes(rd(b, 8)),
                i16::from_le_bytes(rd(b, 10)),
                i16::from_le_bytes(rd(b, 12)),
            ],
            flags: b.get(14).copied().unwrap_or(0),
        }
    }
}

impl WireItem for TrapCommand {
    const SIZE: usize = 16;
    fn put(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.trap_m[0].to_le_bytes());
        out.extend_from_slice(&self.trap_m[1].to_le_bytes());
    }
    fn get(b: &[u8]) -> Self {
        Self {
            trap_m: [f64::from_le_bytes(rd(b, 0)), f64::from_le_bytes(rd(b, 8))],
        }
    }
}

impl WireItem for TweezerWireSample {
    const SIZE: usize = 29;
    fn put(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.bead_m[0].to_le_bytes());
        out.extend_from_slice(&self.bead_m[1].to_le_bytes());
        out.extend_from_slice(&self.sum_v.to_le_bytes());
        out.extend_from_slice(&self.detector_v[0].to_le_bytes());
        out.extend_from_slice(&self.detector_v[1].to_le_bytes());
        out.push(self.status);
    }
    fn get(b: &[u8]) -> Self {
        Self {
            bead_m: [f64::from_le_bytes(rd(b, 0)), f64::from_le_bytes(rd(b, 8))],
            sum_v: f32::from_le_bytes(rd(b, 16)),
            detector_v: [f32::from_le_bytes(rd(b, 20)), f32::from_le_bytes(rd(b, 24))],
            status: b.get(28).copied().unwrap_or(0),
        }
    }
}

/// Most items of type `T` that fit one block frame.
pub const fn max_items<T: WireItem>() -> usize {
    let n = (MAX_PAYLOAD - 5) / T::SIZE;
    if n > 255 { 255 } else { n }
}

/// Append one frame of type `ty` whose payload is written by `body`
/// (which must append at most [`MAX_PAYLOAD`] bytes; more is truncated to
/// keep the frame valid). Allocation-free when `out` has the capacity.
pub fn write_frame(out: &mut Vec<u8>, ty: u8, body: impl FnOnce(&mut Vec<u8>)) {
    let start = out.len();
    out.extend_from_slice(&SYNC);
    out.extend_from_slice(&[0, 0, ty]);
    body(out);
    let plen = (out.len() - start - HEADER).min(MAX_PAYLOAD);
    out.truncate(start + HEADER + plen);
    out[start + 2..start + 4].copy_from_slice(&(plen as u16).to_le_bytes());
    let crc = CRC16.checksum(&out[start + 2..]);
    out.extend_from_slice(&crc.to_le_bytes());
}

/// Append a block frame `seq u32, n u8, n × item` (at most
/// [`max_items`]`::<T>()` items are written).
pub fn write_block<T: WireItem>(out: &mut Vec<u8>, ty: u8, seq: u32, items: &[T]) {
    let n = items.len().min(max_items::<T>());
    write_frame(out, ty, |o| {
        o.extend_from_slice(&seq.to_le_bytes());
        o.push(n as u8);
        for it in &items[..n] {
            it.put(o);
        }
    });
}

/// Header of a block payload: (first sequence number, item count), or
/// `None` when the payload length does not match.
pub fn block_header<T: WireItem>(payload: &[u8]) -> Option<(u32, usize)> {
    if payload.len() < 5 {
        return None;
    }
    let seq = u32::from_le_bytes(rd(payload, 0));
    let n = payload[4] as usize;
    (payload.len() == 5 + n * T::SIZE).then_some((seq, n))
}

/// Item `i` of a block payload already checked by [`block_header`].
pub fn block_item<T: WireItem>(payload: &[u8], i: usize) -> T {
    let at = 5 + i * T::SIZE;
    T::get(payload.get(at..at + T::SIZE).unwrap_or(&[]))
}

fn put_str(o: &mut Vec<u8>, s: &str) {
    let mut n = s.len().min(255);
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    o.push(n as u8);
    o.extend_from_slice(&s.as_bytes()[..n]);
}

/// Append a HELLO frame.
pub fn write_hello(out: &mut Vec<u8>, h: &Hello) {
    write_frame(out, ty::HELLO, |o| {
        o.extend_from_slice(&h.version.to_le_bytes());
        o.push(h.kind().code());
        o.extend_from_slice(&h.sample_rate_hz.to_le_bytes());
        o.extend_from_slice(&h.watchdog_ms.to_le_bytes());
        o.push(h.batch);
        match h.caps {
            Caps::Daq(c) => {
                for v in [
                    c.encoder_counts_per_m,
                    c.accel_m_s2_per_code,
                    c.accel_range_m_s2,
                    c.force_max_n,
                    c.drive_max_v,
                ] {
                    o.extend_from_slice(&v.to_le_bytes());
                }
            }
            Caps::Tweezer(c) => o.extend_from_slice(&c.stiffness_n_per_m.to_le_bytes()),
        }
        put_str(o, &h.name);
        put_str(o, &h.serial);
        put_str(o, &h.firmware);
    });
}

/// Sequential little-endian reader over a payload.
struct Rd<'a> {
    b: &'a [u8],
    at: usize,
}

impl Rd<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        let s = self.b.get(self.at..self.at + n)?;
        self.at += n;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|s| s[0])
    }
    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|s| u16::from_le_bytes(rd(s, 0)))
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4).map(|s| u32::from_le_bytes(rd(s, 0)))
    }
    fn f64(&mut self) -> Option<f64> {
        self.take(8).map(|s| f64::from_le_bytes(rd(s, 0)))
    }
    fn string(&mut self) -> Option<String> {
        let n = self.u8()? as usize;
        self.take(n)
            .map(|s| String::from_utf8_lossy(s).into_owned())
    }
}

/// Parse a HELLO payload.
pub fn parse_hello(payload: &[u8]) -> Option<Hello> {
    let mut r = Rd { b: payload, at: 0 };
    let version = r.u16()?;
    let kind = DeviceKind::from_code(r.u8()?)?;
    let sample_rate_hz = r.u32()?;
    let watchdog_ms = r.u16()?;
    let batch = r.u8()?;
    let caps = match kind {
        DeviceKind::Daq => Caps::Daq(DaqCaps {
            encoder_counts_per_m: r.f64()?,
            accel_m_s2_per_code: r.f64()?,
            accel_range_m_s2: r.f64()?,
            force_max_n: r.f64()?,
            drive_max_v: r.f64()?,
        }),
        DeviceKind::Tweezer => Caps::Tweezer(TweezerCaps {
            stiffness_n_per_m: r.f64()?,
        }),
    };
    Some(Hello {
        version,
        sample_rate_hz,
        watchdog_ms,
        batch,
        caps,
        name: r.string()?,
        serial: r.string()?,
        firmware: r.string()?,
    })
}

/// Append a STATUS frame.
pub fn write_status(out: &mut Vec<u8>, s: &Status) {
    write_frame(out, ty::STATUS, |o| {
        o.extend_from_slice(&s.next_seq.to_le_bytes());
        o.push(s.state.code());
        o.extend_from_slice(&s.host_frames.to_le_bytes());
        o.extend_from_slice(&s.host_crc_errors.to_le_bytes());
        o.extend_from_slice(&s.late_commands.to_le_bytes());
    });
}

/// Parse a STATUS payload.
pub fn parse_status(payload: &[u8]) -> Option<Status> {
    if payload.len() != 17 {
        return None;
    }
    let mut r = Rd { b: payload, at: 0 };
    Some(Status {
        next_seq: r.u32()?,
        state: DeviceState::from_code(r.u8()?)?,
        host_frames: r.u32()?,
        host_crc_errors: r.u32()?,
        late_commands: r.u32()?,
    })
}

/// Append a FAULT frame.
pub fn write_fault(out: &mut Vec<u8>, f: &FaultReport) {
    write_frame(out, ty::FAULT, |o| {
        o.push(f.code);
        o.extend_from_slice(&f.seq.to_le_bytes());
    });
}

/// Parse a FAULT payload.
pub fn parse_fault(payload: &[u8]) -> Option<FaultReport> {
    if payload.len() != 5 {
        return None;
    }
    Some(FaultReport {
        code: payload[0],
        seq: u32::from_le_bytes(rd(payload, 1)),
    })
}

/// Map a 32-bit wire sequence number to the 64-bit one nearest to `near`
/// (streams wrap after 2³² samples, 119 h at 10 kHz).
pub fn unwrap_seq(wire: u32, near: u64) -> u64 {
    let d = i64::from(wire.wrapping_sub(near as u32) as i32);
    (near as i64).saturating_add(d).max(0) as u64
}

/// Counters of a [`Decoder`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Valid frames decoded.
    pub frames: u64,
    /// Candidate frames (sync + plausible header, complete) whose CRC failed.
    pub crc_errors: u64,
    /// Headers rejected because LEN exceeded [`MAX_PAYLOAD`], or because a
    /// complete valid frame began inside the length they claimed.
    pub bad_lengths: u64,
    /// Bytes skipped while searching for a frame.
    pub bytes_skipped: u64,
}

/// One decoded frame, borrowing the decoder's buffer.
#[derive(Debug, Clone, Copy)]
pub struct FrameRef<'a> {
    /// Frame type.
    pub ty: u8,
    /// Payload.
    pub payload: &'a [u8],
}

/// Resynchronising stream decoder with a fixed buffer (module docs).
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: Box<[u8]>,
    start: usize,
    end: usize,
    stats: DecoderStats,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// Buffer capacity, bytes.
    pub const CAPACITY: usize = 2 * MAX_FRAME;

    /// Empty decoder (allocates its buffer once).
    pub fn new() -> Self {
        Self {
            buf: vec![0u8; Self::CAPACITY].into_boxed_slice(),
            start: 0,
            end: 0,
            stats: DecoderStats::default(),
        }
    }

    /// Counters.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes buffered and not yet consumed.
    pub fn buffered(&self) -> usize {
        self.end - self.start
    }

    /// Forget buffered bytes (counters are kept).
    pub fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
    }

    /// Append as much of `data` as fits and return how many bytes were
    /// taken. After [`next_frame`](Self::next_frame) has returned `None` at
    /// least [`MAX_FRAME`] bytes always fit.
    pub fn push(&mut self, data: &[u8]) -> usize {
        if self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let n = data.len().min(Self::CAPACITY - self.end);
        self.buf[self.end..self.end + n].copy_from_slice(&data[..n]);
        self.end += n;
        n
    }

    fn skip(&mut self, n: usize) {
        self.start += n;
        self.stats.bytes_skipped += n as u64;
    }

    /// Next valid frame in the buffered bytes, or `None` when more bytes are
    /// needed. Garbage and invalid frames are skipped and counted.
    pub fn next_frame(&mut self) -> Option<FrameRef<'_>> {
        loop {
            let avail = &self.buf[self.start..self.end];
            // Find the sync marker (a lone first sync byte at the end is kept).
            let pos = avail.windows(2).position(|w| w == SYNC).unwrap_or_else(|| {
                if avail.last() == Some(&SYNC[0]) {
                    avail.len() - 1
                } else {
                    avail.len()
                }
            });
            if pos > 0 {
                self.skip(pos);
            }
            let avail = &self.buf[self.start..self.end];
            if avail.len() < HEADER {
                return None;
            }
            let plen = u16::from_le_bytes([avail[2], avail[3]]) as usize;
            if plen > MAX_PAYLOAD {
                self.stats.bad_lengths += 1;
                self.skip(1);
                continue;
            }
            let total = HEADER + plen + TRAILER;
            if avail.len() < total {
                // A corrupted LEN can claim more bytes than the device will
                // send before it waits for the host (a deadlock until the
                // link times out). A complete, CRC-valid frame starting
                // inside the claimed length shows this header is bad.
                if complete_frame_after(avail) {
                    self.stats.bad_lengths += 1;
                    self.skip(1);
                    continue;
                }
                return None;
            }
            let crc = u16::from_le_bytes([avail[total - 2], avail[total - 1]]);
            if CRC16.checksum(&avail[2..HEADER + plen]) != crc {
                self.stats.crc_errors += 1;
                self.skip(1);
                continue;
            }
            let s = self.start;
            self.start += total;
            self.stats.frames += 1;
            return Some(FrameRef {
                ty: self.buf[s + 4],
                payload: &self.buf[s + HEADER..s + HEADER + plen],
            });
        }
    }
}

/// Whether a complete frame with a valid CRC starts after the first byte of
/// `avail` (which begins with a sync marker). A false positive inside a
/// genuine frame's payload needs the sync marker, a plausible LEN and a
/// matching CRC-16 at once (≈ 2⁻³² per byte position); a scan is bounded by
/// the decoder's buffer, [`Decoder::CAPACITY`] bytes.
fn complete_frame_after(avail: &[u8]) -> bool {
    let mut from = 1;
    while let Some(off) = avail[from..].windows(2).position(|w| w == SYNC) {
        let c = &avail[from + off..];
        from += off + 1;
        if c.len() < HEADER {
            return false;
        }
        let plen = u16::from_le_bytes([c[2], c[3]]) as usize;
        let total = HEADER + plen + TRAILER;
        if plen > MAX_PAYLOAD || c.len() < total {
            continue;
        }
        if CRC16.checksum(&c[2..HEADER + plen]) == u16::from_le_bytes([c[total - 2], c[total - 1]])
        {
            return true;
        }
    }
    false
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// Independent bitwise CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF,
    /// MSB first, no final XOR), after Williams' "painless guide".
    fn bitwise_crc(data: &[u8]) -> u16 {
        let mut c: u16 = 0xFFFF;
        for &b in data {
            c ^= u16::from(b) << 8;
            for _ in 0..8 {
                c = if c & 0x8000 != 0 {
                    (c << 1) ^ 0x1021
                } else {
                    c << 1
                };
            }
        }
        c
    }

    #[test]
    fn crc_check_value_is_that_of_ccitt_false() {
        // Catalogue check value of CRC-16/CCITT-FALSE.
        assert_eq!(CRC16.checksum(b"123456789"), 0x29B1);
        assert_eq!(bitwise_crc(b"123456789"), 0x29B1);
        for data in [&b""[..], b"\x00", b"\xA5\x5A\x00\x00\x02", &[0xFF; 300]] {
            assert_eq!(CRC16.checksum(data), bitwise_crc(data));
        }
    }

    #[test]
    fn worked_example_of_the_protocol_document() {
        // docs/PROTOCOL.md, "Worked example": START, then one COMMANDS frame
        // (seq 0x01020304; +2.5 N, −2.5 N on a 5 N Pantograph; +1 V of 10 V).
        let mut out = Vec::new();
        write_frame(&mut out, ty::START, |_| {});
        assert_eq!(out, [0xA5, 0x5A, 0x00, 0x00, 0x02, 0xDE, 0xEC]);
        assert_eq!(bitwise_crc(&out[2..5]).to_le_bytes(), [0xDE, 0xEC]);
        out.clear();
        let cmd = DaqCommand {
            force: [
                super::super::emulator::value_to_code(2.5, 5.0).0,
                super::super::emulator::value_to_code(-2.5, 5.0).0,
            ],
            drive: super::super::emulator::value_to_code(1.0, 10.0).0,
        };
        // 2.5/5·32767 = 16383.5 → 16384 (half away from zero); 1/10·32767 → 3277.
        assert_eq!(cmd.force, [16384, -16384]);
        assert_eq!(cmd.drive, 3277);
        write_block(&mut out, ty::COMMANDS, 0x0102_0304, &[cmd]);
        let hex: Vec<String> = out.iter().map(|b| format!("{b:02X}")).collect();
        assert_eq!(
            hex.join(" "),
            "A5 5A 0B 00 04 04 03 02 01 01 00 40 00 C0 CD 0C 30 8D"
        );
        assert_eq!(bitwise_crc(&out[2..16]).to_le_bytes(), [0x30, 0x8D]);
        let mut d = Decoder::new();
        d.push(&out);
        let f = d.next_frame().unwrap();
        assert_eq!(f.ty, ty::COMMANDS);
        let (seq, n) = block_header::<DaqCommand>(f.payload).unwrap();
        assert_eq!((seq, n), (0x0102_0304, 1));
        assert_eq!(block_item::<DaqCommand>(f.payload, 0), cmd);
    }

    #[test]
    fn messages_round_trip() {
        let h = Hello {
            version: PROTOCOL_VERSION,
            sample_rate_hz: 10_000,
            watchdog_ms: 100,
            batch: 10,
            caps: Caps::Daq(DaqCaps {
                encoder_counts_per_m: 1e5,
                accel_m_s2_per_code: 1.4528e-2,
                accel_range_m_s2: 58.8399,
                force_max_n: 5.0,
                drive_max_v: 10.0,
            }),
            name: "rig é".into(),
            serial: "0001".into(),
            firmware: "emu 1".into(),
        };
        let st = Status {
            next_seq: 77,
            state: DeviceState::Tripped,
            host_frames: 5,
            host_crc_errors: 2,
            late_commands: 1,
        };
        let fr = FaultReport {
            code: fault::WATCHDOG,
            seq: 9,
        };
        let s = DaqSample {
            enc: [-5, 123_456],
            acc: [-4050, 675, 1],
            flags: flag::CLIPPED,
        };
        let t = TweezerWireSample {
            bead_m: [1e-8, -3.5e-7],
            sum_v: 0.75,
            detector_v: [0.125, -2.5],
            status: tweezer_status::TRAPPED,
        };
        let mut out = Vec::new();
        write_hello(&mut out, &h);
        write_status(&mut out, &st);
        write_fault(&mut out, &fr);
        write_block(&mut out, ty::SAMPLES, 3, &[s, s]);
        write_block(&mut out, ty::TWEEZER_SAMPLES, 4, &[t]);
        let mut d = Decoder::new();
        d.push(&out);
        assert_eq!(parse_hello(d.next_frame().unwrap().payload).unwrap(), h);
        assert_eq!(parse_status(d.next_frame().unwrap().payload).unwrap(), st);
        assert_eq!(parse_fault(d.next_frame().unwrap().payload).unwrap(), fr);
        let f = d.next_frame().unwrap();
        assert_eq!(block_header::<DaqSample>(f.payload), Some((3, 2)));
        assert_eq!(block_item::<DaqSample>(f.payload, 1), s);
        let f = d.next_frame().unwrap();
        assert_eq!(block_item::<TweezerWireSample>(f.payload, 0), t);
        assert!(d.next_frame().is_none());
        assert_eq!(d.stats().frames, 5);
        assert_eq!(d.stats().crc_errors, 0);
    }

    #[test]
    fn sequence_numbers_unwrap_across_the_32_bit_boundary() {
        assert_eq!(unwrap_seq(5, 3), 5);
        assert_eq!(unwrap_seq(2, 3), 2);
        assert_eq!(unwrap_seq(1, (1u64 << 32) - 2), (1u64 << 32) + 1);
        assert_eq!(unwrap_seq(u32::MAX, 1u64 << 32), (1u64 << 32) - 1);
        assert_eq!(unwrap_seq(u32::MAX, 0), 0);
    }

    #[test]
    fn oversized_length_and_lone_sync_bytes_are_skipped() {
        let mut good = Vec::new();
        write_frame(&mut good, ty::HEARTBEAT, |o| {
            o.extend_from_slice(&[1, 2, 3, 4])
        });
        let mut stream = vec![0xA5, 0x5A, 0xFF, 0xFF, 0x01, 0xA5, 0x00, 0xA5];
        stream.extend_from_slice(&good);
        let mut d = Decoder::new();
        d.push(&stream);
        let f = d.next_frame().unwrap();
        assert_eq!((f.ty, f.payload), (ty::HEARTBEAT, &[1u8, 2, 3, 4][..]));
        assert_eq!(d.stats().bad_lengths, 1);
        assert!(d.next_frame().is_none());
        assert_eq!(d.buffered(), 0);
    }

    /// A SAMPLES frame whose LEN was corrupted to claim 900 bytes, then the
    /// STATUS a waiting device sends: the STATUS is decoded at once, not
    /// after 900 more bytes.
    #[test]
    fn a_corrupted_length_does_not_hide_the_frames_after_it() {
        let s = DaqSample {
            enc: [1, 2],
            acc: [3, 4, 5],
            flags: 0,
        };
        let mut stream = Vec::new();
        write_block(&mut stream, ty::SAMPLES, 10, &[s, s, s]);
        stream[3] = 0x03; // LEN high byte: 768 + low byte, ≤ MAX_PAYLOAD
        let st = Status {
            next_seq: 13,
            state: DeviceState::Running,
            host_frames: 1,
            host_crc_errors: 0,
            late_commands: 0,
        };
        write_status(&mut stream, &st);
        let mut d = Decoder::new();
        // Byte by byte, as a slow link delivers them.
        let mut got = None;
        for b in &stream {
            d.push(std::slice::from_ref(b));
            if let Some(f) = d.next_frame() {
                got = Some((f.ty, parse_status(f.payload).unwrap()));
                break;
            }
        }
        assert_eq!(got, Some((ty::STATUS, st)));
        assert_eq!(d.stats().bad_lengths, 1);
        assert_eq!(d.buffered(), 0);
    }

    /// A genuine long frame whose payload is full of sync markers, arriving
    /// a byte at a time, is decoded whole: partial frames are not abandoned
    /// for lack of a later valid frame.
    #[test]
    fn a_long_frame_full_of_sync_markers_arrives_whole() {
        let payload: Vec<u8> = (0..1000).map(|i| SYNC[i % 2]).collect();
        let mut stream = Vec::new();
        write_frame(&mut stream, ty::HEARTBEAT, |o| {
            o.extend_from_slice(&payload)
        });
        let mut d = Decoder::new();
        for (i, b) in stream.iter().enumerate() {
            d.push(std::slice::from_ref(b));
            match d.next_frame() {
                Some(f) => {
                    assert_eq!(i, stream.len() - 1, "decoded early");
                    assert_eq!(f.payload, &payload[..]);
                }
                None => assert!(i < stream.len() - 1, "not decoded"),
            }
        }
        assert_eq!(d.stats().frames, 1);
        assert_eq!(d.stats().bad_lengths + d.stats().crc_errors, 0);
    }
}
