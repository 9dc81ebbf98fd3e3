//! Frame layout and CRC (`docs/PROTOCOL.md` §3–§4, §6.1, §6.4).
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

use crc::{CRC_16_IBM_3740, Crc};

/// CRC-16/CCITT-FALSE (= CRC-16/IBM-3740): poly 0x1021, init 0xFFFF.
/// The `crc` crate's 256-entry table (512 bytes of flash on the device).
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

/// Why a frame or payload could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireError {
    /// The payload exceeds [`MAX_PAYLOAD`] bytes (length given).
    PayloadTooLong(usize),
    /// The output slice is too short (bytes needed given).
    BufferTooSmall(usize),
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::PayloadTooLong(n) => {
                write!(f, "payload of {n} bytes exceeds {MAX_PAYLOAD} bytes")
            }
            WireError::BufferTooSmall(n) => write!(f, "output buffer too small ({n} bytes needed)"),
        }
    }
}

impl core::error::Error for WireError {}

/// Frame types (`docs/PROTOCOL.md`, "Frame types"). Host → device types
/// are 0x01–0x3F, device → host types 0x81–0xBF.
pub mod ty {
    /// Host → device: handshake request (payload: host protocol version u16).
    pub const HELLO_REQ: u8 = 0x01;
    /// Host → device: arm and start streaming (no payload).
    pub const START: u8 = 0x02;
    /// Host → device: outputs to zero, stop streaming (no payload).
    pub const STOP: u8 = 0x03;
    /// Host → device: DAQ commands (block of [`crate::DaqCommand`]).
    pub const COMMANDS: u8 = 0x04;
    /// Host → device: heartbeat (payload: counter u32).
    pub const HEARTBEAT: u8 = 0x05;
    /// Host → device: tweezer trap positions (block of [`crate::TrapCommand`]).
    pub const TRAP: u8 = 0x06;
    /// Host → device: reset the instrument state to one command item
    /// (tweezer: trap and bead at the given position).
    pub const RESET: u8 = 0x07;
    /// Host → device: ask a tweezer for its scene (no payload); answered
    /// by [`SCENE`], or FAULT `BAD_FRAME` by a device without one.
    pub const SCENE_REQ: u8 = 0x08;
    /// Host → device: information about the experiment
    /// ([`crate::info::Info`]); optional, a device may ignore it.
    pub const INFO: u8 = 0x20;
    /// Device → host: handshake answer ([`crate::Hello`]).
    pub const HELLO: u8 = 0x81;
    /// Device → host: DAQ samples (block of [`crate::DaqSample`]).
    pub const SAMPLES: u8 = 0x82;
    /// Device → host: status ([`crate::Status`]).
    pub const STATUS: u8 = 0x83;
    /// Device → host: fault ([`crate::FaultReport`]).
    pub const FAULT: u8 = 0x84;
    /// Device → host: tweezer samples (block of [`crate::TweezerWireSample`]).
    pub const TWEEZER_SAMPLES: u8 = 0x85;
    /// Device → host: the tweezer's scene ([`crate::Scene`]): bead radius
    /// and obstacles in the trap's frame.
    pub const SCENE: u8 = 0x86;
    /// Host → device: a test frame ([`crate::testing`]); only test builds
    /// (the firmware's QEMU build) act on it, others answer FAULT BAD_FRAME.
    pub const TEST: u8 = 0x3F;
    /// Device → host: the answer to a [`TEST`] frame ([`crate::testing::Ack`]).
    pub const TEST_ACK: u8 = 0xBF;
}

/// Per-sample flag bits of device samples (`docs/PROTOCOL.md` §6.1).
/// Bits 1–4 equal the host's `FrameFlags` bits; bit 0 is never sent (the
/// host uses it for lost-frame placeholders).
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
    /// Bits the host copies into its `FrameFlags`.
    pub const HOST_MASK: u8 = CLIPPED | LIMITED | END_STOP | NONFINITE;
}

/// Fault codes of [`crate::FaultReport`] (`docs/PROTOCOL.md` §6.4).
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
    /// The emergency-stop input is engaged: outputs zeroed, device tripped
    /// until it is released and the host sends START.
    pub const ESTOP: u8 = 0x07;

    /// Human-readable name of a fault code.
    pub fn name(code: u8) -> &'static str {
        match code {
            WATCHDOG => "watchdog tripped",
            BAD_FRAME => "bad host frame",
            VERSION => "protocol version mismatch",
            OVERFLOW => "command buffer overflow",
            LATE => "late command",
            NOT_RUNNING => "command while idle",
            ESTOP => "emergency stop",
            _ => "unknown fault",
        }
    }
}

