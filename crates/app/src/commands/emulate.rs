//! `kilotouch emulate daq|tweezer --pty`: device emulators serving the
//! serial protocol (`docs/PROTOCOL.md`) on a pseudo-terminal, with the
//! simulated plant (DAQ) or the simulated tweezer behind it.
//!
//! The first line of stdout is the path of the pty's slave side (e.g.
//! `/dev/pts/3`), flushed at once, so that scripts and tests can read it
//! and open the port; the emulator then runs until it is killed (or until
//! an injected disconnect).

use anyhow::Context;
use clap::Subcommand;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::{Clock, SystemClock};
use kilotouch_rig::serial::emulator::{
    Emulator, EmulatorConfig, FaultInjection, Instrument, Misbehaviour,
};
use kilotouch_rig::serial::pty::{Pty, ServeEnd, serve};
use kilotouch_rig::serial::{DaqInstrument, TweezerInstrument};
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// `kilotouch emulate` subcommands.
#[derive(Debug, Subcommand)]
pub enum EmulateCommand {
    /// Emulate the haptic DAQ (encoders, accelerometer, Pantograph and Haptuator outputs) with the simulated plant.
    Daq(Args),
    /// Emulate a live optical tweezer with the simulated tweezer.
    Tweezer(Args),
}

/// Options shared by the emulators.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Serve on a new pseudo-terminal (its path is printed on the first line of stdout).
    #[arg(long, required = true)]
    pub pty: bool,
    /// Rig file (default: the built-in rig).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Device watchdog window, ms: outputs safe when no valid host frame arrives within it.
    #[arg(long, default_value_t = 100)]
    pub watchdog_ms: u64,
    /// Samples per device frame (default: 10 for the DAQ, 1 for the tweezer).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Probability that an outgoing byte is corrupted.
    #[arg(long, default_value_t = 0.0)]
    pub corrupt_rate: f64,
    /// Probability that an outgoing byte is dropped.
    #[arg(long, default_value_t = 0.0)]
    pub drop_rate: f64,
    /// Hang (no input, no output) after this many seconds.
    #[arg(long)]
    pub stall_after_s: Option<f64>,
    /// Length of the stall, s (default: for ever).
    #[arg(long)]
    pub stall_for_s: Option<f64>,
    /// Close the pty and exit after this many seconds.
    #[arg(long)]
    pub disconnect_after_s: Option<f64>,
    /// Seed of the fault injection (and of the sensor noise, when given).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Once started, misbehave without breaking the protocol: stream valid
    /// frames that never advance the sample stream (a test device for the
    /// host's progress watchdog).
    #[arg(long, value_enum)]
    pub misbehave: Option<MisbehaveArg>,
    /// Test device: set every flag bit (clipped, limited, end stop,
    /// non-finite, late command, watchdog) on every sample.
    #[arg(long)]
    pub flag_every_sample: bool,
    /// Test device: stream this many times faster than the sample rate
    /// announced in HELLO (0.01 to 100).
    #[arg(long, value_name = "FACTOR")]
    pub speedup: Option<f64>,
}

/// `--misbehave` modes (see [`Misbehaviour`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MisbehaveArg {
    /// Only STATUS frames, the sequence number never moving.
    StatusOnly,
    /// Only frames of an unknown type.
    UnknownFrames,
    /// SAMPLES frames with stray sequence numbers.
    StraySeq,
}

impl From<MisbehaveArg> for Misbehaviour {
    fn from(m: MisbehaveArg) -> Self {
        match m {
            MisbehaveArg::StatusOnly => Self::StatusOnly,
            MisbehaveArg::UnknownFrames => Self::UnknownFrames,
            MisbehaveArg::StraySeq => Self::StraySequence,
        }
    }
}

fn secs(name: &str, v: Option<f64>) -> anyhow::Result<Option<Duration>> {
    v.map(|s| {
        if s.is_finite() && s >= 0.0 {
            Ok(Duration::from_secs_f64(s))
        } else {
            anyhow::bail!("--{name} must be finite and ≥ 0, got {s}")
        }
    })
    .transpose()
}

impl Args {
    fn config(&self, default_batch: usize) -> anyhow::Result<EmulatorConfig> {
        let cfg = EmulatorConfig {
            watchdog: Duration::from_millis(self.watchdog_ms),
            batch: self.batch.unwrap_or(default_batch),
            faults: FaultInjection {
                corrupt_rate: self.corrupt_rate,
                drop_rate: self.drop_rate,
                stall_after: secs("stall-after-s", self.stall_after_s)?,
                stall_for: secs("stall-for-s", self.stall_for_s)?,
                disconnect_after: secs("disconnect-after-s", self.disconnect_after_s)?,
                seed: self.seed.unwrap_or(0),
                misbehave: self.misbehave.map(Misbehaviour::from),
                sample_flags: if self.flag_every_sample {
                    use kilotouch_rig::serial::frame::flag;
                    flag::CLIPPED
                        | flag::LIMITED
                        | flag::END_STOP
                        | flag::NONFINITE
                        | flag::CMD_LATE
                        | flag::WATCHDOG
                } else {
                    0
                },
                speedup: self.speedup,
            },
        };
        cfg.validate()?;
        Ok(cfg)
    }

    fn rig_config(&self) -> anyhow::Result<RigConfig> {
        let mut rc = RigConfig::load_or_default(self.rig_config.as_ref())?;
        if let Some(s) = self.seed {
            rc.accelerometer.seed = s;
            rc.tweezer.seed = s;
        }
        Ok(rc)
    }
}

fn run_on_pty<I: Instrument>(inst: I, cfg: EmulatorConfig, what: &str) -> anyhow::Result<()> {
    let pty = Pty::open().context("cannot create a pseudo-terminal")?;
    let clock = SystemClock::default();
    let mut emu = Emulator::new(inst, cfg, clock.now())?;
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", pty.path())?;
        out.flush()?;
    }
    let h = emu.hello();
    eprintln!(
        "kilotouch emulate {what}: `{}` at {} Hz on {} (watchdog {} ms, {} samples/frame); \
         stop with Ctrl-C",
        h.name,
        h.sample_rate_hz,
        pty.path(),
        h.watchdog_ms,
        h.batch
    );
    let stop = AtomicBool::new(false);
    match serve(&mut emu, &pty, &clock, &stop)? {
        ServeEnd::Disconnect => {
            eprintln!("kilotouch emulate {what}: injected disconnect, closing the pty");
        }
        ServeEnd::Stopped => {}
    }
    Ok(())
}

/// Run an `emulate` subcommand.
pub fn run(cmd: &EmulateCommand) -> anyhow::Result<()> {
    match cmd {
        EmulateCommand::Daq(a) => {
            let inst = DaqInstrument::new(&a.rig_config()?)?;
            run_on_pty(inst, a.config(10)?, "daq")
        }
        EmulateCommand::Tweezer(a) => {
            let inst = TweezerInstrument::new(&a.rig_config()?)?;
            run_on_pty(inst, a.config(1)?, "tweezer")
        }
    }
}
