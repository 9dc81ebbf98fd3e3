//! QEMU's netduinoplus2 (STM32F405RG): what QEMU emulates — USART2 (the
//! second `-serial`), SysTick, the NVIC — and the plant model as the analog
//! front end. QEMU's RCC is a stub, so the clocks are left at reset (HSI,
//! no PLL: nothing to wait for). The sample clock is SysTick on QEMU's
//! 168 MHz CPU clock (reload 16 800): its exception pends TIM4's interrupt,
//! to which the sample task is bound as on a board. (QEMU 7.2's model of
//! TIM2–5 reschedules its update events from a wrong base and fires about
//! 100 times too slowly, measured.)

use crate::TxQueue;
use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;
use heapless::spsc::Consumer;
use kilotouch_device::{Device, PlantFrontend};
use kilotouch_proto::testing::PlantSensors;
use stm32f4xx_hal::pac;

/// The analog front end of this build: the plant model.
pub type Frontend = PlantFrontend;

/// QEMU's CPU clock for netduinoplus2, Hz (SysTick's clock source).
const CPU_HZ: u32 = 168_000_000;
/// SysTick reload: one sample period.
const RELOAD: u32 = CPU_HZ / super::SAMPLE_RATE_HZ;
/// SysTick periods since reset (the high part of [`cycles`]).
static EPOCH: AtomicU32 = AtomicU32::new(0);

#[exception]
fn SysTick() {
    EPOCH.fetch_add(1, Ordering::Relaxed);
    cortex_m::peripheral::NVIC::pend(pac::Interrupt::TIM4);
}

/// The sample-clock side of the board.
#[derive(Debug)]
pub struct Board;

impl Board {
    /// The sample interrupt was pended by SysTick: nothing to acknowledge.
    pub fn ack_tick(&mut self) {}

    /// QEMU has no independent watchdog to feed.
    pub fn feed_watchdog(&mut self) {}

    /// Counts spent in the plant model during the last tick.
    pub fn plant_cost(&mut self, d: &mut Device<Frontend, TxQueue>) -> u32 {
        d.frontend_mut().take_cost()
    }
}

/// The transmit side of the link.
#[derive(Debug)]
pub struct Link;

impl Link {
    /// Send whatever is queued (QEMU's USART transmits synchronously).
    pub fn drain(&mut self, q: &mut Consumer<'static, u8>) {
        while let Some(b) = q.dequeue() {
            super::usart_write(b);
        }
        cortex_m::asm::wfi();
    }
}

/// QEMU's virtual time in nanoseconds (modulo 2³²) from SysTick: with
/// `-icount shift=0` one nanosecond per executed instruction, so
/// differences count instructions (to the SysTick step, 1000/168 ≈ 6).
pub fn cycles() -> u32 {
    loop {
        let e = EPOCH.load(Ordering::Relaxed);
        let val = cortex_m::peripheral::SYST::get_current();
        if EPOCH.load(Ordering::Relaxed) == e {
            let counts = u64::from(e) * u64::from(RELOAD) + u64::from(RELOAD - 1 - val);
            return (counts * 1000 / u64::from(CPU_HZ / 1_000_000)) as u32;
        }
    }
}

/// The sensors before a plant is loaded: the built-in rig's accelerometer
/// and scales (overwritten by `kilotouch firmware load-plant`).
fn default_sensors() -> PlantSensors {
    PlantSensors {
        accel_alpha: [0.777_691_2, 0.777_691_2, 0.828_204_6],
        accel_offset_m_s2: [0.0, 0.0, 9.806_65],
        accel_range_m_s2: 58.839_9,
        accel_m_s2_per_code: 1.452_8e-2,
        encoder_counts_per_m: 1e7,
        force_max_n: 5.0,
        drive_max_v: 10.0,
    }
}

/// Set up USART2 with its receive interrupt and SysTick at 10 kHz; the
/// plant model without sections.
pub fn init(
    dp: pac::Peripherals,
    mut cp: cortex_m::Peripherals,
) -> (Board, Link, Frontend, [u8; 24]) {
    dp.RCC.apb1enr().modify(|_, w| w.usart2en().set_bit());
    super::usart2_enable(&dp.USART2);
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(RELOAD - 1);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();
    let mut serial = [0u8; 24];
    serial[..4].copy_from_slice(b"qemu");
    (
        Board,
        Link,
        PlantFrontend::new(default_sensors(), cycles),
        serial,
    )
}
