//! kilotouch DAQ firmware (docs/FIRMWARE.md): the serial protocol of
//! docs/PROTOCOL.md on an STM32F405/F407, as an RTIC application.
//!
//! Tasks, by priority (higher preempts lower):
//!
//! 4. `estop` (EXTI1, boards only): the emergency-stop input zeroes the
//!    outputs and trips the device.
//! 3. `tick` (TIM4 update, 10 kHz): one sample period (`Device::tick`): the
//!    sensors of the period that ended, the command of the one that begins,
//!    batching, watchdog; feeds the independent watchdog; its cost is
//!    counted (DWT cycles on a board, instructions under QEMU's `-icount`).
//! 2. `usart` (USART2 receive): bytes into the decoder; each valid host
//!    frame is handled under the device lock (`Device::handle`).
//! 2. `usb` (OTG_FS, boards only): the USB CDC-ACM link, same decoder path.
//! 0. `idle`: drains the transmit queue to the USART (and USB).
//!
//! The device, the decoder and the queues are fixed-size statics: nothing
//! is allocated. Panics zero the outputs and reset the MCU (`panic.rs`).

#![no_std]
#![no_main]

mod board;
mod panic;

/// Transmit queue, bytes: 50 ms of SAMPLES frames at 10 kHz.
pub const TX_QUEUE: usize = 8192;

/// Firmware version and build hash (from build.rs), shown in HELLO.
pub const FIRMWARE: &str = concat!(
    "kilotouch-firmware ",
    env!("CARGO_PKG_VERSION"),
    " (",
    env!("KILOTOUCH_BUILD_HASH"),
    ")"
);

/// The device's outbox: the producer end of the transmit queue.
pub struct TxQueue(heapless::spsc::Producer<'static, u8>);

impl kilotouch_device::Outbox for TxQueue {
    fn free(&self) -> usize {
        self.0.capacity() - self.0.len()
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            // `free` was checked for the whole frame.
            let _ = self.0.enqueue(b);
        }
    }
}

impl core::fmt::Debug for TxQueue {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TxQueue")
            .field("len", &self.0.len())
            .finish()
    }
}

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true)]
mod app {
    use crate::board::{self, Board, Frontend};
    use crate::{TX_QUEUE, TxQueue};
    use heapless::spsc::{Consumer, Queue};
    use kilotouch_device::Device;
    use kilotouch_proto::Decoder;

    #[shared]
    struct Shared {
        device: Device<Frontend, TxQueue>,
    }

    #[local]
    struct Local {
        board: Board,
        link: board::Link,
        decoder: Decoder,
        tx: Consumer<'static, u8>,
    }

    #[init(local = [queue: Queue<u8, TX_QUEUE> = Queue::new()])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let (producer, consumer) = cx.local.queue.split();
        let (board, link, frontend, serial) = board::init(cx.device, cx.core);
        let device = Device::new(board::config(), &serial, frontend, TxQueue(producer));
        (
            Shared { device },
            Local {
                board,
                link,
                decoder: Decoder::new(),
                tx: consumer,
            },
        )
    }

    #[idle(local = [link, tx])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            cx.local.link.drain(cx.local.tx);
        }
    }

    #[task(binds = TIM4, priority = 3, local = [board], shared = [device])]
    fn tick(mut cx: tick::Context) {
        let board = cx.local.board;
        board.ack_tick();
        let t0 = board::cycles();
        cx.shared.device.lock(|d| {
            d.tick();
            let plant = board.plant_cost(d);
            d.record_cost(board::cycles().wrapping_sub(t0), plant);
        });
        board.feed_watchdog();
    }

    #[task(binds = USART2, priority = 2, local = [decoder], shared = [device])]
    fn usart(mut cx: usart::Context) {
        let dec = cx.local.decoder;
        while let Some(b) = board::usart_read() {
            if !dec.push_byte(b) {
                // Cannot happen: frames are drained after every byte.
                dec.clear();
            }
            while let Some(f) = dec.next_frame() {
                cx.shared.device.lock(|d| d.handle(f.ty, f.payload));
            }
        }
        let errors = dec.stats().crc_errors;
        cx.shared.device.lock(|d| d.set_host_crc_errors(errors));
    }

    /// The emergency-stop input changed (both edges).
    #[cfg(not(feature = "qemu"))]
    #[task(binds = EXTI1, priority = 4, shared = [device])]
    fn estop(mut cx: estop::Context) {
        let engaged = board::estop_edge();
        cx.shared.device.lock(|d| d.set_estop(engaged));
    }

    /// The USB CDC-ACM link: polled on its interrupt; received bytes go
    /// through the same decoder path as the USART's.
    #[cfg(not(feature = "qemu"))]
    #[task(binds = OTG_FS, priority = 2, local = [usb_decoder: Decoder = Decoder::new()], shared = [device])]
    fn usb(mut cx: usb::Context) {
        let dec = cx.local.usb_decoder;
        let mut buf = [0u8; 64];
        while let Some(n) = board::usb_read(&mut buf) {
            let mut rest = &buf[..n];
            while !rest.is_empty() {
                let k = dec.push(rest);
                rest = &rest[k..];
                while let Some(f) = dec.next_frame() {
                    cx.shared.device.lock(|d| d.handle(f.ty, f.payload));
                }
            }
        }
    }
}
