//! A real board: STM32F4DISCOVERY (STM32F407VG) or Olimex STM32-H405
//! (STM32F405RG), both with an 8 MHz crystal. Pin map and wiring:
//! docs/FIRMWARE.md.
//!
//! * Clocks: HSE 8 MHz → PLL → 168 MHz; APB1 42 MHz (timers 84 MHz), APB2
//!   84 MHz; 48 MHz for USB.
//! * Sample clock: TIM4 update at 84 MHz / 8400 = 10 kHz; its channel 1
//!   compare, 5 µs before the update, triggers the ADC's injected
//!   conversions so that the accelerometer is sampled at the end of the
//!   period and read in the update interrupt.
//! * Encoders: TIM2 (PA15, PB3) and TIM5 (PA0, PA1) in encoder mode, 32-bit.
//! * Accelerometer: ADC1 injected channels 11, 12, 14 (PC1, PC2, PC4).
//! * Haptuator drive: DAC channel 1 (PA4); Pantograph x: DAC channel 2
//!   (PA5); Pantograph y: TIM1 channel 1 PWM at 20 kHz (PA8) behind an RC
//!   filter; all mid-scale at zero. Amplifier enable: PB0 (high = on).
//! * Emergency stop: PB1, pulled up, to ground through a normally closed
//!   switch: high = stop (a broken wire stops too).
//! * Link: USART2 (PA2 TX, PA3 RX) at 2 Mbaud; USB CDC-ACM on PA11/PA12.
//! * Independent watchdog: 5 ms, fed every sample period.

use super::SAMPLE_RATE_HZ;
use crate::TxQueue;
use core::cell::RefCell;
use cortex_m::interrupt::Mutex;
use heapless::spsc::Consumer;
use kilotouch_device::analog;
use kilotouch_device::{Device, Frontend as DeviceFrontend};
use kilotouch_proto::{DaqCaps, DaqCommand, DaqSample};
use stm32f4xx_hal::otg_fs::{USB, UsbBus, UsbBusType};
use stm32f4xx_hal::pac;
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::rcc::Config as RccConfig;
use stm32f4xx_hal::watchdog::IndependentWatchdog;
use usb_device::bus::UsbBusAllocator;
use usb_device::prelude::*;
use usbd_serial::SerialPort;

/// Timer clock of TIM4 (APB1 × 2), Hz.
const TIM_CLOCK_HZ: u32 = 84_000_000;
/// ADC trigger lead before the end of the period, timer counts (5 µs).
const ADC_LEAD: u32 = 420;

/// The analog front end's scales (docs/FIRMWARE.md, "Scales"): what the
/// board announces in HELLO. Edit them for your amplifiers and sensors.
pub const CAPS: DaqCaps = DaqCaps {
    // 500-line encoders (2000 counts/rev) on 20 mm capstans: 31 831 counts/m.
    encoder_counts_per_m: 31_830.988_6,
    // MMA7361L at ±6 g, 206 mV/g, 12-bit ADC over 3.3 V: 0.806 mV per code.
    accel_m_s2_per_code: 0.038_364_4,
    accel_range_m_s2: 58.839_9,
    force_max_n: 5.0,
    drive_max_v: 10.0,
};

type UsbDev = UsbDevice<'static, UsbBusType>;
type UsbSerial = SerialPort<'static, UsbBusType>;

static USB_LINK: Mutex<RefCell<Option<(UsbDev, UsbSerial)>>> = Mutex::new(RefCell::new(None));

/// The analog front end (module docs).
#[derive(Debug)]
pub struct Frontend {
    adc_zero: [u16; 3],
    applied: DaqCommand,
}

