//! Property tests of the stream decoder (`docs/PROTOCOL.md` §3): for any
//! bytes in any pieces it keeps its contract
//! ([`kilotouch_proto::contract`]: no panic, bounded buffer, every frame it
//! returns lies in the input as sent); valid frames buried in garbage all
//! come out in order; damaged frames are refused, never altered. Case
//! counts and the seed are fixed, so the run is bounded and repeatable
//! (≈ 1 s in a debug build).

#![allow(clippy::unwrap_used)]

use kilotouch_proto::contract::{Feed, check_fuzz_input, check_stream};
use kilotouch_proto::frame::encode_payload;
use kilotouch_proto::{Decoder, MAX_FRAME, MAX_PAYLOAD};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

fn config() -> ProptestConfig {
    ProptestConfig {
        cases: 256,
        rng_seed: RngSeed::Fixed(0x7072_6f74),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

fn encode(ty: u8, payload: &[u8]) -> Vec<u8> {
    let mut b = vec![0u8; MAX_FRAME];
    let n = encode_payload(&mut b, ty, payload).unwrap();
    b.truncate(n);
    b
}

fn pieces(sizes: Vec<usize>) -> impl FnMut() -> usize {
    let mut i = 0;
    move || {
        i += 1;
        sizes[i % sizes.len()]
    }
}

/// Decode `bytes` fed in the given pieces; every frame as (type, payload).
fn decode_all(bytes: &[u8], sizes: &[usize]) -> Vec<(u8, Vec<u8>)> {
    let mut d = Decoder::new();
    let mut out = Vec::new();
    let mut rest = bytes;
    let mut i = 0;
    while !rest.is_empty() {
        let n = d.push(&rest[..sizes[i % sizes.len()].clamp(1, MAX_FRAME).min(rest.len())]);
        i += 1;
        rest = &rest[n..];
        while let Some(f) = d.next_frame() {
            out.push((f.ty, f.payload.to_vec()));
        }
    }
    out
}

/// Bytes rich in sync markers and plausible headers, so that the decoder's
/// resynchronisation paths are exercised, not only its scan.
fn nasty_bytes(max: usize) -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        prop_oneof![
            3 => any::<u8>(),
            1 => Just(0xA5u8),
            1 => Just(0x5Au8),
            1 => Just(0x00u8),
            1 => Just(0x04u8),
        ],
        0..max,
    )
}

proptest! {
    #![proptest_config(config())]

    /// Any bytes, any pieces, either feed: the contract holds.
    #[test]
    fn any_bytes_keep_the_contract(
        bytes in nasty_bytes(6000),
        sizes in prop::collection::vec(1usize..1100, 1..8),
        bytewise in any::<bool>(),
    ) {
        let feed = if bytewise { Feed::Bytes } else { Feed::Slices };
        prop_assert!(check_stream(&bytes, pieces(sizes), feed).is_ok());
    }

    /// The fuzz target's own input mapping on random inputs.
    #[test]
    fn fuzz_inputs_keep_the_contract(data in nasty_bytes(3000)) {
        prop_assert!(check_fuzz_input(&data).is_ok());
    }

    /// Valid frames buried in garbage (which may itself hold sync markers
    /// and false headers) all come out, in order and intact.
    #[test]
    fn valid_frames_in_garbage_all_come_out_in_order(
        frames in prop::collection::vec(
            (any::<u8>(), prop_oneof![
                4 => prop::collection::vec(any::<u8>(), 0..64),
                1 => prop::collection::vec(any::<u8>(), 0..=MAX_PAYLOAD),
            ]),
            1..12),
        garbage in prop::collection::vec(nasty_bytes(300), 13),
        sizes in prop::collection::vec(1usize..1100, 1..8),
    ) {
        let mut bytes = Vec::new();
        for (i, (t, p)) in frames.iter().enumerate() {
            bytes.extend_from_slice(&garbage[i]);
            bytes.extend_from_slice(&encode(*t, p));
        }
        bytes.extend_from_slice(&garbage[12]);
        // A false header at the end claiming a long payload is resolved.
        bytes.extend(std::iter::repeat_n(0u8, MAX_FRAME));
        let got = decode_all(&bytes, &sizes);
        let mut it = got.iter();
        for f in &frames {
            prop_assert!(it.any(|g| g == f), "frame of type {:#x} lost", f.0);
        }
    }

    /// One damaged byte in a frame: that frame is refused (CRC-16 detects
    /// every burst of ≤ 16 bits), the frames around it come out unchanged.
    #[test]
    fn a_damaged_frame_is_refused_never_altered(
        payloads in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..100), 3),
        at in any::<prop::sample::Index>(),
        x in 1..=255u8,
    ) {
        let f: Vec<Vec<u8>> = payloads.iter().map(|p| encode(0x42, p)).collect();
        let mut bytes = f.concat();
        let pos = f[0].len() + at.index(f[1].len());
        bytes[pos] ^= x;
        bytes.extend(std::iter::repeat_n(0u8, MAX_FRAME));
        let got = decode_all(&bytes, &[bytes.len()]);
        let want = vec![(0x42, payloads[0].clone()), (0x42, payloads[2].clone())];
        prop_assert_eq!(got, want);
    }
}

/// The check counts the frames of a known stream, in either feed.
#[test]
fn the_contract_check_counts_known_frames() {
    let f = encode(1, b"abc");
    assert_eq!(check_stream(&f, || 3, Feed::Slices), Ok(1));
    assert_eq!(check_stream(&f, || 1, Feed::Bytes), Ok(1));
    assert_eq!(check_stream(&[], || 1, Feed::Slices), Ok(0));
    // Two copies: both found, in order.
    let two = [f.clone(), f].concat();
    assert_eq!(check_stream(&two, || 5, Feed::Slices), Ok(2));
    // A frame split by a byte the sender never sent is refused.
    let mut cut = two.clone();
    cut.insert(4, 0);
    assert_eq!(check_stream(&cut, || 7, Feed::Bytes), Ok(1));
}
