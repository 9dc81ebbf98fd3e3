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

use super::emulator::{Emulator, Instrument, Next};
use crate::device::Clock;
use crate::error::RigError;
use nix::fcntl::{FcntlArg, OFlag, fcntl, open};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{PtyMaster, grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::stat::Mode;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
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
    let mut buf = [0u8; 4096];
    let mut master = &pty.master;
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(ServeEnd::Stopped);
        }
        let now = clock.now();
        let wake = match emu.advance(now) {
            Next::Disconnect => return Ok(ServeEnd::Disconnect),
            Next::WakeAt(t) => t,
        };
        // Send what is pending (non-blocking; the rest waits for POLLOUT).
        while !emu.output().is_empty() {
            match master.write(emu.output()) {
                Ok(0) => break,
                Ok(n) => emu.consume_output(n),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(RigError::Device(format!("pty write: {e}"))),
            }
        }
        let wait = wake
            .saturating_sub(clock.now())
            .min(Duration::from_millis(50));
        // Round up to whole milliseconds (poll's resolution) so we never spin.
        let ms = wait.as_micros().div_ceil(1000) as u16;
        let mut flags = PollFlags::POLLIN;
        if !emu.output().is_empty() {
            flags |= PollFlags::POLLOUT;
        }
        let mut fds = [PollFd::new(pty.master.as_fd(), flags)];
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(_) | Err(nix::Error::EINTR) => {}
            Err(e) => return Err(sys("poll", e)),
        }
        let readable = fds[0]
            .revents()
            .is_some_and(|r| r.intersects(PollFlags::POLLIN));
        if readable {
            loop {
                match master.read(&mut buf) {
                    Ok(0) => break,
                    Ok(n) => emu.receive(&buf[..n], clock.now()),
                    Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                    Err(e) if e.kind() == ErrorKind::Interrupted => {}
                    // EIO: no slave open (cannot happen: we hold one).
                    Err(_) => break,
                }
            }
        }
    }
}