impl DeviceFrontend for Frontend {
    fn apply(&mut self, c: &DaqCommand) {
        self.applied = *c;
        // SAFETY: the DAC holding registers, TIM1's compare register and
        // PB0 are written only here, in `safe` and by the panic handler.
        unsafe {
            let dac = &*pac::DAC::ptr();
            dac.dhr12r1()
                .write(|w| w.bits(u32::from(analog::dac12(c.drive))));
            dac.dhr12r2()
                .write(|w| w.bits(u32::from(analog::dac12(c.force[0]))));
            let t1 = &*pac::TIM1::ptr();
            let arr = t1.arr().read().bits() as u16;
            t1.ccr1()
                .write(|w| w.bits(u32::from(analog::pwm_duty(c.force[1], arr))));
            (*pac::GPIOB::ptr()).bsrr().write(|w| w.bits(1));
        }
    }

    fn read(&mut self) -> DaqSample {
        // SAFETY: reads of counters and conversion results only.
        let (enc, raw) = unsafe {
            let enc = [
                (*pac::TIM2::ptr()).cnt().read().bits() as i32,
                (*pac::TIM5::ptr()).cnt().read().bits() as i32,
            ];
            let adc = &*pac::ADC1::ptr();
            let raw = [
                adc.jdr1().read().bits() as u16,
                adc.jdr2().read().bits() as u16,
                adc.jdr3().read().bits() as u16,
            ];
            adc.sr().write(|w| w.bits(0));
            (enc, raw)
        };
        let mut acc = [0i16; 3];
        let mut flags = 0;
        for i in 0..3 {
            let (a, f) = analog::accel_code(raw[i], self.adc_zero[i]);
            acc[i] = a;
            flags |= f;
        }
        DaqSample { enc, acc, flags }
    }

    fn safe(&mut self) {
        self.applied = DaqCommand::default();
        safe_outputs();
    }

    fn outputs(&self) -> DaqCommand {
        self.applied
    }

    fn caps(&self) -> DaqCaps {
        CAPS
    }
}

/// Amplifiers off, every output at its zero (also from the panic handler).
pub fn safe_outputs() {
    // SAFETY: plain register writes that only ever move the outputs to
    // their safe state; callable from any context.
    unsafe {
        (*pac::GPIOB::ptr()).bsrr().write(|w| w.bits(1 << 16));
        let dac = &*pac::DAC::ptr();
        dac.dhr12r1().write(|w| w.bits(u32::from(analog::dac12(0))));
        dac.dhr12r2().write(|w| w.bits(u32::from(analog::dac12(0))));
        let t1 = &*pac::TIM1::ptr();
        let arr = t1.arr().read().bits() as u16;
        t1.ccr1()
            .write(|w| w.bits(u32::from(analog::pwm_duty(0, arr))));
    }
}

/// The sample-clock side of the board.
pub struct Board {
    iwdg: IndependentWatchdog,
}

impl core::fmt::Debug for Board {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Board")
    }
}

impl Board {
    /// Acknowledge the sample interrupt.
    pub fn ack_tick(&mut self) {
        ack_sample_timer();
    }

    /// Feed the independent watchdog (a firmware that stops ticking is reset).
    pub fn feed_watchdog(&mut self) {
        self.iwdg.feed();
    }

    /// No plant model on a board.
    pub fn plant_cost(&mut self, _d: &mut Device<Frontend, TxQueue>) -> u32 {
        0
    }
}

/// The transmit side of the link.
#[derive(Debug)]
pub struct Link;

