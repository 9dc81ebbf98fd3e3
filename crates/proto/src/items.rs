//! Fixed-size block items and block payloads (`docs/PROTOCOL.md` §4–§6).
//!
//! A block payload is `u32 seq` (sequence number of the first item), `u8 n`
//! (item count) and `n` items of [`WireItem::SIZE`] bytes; its length is
//! exactly `5 + n · SIZE`, at most [`MAX_PAYLOAD`].

use crate::frame::{HEADER, MAX_PAYLOAD, TRAILER, WireError, encode_frame, rd};

/// One fixed-size item of a block payload (little-endian fields).
pub trait WireItem: Copy + Default + Send + core::fmt::Debug {
    /// Encoded size, bytes.
    const SIZE: usize;
    /// Write the encoding into the first [`SIZE`](Self::SIZE) bytes of
    /// `out` (a shorter `out` gets a truncated encoding, never a panic).
    fn encode(&self, out: &mut [u8]);
    /// Decode from the first [`SIZE`](Self::SIZE) bytes of `b` (missing
    /// bytes read as zero; callers check lengths with [`block_header`]).
    fn decode(b: &[u8]) -> Self;
}

/// DAQ command of one sample (host → device, §5.2): output codes, full
/// scale ±32767 = ± the limits of [`crate::DaqCaps`] (−32768 counts as
/// −32767).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DaqCommand {
    /// Pantograph force codes (x, y).
    pub force: [i16; 2],
    /// Haptuator drive code.
    pub drive: i16,
}

/// DAQ sample (device → host, §6.1).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DaqSample {
    /// Encoder counts (x, y).
    pub enc: [i32; 2],
    /// Accelerometer codes (x, y, z).
    pub acc: [i16; 3],
    /// Flags ([`crate::flag`]).
    pub flags: u8,
}

/// Tweezer trap command of one sample (host → device, §5.3), m.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrapCommand {
    /// Trap centre (x, y), m.
    pub trap_m: [f64; 2],
}

/// Tweezer status bits of [`TweezerWireSample::status`] (§6.2).
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
    /// The trap set-point for this sample had not arrived: the previous
    /// one was held (a free-running device, `docs/PROTOCOL.md` §7).
    pub const CMD_LATE: u8 = 0x80;
}

/// Tweezer sample (device → host, §6.2).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TweezerWireSample {
    /// Bead centre (x, y), m.
    pub bead_m: [f64; 2],
    /// Position-detector sum signal, V.
    pub sum_v: f32,
    /// Position-detector difference signals (x, y), V: the raw signal a
    /// trap calibration fits.
    pub detector_v: [f32; 2],
    /// Status bits ([`tweezer_status`]).
    pub status: u8,
}

/// Little-endian field writer over a slice (bytes past its end are dropped).
struct Wr<'a> {
    out: &'a mut [u8],
    at: usize,
}

impl Wr<'_> {
    fn put(&mut self, b: &[u8]) {
        let end = self.at.saturating_add(b.len()).min(self.out.len());
        if let Some(dst) = self.out.get_mut(self.at..end) {
            dst.copy_from_slice(&b[..end - self.at]);
        }
        self.at = self.at.saturating_add(b.len());
    }
}

impl WireItem for DaqCommand {
    const SIZE: usize = 6;
    fn encode(&self, out: &mut [u8]) {
        let mut w = Wr { out, at: 0 };
        w.put(&self.force[0].to_le_bytes());
        w.put(&self.force[1].to_le_bytes());
        w.put(&self.drive.to_le_bytes());
    }
    fn decode(b: &[u8]) -> Self {
        Self {
            force: [i16::from_le_bytes(rd(b, 0)), i16::from_le_bytes(rd(b, 2))],
            drive: i16::from_le_bytes(rd(b, 4)),
        }
    }
}

