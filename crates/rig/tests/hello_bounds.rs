//! A device that announces absurd values in its HELLO is refused at the
//! handshake, naming the field, before anything is streamed: the checks of
//! `docs/PROTOCOL.md` §5.1 through a real pseudo-terminal, with a device
//! that runs the simulated DAQ but lies about itself.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::{Clock, SystemClock};
use kilotouch_rig::serial::emulator::{DaqInstrument, Emulator, EmulatorConfig, Instrument};
use kilotouch_rig::serial::frame::{self, Caps, DaqCommand, DaqSample, Hello};
use kilotouch_rig::serial::pty::{Pty, serve};
use kilotouch_rig::serial::{SerialConfig, SerialRig};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// The simulated DAQ with a HELLO changed by `edit`.
struct Lying {
    inner: DaqInstrument,
    edit: fn(&mut Hello),
}

impl Instrument for Lying {
    type Command = DaqCommand;
    type Sample = DaqSample;
    const COMMAND_TYPE: u8 = frame::ty::COMMANDS;
    const SAMPLE_TYPE: u8 = frame::ty::SAMPLES;

    fn hello(&self) -> Hello {
        let mut h = self.inner.hello();
        (self.edit)(&mut h);
        h
    }
    fn step(&mut self, cmd: &DaqCommand, extra_flags: u8) -> DaqSample {
        self.inner.step(cmd, extra_flags)
    }
    fn safe_command(&self, last: &DaqCommand) -> DaqCommand {
        self.inner.safe_command(last)
    }
    fn reset(&mut self, cmd: &DaqCommand) {
        self.inner.reset(cmd);
    }
}

/// Opens a serial rig on a device whose HELLO `edit` changed.
fn open_lying(edit: fn(&mut Hello)) -> Result<SerialRig, String> {
    let pty = Pty::open().unwrap();
    let path = pty.path().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    let inst = Lying {
        inner: DaqInstrument::new(&RigConfig::default()).unwrap(),
        edit,
    };
    let handle = std::thread::spawn(move || {
        let clock = SystemClock::default();
        let mut emu = Emulator::new(inst, EmulatorConfig::default(), clock.now()).unwrap();
        let _ = serve(&mut emu, &pty, &clock, &s);
    });
    let r = SerialRig::open(&SerialConfig::new(&path)).map_err(|e| e.to_string());
    stop.store(true, Ordering::Relaxed);
    handle.join().unwrap();
    r
}

fn daq_caps(h: &mut Hello) -> &mut frame::DaqCaps {
    match &mut h.caps {
        Caps::Daq(c) => c,
        Caps::Tweezer(_) => panic!("a DAQ"),
    }
}

#[test]
fn the_emulators_hello_is_accepted() {
    open_lying(|_| {}).unwrap();
}

/// An edit of the emulator's HELLO.
type Edit = fn(&mut Hello);

#[test]
fn each_absurd_hello_value_is_refused_naming_the_field() {
    let cases: [(&str, Edit); 6] = [
        ("accel_range_m_s2 = NaN", |h| {
            daq_caps(h).accel_range_m_s2 = f64::NAN;
        }),
        ("accel_m_s2_per_code = 1e308", |h| {
            daq_caps(h).accel_m_s2_per_code = 1e308;
        }),
        ("encoder_counts_per_m = 5e-324", |h| {
            daq_caps(h).encoder_counts_per_m = 5e-324;
        }),
        ("force_max_n = inf", |h| {
            daq_caps(h).force_max_n = f64::INFINITY;
        }),
        ("drive_max_v = -2e0", |h| {
            daq_caps(h).drive_max_v = -2.0;
        }),
        ("sample_rate_hz = 1e0", |h| h.sample_rate_hz = 1),
    ];
    for (named, edit) in cases {
        let e = open_lying(edit).err().unwrap_or_default();
        assert!(
            e.contains(named) && e.contains("refusing to connect"),
            "{named}: {e}"
        );
    }
}