impl Link {
    /// Send what is queued: to USB when a host has opened the CDC port,
    /// else to USART2.
    pub fn drain(&mut self, q: &mut Consumer<'static, u8>) {
        let usb = cortex_m::interrupt::free(|cs| {
            USB_LINK
                .borrow(cs)
                .borrow()
                .as_ref()
                .is_some_and(|(d, s)| d.state() == UsbDeviceState::Configured && s.dtr())
        });
        if usb {
            let mut buf = [0u8; 64];
            let mut n = 0;
            while n < buf.len() {
                match q.peek() {
                    Some(&b) => {
                        buf[n] = b;
                        n += 1;
                        q.dequeue();
                    }
                    None => break,
                }
            }
            let mut sent = 0;
            while sent < n {
                let k = cortex_m::interrupt::free(|cs| {
                    USB_LINK
                        .borrow(cs)
                        .borrow_mut()
                        .as_mut()
                        .and_then(|(_, s)| s.write(&buf[sent..n]).ok())
                        .unwrap_or(0)
                });
                if k == 0 {
                    // Host gone or endpoint busy: the rest of this chunk is
                    // lost, which the host's loss accounting reports.
                    break;
                }
                sent += k;
            }
        } else {
            while let Some(b) = q.dequeue() {
                super::usart_write(b);
            }
        }
    }
}

/// DWT cycle counter (CPU cycles at 168 MHz).
pub fn cycles() -> u32 {
    cortex_m::peripheral::DWT::cycle_count()
}

/// Poll the USB device and read what the host sent; `None` when nothing.
pub fn usb_read(buf: &mut [u8]) -> Option<usize> {
    cortex_m::interrupt::free(|cs| {
        let mut l = USB_LINK.borrow(cs).borrow_mut();
        let (dev, serial) = l.as_mut()?;
        dev.poll(&mut [serial]);
        match serial.read(buf) {
            Ok(n) if n > 0 => Some(n),
            _ => None,
        }
    })
}

/// The emergency-stop input after an edge: `true` when engaged.
pub fn estop_edge() -> bool {
    // SAFETY: clearing EXTI line 1's pending bit and reading PB1.
    unsafe {
        (*pac::EXTI::ptr()).pr().write(|w| w.bits(1 << 1));
        (*pac::GPIOB::ptr()).idr().read().bits() & (1 << 1) != 0
    }
}

/// Configure ADC1: injected sequence of channels 11, 12, 14, triggered by
/// TIM4 channel 1 (rising edge), 15-cycle sampling.
fn init_adc(adc: &pac::ADC1) {
    adc.cr2().write(|w| w.adon().set_bit());
    adc.smpr1()
        .write(|w| unsafe { w.smp11().bits(1).smp12().bits(1).smp14().bits(1) });
    adc.cr1().write(|w| w.scan().set_bit());
    // JL = 2 (three conversions): JSQ2..4 hold them.
    adc.jsqr().write(|w| unsafe {
        w.jl()
            .bits(2)
            .jsq2()
            .bits(11)
            .jsq3()
            .bits(12)
            .jsq4()
            .bits(14)
    });
    // JEXTSEL 0b0110 = TIM4_CH1 … trigger on the rising edge.
    adc.cr2()
        .modify(|_, w| unsafe { w.jextsel().bits(0b0110).jexten().bits(0b01) });
}

/// Configure TIM1 channel 1 as a 20 kHz PWM at mid-scale.
fn init_pwm(t1: &pac::TIM1) {
    let arr = 168_000_000 / 20_000 - 1;
    t1.arr().write(|w| unsafe { w.bits(arr) });
    t1.ccr1().write(|w| unsafe { w.bits(arr / 2) });
    t1.ccmr1_output()
        .write(|w| unsafe { w.oc1m().bits(0b110).oc1pe().set_bit() });
    t1.ccer().write(|w| w.cc1e().set_bit());
    t1.bdtr().write(|w| w.moe().set_bit());
    t1.cr1().write(|w| w.cen().set_bit());
}

