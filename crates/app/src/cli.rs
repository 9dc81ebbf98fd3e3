//! Command-line interface: argument parsing and dispatch.
//!
//! Every headless command prints JSON on stdout with `--json` (one object),
//! a human-readable table otherwise; errors go to stderr with a non-zero exit
//! status (2 for usage errors, 1 for everything else).

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

use crate::commands;

/// kilotouch — dual-stage haptic psychophysics workbench.
#[derive(Debug, Parser)]
#[command(name = "kilotouch", version, about, long_about = None)]
pub struct Cli {
    /// Command; without one, kilotouch opens the desktop app on the simulated rig.
    #[command(subcommand)]
    pub command: Option<Command>,
}

/// The commands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Open the desktop app (the default without a command).
    Gui(crate::gui::GuiArgs),
    /// Response of the digital Linkwitz–Riley crossover at given frequencies.
    Crossover(commands::crossover::Args),
    /// Welch power spectral density of one CSV column (scipy.signal.welch conventions).
    Psd(commands::psd::Args),
    /// H1 frequency-response estimate with coherence between two CSV columns.
    Frf(commands::frf::Args),
    /// Fit a continuous-time transfer function to frequency-response data (columns f,re,im[,weight]).
    Tfest(commands::tfest::Args),
    /// Statistics on a long-format CSV: one-way ANOVA, repeated-measures ANOVA or Friedman.
    Stats(commands::stats::Args),
    /// Calibrate a rig: identify both channels, choose the crossover, design the compensators, verify flatness.
    Calibrate(commands::calibrate::Args),
    /// Rig files and rig checks.
    #[command(subcommand)]
    Rig(commands::rig::RigCommand),
    /// The simulated rig's models: analytic channel responses, tweezer statistics.
    #[command(subcommand)]
    Sim(commands::sim::SimCommand),
    /// Measure the speed of the signal chain and of Welch's estimator.
    Bench(commands::bench::Args),
    /// Device emulators serving the serial protocol on a pseudo-terminal (for tests and firmware work).
    #[command(subcommand)]
    Emulate(commands::emulate::EmulateCommand),
    /// The DAQ firmware's QEMU build: load its plant model, set its test options, read its costs.
    #[command(subcommand)]
    Firmware(commands::firmware::FirmwareCommand),
    /// Studies: simulated runs of a protocol.
    #[command(subcommand)]
    Study(commands::study::StudyCommand),
    /// Regenerate the paper's Figs. 4, 5, 7, 9–12 from the simulator and check its claims.
    Paper(commands::paper::Args),
    /// Optical trap: power-spectral calibration (κ, detector sensitivity) and detector records.
    #[command(subcommand)]
    Tweezer(commands::tweezer::TweezerCommand),
}

/// Parse arguments, run, and map errors to exit codes.
pub fn main_entry() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap prints help/version to stdout with exit 0, usage errors to stderr with 2.
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    if let None | Some(Command::Gui(_)) = &cli.command {
        let args = match cli.command {
            Some(Command::Gui(a)) => a,
            _ => crate::gui::GuiArgs::default_args(),
        };
        return match crate::gui::run(&args) {
            Ok(code) => code,
            Err(e) => {
                eprintln!("kilotouch: error: {e}");
                ExitCode::FAILURE
            }
        };
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprint!("{}", error_text(&e));
            ExitCode::FAILURE
        }
    }
}

/// Characters of one error message shown (a 20 MB CSV cell in a message
/// is cut, with the count of what was left out).
const ERROR_MAX_CHARS: usize = 2_000;

/// The error and its causes, one per line: each cause printed once (a
/// cause whose text the messages above already contain is skipped), each
/// made printable and cut at [`ERROR_MAX_CHARS`].
pub fn error_text(e: &anyhow::Error) -> String {
    use kilotouch_rig::text::printable;
    let mut shown: Vec<String> = Vec::new();
    let mut out = String::new();
    for (i, cause) in e.chain().enumerate() {
        let text = cause.to_string();
        if shown.iter().any(|s| s.contains(&text)) {
            continue;
        }
        let line = printable(&text, ERROR_MAX_CHARS);
        if i == 0 {
            out.push_str(&format!("kilotouch: error: {line}\n"));
        } else {
            out.push_str(&format!("  caused by: {line}\n"));
        }
        shown.push(text);
    }
    out
}

/// Run a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        None | Some(Command::Gui(_)) => {
            use clap::CommandFactory;
            Cli::command().print_help()?;
            println!();
            Ok(())
        }
        Some(Command::Crossover(a)) => commands::crossover::run(&a),
        Some(Command::Psd(a)) => commands::psd::run(&a),
        Some(Command::Frf(a)) => commands::frf::run(&a),
        Some(Command::Tfest(a)) => commands::tfest::run(&a),
        Some(Command::Stats(a)) => commands::stats::run(&a),
        Some(Command::Calibrate(a)) => commands::calibrate::run(&a),
        Some(Command::Rig(c)) => commands::rig::run(&c),
        Some(Command::Sim(c)) => commands::sim::run(&c),
        Some(Command::Bench(a)) => commands::bench::run(&a),
        Some(Command::Emulate(c)) => commands::emulate::run(&c),
        Some(Command::Firmware(c)) => commands::firmware::run(&c),
        Some(Command::Study(c)) => commands::study::run(&c),
        Some(Command::Paper(a)) => commands::paper::run_cmd(&a),
        Some(Command::Tweezer(c)) => commands::tweezer::run(&c),
    }
}

/// Path argument helper for commands that read files.
pub type FileArg = PathBuf;
