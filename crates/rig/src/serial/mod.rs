//! Live rigs over a serial link: the protocol of `docs/PROTOCOL.md`, the
//! host side ([`SerialRig`], [`LinkTweezer`]) and the device emulators that
//! serve the protocol on a pseudo-terminal with the simulated plant or
//! tweezer behind it (`kilotouch emulate daq|tweezer --pty`).
//!
//! * [`frame`]: framing (sync, length, type, payload, CRC-16/CCITT-FALSE),
//!   payloads and the resynchronising [`frame::Decoder`].
//! * [`emulator`]: device logic independent of the transport (pacing,
//!   command buffer, batching, watchdog, fault injection), with the DAQ
//!   instrument ([`emulator::DaqInstrument`]).
//! * [`pty`]: pseudo-terminal creation and the serving loop.
//! * [`rig`]: [`SerialRig`] ([`crate::Rig`]) and the shared [`rig::Link`].
//! * [`lead`]: the command lead of a pipelined block exchange, shared by
//!   both links.
//! * [`test_link`]: the host side of test frames (the firmware's QEMU build:
//!   plant model, late-command policy, e-stop, fault injection, cost).
//! * [`tweezer_link`]: [`LinkTweezer`] ([`crate::Tweezer`]) and the tweezer
//!   instrument.
//! * [`watch`]: the host's watchdog on stream progress (new samples, not
//!   frames).

pub mod announce;
pub mod emulator;
pub mod frame;
pub mod lead;
pub mod pty;
pub mod rig;
pub mod test_link;
pub mod tweezer_link;
pub mod watch;

pub use emulator::{DaqInstrument, Emulator, EmulatorConfig, FaultInjection, Misbehaviour};
pub use rig::{CommandLead, LinkStats, MAX_LEAD_SAMPLES, SerialConfig, SerialRig};
pub use tweezer_link::{LinkTweezer, TweezerInstrument};
