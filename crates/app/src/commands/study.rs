//! `kilotouch study simulate`: a whole study (or a shard of its
//! participants) run by the simulated operator on the simulated rig,
//! written to a crash-safe output folder (`trials.csv`, summaries,
//! `session.json`, journal, raw NPY files); `kilotouch study merge`: shard
//! folders joined into one.

use std::path::PathBuf;

use anyhow::Context;
use kilotouch_rig::config::RigConfig;
use kilotouch_study::runner::RunnerConfig;
use kilotouch_study::simulate::{SimulateOptions, SimulateReport, simulate};
use kilotouch_study::size::{available_space, check_free_space, estimate_simulated_study};

use super::progress::Progress;
use crate::output::emit;

/// `kilotouch study …`.
#[derive(Debug, clap::Subcommand)]
pub enum StudyCommand {
    /// Run a whole study with simulated participants on the simulated rig.
    Simulate(SimulateArgs),
    /// One participant's sitting on the real-time engine, headless: the
    /// simulated participant on the simulated rig, or a live rig whose
    /// handle a real hand moves (hardware in the loop with the emulator's
    /// `--participant`).
    Run(super::study_run::RunArgs),
    /// How many participants? Power of the planned analysis, simulated from a pilot.
    Power(super::study_power::PowerArgs),
    /// Join study folders of one protocol and seed (the shards of
    /// `study simulate --shard K/N`) into one study folder: checksums and
    /// journals verified, rows in plan order, summaries regenerated.
    Merge(MergeArgs),
}

/// Arguments of `kilotouch study merge`.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The study folders to join (e.g. the shard folders).
    #[arg(required = true, value_name = "DIR")]
    pub inputs: Vec<PathBuf>,
    /// The new study folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Fail unless the merged study is complete (every planned trial has
    /// its row).
    #[arg(long)]
    pub require_complete: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `kilotouch study simulate`.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Protocol: a TOML file, or a built-in name (`paper`, `blind`).
    #[arg(long, default_value = "paper")]
    pub protocol: String,
    /// Number of participants (default: the protocol's).
    #[arg(long)]
    pub participants: Option<u32>,
    /// Study seed (default: the protocol's).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the study in --out (after a kill or crash).
    #[arg(long)]
    pub resume: bool,
    /// Do not write raw-signal files.
    #[arg(long)]
    pub no_raw: bool,
    /// Worker threads (default: available cores). Results do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// How much of the model each trial runs: `scene` (only what the
    /// trial's condition and recording need), `full` (everything, the
    /// reference) or `draft` (scene with P and D's haptic loop at a fifth of
    /// the rig's rate, cleared at that rate; for power planning). Recorded in
    /// session.json.
    #[arg(long, default_value = "scene")]
    pub fidelity: kilotouch_study::fidelity::Fidelity,
    /// Run only shard K of N: the participants whose 0-based index i has
    /// i mod N = K − 1 (e.g. `3/8`; one shard per cluster job). Join the
    /// shard folders with `kilotouch study merge`.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<kilotouch_study::shard::Shard>,
    /// The simulated rig and D's chain. A calibration is recorded with its
    /// SHA-256 in session.json and the journal; without one, the model's
    /// as-designed chain is recorded as uncalibrated.
    #[command(flatten)]
    pub rig: super::rig::LoopArgs,
    /// With --resume: continue although the rig file, calibration or raw
    /// recording differ from the folder's, recording this reason in the
    /// journal (otherwise such a resume is refused with the differences).
    #[arg(long, value_name = "REASON", requires = "resume")]
    pub new_sitting: Option<String>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Free space of the target disk in bytes, instead of asking the
    /// operating system (tests of the refusal).
    #[arg(long, hide = true, value_name = "BYTES")]
    pub assume_free_bytes: Option<u64>,
}

/// Run a `study` subcommand.
pub fn run(c: &StudyCommand) -> anyhow::Result<()> {
    match c {
        StudyCommand::Simulate(a) => run_simulate(a),
        StudyCommand::Run(a) => super::study_run::run(a),
        StudyCommand::Power(a) => super::study_power::run(a),
        StudyCommand::Merge(a) => run_merge(a),
    }
}

