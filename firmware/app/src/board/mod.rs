//! The board: clocks, pins, the sample timer, the link and the analog front
//! end. `hw` drives a real board (STM32F4DISCOVERY or Olimex STM32-H405:
//! DAC, PWM, ADC, encoders, USART2 at 2 Mbaud, USB CDC-ACM, e-stop,
//! independent watchdog); `qemu` runs on QEMU's netduinoplus2 with the
//! plant model instead of the analog front end. Pin map: docs/FIRMWARE.md.
//!
//! Register access goes through the PAC (`stm32f4xx_hal::pac`); the few
//! places that touch a peripheral outside its owner (the USART data
//! register from the interrupt and the idle loop, the cycle counter, the
//! panic handler) are marked `unsafe` with their reasons.

#![allow(unsafe_code)]

#[cfg(not(feature = "qemu"))]
mod hw;
#[cfg(feature = "qemu")]
mod qemu;

#[cfg(not(feature = "qemu"))]
pub use hw::{Board, Frontend, Link, cycles, estop_edge, init, safe_outputs, usb_read};
#[cfg(feature = "qemu")]
pub use qemu::{Board, Frontend, Link, cycles, init};

use kilotouch_device::{Config, LatePolicy};
use stm32f4xx_hal::pac;

/// Sample rate, Hz.
pub const SAMPLE_RATE_HZ: u32 = 10_000;

/// The device settings of this build.
pub fn config() -> Config {
    Config {
        sample_rate_hz: SAMPLE_RATE_HZ,
        // QEMU hands the firmware the host's bytes one at a time, each a
        // round trip between two of its threads, which a loaded machine
        // slows to a few hundred bytes per second while the emulated clock
        // runs on: the QEMU build's window is 5 s, a board's 100 ms
        // (docs/FIRMWARE.md).
        watchdog_ms: if cfg!(feature = "qemu") { 5000 } else { 100 },
        batch: 10,
        // A simulated plant waits for late commands, as the emulator does;
        // a real one cannot.
        policy: if cfg!(feature = "qemu") {
            LatePolicy::Wait
        } else {
            LatePolicy::Hold
        },
        max_code: 32767,
        test_frames: cfg!(feature = "qemu"),
        name: NAME,
        firmware: crate::FIRMWARE,
    }
}

/// HELLO name of the build.
const NAME: &str = if cfg!(feature = "qemu") {
    "kilotouch DAQ (qemu netduinoplus2, plant model)"
} else if cfg!(feature = "board-h405") {
    "kilotouch DAQ (Olimex STM32-H405)"
} else {
    "kilotouch DAQ (STM32F4DISCOVERY)"
};

/// Turn USART2 on: transmitter, receiver and receive interrupt (its clock
/// and baud rate are the board's to set first).
fn usart2_enable(u: &pac::USART2) {
    u.cr1().write(|w| {
        w.ue()
            .set_bit()
            .te()
            .set_bit()
            .re()
            .set_bit()
            .rxneie()
            .set_bit()
    });
}

/// The next received byte of USART2, if any (clears an overrun, whose
/// lost bytes the decoder's resynchronisation absorbs).
pub fn usart_read() -> Option<u8> {
    // SAFETY: reads of SR then DR, the documented sequence that clears RXNE
    // and ORE; only the USART2 interrupt reads DR.
    let u = unsafe { &*pac::USART2::ptr() };
    let sr = u.sr().read();
    (sr.rxne().bit_is_set() || sr.ore().bit_is_set())
        .then(|| u.dr().read().bits() as u8)
        .filter(|_| sr.rxne().bit_is_set())
}

/// Send one byte on USART2, waiting for the data register to be free.
pub fn usart_write(b: u8) {
    // SAFETY: only the idle loop writes DR; TXE is polled first.
    let u = unsafe { &*pac::USART2::ptr() };
    while u.sr().read().txe().bit_is_clear() {}
    u.dr().write(|w| unsafe { w.bits(u16::from(b)) });
}
