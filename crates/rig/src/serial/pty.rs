//! Pseudo-terminals for the device emulators, and the loop that serves an
//! [`Emulator`] on one.
//!
//! [`Pty::open`] creates a master/slave pair with `posix_openpt`,
//! `grantpt`, `unlockpt` and `ptsname_r` (all safe in `nix`), sets both ends
//! to raw mode (`cfmakeraw`: no echo, no line editing, no CR/LF
//! translation, 8-bit clean) and keeps the slave open itself, so the master
//! never sees a hang-up while no host is connected and a host can close and
//! reopen the port (reconnect). The host opens [`Pty::path`] like any
//! serial port.

use super::emulator::{Emulator, Instrument, MAX_PENDING_OUTPUT, Next};
use crate::device::Clock;
use crate::error::RigError;
use nix::fcntl::{FcntlArg, OFlag, fcntl, open};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{PtyMaster, grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::stat::Mode;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// A pseudo-terminal whose slave side is the emulated device's port.
#[derive(Debug)]
pub struct Pty {
    master: PtyMaster,
    _slave: OwnedFd,
    path: String,
}

fn sys(what: &str, e: nix::Error) -> RigError {
    RigError::Device(format!("pty: {what}: {e}"))
}

fn make_raw(fd: impl AsFd, what: &str) -> Result<(), RigError> {
    let mut t = tcgetattr(&fd).map_err(|e| sys(what, e))?;
    cfmakeraw(&mut t);
    tcsetattr(&fd, SetArg::TCSANOW, &t).map_err(|e| sys(what, e))
}

impl Pty {
    /// Create a raw pty pair (module docs).
    pub fn open() -> Result<Self, RigError> {
        let master =
            posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY).map_err(|e| sys("posix_openpt", e))?;
        grantpt(&master).map_err(|e| sys("grantpt", e))?;
        unlockpt(&master).map_err(|e| sys("unlockpt", e))?;
        let path = ptsname_r(&master).map_err(|e| sys("ptsname_r", e))?;
        let slave = open(
            path.as_str(),
            OFlag::O_RDWR | OFlag::O_NOCTTY,
            Mode::empty(),
        )
        .map_err(|e| sys("open slave", e))?;
        make_raw(&slave, "raw mode (slave)")?;
        make_raw(&master, "raw mode (master)")?;
        let fl = fcntl(&master, FcntlArg::F_GETFL).map_err(|e| sys("F_GETFL", e))?;
        fcntl(
            &master,
            FcntlArg::F_SETFL(OFlag::from_bits_truncate(fl) | OFlag::O_NONBLOCK),
        )
        .map_err(|e| sys("O_NONBLOCK", e))?;
        Ok(Self {
            master,
            _slave: slave,
            path,
        })
    }

    /// Path of the slave side, e.g. `/dev/pts/3`.
    pub fn path(&self) -> &str {
        &self.path
    }
}

/// Why [`serve`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServeEnd {
    /// The stop flag was raised.
    Stopped,
    /// Injected disconnect: the caller should close the pty (drop it / exit).
    Disconnect,
}

/// Serve `emu` on `pty` with wall time from `clock` until `stop` is raised
/// or an injected disconnect.
pub fn serve<I: Instrument>(
    emu: &mut Emulator<I>,
    pty: &Pty,
    clock: &impl Clock,
    stop: &AtomicBool,
) -> Result<ServeEnd, RigError> {
    serve_delayed(emu, pty, clock, stop, Duration::ZERO)
}

/// Bytes held back by a link delay, in arrival order with the time each
/// chunk may go on.
#[derive(Debug, Default)]
struct DelayLine {
    q: VecDeque<(Duration, Vec<u8>)>,
}

impl DelayLine {
    fn push(&mut self, due: Duration, bytes: &[u8]) {
        if !bytes.is_empty() {
            self.q.push_back((due, bytes.to_vec()));
        }
    }
    /// The earliest time a chunk is due.
    fn next_due(&self) -> Option<Duration> {
        self.q.front().map(|(t, _)| *t)
    }
}

