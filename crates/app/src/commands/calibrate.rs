//! `kilotouch calibrate`: the paper's §3 procedure (identify both channels,
//! choose the crossover, design C_L and C_H, verify flatness at third-octave
//! centres) on a rig, headless.

use crate::output::emit;
use kilotouch_rig::calibration::sim::calibrate_sim;
use kilotouch_rig::calibration::{CalibrationConfig, Step};
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

/// Arguments of `kilotouch calibrate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Rig to calibrate: `sim` (the simulated rig).
    #[arg(long, default_value = "sim")]
    pub rig: String,
    /// Rig file for the simulated rig (default: the built-in rig).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Seed of the simulated sensor noise.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Write the calibration file (TOML) here.
    #[arg(long)]
    pub out: Option<PathBuf>,
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

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    if a.rig != "sim" {
        anyhow::bail!(
            "--rig {}: only the simulated rig (`--rig sim`) is available in this build",
            a.rig
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
    let outcome = calibrate_sim(
        a.rig_config.as_deref(),
        a.seed,
        &cal_cfg,
        a.out.as_deref(),
        &mut progress,
        &cancel,
    )?;
    let report = outcome.report();
    if let Some(p) = &a.out {
        eprintln!("calibration file written to {}", p.display());
    }
    emit(a.json, &report, || report.table())
}
