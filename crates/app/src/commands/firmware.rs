//! `kilotouch firmware …`: the test build of the DAQ firmware (`firmware/`,
//! feature `qemu`, run in `qemu-system-arm -M netduinoplus2`) through its
//! test frames (docs/PROTOCOL.md §13, docs/FIRMWARE.md): load the plant
//! model from a rig file, set the late-command policy, the simulated
//! emergency stop and fault injection, read the sample interrupt's cost.

use crate::output::emit;
use anyhow::Context;
use clap::Subcommand;
use kilotouch_rig::RigConfig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::serial::test_link::{Policy, TestLink};
use serde::Serialize;
use std::path::PathBuf;

/// `kilotouch firmware` subcommands.
#[derive(Debug, Subcommand)]
pub enum FirmwareCommand {
    /// Load a rig file's plant (second-order sections, accelerometer, scales) into the firmware's QEMU build.
    LoadPlant(LoadArgs),
    /// Set the test build's late-command policy, simulated emergency stop or fault injection.
    Set(SetArgs),
    /// Read (and reset) the sample interrupt's cost counters.
    Profile(ProfileArgs),
}

/// Arguments of `kilotouch firmware load-plant`.
#[derive(Debug, clap::Args)]
pub struct LoadArgs {
    /// The device: `serial:PATH`.
    #[arg(long)]
    pub rig: String,
    /// Rig file (default: the built-in rig).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `--mode` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModeArg {
    /// Wait for late commands (the emulator's semantics; the default).
    Wait,
    /// Hold the previous command and flag CMD_LATE (a free-running device).
    Hold,
}

/// `--estop` values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    /// Engaged.
    On,
    /// Released.
    Off,
}

/// Arguments of `kilotouch firmware set`.
#[derive(Debug, clap::Args)]
pub struct SetArgs {
    /// The device: `serial:PATH`.
    #[arg(long)]
    pub rig: String,
    /// Late-command policy (idle device).
    #[arg(long, value_enum)]
    pub mode: Option<ModeArg>,
    /// Simulated emergency-stop input.
    #[arg(long, value_enum)]
    pub estop: Option<OnOff>,
    /// Probability that a device → host byte is corrupted (with --drop-rate, --seed).
    #[arg(long)]
    pub corrupt_rate: Option<f64>,
    /// Probability that a device → host byte is dropped.
    #[arg(long, default_value_t = 0.0)]
    pub drop_rate: f64,
    /// Seed of the fault injection.
    #[arg(long, default_value_t = 1)]
    pub seed: u32,
}

/// Arguments of `kilotouch firmware profile`.
#[derive(Debug, clap::Args)]
pub struct ProfileArgs {
    /// The device: `serial:PATH`.
    #[arg(long)]
    pub rig: String,
    /// Reset the counters after reading them.
    #[arg(long)]
    pub reset: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// `load-plant --json`.
#[derive(Debug, Serialize)]
struct LoadReport {
    sections: u32,
    sections_per_channel: Vec<usize>,
    encoder_counts_per_m: f64,
    accel_m_s2_per_code: f64,
    force_max_n: f64,
    drive_max_v: f64,
}

/// `profile --json`: counts of the device's cycle counter (CPU cycles on a
/// board, instructions under QEMU's `-icount shift=0`).
#[derive(Debug, Serialize)]
struct ProfileReport {
    ticks: u32,
    max: u32,
    mean: f64,
    plant_max: u32,
    plant_mean: f64,
    /// Frames the device dropped whole for a full transmit queue.
    tx_dropped: u32,
}

fn open(rig: &str) -> anyhow::Result<TestLink> {
    match rig.parse::<RigSpec>()? {
        RigSpec::Serial(cfg) => Ok(TestLink::open(&cfg.path)?),
        other => anyhow::bail!(
            "--rig {}: the firmware's test frames need a serial device",
            other.describe()
        ),
    }
}

/// Run a `firmware` subcommand.
pub fn run(cmd: &FirmwareCommand) -> anyhow::Result<()> {
    match cmd {
        FirmwareCommand::LoadPlant(a) => {
            let rc = RigConfig::load_or_default(a.rig_config.as_ref())?;
            let mut link = open(&a.rig)?;
            let l = link
                .load_plant(&rc)
                .with_context(|| format!("firmware load-plant --rig {}", a.rig))?;
            let r = LoadReport {
                sections: l.total,
                sections_per_channel: l.sections_per_channel,
                encoder_counts_per_m: l.sensors.encoder_counts_per_m,
                accel_m_s2_per_code: l.sensors.accel_m_s2_per_code,
                force_max_n: l.sensors.force_max_n,
                drive_max_v: l.sensors.drive_max_v,
            };
            emit(a.json, &r, || {
                format!(
                    "loaded {} plant sections ({:?} per channel)\n",
                    r.sections, r.sections_per_channel
                )
            })
        }
        FirmwareCommand::Set(a) => {
            let mut link = open(&a.rig)?;
            let ctx = || format!("firmware set --rig {}", a.rig);
            if let Some(m) = a.mode {
                let p = match m {
                    ModeArg::Wait => Policy::Wait,
                    ModeArg::Hold => Policy::Hold,
                };
                link.set_policy(p).with_context(ctx)?;
            }
            if let Some(e) = a.estop {
                link.set_estop(e == OnOff::On).with_context(ctx)?;
            }
            if let Some(c) = a.corrupt_rate {
                link.set_faults(c, a.drop_rate, a.seed).with_context(ctx)?;
            }
            Ok(())
        }
        FirmwareCommand::Profile(a) => {
            let mut link = open(&a.rig)?;
            let p = link
                .profile(a.reset)
                .with_context(|| format!("firmware profile --rig {}", a.rig))?;
            let n = f64::from(p.ticks.max(1));
            let r = ProfileReport {
                ticks: p.ticks,
                max: p.max,
                mean: p.sum as f64 / n,
                plant_max: p.plant_max,
                plant_mean: p.plant_sum as f64 / n,
                tx_dropped: p.tx_dropped,
            };
            emit(a.json, &r, || {
                format!(
                    "{} sample interrupts: mean {:.0}, max {} counts (plant model: mean {:.0}, \
                     max {}); {} frame(s) dropped for a full transmit queue\n",
                    r.ticks, r.mean, r.max, r.plant_mean, r.plant_max, r.tx_dropped
                )
            })
        }
    }
}