/// Size of a frame with a payload of `payload_len` bytes.
pub const fn frame_len(payload_len: usize) -> usize {
    HEADER + payload_len + TRAILER
}

/// Complete a frame whose payload is already in place: `frame` is exactly
/// [`HEADER`] + payload + [`TRAILER`] bytes long; the sync marker, LEN,
/// TYPE and the CRC are written around the payload. Returns the frame
/// length.
pub fn seal(frame: &mut [u8], ty: u8) -> Result<usize, WireError> {
    let total = frame.len();
    let Some(plen) = total.checked_sub(HEADER + TRAILER) else {
        return Err(WireError::BufferTooSmall(HEADER + TRAILER));
    };
    if plen > MAX_PAYLOAD {
        return Err(WireError::PayloadTooLong(plen));
    }
    frame[..2].copy_from_slice(&SYNC);
    frame[2..4].copy_from_slice(&(plen as u16).to_le_bytes());
    frame[4] = ty;
    let crc = CRC16.checksum(&frame[2..HEADER + plen]);
    frame[HEADER + plen..].copy_from_slice(&crc.to_le_bytes());
    Ok(total)
}

/// Encode a frame of type `ty` with a payload of `payload_len` bytes at the
/// start of `out`; `fill` writes the payload into a slice of exactly that
/// length. Returns the frame length.
pub fn encode_frame(
    out: &mut [u8],
    ty: u8,
    payload_len: usize,
    fill: impl FnOnce(&mut [u8]),
) -> Result<usize, WireError> {
    if payload_len > MAX_PAYLOAD {
        return Err(WireError::PayloadTooLong(payload_len));
    }
    let total = frame_len(payload_len);
    let Some(frame) = out.get_mut(..total) else {
        return Err(WireError::BufferTooSmall(total));
    };
    fill(&mut frame[HEADER..HEADER + payload_len]);
    seal(frame, ty)
}

/// Encode a frame of type `ty` carrying `payload` at the start of `out`.
pub fn encode_payload(out: &mut [u8], ty: u8, payload: &[u8]) -> Result<usize, WireError> {
    encode_frame(out, ty, payload.len(), |p| p.copy_from_slice(payload))
}

/// `N` bytes of `b` from `at` (zeros where `b` is too short: callers check
/// lengths first, this only keeps a wrong length from panicking).
pub(crate) fn rd<const N: usize>(b: &[u8], at: usize) -> [u8; N] {
    let mut a = [0u8; N];
    if let Some(s) = b.get(at..at.saturating_add(N)) {
        a.copy_from_slice(s);
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent bitwise CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF,
    /// MSB first, no final XOR): the C reference of `docs/PROTOCOL.md` §3.
    pub(crate) fn bitwise_crc(data: &[u8]) -> u16 {
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
    fn crc_is_ccitt_false() {
        assert_eq!(CRC16.checksum(b"123456789"), 0x29B1);
        assert_eq!(bitwise_crc(b"123456789"), 0x29B1);
        for data in [&b""[..], b"\x00", b"\xA5\x5A\x00\x00\x02", &[0xFF; 300]] {
            assert_eq!(CRC16.checksum(data), bitwise_crc(data));
        }
    }

    /// `docs/PROTOCOL.md` §10: START is `A5 5A 00 00 02 DE EC`.
    #[test]
    fn start_frame_of_the_worked_example() {
        let mut out = [0u8; 16];
        assert_eq!(encode_payload(&mut out, ty::START, &[]), Ok(7));
        assert_eq!(out[..7], [0xA5, 0x5A, 0x00, 0x00, 0x02, 0xDE, 0xEC]);
    }

    #[test]
    fn encoding_refuses_what_does_not_fit() {
        let mut out = [0u8; 8];
        assert_eq!(
            encode_payload(&mut out, ty::HEARTBEAT, &[0; 4]),
            Err(WireError::BufferTooSmall(11))
        );
        let mut big = [0u8; MAX_FRAME + 10];
        assert_eq!(
            encode_frame(&mut big, ty::HEARTBEAT, MAX_PAYLOAD + 1, |_| {}),
            Err(WireError::PayloadTooLong(MAX_PAYLOAD + 1))
        );
        assert_eq!(
            encode_frame(&mut big, ty::HEARTBEAT, MAX_PAYLOAD, |_| {}),
            Ok(MAX_FRAME)
        );
        assert_eq!(seal(&mut out[..6], 1), Err(WireError::BufferTooSmall(7)));
    }
}
