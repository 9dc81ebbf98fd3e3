//! `kilotouch calibrate`: the paper's §3 procedure (identify both channels,
//! choose the crossover, design C_L and C_H, verify flatness at third-octave
//! centres) on a rig, headless.

use crate::output::emit;
use kilotouch_rig::RigConfig;
use kilotouch_rig::accel::Accelerometer;
use kilotouch_rig::calibration::sim::{calibrate_sim, rig_config_hash};
use kilotouch_rig::calibration::{
    CalibrationConfig, CalibrationOutcome, RigAdapter, Step, calibrate,
};
use kilotouch_rig::device::Rig;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::serial::{SerialConfig, SerialRig};
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

/// Arguments of `kilotouch calibrate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Rig to calibrate: `sim` (the simulated rig) or `serial:PATH[,baud=N][,timeout-ms=N]`
    /// (a DAQ speaking docs/PROTOCOL.md, e.g. `kilotouch emulate daq --pty`).
    #[arg(long, default_value = "sim")]
    pub rig: String,
    /// Rig file: the simulated rig, or for a serial rig the description of its
    /// accelerometer (whose response is divided out) and the configuration hash
    /// stored in the calibration file (default: the built-in rig).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Seed of the simulated sensor noise.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Write the calibration file (TOML) here; an existing file is kept
    /// unless --overwrite is given (as on the Calibration page).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an existing --out file.
    #[arg(long, requires = "out")]
    pub overwrite: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Progress on stderr: a bar redrawn in place on a terminal, one line per
/// step otherwise (logs stay readable).
struct StderrProgress {
    tty: bool,
    last_step: Option<Step>,
}

impl StderrProgress {
    fn report(&mut self, step: Step, fraction: f64, message: &str) {
        let mut err = std::io::stderr().lock();
        let overall = step.overall(fraction).clamp(0.0, 1.0);
        if self.tty {
            let width = 30;
            let filled = (overall * width as f64).round() as usize;
            let _ = write!(
                err,
                "\r\x1b[2K[{}{}] {:3.0}% {}: {}",
                "#".repeat(filled),
                " ".repeat(width - filled.min(width)),
                overall * 100.0,
                step.name(),
                message
            );
            if overall >= 1.0 {
                let _ = writeln!(err);
            }
        } else if self.last_step != Some(step) {
            let _ = writeln!(
                err,
                "[{:3.0}%] {}: {}",
                overall * 100.0,
                step.name(),
                message
            );
        }
        self.last_step = Some(step);
    }
}

/// Calibrate the DAQ on a serial link: the rig file describes its
/// accelerometer (response divided out) and identifies its configuration.
fn calibrate_serial(
    cfg: &SerialConfig,
    rig_config: Option<&std::path::Path>,
    cal_cfg: &CalibrationConfig,
    out: Option<&std::path::Path>,
    progress: &mut dyn kilotouch_rig::calibration::Progress,
    cancel: &AtomicBool,
) -> anyhow::Result<CalibrationOutcome> {
    let rc = RigConfig::load_or_default(rig_config)?;
    let mut cfg = cfg.clone();
    // The device idles between runs while the host computes; its watchdog
    // may trip then, with nothing owed: restart it instead of failing.
    cfg.rearm_after_idle_trip = true;
    // Open-loop measurement: each block's sensor frames must be those of
    // its own commands (no command lead).
    cfg.lead = kilotouch_rig::serial::CommandLead::Blocks(0);
    let rig = SerialRig::open(&cfg)?;
    let fs = rig.sample_rate_hz();
    if (fs - rc.rig.sample_rate_hz).abs() > 1e-9 * fs {
        anyhow::bail!(
            "the device runs at {fs} Hz but the rig file says {} Hz",
            rc.rig.sample_rate_hz
        );
    }
    let sensor = Accelerometer::new(&rc.accelerometer, fs)?;
    let mut adapter = RigAdapter::new(rig, rig_config_hash(&rc)?, Some(sensor));
    let outcome = calibrate(&mut adapter, cal_cfg, out, progress, cancel);
    let _ = adapter.rig_mut().stop();
    Ok(outcome?)
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let spec: RigSpec = a.rig.parse()?;
    // Messages name the full path; an existing file is refused before the
    // calibration runs (the same rule as the GUI's "overwrite" box).
    let out = a
        .out
        .as_ref()
        .map(|p| std::path::absolute(p).unwrap_or_else(|_| p.clone()));
    if let Some(p) = &out
        && p.exists()
        && !a.overwrite
    {
        anyhow::bail!(
            "{} exists; add --overwrite to replace it (nothing was calibrated)",
            p.display()
        );
    }
    let cal_cfg = CalibrationConfig::default();
    let cancel = AtomicBool::new(false);
    let mut bar = StderrProgress {
        tty: std::io::stderr().is_terminal(),
        last_step: None,
    };
    let mut progress =
        |step: Step, fraction: f64, message: &str| bar.report(step, fraction, message);
    let outcome = match &spec {
        RigSpec::Sim => calibrate_sim(
            a.rig_config.as_deref(),
            a.seed,
            &cal_cfg,
            out.as_deref(),
            &mut progress,
            &cancel,
        )?,
        RigSpec::Serial(cfg) => calibrate_serial(
            cfg,
            a.rig_config.as_deref(),
            &cal_cfg,
            out.as_deref(),
            &mut progress,
            &cancel,
        )
        .map_err(|e| anyhow::anyhow!("--rig {}: {e:#}", spec.describe()))?,
        RigSpec::Audio(_) => {
            anyhow::bail!("--rig {}: {}", spec.describe(), RigSpec::audio_not_built())
        }
    };
    let report = outcome.report();
    if let Some(p) = &out {
        eprintln!("calibration file written to {}", p.display());
    }
    emit(a.json, &report, || report.table())
}