/// The USB CDC-ACM device (serial number: the MCU's unique ID in hex,
/// which is returned for HELLO too).
fn init_usb(usb: USB) -> [u8; 24] {
    static mut EP_MEMORY: [u32; 1024] = [0; 1024];
    static mut USB_BUS: Option<UsbBusAllocator<UsbBusType>> = None;
    let mut serial_no = [0u8; 24];
    // SAFETY: the 96-bit unique device ID, read-only memory (RM0090 §39.1).
    let uid: [u8; 12] = unsafe { core::ptr::read_volatile(0x1FFF_7A10 as *const [u8; 12]) };
    hex(&uid, &mut serial_no);
    // SAFETY: init runs once, before interrupts are enabled; the statics
    // are only reached through the references created here.
    let bus: &'static UsbBusAllocator<UsbBusType> = unsafe {
        let mem = &mut *core::ptr::addr_of_mut!(EP_MEMORY);
        let slot = &mut *core::ptr::addr_of_mut!(USB_BUS);
        slot.insert(UsbBus::new(usb, mem))
    };
    let serial = SerialPort::new(bus);
    // The serial-number string must outlive the device: keep it static.
    static mut SERIAL_STR: [u8; 24] = [0; 24];
    // SAFETY: written once here before the USB device exists.
    let sn: &'static str = unsafe {
        let s = &mut *core::ptr::addr_of_mut!(SERIAL_STR);
        s.copy_from_slice(&serial_no);
        core::str::from_utf8(s).unwrap_or("unknown")
    };
    let dev = UsbDeviceBuilder::new(bus, UsbVidPid(0x16c0, 0x27dd))
        .device_class(usbd_serial::USB_CLASS_CDC)
        .strings(&[StringDescriptors::default()
            .manufacturer("kilotouch")
            .product("kilotouch DAQ")
            .serial_number(sn)])
        .map(|b| b.build());
    if let Ok(dev) = dev {
        cortex_m::interrupt::free(|cs| USB_LINK.borrow(cs).replace(Some((dev, serial))));
    }
    serial_no
}

