//! The device side of the kilotouch serial DAQ protocol (`docs/PROTOCOL.md`)
//! for the firmware (`firmware/app`), independent of the board: `no_std`,
//! no allocator, every buffer fixed, tested on the host
//! (`cargo test -p kilotouch-device --target x86_64-unknown-linux-gnu`).
//!
//! * [`device`]: the state machine on the sample clock — command buffer,
//!   late commands, batching, STATUS while waiting, the watchdog, clamps
//!   and flags, the emergency stop, HELLO, test frames.
//! * [`ring`]: the command buffer.
//! * [`plant`]: the plant model of the QEMU build (second-order sections,
//!   accelerometer, encoders).

#![no_std]

pub mod analog;
pub mod device;
pub mod plant;
pub mod ring;

pub use device::{Config, Counters, Device, Frontend, LatePolicy, Outbox};
pub use plant::PlantFrontend;

#[cfg(test)]
extern crate std;

#[cfg(test)]
mod tests;
