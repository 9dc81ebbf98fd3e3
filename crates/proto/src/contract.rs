//! The decoder's contract as an executable check, shared by the property
//! test (`tests/decoder_props.rs`) and the fuzz target (`fuzz/`): fed any
//! byte sequence in any pieces, the [`Decoder`] never panics, always takes
//! a piece of up to [`MAX_FRAME`] bytes once it has returned every frame it
//! holds, stays within its buffer, and every frame it returns is one that
//! lies in the input — type, payload and CRC exactly as sent — after the
//! previous one (it refuses or decodes, never invents or alters a frame).

use crate::decoder::Decoder;
use crate::frame::{MAX_FRAME, MAX_PAYLOAD, encode_payload};

/// A broken promise of the decoder, with the index of the frame or piece.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Violation {
    /// Decoded frame `n` does not occur in the input after frame `n − 1`.
    NotInInput(u64),
    /// A payload longer than [`MAX_PAYLOAD`] came out.
    PayloadTooLong(u64),
    /// Piece `n` was not taken whole although every frame had been drained.
    PieceRefused(u64),
    /// Less than [`MAX_FRAME`] bytes free after draining.
    BufferFull,
    /// The decoder's frame counter disagrees with the frames returned.
    CountMismatch,
}

/// How to feed the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feed {
    /// Slices through [`Decoder::push`].
    Slices,
    /// One byte at a time through [`Decoder::push_byte`].
    Bytes,
}

/// Start of the first occurrence of `needle` in `hay`.
fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() {
        return Some(0);
    }
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Feed `stream` to a new decoder in pieces of `piece()` bytes (clamped to
/// 1 ..= [`MAX_FRAME`]), draining frames after every piece, and check the
/// contract (module docs). Returns the number of frames decoded.
pub fn check_stream(
    stream: &[u8],
    mut piece: impl FnMut() -> usize,
    feed: Feed,
) -> Result<u64, Violation> {
    let mut d = Decoder::new();
    let mut enc = [0u8; MAX_FRAME];
    let (mut rest, mut cursor, mut frames, mut pieces) = (stream, 0usize, 0u64, 0u64);
    while !rest.is_empty() {
        let want = piece().clamp(1, MAX_FRAME).min(rest.len());
        let taken = match feed {
            Feed::Slices => d.push(&rest[..want]),
            Feed::Bytes => rest[..want].iter().take_while(|&&b| d.push_byte(b)).count(),
        };
        if taken != want {
            return Err(Violation::PieceRefused(pieces));
        }
        pieces += 1;
        rest = &rest[taken..];
        while let Some(f) = d.next_frame() {
            if f.payload.len() > MAX_PAYLOAD {
                return Err(Violation::PayloadTooLong(frames));
            }
            let n = encode_payload(&mut enc, f.ty, f.payload)
                .map_err(|_| Violation::PayloadTooLong(frames))?;
            let at = find(&stream[cursor..], &enc[..n]).ok_or(Violation::NotInInput(frames))?;
            cursor += at + n;
            frames += 1;
        }
        if Decoder::CAPACITY - d.buffered() < MAX_FRAME {
            return Err(Violation::BufferFull);
        }
    }
    if d.stats().frames != frames {
        return Err(Violation::CountMismatch);
    }
    Ok(frames)
}

/// [`check_stream`] for a fuzzer's input: the first byte chooses the feed
/// (bit 0) and seeds the piece sizes (1 ..= 1100 bytes, an LCG), the rest
/// is the stream.
pub fn check_fuzz_input(data: &[u8]) -> Result<u64, Violation> {
    let Some((&k, stream)) = data.split_first() else {
        return Ok(0);
    };
    let mut x = u32::from(k) | 0x100;
    let piece = move || {
        x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        1 + (x >> 16) as usize % 1100
    };
    let feed = if k & 1 == 0 {
        Feed::Slices
    } else {
        Feed::Bytes
    };
    check_stream(stream, piece, feed)
}
