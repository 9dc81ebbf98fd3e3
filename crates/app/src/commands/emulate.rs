//! `kilotouch emulate daq|tweezer --pty`: device emulators serving the
//! serial protocol (`docs/PROTOCOL.md`) on a pseudo-terminal, with the
//! simulated plant (DAQ) or the simulated tweezer behind it.
//!
//! The first line of stdout is the path of the pty's slave side (e.g.
//! `/dev/pts/3`), flushed at once, so that scripts and tests can read it
//! and open the port; the emulator then runs until it is killed (or until
//! an injected disconnect).
//!
//! Hardware in the loop on one machine: `emulate daq --participant
//! operator:SEED` puts the study's simulated participant at the emulated
//! handle ([`kilotouch_study::at_device::DeviceParticipant`]); a host's
//! sitting on that port (`kilotouch study run --rig serial:PTY`) then runs
//! as with a person at a real rig. `--free-running` makes the device run
//! every sample at its time (holding the previous command when the host's
//! is late, as firmware does), `--link-delay-ms` delays every byte in each
//! direction.

use anyhow::Context;
use clap::Subcommand;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::{Clock, SystemClock};
use kilotouch_rig::serial::emulator::{
    Emulator, EmulatorConfig, FaultInjection, Instrument, Misbehaviour,
};
use kilotouch_rig::serial::pty::{Pty, ServeEnd, serve_delayed};
use kilotouch_rig::serial::{DaqInstrument, TweezerInstrument};
use kilotouch_study::at_device::DeviceParticipant;
use kilotouch_study::task::{Geometry, TaskParams};
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
    /// Samples per device frame (default 10: a 10-sample block in one frame).
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
    /// Run like firmware: every sample at its time; a command that has not
    /// arrived is replaced by the previous one and the sample flagged
    /// CMD_LATE (default: wait for it, simulated time standing still).
    #[arg(long)]
    pub free_running: bool,
    /// Delay every byte by this long in each direction, ms (the round trip
    /// grows by twice this).
    #[arg(long, default_value_t = 0.0)]
    pub link_delay_ms: f64,
    /// Clock speed: simulated seconds per wall-clock second (1 = real
    /// time). The device still announces its rig's rate, so the host's
    /// loop delay and time-outs in samples are unchanged; for benchmarks
    /// that run many sittings. 0.1 ..= 20.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Who is at the emulated handle: `operator:SEED` — the study's
    /// simulated participant of study seed SEED (the protocol's
    /// `seeds.study` gives `study simulate`'s participants). DAQ only.
    #[arg(long, value_name = "operator:SEED")]
    pub participant: Option<String>,
    /// Test device: set every flag bit (clipped, limited, end stop,
    /// non-finite, late command, watchdog) on every sample.
    #[arg(long)]
    pub flag_every_sample: bool,
    /// The micro-world of a study's scene (tweezer only): the protocol's
    /// manipulated bead, escape distance and obstacle (centred at the
    /// instrument's origin) replace the rig file's. A TOML file or a
    /// built-in name (`paper`, `blind`).
    #[arg(long, value_name = "PROTOCOL")]
    pub protocol: Option<String>,
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
            free_running: self.free_running,
            speed: self.speed,
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

/// The link delay of `--link-delay-ms`.
fn link_delay(ms: f64) -> anyhow::Result<Duration> {
    if !(ms.is_finite() && (0.0..=1000.0).contains(&ms)) {
        anyhow::bail!("--link-delay-ms must be in [0, 1000] ms, got {ms}");
    }
    Ok(Duration::from_secs_f64(ms * 1e-3))
}

/// The study seed of `--participant operator:SEED`.
fn operator_seed(spec: &str) -> anyhow::Result<u64> {
    let seed = spec.strip_prefix("operator:").ok_or_else(|| {
        anyhow::anyhow!(
            "--participant {spec}: expected `operator:SEED` (the study's simulated participant)"
        )
    })?;
    seed.trim().parse().map_err(|_| {
        anyhow::anyhow!("--participant {spec}: SEED must be a whole number (the study seed)")
    })
}

fn run_on_pty<I: Instrument>(
    inst: I,
    cfg: EmulatorConfig,
    delay: Duration,
    what: &str,
) -> anyhow::Result<()> {
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
        "kilotouch emulate {what}: `{}` at {} Hz on {} (watchdog {} ms, {} samples/frame{}{}); \
         stop with Ctrl-C",
        h.name,
        h.sample_rate_hz,
        pty.path(),
        h.watchdog_ms,
        h.batch,
        if cfg.free_running {
            ", free-running"
        } else {
            ""
        },
        if delay.is_zero() {
            String::new()
        } else {
            format!(", link delay {:.2} ms each way", delay.as_secs_f64() * 1e3)
        }
    );
    // A device keeps its own time: the serving thread runs real-time where
    // the system allows it (it sleeps in poll between samples).
    if let kilotouch_rig::realtime::Scheduling::Normal(why) =
        kilotouch_rig::realtime::promote_current_thread()
    {
        eprintln!("kilotouch emulate {what}: {why}; timing will follow the machine's load");
    }
    let stop = AtomicBool::new(false);
    match serve_delayed(&mut emu, &pty, &clock, &stop, delay)? {
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
            if a.protocol.is_some() {
                anyhow::bail!(
                    "--protocol: the protocol's micro-world is the tweezer's (`emulate tweezer \
                     --protocol`); the DAQ hosts the study's participant (`--participant`)"
                );
            }
            let rc = a.rig_config()?;
            let mut inst = DaqInstrument::new(&rc)?;
            if let Some(p) = &a.participant {
                let seed = operator_seed(p)?;
                let act_every = kilotouch_study::runner::RunnerConfig::default().act_every;
                inst = inst.with_agent(Box::new(DeviceParticipant::new(
                    seed,
                    rc.rig.sample_rate_hz,
                    act_every,
                )));
                eprintln!(
                    "kilotouch emulate daq: the simulated participant of study seed {seed} is at \
                     the handle"
                );
            }
            run_on_pty(inst, a.config(10)?, link_delay(a.link_delay_ms)?, "daq")
        }
        EmulateCommand::Tweezer(a) => {
            if a.participant.is_some() {
                anyhow::bail!(
                    "--participant: a participant sits at the DAQ's handle, not the tweezer"
                );
            }
            let mut rc = a.rig_config()?;
            if let Some(p) = &a.protocol {
                let protocol = super::protocol_arg::load_protocol(p)?;
                let escape = TaskParams::from_protocol(&protocol).escape_distance_m();
                Geometry::of_protocol(&protocol.task).apply_to(&mut rc.tweezer, escape);
                eprintln!(
                    "kilotouch emulate tweezer: the micro-world of the protocol `{}`",
                    protocol.name
                );
            }
            let inst = TweezerInstrument::new(&rc)?;
            run_on_pty(inst, a.config(10)?, link_delay(a.link_delay_ms)?, "tweezer")
        }
    }
}
