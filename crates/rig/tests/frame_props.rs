//! Property tests of the serial frame decoder and the payload parsers
//! (`docs/PROTOCOL.md`): for ANY bytes the decoder neither panics nor
//! stalls, and valid frames buried in arbitrary garbage, delivered in
//! arbitrary pieces, all come out, in order and intact. The parsers of
//! HELLO, STATUS, FAULT and sample blocks accept or refuse any payload
//! without panicking. Case counts are fixed, so the suite's time is
//! bounded (≈ 1 s in a debug build).

#![allow(clippy::unwrap_used)]

use kilotouch_rig::serial::frame::{
    self, DaqSample, Decoder, MAX_FRAME, MAX_PAYLOAD, block_header, parse_fault, parse_hello,
    parse_status, write_frame,
};
use proptest::prelude::*;

/// Feed `bytes` to `dec` in pieces of the given sizes (cycled), draining
/// frames as they come; returns (type, payload) of every frame.
fn decode(dec: &mut Decoder, bytes: &[u8], pieces: &[usize]) -> Vec<(u8, Vec<u8>)> {
    let mut out = Vec::new();
    let mut rest = bytes;
    let mut i = 0usize;
    while !rest.is_empty() {
        let want = pieces[i % pieces.len()].clamp(1, MAX_FRAME);
        i += 1;
        let piece = &rest[..want.min(rest.len())];
        let taken = dec.push(piece);
        rest = &rest[taken..];
        while let Some(f) = dec.next_frame() {
            out.push((f.ty, f.payload.to_vec()));
        }
        // After next_frame returned None at least MAX_FRAME bytes fit.
        assert!(taken > 0 || piece.is_empty(), "the decoder took nothing");
    }
    out
}

fn frame_strategy() -> impl Strategy<Value = (u8, Vec<u8>)> {
    (any::<u8>(), prop::collection::vec(any::<u8>(), 0..200))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic_or_stall(
        bytes in prop::collection::vec(any::<u8>(), 0..4096),
        pieces in prop::collection::vec(1usize..600, 1..8),
    ) {
        let mut dec = Decoder::new();
        let frames = decode(&mut dec, &bytes, &pieces);
        for (_, p) in &frames {
            prop_assert!(p.len() <= MAX_PAYLOAD);
        }
        let s = dec.stats();
        prop_assert_eq!(s.frames, frames.len() as u64);
    }

    #[test]
    fn valid_frames_in_garbage_all_come_out_in_order(
        frames in prop::collection::vec(frame_strategy(), 1..12),
        garbage in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..300), 13),
        pieces in prop::collection::vec(1usize..700, 1..8),
    ) {
        let mut bytes = Vec::new();
        for (i, (ty, payload)) in frames.iter().enumerate() {
            bytes.extend_from_slice(&garbage[i]);
            write_frame(&mut bytes, *ty, |o| o.extend_from_slice(payload));
        }
        bytes.extend_from_slice(&garbage[12]);
        // Padding: a garbage header claiming a long payload is resolved.
        bytes.extend(std::iter::repeat_n(0u8, MAX_FRAME));
        let mut dec = Decoder::new();
        let got = decode(&mut dec, &bytes, &pieces);
        // Every sent frame, in order (garbage may, rarely, hold a frame of
        // its own with a valid CRC: the sent ones are a subsequence).
        let mut it = got.iter();
        for f in &frames {
            prop_assert!(it.any(|g| g == f), "frame {:?} lost", f.0);
        }
    }

    #[test]
    fn payload_parsers_accept_or_refuse_anything(
        payload in prop::collection::vec(any::<u8>(), 0..MAX_PAYLOAD),
    ) {
        let _ = parse_hello(&payload);
        let _ = parse_status(&payload);
        let _ = parse_fault(&payload);
        if let Some((_, n)) = block_header::<DaqSample>(&payload) {
            for i in 0..n {
                let _ = frame::block_item::<DaqSample>(&payload, i);
            }
        }
    }
}