fn human(r: &SimulateReport) -> String {
    let mut s = String::new();
    s.push_str(&format!(
        "study `{}` (seed {}, {} participants) in {}\n",
        r.protocol,
        r.seed,
        r.participants,
        r.out.display()
    ));
    s.push_str(&format!("  {}\n", r.recovery));
    s.push_str(&format!(
        "  trials: {} planned, {} already complete, {} run now\n",
        r.planned, r.already_completed, r.ran
    ));
    s.push_str(&format!(
        "  rows: {} test ({} successful), {} practice\n",
        r.test_rows, r.test_success, r.practice_rows
    ));
    s.push_str(&format!(
        "  simulated {:.1} s in {:.2} s wall on {} thread(s), raw files: {}\n",
        r.simulated_s,
        r.wall_s,
        r.threads,
        if r.raw { "yes" } else { "no" }
    ));
    s.push_str(&format!("  fidelity: {}\n", r.fidelity));
    if let Some(shard) = r.shard {
        s.push_str(&format!(
            "  shard {shard}: participants {}, {}, … (1-based); join the shard folders with `kilotouch study merge`\n",
            shard.index,
            shard.index + shard.count
        ));
    }
    s
}

fn run_simulate(a: &SimulateArgs) -> anyhow::Result<()> {
    let protocol = super::protocol_arg::load_protocol_with(&a.protocol, a.participants, a.seed)?;
    let rig = RigConfig::load_or_default(a.rig.rig_config.as_ref())?;
    let threads = super::protocol_arg::threads(a.threads)?;
    let mut runner = RunnerConfig::default();
    if a.no_raw {
        runner.raw = None;
    }
    let opts = SimulateOptions {
        protocol,
        out: a.out.clone(),
        resume: a.resume,
        rig,
        calibration: a.rig.calibration.clone(),
        runner,
        threads,
        new_sitting: a.new_sitting.clone(),
        fidelity: a.fidelity,
        shard: a.shard,
    };
    let size = estimate_simulated_study(&opts)
        .with_context(|| format!("estimating the size of the study in {}", a.out.display()))?;
    eprintln!("kilotouch: the run will write {}", size.describe());
    let available = match a.assume_free_bytes {
        Some(b) => b,
        None => available_space(&a.out)
            .with_context(|| format!("free space of the disk of {}", a.out.display()))?,
    };
    check_free_space(&size, &a.out, available)?;
    let mut bar = Progress::new("trials");
    let report = simulate(&opts, &mut |done, total| bar.count(done, total))
        .with_context(|| format!("study simulate into {}", a.out.display()))?;
    let out = SimulateOutput {
        report: &report,
        estimate: &size,
    };
    emit(a.json, &out, || human(&report))
}

/// JSON of `kilotouch study simulate`: the report and the size estimated
/// before the run.
#[derive(serde::Serialize)]
struct SimulateOutput<'a> {
    #[serde(flatten)]
    report: &'a SimulateReport,
    estimate: &'a kilotouch_study::size::StudySize,
}

fn run_merge(a: &MergeArgs) -> anyhow::Result<()> {
    let report = kilotouch_study::merge::merge(&a.inputs, &a.out)
        .with_context(|| format!("study merge into {}", a.out.display()))?;
    emit(a.json, &report, || {
        let mut s = format!(
            "merged {} folder(s) into {}: {} of {} planned trials ({}), {} raw file(s)\n",
            report.inputs.len(),
            report.out.display(),
            report.rows,
            report.planned,
            if report.complete {
                "complete"
            } else {
                "incomplete"
            },
            report.raw_files
        );
        for (p, n) in report.inputs.iter().zip(&report.rows_per_input) {
            s.push_str(&format!("  {}: {n} rows\n", p.display()));
        }
        s
    })?;
    if a.require_complete && !report.complete {
        anyhow::bail!(
            "the merged study has {} of {} planned trials (--require-complete): a shard is missing or unfinished",
            report.rows,
            report.planned
        );
    }
    Ok(())
}