impl WireItem for DaqSample {
    const SIZE: usize = 15;
    fn encode(&self, out: &mut [u8]) {
        let mut w = Wr { out, at: 0 };
        w.put(&self.enc[0].to_le_bytes());
        w.put(&self.enc[1].to_le_bytes());
        for a in self.acc {
            w.put(&a.to_le_bytes());
        }
        w.put(&[self.flags]);
    }
    fn decode(b: &[u8]) -> Self {
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
    fn encode(&self, out: &mut [u8]) {
        let mut w = Wr { out, at: 0 };
        w.put(&self.trap_m[0].to_le_bytes());
        w.put(&self.trap_m[1].to_le_bytes());
    }
    fn decode(b: &[u8]) -> Self {
        Self {
            trap_m: [f64::from_le_bytes(rd(b, 0)), f64::from_le_bytes(rd(b, 8))],
        }
    }
}

impl WireItem for TweezerWireSample {
    const SIZE: usize = 29;
    fn encode(&self, out: &mut [u8]) {
        let mut w = Wr { out, at: 0 };
        w.put(&self.bead_m[0].to_le_bytes());
        w.put(&self.bead_m[1].to_le_bytes());
        w.put(&self.sum_v.to_le_bytes());
        w.put(&self.detector_v[0].to_le_bytes());
        w.put(&self.detector_v[1].to_le_bytes());
        w.put(&[self.status]);
    }
    fn decode(b: &[u8]) -> Self {
        Self {
            bead_m: [f64::from_le_bytes(rd(b, 0)), f64::from_le_bytes(rd(b, 8))],
            sum_v: f32::from_le_bytes(rd(b, 16)),
            detector_v: [f32::from_le_bytes(rd(b, 20)), f32::from_le_bytes(rd(b, 24))],
            status: b.get(28).copied().unwrap_or(0),
        }
    }
}

/// Most items of type `T` that fit one block frame (≤ 255, the width of
/// the count byte).
pub const fn max_items<T: WireItem>() -> usize {
    let n = (MAX_PAYLOAD - 5) / T::SIZE;
    if n > 255 { 255 } else { n }
}

/// Length of a block frame of `n` items of type `T` (header, payload, CRC).
pub const fn block_len<T: WireItem>(n: usize) -> usize {
    HEADER + 5 + n * T::SIZE + TRAILER
}

/// Encode a block frame `seq u32, n u8, n × item` of type `ty` at the start
/// of `out` (at most [`max_items`]`::<T>()` items are written). Returns the
/// frame length.
pub fn encode_block<T: WireItem>(
    out: &mut [u8],
    ty: u8,
    seq: u32,
    items: &[T],
) -> Result<usize, WireError> {
    let n = items.len().min(max_items::<T>());
    encode_frame(out, ty, 5 + n * T::SIZE, |p| {
        p[..4].copy_from_slice(&seq.to_le_bytes());
        p[4] = n as u8;
        for (it, dst) in items[..n].iter().zip(p[5..].chunks_exact_mut(T::SIZE)) {
            it.encode(dst);
        }
    })
}

/// Header of a block payload: (first sequence number, item count), or
/// `None` when the payload length is not exactly `5 + n · SIZE`.
pub fn block_header<T: WireItem>(payload: &[u8]) -> Option<(u32, usize)> {
    if payload.len() < 5 {
        return None;
    }
    let seq = u32::from_le_bytes(rd(payload, 0));
    let n = payload[4] as usize;
    (payload.len() == 5 + n * T::SIZE).then_some((seq, n))
}

/// Item `i` of a block payload already checked by [`block_header`] (an
/// index past the end reads as the default item).
pub fn block_item<T: WireItem>(payload: &[u8], i: usize) -> T {
    let at = i.saturating_mul(T::SIZE).saturating_add(5);
    T::decode(payload.get(at..at.saturating_add(T::SIZE)).unwrap_or(&[]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{SYNC, ty};

    /// `docs/PROTOCOL.md` §10: COMMANDS for sample 0x01020304, one item
    /// (+16384, −16384, 3277).
    #[test]
    fn commands_frame_of_the_worked_example() {
        let cmd = DaqCommand {
            force: [16384, -16384],
            drive: 3277,
        };
        let mut out = [0u8; 32];
        let n = encode_block(&mut out, ty::COMMANDS, 0x0102_0304, &[cmd]).unwrap();
        assert_eq!(n, 18);
        assert_eq!(
            out[..n],
            [
                0xA5, 0x5A, 0x0B, 0x00, 0x04, 0x04, 0x03, 0x02, 0x01, 0x01, 0x00, 0x40, 0x00, 0xC0,
                0xCD, 0x0C, 0x30, 0x8D
            ]
        );
        assert_eq!(out[..2], SYNC);
        let payload = &out[HEADER..n - TRAILER];
        assert_eq!(block_header::<DaqCommand>(payload), Some((0x0102_0304, 1)));
        assert_eq!(block_item::<DaqCommand>(payload, 0), cmd);
        assert_eq!(block_len::<DaqCommand>(1), n);
    }

    #[test]
    fn items_round_trip_and_blocks_are_bounded() {
        let s = DaqSample {
            enc: [-5, 123_456],
            acc: [-4050, 675, 1],
            flags: crate::flag::CLIPPED,
        };
        let t = TweezerWireSample {
            bead_m: [1e-8, -3.5e-7],
            sum_v: 0.75,
            detector_v: [0.125, -2.5],
            status: tweezer_status::TRAPPED,
        };
        let tc = TrapCommand {
            trap_m: [1.5e-6, -2e-7],
        };
        let mut b = [0u8; 32];
        s.encode(&mut b);
        assert_eq!(DaqSample::decode(&b), s);
        t.encode(&mut b);
        assert_eq!(TweezerWireSample::decode(&b), t);
        tc.encode(&mut b);
        assert_eq!(TrapCommand::decode(&b), tc);
        // Short buffers neither panic nor read out of bounds.
        s.encode(&mut b[..3]);
        // A field not wholly present reads as zero.
        assert_eq!(DaqSample::decode(&[1, 0, 0, 0, 2]).enc, [1, 0]);
        assert_eq!(max_items::<DaqCommand>(), 169);
        assert_eq!(max_items::<DaqSample>(), 67);
        assert_eq!(max_items::<TweezerWireSample>(), 35);
        let mut big = [0u8; crate::MAX_FRAME];
        let many = [s; 300];
        let n = encode_block(&mut big, ty::SAMPLES, 7, &many).unwrap();
        assert_eq!(n, block_len::<DaqSample>(67));
        let p = &big[HEADER..n - TRAILER];
        assert_eq!(block_header::<DaqSample>(p), Some((7, 67)));
        assert_eq!(block_header::<DaqSample>(&p[..p.len() - 1]), None);
        assert_eq!(block_item::<DaqSample>(p, 1000), DaqSample::default());
    }
}
