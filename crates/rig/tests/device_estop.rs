//! A DAQ whose emergency stop is engaged while it runs (FAULT `ESTOP`, then
//! STATUS `tripped`, `docs/PROTOCOL.md` §6), as the firmware reports it:
//! the host names the emergency stop, not its watchdog, does not re-arm on
//! its own, and reports START refused while the stop stays engaged. The
//! device is a small scripted one on a pseudo-terminal (the emulator has no
//! emergency-stop input); every wait is on a frame with a deadline.

#![allow(clippy::unwrap_used)]

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::{ActuatorFrame, Rig, RigFault, RigState, SensorFrame};
use kilotouch_rig::error::RigError;
use kilotouch_rig::serial::emulator::{DaqInstrument, Instrument};
use kilotouch_rig::serial::frame::{
    self, DaqCommand, DaqSample, Decoder, DeviceState, FaultReport, Status, fault, ty,
};
use kilotouch_rig::serial::{SerialConfig, SerialRig};
use nix::fcntl::{OFlag, open};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{PtyMaster, grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::stat::Mode;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::io::{Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

/// Samples the device executes before its emergency stop is engaged.
const TRIP_AT: u64 = 100;

/// The scripted device: answers HELLO, START, STOP; answers each COMMANDS
/// frame with its samples until sample [`TRIP_AT`], where the emergency
/// stop is engaged (until `release` is raised).
struct EStopDevice {
    path: String,
    release: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

fn raw(fd: impl AsFd) {
    let mut t = tcgetattr(&fd).unwrap();
    cfmakeraw(&mut t);
    tcsetattr(&fd, SetArg::TCSANOW, &t).unwrap();
}

impl EStopDevice {
    fn spawn() -> Self {
        let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY).unwrap();
        grantpt(&master).unwrap();
        unlockpt(&master).unwrap();
        let path = ptsname_r(&master).unwrap();
        let slave: OwnedFd = open(
            path.as_str(),
            OFlag::O_RDWR | OFlag::O_NOCTTY,
            Mode::empty(),
        )
        .unwrap();
        raw(&slave);
        raw(&master);
        let release = Arc::new(AtomicBool::new(false));
        let stop = Arc::new(AtomicBool::new(false));
        let (r, s) = (release.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            let _slave = slave; // no hang-up while the host reopens
            serve(master, &r, &s);
        });
        Self {
            path,
            release,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for EStopDevice {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn status(out: &mut Vec<u8>, state: DeviceState, next: u64) {
    frame::write_status(
        out,
        &Status {
            next_seq: next as u32,
            state,
            host_frames: 0,
            host_crc_errors: 0,
            late_commands: 0,
        },
    );
}

fn serve(mut master: PtyMaster, release: &AtomicBool, stop: &AtomicBool) {
    // A device announces its watchdog window and batch (the host refuses
    // zeros, docs/PROTOCOL.md §5.1); the instrument leaves them to the
    // emulator.
    let hello = frame::Hello {
        watchdog_ms: 100,
        batch: 10,
        ..DaqInstrument::new(&RigConfig::default()).unwrap().hello()
    };
    let mut dec = Decoder::new();
    let mut buf = [0u8; 1024];
    let (mut state, mut next, mut engaged) = (DeviceState::Idle, 0u64, false);
    while !stop.load(Ordering::Relaxed) {
        let mut fds = [PollFd::new(master.as_fd(), PollFlags::POLLIN)];
        if poll(&mut fds, PollTimeout::from(20u8)).unwrap_or(0) == 0 {
            continue;
        }
        let Ok(n) = master.read(&mut buf) else {
            continue;
        };
        let mut out = Vec::new();
        // The host's frames are short: a read never holds more than the
        // decoder takes after its frames were taken out.
        let took = dec.push(&buf[..n]);
        assert_eq!(took, n);
        while let Some(f) = dec.next_frame() {
            if engaged && release.load(Ordering::Relaxed) {
                engaged = false;
            }
            match f.ty {
                ty::HELLO_REQ => frame::write_hello(&mut out, &hello),
                ty::START if engaged => {
                    frame::write_fault(
                        &mut out,
                        &FaultReport {
                            code: fault::ESTOP,
                            seq: next as u32,
                        },
                    );
                    status(&mut out, DeviceState::Tripped, next);
                }
                ty::START => {
                    state = DeviceState::Running;
                    status(&mut out, state, next);
                }
                ty::STOP => {
                    state = DeviceState::Idle;
                    status(&mut out, state, next);
                }
                ty::COMMANDS if state == DeviceState::Running => {
                    let (seq, cnt) = frame::block_header::<DaqCommand>(f.payload).unwrap();
                    if u64::from(seq) != next {
                        continue;
                    }
                    if next >= TRIP_AT && !release.load(Ordering::Relaxed) {
                        engaged = true;
                        state = DeviceState::Tripped;
                        frame::write_fault(
                            &mut out,
                            &FaultReport {
                                code: fault::ESTOP,
                                seq: next as u32,
                            },
                        );
                        status(&mut out, state, next);
                        continue;
                    }
                    let s = vec![DaqSample::default(); cnt];
                    frame::write_block(&mut out, ty::SAMPLES, next as u32, &s);
                    next += cnt as u64;
                }
                _ => {}
            }
        }
        let _ = master.write_all(&out);
    }
}

#[test]
fn an_emergency_stop_is_named_as_such_and_not_re_armed() {
    let dev = EStopDevice::spawn();
    let mut cfg = SerialConfig::new(&dev.path);
    // Even a link that re-arms after an idle watchdog trip must not
    // restart a device whose emergency stop is engaged.
    cfg.rearm_after_idle_trip = true;
    let mut rig = SerialRig::open(&cfg).unwrap();
    rig.start().unwrap();
    let cmds = vec![ActuatorFrame::default(); TRIP_AT as usize];
    let mut out = vec![SensorFrame::default(); TRIP_AT as usize];
    rig.process_block(&cmds, &mut out).unwrap();
    let err = rig.process_block(&cmds, &mut out).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, RigError::Device(_)), "{err:?}");
    assert!(
        msg.contains("emergency stop was engaged at sample 100") && !msg.contains("watchdog"),
        "{msg}"
    );
    assert_eq!(rig.status().state, RigState::Faulted);
    let faults: Vec<RigFault> = std::iter::from_fn(|| rig.pop_fault()).collect();
    assert!(
        faults.contains(&RigFault::EmergencyStop { seq: TRIP_AT }),
        "{faults:?}"
    );
    assert!(
        !faults
            .iter()
            .any(|f| matches!(f, RigFault::WatchdogTripped { .. })),
        "{faults:?}"
    );
    // START is refused while the stop stays engaged, and said so (not a
    // time-out).
    let err = rig.start().unwrap_err().to_string();
    assert!(err.contains("emergency stop is engaged"), "{err}");
    // Released: START runs again.
    dev.release.store(true, Ordering::Relaxed);
    rig.start().unwrap();
    rig.process_block(&cmds, &mut out).unwrap();
    rig.stop().unwrap();
}
