//! The kilotouch serial protocol on the wire (`docs/PROTOCOL.md`), for the
//! host (`kilotouch_rig::serial`), its device emulator and the firmware
//! (`firmware/`): one definition of the bytes.
//!
//! `#![no_std]` and without an allocator: every buffer is a caller's slice
//! or a fixed array, every size has a constant bound, and nothing panics on
//! any input (decoding refuses what it cannot read; encoding returns
//! [`WireError`] when the output does not fit).
//!
//! * [`frame`]: layout, CRC-16/CCITT-FALSE, frame types, flags and fault
//!   codes, encoding a frame into a slice.
//! * [`items`]: the fixed-size block items (DAQ commands and samples, trap
//!   commands, tweezer samples) and block payloads.
//! * [`message`]: HELLO (identity with bounded strings), STATUS, FAULT,
//!   SCENE (a tweezer's obstacles).
//! * [`info`]: the host's optional information frames (trial, screen).
//! * [`decoder`]: the resynchronising stream decoder with a fixed buffer.
//! * [`seq`]: extension of the wire's 32-bit sequence numbers.
//! * [`testing`]: test frames (plant model, late-command policy, simulated
//!   emergency stop, fault injection, cost counters).

#![no_std]

pub mod contract;
pub mod decoder;
pub mod frame;
pub mod info;
pub mod items;
pub mod message;
pub mod seq;
pub mod testing;

pub use decoder::{Decoder, DecoderStats, FrameRef};
pub use frame::{
    CRC16, HEADER, MAX_FRAME, MAX_PAYLOAD, PROTOCOL_VERSION, SYNC, TRAILER, WireError, fault, flag,
    ty,
};
pub use items::{
    DaqCommand, DaqSample, TrapCommand, TweezerWireSample, WireItem, block_header, block_item,
    block_len, encode_block, max_items, tweezer_status,
};
pub use message::{
    Caps, DaqCaps, DeviceKind, DeviceState, FaultReport, Hello, MAX_SCENE_OBSTACLES, Scene,
    SceneObstacle, Status, TweezerCaps,
};
pub use seq::unwrap_seq;