/// Set up everything (module docs); returns the board, the link, the
/// frontend and the HELLO serial number (the MCU's unique ID in hex).
pub fn init(
    dp: pac::Peripherals,
    mut cp: cortex_m::Peripherals,
) -> (Board, Link, Frontend, [u8; 24]) {
    let mut rcc = dp.RCC.freeze(
        RccConfig::hse(8.MHz())
            .sysclk(168.MHz())
            .pclk1(42.MHz())
            .pclk2(84.MHz())
            .require_pll48clk(),
    );
    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();

    let gpioa = dp.GPIOA.split(&mut rcc);
    let gpiob = dp.GPIOB.split(&mut rcc);
    let gpioc = dp.GPIOC.split(&mut rcc);

    // Outputs off before anything can drive them.
    // (The pin objects are configuration only: dropping them leaves the
    // pins as configured; the frontend writes PB0 through BSRR.)
    let mut amp_enable = gpiob.pb0.into_push_pull_output();
    amp_enable.set_low();
    let _estop_pin = gpiob.pb1.into_pull_up_input();

    // Encoders: encoder mode stays configured when the drivers are
    // dropped; the frontend reads the counters directly.
    let _qx = dp
        .TIM2
        .qei((gpioa.pa15.into_input(), gpiob.pb3.into_input()), &mut rcc);
    let _qy = dp.TIM5.qei((gpioa.pa0, gpioa.pa1), &mut rcc);

    // Outputs: DAC 1 and 2, TIM1 CH1 PWM.
    let (mut c1, mut c2) = stm32f4xx_hal::dac::dac(
        dp.DAC,
        (gpioa.pa4.into_analog(), gpioa.pa5.into_analog()),
        &mut rcc,
    );
    use stm32f4xx_hal::dac::DacPin;
    c1.enable();
    c2.enable();
    let _pwm_pin = gpioa.pa8.into_alternate::<1>();
    // SAFETY: enabling peripheral clocks the HAL does not wrap here.
    unsafe {
        let r = &*pac::RCC::ptr();
        r.apb2enr()
            .modify(|_, w| w.tim1en().set_bit().adc1en().set_bit().syscfgen().set_bit());
        r.apb1enr().modify(|_, w| w.tim4en().set_bit());
    }
    init_pwm(&dp.TIM1);
    safe_outputs();

    // Accelerometer on ADC1, triggered by TIM4 CH1.
    let _ax = gpioc.pc1.into_analog();
    let _ay = gpioc.pc2.into_analog();
    let _az = gpioc.pc4.into_analog();
    init_adc(&dp.ADC1);
    let arr = TIM_CLOCK_HZ / SAMPLE_RATE_HZ - 1;
    dp.TIM4.ccr1().write(|w| unsafe { w.bits(arr - ADC_LEAD) });
    dp.TIM4
        .ccmr1_output()
        .write(|w| unsafe { w.oc1m().bits(0b011) });
    dp.TIM4.ccer().write(|w| w.cc1e().set_bit());

    // Emergency stop: EXTI line 1 on port B, both edges.
    dp.SYSCFG
        .exticr1()
        .modify(|_, w| unsafe { w.exti1().bits(1) });
    dp.EXTI.imr().modify(|_, w| w.mr1().set_bit());
    dp.EXTI.rtsr().modify(|_, w| w.tr1().set_bit());
    dp.EXTI.ftsr().modify(|_, w| w.tr1().set_bit());

    // Link: USART2 at 2 Mbaud (42 MHz / (16 · 1.3125)), receive interrupt.
    let _tx = gpioa.pa2.into_alternate::<7>();
    let _rx = gpioa.pa3.into_alternate::<7>();
    // SAFETY: clock enable of USART2.
    unsafe {
        (*pac::RCC::ptr())
            .apb1enr()
            .modify(|_, w| w.usart2en().set_bit());
    }
    dp.USART2.brr().write(|w| unsafe { w.bits((1 << 4) | 5) });
    super::usart2_enable(&dp.USART2);

    // USB CDC-ACM.
    let usb = USB {
        usb_global: dp.OTG_FS_GLOBAL,
        usb_device: dp.OTG_FS_DEVICE,
        usb_pwrclk: dp.OTG_FS_PWRCLK,
        pin_dm: gpioa.pa11.into(),
        pin_dp: gpioa.pa12.into(),
        hclk: rcc.clocks.hclk(),
    };
    let serial_no = init_usb(usb);

    // Sample clock last: 84 MHz / 8400 = 10 kHz.
    start_sample_timer(&dp.TIM4, 0, arr as u16);
    let mut iwdg = IndependentWatchdog::new(dp.IWDG);
    iwdg.start(5.millis());
    (
        Board { iwdg },
        Link,
        Frontend {
            adc_zero: [2048; 3],
            applied: DaqCommand::default(),
        },
        serial_no,
    )
}

/// Hex digits of `bytes` into `out` (two per byte).
pub fn hex(bytes: &[u8], out: &mut [u8]) {
    const D: &[u8; 16] = b"0123456789ABCDEF";
    for (b, o) in bytes.iter().zip(out.chunks_exact_mut(2)) {
        o[0] = D[usize::from(b >> 4)];
        o[1] = D[usize::from(b & 15)];
    }
}

/// Configure TIM4 as the sample clock: update event every `(psc + 1) ·
/// (arr + 1)` timer-clock periods, interrupt on update.
pub fn start_sample_timer(tim: &pac::TIM4, psc: u16, arr: u16) {
    tim.cr1().write(|w| w.cen().clear_bit());
    tim.psc().write(|w| w.psc().set(psc));
    tim.arr().write(|w| unsafe { w.bits(u32::from(arr)) });
    tim.egr().write(|w| w.ug().set_bit());
    tim.sr().write(|w| unsafe { w.bits(0) });
    tim.dier().write(|w| w.uie().set_bit());
    tim.cr1().write(|w| w.cen().set_bit());
}

/// Acknowledge TIM4's update interrupt.
pub fn ack_sample_timer() {
    // SAFETY: clearing UIF (write 0, others 1: rc_w0) only from the tick task.
    let t = unsafe { &*pac::TIM4::ptr() };
    t.sr().write(|w| unsafe { w.bits(!1) });
}
