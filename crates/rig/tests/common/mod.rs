//! Test helpers shared by the live-link tests: an emulated device served on
//! a real pseudo-terminal by a thread of the test.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::device::{Clock, SystemClock};
use kilotouch_rig::serial::emulator::{Emulator, EmulatorConfig, Instrument};
use kilotouch_rig::serial::pty::{Pty, serve};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

/// An emulated device on a pty, served until [`Device::finish`] or drop.
pub struct Device<I: Instrument + 'static> {
    /// The pty's slave path.
    pub path: String,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Emulator<I>>>,
}

impl<I: Instrument + 'static> Device<I> {
    /// Serve `inst` with `cfg` on a new pty.
    pub fn spawn(inst: I, cfg: EmulatorConfig) -> Self {
        let pty = Pty::open().unwrap();
        let path = pty.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let handle = std::thread::spawn(move || {
            // As `kilotouch emulate` does: a device keeps its own time.
            let _ = kilotouch_rig::realtime::promote_current_thread();
            let clock = SystemClock::default();
            let mut emu = Emulator::new(inst, cfg, clock.now()).unwrap();
            serve(&mut emu, &pty, &clock, &s).unwrap();
            drop(pty); // an injected disconnect closes the pty here
            emu
        });
        Self {
            path,
            stop,
            handle: Some(handle),
        }
    }

    /// Stop serving; the emulator (its counters, its instrument).
    pub fn finish(mut self) -> Emulator<I> {
        self.stop.store(true, Ordering::Relaxed);
        self.handle.take().unwrap().join().unwrap()
    }
}

impl<I: Instrument + 'static> Drop for Device<I> {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
