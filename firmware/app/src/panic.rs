//! The panic handler: outputs to zero, then reset.
//!
//! A panic (which the firmware is written never to reach: no unwrap, no
//! indexing that can fail on device input) first disables the amplifiers
//! and puts every output at its zero (board builds; QEMU has no outputs),
//! then requests a system reset through the SCB (AIRCR.SYSRESETREQ). After
//! the reset the device is idle with outputs off until a host sends START,
//! and the host sees the link go quiet (its progress watchdog, then the
//! handshake of a reconnect). The independent watchdog (5 ms) resets a
//! firmware that hangs instead of panicking.

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo<'_>) -> ! {
    cortex_m::interrupt::disable();
    #[cfg(not(feature = "qemu"))]
    crate::board::safe_outputs();
    cortex_m::peripheral::SCB::sys_reset()
}
