//! The resynchronising stream decoder (`docs/PROTOCOL.md` §3, "Receiving").
//!
//! [`Decoder`] keeps the unconsumed bytes in a fixed buffer of
//! 2·[`MAX_FRAME`] bytes (bounded memory, no allocation). It scans for the
//! sync marker, rejects a header whose LEN exceeds [`MAX_PAYLOAD`], and on a
//! CRC mismatch discards only the first sync byte and scans again, so a
//! valid frame that follows garbage or a corrupted frame is always found
//! (resynchronisation on the next valid frame). A header whose (corrupted)
//! LEN runs past the start of a complete valid frame is dropped without
//! waiting for the bytes it claims: otherwise a device that has paused for
//! the host's next commands would leave the host waiting for bytes that
//! never come.
//!
//! Every frame it returns passed its CRC and lies in the input exactly as
//! returned (type and payload), after the previous frame; it never panics
//! (property test `tests/decoder_props.rs`, fuzz target `fuzz/`).

use crate::frame::{CRC16, HEADER, MAX_FRAME, MAX_PAYLOAD, SYNC, TRAILER};

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
    /// Payload (at most [`MAX_PAYLOAD`] bytes).
    pub payload: &'a [u8],
}

/// Resynchronising stream decoder with a fixed buffer (module docs).
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: [u8; Self::CAPACITY],
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
    /// Buffer capacity, bytes: a false header claiming the largest payload
    /// can be rejected without losing the valid frame behind it.
    pub const CAPACITY: usize = 2 * MAX_FRAME;

    /// Empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0u8; Self::CAPACITY],
            start: 0,
            end: 0,
            stats: DecoderStats {
                frames: 0,
                crc_errors: 0,
                bad_lengths: 0,
                bytes_skipped: 0,
            },
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

    /// Append one byte (what a receive interrupt has); `false` when the
    /// buffer is full (call [`next_frame`](Self::next_frame) first).
    pub fn push_byte(&mut self, b: u8) -> bool {
        if self.end == Self::CAPACITY && self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        if self.end == Self::CAPACITY {
            return false;
        }
        self.buf[self.end] = b;
        self.end += 1;
        true
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
    use super::*;
    use crate::frame::{encode_payload, ty};

    #[test]
    fn oversized_length_and_lone_sync_bytes_are_skipped() {
        let mut good = [0u8; 16];
        let n = encode_payload(&mut good, ty::HEARTBEAT, &[1, 2, 3, 4]).unwrap();
        let mut d = Decoder::new();
        d.push(&[0xA5, 0x5A, 0xFF, 0xFF, 0x01, 0xA5, 0x00, 0xA5]);
        d.push(&good[..n]);
        let f = d.next_frame().unwrap();
        assert_eq!((f.ty, f.payload), (ty::HEARTBEAT, &[1u8, 2, 3, 4][..]));
        assert_eq!(d.stats().bad_lengths, 1);
        assert!(d.next_frame().is_none());
        assert_eq!(d.buffered(), 0);
    }

    /// A frame whose LEN was corrupted to claim 768+ bytes, then a STATUS
    /// arriving a byte at a time (`push_byte`, as the firmware's receive
    /// interrupt feeds it): the STATUS is decoded at once.
    #[test]
    fn a_corrupted_length_does_not_hide_the_frames_after_it() {
        let mut stream = [0u8; 64];
        let a = encode_payload(&mut stream, ty::SAMPLES, &[7; 20]).unwrap();
        stream[3] = 0x03;
        let b = encode_payload(&mut stream[a..], ty::STATUS, &[9; 17]).unwrap();
        let mut d = Decoder::new();
        let mut got = None;
        for &x in &stream[..a + b] {
            assert!(d.push_byte(x));
            if let Some(f) = d.next_frame() {
                got = Some((f.ty, f.payload.len()));
                break;
            }
        }
        assert_eq!(got, Some((ty::STATUS, 17)));
        assert_eq!(d.stats().bad_lengths, 1);
    }

    #[test]
    fn a_full_buffer_refuses_bytes_until_drained() {
        let mut d = Decoder::new();
        // A header claiming 1024 bytes keeps everything buffered.
        let mut n = 0;
        for b in [0xA5, 0x5A, 0x00, 0x04]
            .into_iter()
            .chain(core::iter::repeat(0))
        {
            if !d.push_byte(b) {
                break;
            }
            n += 1;
        }
        assert_eq!(n, Decoder::CAPACITY);
        assert!(d.next_frame().is_none());
        assert!(Decoder::CAPACITY - d.buffered() >= MAX_FRAME);
        assert!(d.push_byte(0));
    }
}