/// [`serve`] behind a link that delays every byte by `delay` in each
/// direction (a long USB chain, a remote device): the device sees the
/// host's bytes `delay` after they were written, the host the device's
/// `delay` after they were sent, so the round trip grows by 2 × `delay`.
pub fn serve_delayed<I: Instrument>(
    emu: &mut Emulator<I>,
    pty: &Pty,
    clock: &impl Clock,
    stop: &AtomicBool,
    delay: Duration,
) -> Result<ServeEnd, RigError> {
    let mut buf = [0u8; 4096];
    let mut master = &pty.master;
    let mut to_host = DelayLine::default();
    let mut to_device = DelayLine::default();
    // Delayed output waiting to be written (partially written chunks).
    let mut pending: Vec<u8> = Vec::new();
    loop {
        let now = clock.now();
        // Everything the host has written so far, stamped `now`, before the
        // device runs: a device that was busy (its participant preparing a
        // trial) or descheduled must not trip its watchdog on host frames
        // waiting unread in its input.
        loop {
            match master.read(&mut buf) {
                Ok(0) => break,
                Ok(n) if delay.is_zero() => emu.receive(&buf[..n], now),
                Ok(n) => to_device.push(now + delay, &buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                // EIO: no slave open (cannot happen: we hold one).
                Err(_) => break,
            }
        }
        while to_device.next_due().is_some_and(|t| t <= now) {
            if let Some((t, bytes)) = to_device.q.pop_front() {
                emu.receive(&bytes, t);
            }
        }
        // Stopped after the host's last frames were taken in (a STOP the
        // host sent before the emulator was stopped is obeyed).
        if stop.load(Ordering::Relaxed) {
            return Ok(ServeEnd::Stopped);
        }
        let wake = match emu.advance(now) {
            Next::Disconnect => return Ok(ServeEnd::Disconnect),
            Next::WakeAt(t) => t,
        };
        if delay.is_zero() {
            // Send what is pending (non-blocking; the rest stays in the
            // emulator's bounded output and waits for POLLOUT).
            while !emu.output().is_empty() {
                match master.write(emu.output()) {
                    Ok(0) => break,
                    Ok(n) => emu.consume_output(n),
                    Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    Err(e) => return Err(RigError::Device(format!("pty write: {e}"))),
                }
            }
        } else {
            // The delayed link holds at most the emulator's own bound;
            // beyond it the device's bytes are lost, as on a full cable
            // buffer.
            let held: usize = pending.len() + to_host.q.iter().map(|(_, b)| b.len()).sum::<usize>();
            if held + emu.output().len() <= MAX_PENDING_OUTPUT {
                to_host.push(now + delay, emu.output());
            }
            let taken = emu.output().len();
            emu.consume_output(taken);
            while to_host.next_due().is_some_and(|t| t <= now) {
                if let Some((_, bytes)) = to_host.q.pop_front() {
                    pending.extend_from_slice(&bytes);
                }
            }
            while !pending.is_empty() {
                match master.write(&pending) {
                    Ok(0) => break,
                    Ok(n) => {
                        pending.drain(..n);
                    }
                    Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    Err(e) => return Err(RigError::Device(format!("pty write: {e}"))),
                }
            }
        }
        let mut wake = wake;
        for t in [to_host.next_due(), to_device.next_due()]
            .into_iter()
            .flatten()
        {
            wake = wake.min(t);
        }
        let wait = wake
            .saturating_sub(clock.now())
            .min(Duration::from_millis(50));
        // Round up to whole milliseconds (poll's resolution) so we never
        // spin, except for a delayed chunk due within the millisecond.
        let ms = wait.as_micros().div_ceil(1000) as u16;
        let mut flags = PollFlags::POLLIN;
        if !pending.is_empty() || !emu.output().is_empty() {
            flags |= PollFlags::POLLOUT;
        }
        let mut fds = [PollFd::new(pty.master.as_fd(), flags)];
        // Input is read at the top of the loop.
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(_) | Err(nix::Error::EINTR) => {}
            Err(e) => return Err(sys("poll", e)),
        }
    }
}
