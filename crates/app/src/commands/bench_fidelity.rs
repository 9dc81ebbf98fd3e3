//! `kilotouch bench fidelity`: the simulation's fidelity levels as a
//! frontier of speed against error.
//!
//! The same cohort (one protocol, one study seed) is simulated at each
//! level of [`Fidelity`] — `full` (the reference), `scene` and `draft` — one
//! level after the other. For each level the report gives:
//!
//! * the process's CPU time ([`process_cpu_ns`], all worker threads
//!   together, so the figure does not depend on `--threads`) per trial
//!   (practice and test) and per participant, and the speed ratio to
//!   `full` (full's CPU time over the level's);
//! * per condition and metric (success, time, optical force, displacement
//!   error, contact fraction), the difference of the level's test-trial mean
//!   from full's in pooled standard errors
//!   ([`kilotouch_study::stats::agreement`]), and the largest |difference|;
//! * the answer a power analysis gives when the level's study is the pilot
//!   (`study power` on its `trials.csv`: the paired contrast `--contrast` of
//!   `--dv`, the smallest n of `--n` reaching `--target`).
//!
//! Under `--out` it keeps the three study folders and writes the frontier
//! (`frontier.png`, `frontier.svg`: speed-up against |difference| / SE,
//! [`crate::fidelity_plot`]) and the JSON (`frontier.json`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use kilotouch_rig::realtime::{load_average, process_cpu_ns};
use kilotouch_study::export::{TRIALS_FILE, TrialRow, read_trials};
use kilotouch_study::fidelity::Fidelity;
use kilotouch_study::power::{
    PowerOptions, PowerPoint, PowerReport, PowerTest, conditions_of, parse_contrast,
    parse_sample_sizes, power, read_pilot,
};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::runner::RunnerConfig;
use kilotouch_study::seeds::Phase;
use kilotouch_study::simulate::{SimulateOptions, simulate};
use kilotouch_study::stats::agreement::{Agreement, Compared, agreement};
use serde::Serialize;

use super::progress::Progress;
use crate::output::emit;

/// The levels in the order they run and are reported: the reference first.
pub const LEVELS: [Fidelity; 3] = [Fidelity::Full, Fidelity::Scene, Fidelity::Draft];

/// The bound of the frontier plot and of `within_bound`, pooled SE: a
/// level's metric further than this from full's differs beyond sampling
/// error (two-sided 0.27 % per comparison for normal means).
pub const BOUND_SE: f64 = 3.0;

/// Largest number of participants per level (each runs three times).
pub const MAX_PARTICIPANTS: u32 = 256;

/// Arguments of `kilotouch bench fidelity`.
#[derive(Debug, Clone, clap::Args)]
pub struct FidelityArgs {
    /// Participants per level (10 test trials per condition each in the
    /// paper's protocol; 24 give the 240 per condition of the docs' table).
    #[arg(long, default_value_t = 4)]
    pub participants: u32,
    /// The study seed (the cohort every level runs).
    #[arg(long, default_value_t = 33)]
    pub seed: u64,
    /// Protocol: a TOML file or a built-in name (`paper`, `blind`).
    #[arg(long, default_value = "paper")]
    pub protocol: String,
    /// Folder for the three studies, the plot and the JSON (default: a new
    /// temporary folder, kept and named in the report).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Worker threads (default: available cores). The CPU figures add up
    /// every thread, so they do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// The power question each level answers: dependent variable.
    #[arg(long, default_value = "disp_err_mean_um")]
    pub dv: String,
    /// The power question: paired contrast of two conditions.
    #[arg(long, default_value = "P-D")]
    pub contrast: String,
    /// The power question: numbers of participants to try (comma list
    /// and/or `FROM:TO:STEP`).
    #[arg(long, default_value = "4:96:4")]
    pub n: String,
    /// The power question: simulated studies per number of participants.
    #[arg(long, default_value_t = 1000)]
    pub replications: u32,
    /// The power question: power wanted.
    #[arg(long, default_value_t = 0.8)]
    pub target: f64,
    /// Also write the frontier PNG here (e.g. the docs' figure,
    /// `docs/figures/fidelity-frontier.png`).
    #[arg(long, value_name = "FILE")]
    pub figure: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// The power question every level answers (`study power` options).
#[derive(Debug, Clone, Serialize)]
pub struct PowerQuestion {
    /// Dependent variable column.
    pub dv: String,
    /// The paired contrast, `A-B`.
    pub contrast: String,
    /// Numbers of participants tried.
    pub n: Vec<u32>,
    /// Simulated studies per n.
    pub replications: u32,
    /// Power wanted.
    pub target: f64,
    /// α.
    pub alpha: f64,
    /// Seed of the power simulation (the study seed).
    pub seed: u64,
}

/// One level of the frontier.
#[derive(Debug, Clone, Serialize)]
pub struct LevelReport {
    /// The fidelity level.
    pub fidelity: Fidelity,
    /// Its study folder.
    pub folder: PathBuf,
    /// Trials simulated (practice and test).
    pub trials: usize,
    /// Process CPU time of the simulation, s (every thread).
    pub cpu_s: f64,
    /// Wall time of the simulation, s.
    pub wall_s: f64,
    /// CPU time per trial, ms.
    pub cpu_ms_per_trial: f64,
    /// CPU time per participant, s.
    pub cpu_s_per_participant: f64,
    /// Full's CPU time over this level's (1 for full).
    pub speedup_vs_full: f64,
    /// Per condition and metric: a = this level, b = full.
    pub differences: Vec<Agreement>,
    /// The largest |z| of `differences` (0 for full).
    pub max_abs_z: f64,
    /// Every |z| ≤ [`BOUND_SE`].
    pub within_bound: bool,
    /// The power question's answer with this level's study as the pilot
    /// (`None`: the target is not reached at any n tried, or see
    /// `power_error`).
    pub n_for_target: Option<u32>,
    /// The pilot's effect (A − B) seen at this level, DV units.
    pub pilot_effect: Option<f64>,
    /// The power curve.
    pub power: Vec<PowerPoint>,
    /// Why the power analysis could not run on this level's study.
    pub power_error: Option<String>,
}

/// `kilotouch bench fidelity --json` (also `frontier.json` under `--out`).
#[derive(Debug, Clone, Serialize)]
pub struct FidelityReport {
    /// Protocol name.
    pub protocol: String,
    /// Participants per level.
    pub participants: u32,
    /// Test trials per condition and participant.
    pub test_trials_per_condition: usize,
    /// The study seed.
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
    /// 1-minute load average at the end (Linux).
    pub load_average: Option<f64>,
    /// The bound, pooled SE.
    pub bound_se: f64,
    /// The power question.
    pub question: PowerQuestion,
    /// The levels, full first.
    pub levels: Vec<LevelReport>,
    /// The folder of everything.
    pub out: PathBuf,
    /// The frontier plot (PNG; an SVG beside it).
    pub plot: PathBuf,
}

/// One simulated study and its cost.
#[derive(Debug, Clone)]
pub struct LevelRun {
    /// The study folder.
    pub folder: PathBuf,
    /// Trials simulated.
    pub trials: usize,
    /// Process CPU time, s.
    pub cpu_s: f64,
    /// Wall time, s.
    pub wall_s: f64,
}

/// Simulate `protocol` at `fidelity` into `folder` (no raw files), timing
/// its process CPU time. Used by `bench fidelity` and by `study power
/// --simulate`.
///
/// # Errors
/// The simulation's errors, naming the folder.
pub fn simulate_level(
    protocol: &Protocol,
    fidelity: Fidelity,
    folder: &Path,
    threads: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> anyhow::Result<LevelRun> {
    let opts = SimulateOptions {
        runner: RunnerConfig {
            raw: None,
            ..RunnerConfig::default()
        },
        threads: threads.max(1),
        fidelity,
        ..SimulateOptions::new(protocol.clone(), folder)
    };
    let cpu0 = process_cpu_ns();
    let t0 = Instant::now();
    let report = simulate(&opts, progress).with_context(|| {
        format!(
            "study simulate --fidelity {fidelity} into {}",
            folder.display()
        )
    })?;
    let wall_s = t0.elapsed().as_secs_f64();
    let cpu_s = match (cpu0, process_cpu_ns()) {
        (Some(a), Some(b)) => b.saturating_sub(a) as f64 * 1e-9,
        // No process clock: wall time times threads is an upper bound.
        _ => wall_s * opts.threads as f64,
    };
    Ok(LevelRun {
        folder: folder.to_path_buf(),
        trials: report.ran,
        cpu_s,
        wall_s,
    })
}

/// The power question's options, checked against the pilot's conditions.
fn power_options(
    q: &PowerQuestion,
    available: &[String],
    threads: usize,
) -> anyhow::Result<PowerOptions> {
    let (a, b) = parse_contrast(&q.contrast, available)?;
    let mut o = PowerOptions::new(&q.dv, PowerTest::Contrast { a, b }, q.n.clone());
    o.replications = q.replications;
    o.target = q.target;
    o.alpha = q.alpha;
    o.seed = q.seed;
    o.threads = threads;
    Ok(o)
}

/// The power analysis of `q` with the study in `folder` as the pilot.
///
/// # Errors
/// Reading the pilot, an option the pilot cannot serve, a pilot too small
/// to fit.
pub fn power_of(folder: &Path, q: &PowerQuestion, threads: usize) -> anyhow::Result<PowerReport> {
    let table = read_pilot(folder, &q.dv, "condition", "participant")?;
    let opts = power_options(q, &conditions_of(&table), threads)?;
    power(&table, &opts, &|_, _| true)
        .with_context(|| format!("study power on {}", folder.display()))
}

/// Test trials per condition and participant (the largest over
/// conditions; rounded up) in `rows` of `participants` participants.
fn test_trials_per_condition(rows: &[TrialRow], participants: u32) -> usize {
    let per_condition = Condition::ALL
        .iter()
        .map(|&c| {
            rows.iter()
                .filter(|r| r.condition == c && r.phase == Phase::Test)
                .count()
        })
        .max()
        .unwrap_or(0);
    per_condition.div_ceil(participants.max(1) as usize)
}

/// Run the benchmark.
///
/// # Errors
/// Bad arguments, an existing study folder under `--out`, simulation and
/// file errors.
pub fn run(a: &FidelityArgs) -> anyhow::Result<()> {
    let report = frontier(a)?;
    emit(a.json, &report, || human(&report))
}

/// Runs every level and builds the report (module docs).
///
/// # Errors
/// As [`run`].
pub fn frontier(a: &FidelityArgs) -> anyhow::Result<FidelityReport> {
    if !(1..=MAX_PARTICIPANTS).contains(&a.participants) {
        anyhow::bail!(
            "--participants must be 1 ..= {MAX_PARTICIPANTS}, got {}",
            a.participants
        );
    }
    let threads = match a.threads {
        Some(0) => anyhow::bail!("--threads must be at least 1"),
        Some(t) => t,
        None => std::thread::available_parallelism().map_or(1, usize::from),
    };
    let question = PowerQuestion {
        dv: a.dv.clone(),
        contrast: a.contrast.clone(),
        n: parse_sample_sizes(&a.n)?,
        replications: a.replications,
        target: a.target,
        alpha: 0.05,
        seed: a.seed,
    };
    let mut protocol = super::protocol_arg::load_protocol(&a.protocol)?;
    protocol.participants = a.participants;
    protocol.seeds.study = a.seed;
    protocol
        .validate()
        .map_err(|e| anyhow::anyhow!("invalid protocol after the command-line overrides: {e}"))?;
    let out = a.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!(
            "kilotouch-bench-fidelity-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs())
        ))
    });
    for f in LEVELS {
        let d = out.join(f.name());
        if d.exists() {
            anyhow::bail!("{} exists: give --out an empty or new folder", d.display());
        }
    }
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;

    let mut bar = Progress::stages();
    let mut runs = Vec::new();
    for (k, f) in LEVELS.into_iter().enumerate() {
        let mut tick = |done: usize, total: usize| {
            let within = if total == 0 {
                1.0
            } else {
                done as f64 / total as f64
            };
            bar.fraction(
                (k as f64 + within) / LEVELS.len() as f64,
                &format!("{f}: {done}/{total} trials"),
            );
        };
        runs.push(simulate_level(
            &protocol,
            f,
            &out.join(f.name()),
            threads,
            &mut tick,
        )?);
    }
    drop(bar);

    let rows: Vec<Vec<TrialRow>> = runs
        .iter()
        .map(|r| {
            read_trials(&r.folder.join(TRIALS_FILE))
                .map(|t| t.rows)
                .with_context(|| format!("reading {}", r.folder.join(TRIALS_FILE).display()))
        })
        .collect::<anyhow::Result<_>>()?;
    let full_cpu = runs[0].cpu_s;
    let participants = f64::from(a.participants);
    let levels = LEVELS
        .into_iter()
        .zip(&runs)
        .zip(&rows)
        .map(|((f, run), level_rows)| {
            let differences = agreement(level_rows, &rows[0], &Compared::CIRCLING, BOUND_SE);
            let max_abs_z = differences.iter().map(|d| d.z.abs()).fold(0.0, f64::max);
            let (n_for_target, pilot_effect, power, power_error) =
                match power_of(&run.folder, &question, threads) {
                    Ok(p) => (
                        p.n_for_target,
                        Some(p.pilot_effect.estimate),
                        p.points,
                        None,
                    ),
                    Err(e) => (None, None, Vec::new(), Some(format!("{e:#}"))),
                };
            LevelReport {
                fidelity: f,
                folder: run.folder.clone(),
                trials: run.trials,
                cpu_s: run.cpu_s,
                wall_s: run.wall_s,
                cpu_ms_per_trial: run.cpu_s * 1e3 / run.trials.max(1) as f64,
                cpu_s_per_participant: run.cpu_s / participants,
                speedup_vs_full: full_cpu / run.cpu_s.max(f64::MIN_POSITIVE),
                within_bound: differences.iter().all(|d| d.agrees),
                differences,
                max_abs_z,
                n_for_target,
                pilot_effect,
                power,
                power_error,
            }
        })
        .collect();
    let plot = out.join("frontier.png");
    let report = FidelityReport {
        protocol: protocol.name.clone(),
        participants: a.participants,
        test_trials_per_condition: test_trials_per_condition(&rows[0], a.participants),
        seed: a.seed,
        threads,
        load_average: load_average(),
        bound_se: BOUND_SE,
        question,
        levels,
        out: out.clone(),
        plot: plot.clone(),
    };
    crate::fidelity_plot::save(&report, &plot, &out.join("frontier.svg"))
        .map_err(|e| anyhow::anyhow!("the frontier plot: {e}"))?;
    if let Some(figure) = &a.figure {
        std::fs::copy(&plot, figure)
            .with_context(|| format!("--figure: copying the frontier to {}", figure.display()))?;
    }
    let json = serde_json::to_string_pretty(&report)?;
    std::fs::write(out.join("frontier.json"), json + "\n")
        .with_context(|| format!("writing {}", out.join("frontier.json").display()))?;
    Ok(report)
}

/// `n` or "not reached".
fn n_text(n: Option<u32>, l: &LevelReport) -> String {
    match (n, &l.power_error) {
        (Some(n), _) => n.to_string(),
        (None, Some(_)) => "error".into(),
        (None, None) => format!("> {}", l.power.last().map_or(0, |p| p.n)),
    }
}

/// The readable report.
pub fn human(r: &FidelityReport) -> String {
    let q = &r.question;
    let mut s = format!(
        "fidelity frontier: `{}` protocol, {} participant(s) × {} test trials per condition, seed {}, {} thread(s)\n\n",
        r.protocol, r.participants, r.test_trials_per_condition, r.seed, r.threads
    );
    s += &format!(
        "level   CPU/trial   CPU/participant   speed-up   max |Δ|/SE   n for power ≥ {} ({}, {})\n",
        q.target, q.dv, q.contrast
    );
    for l in &r.levels {
        s += &format!(
            "{:<7} {:>7.1} ms   {:>11.2} s   {:>7.2}×   {:>10.2}   {}\n",
            l.fidelity.name(),
            l.cpu_ms_per_trial,
            l.cpu_s_per_participant,
            l.speedup_vs_full,
            l.max_abs_z,
            n_text(l.n_for_target, l)
        );
    }
    s += "\ndifference from full: (level − full) / pooled SE of the test-trial means\n";
    s += "level  cond  ";
    let metrics: Vec<&str> = Compared::CIRCLING.iter().map(|c| c.name()).collect();
    for m in &metrics {
        s += &format!("{m:>18}");
    }
    s += "\n";
    for l in r.levels.iter().skip(1) {
        for c in Condition::ALL {
            s += &format!("{:<6} {:<4}", l.fidelity.name(), c.code());
            for m in &metrics {
                match l
                    .differences
                    .iter()
                    .find(|d| d.condition == c && d.metric == *m)
                {
                    Some(d) => s += &format!("{:>+18.2}", d.z),
                    None => s += &format!("{:>18}", "–"),
                }
            }
            s += "\n";
        }
    }
    for l in &r.levels {
        if let Some(e) = &l.power_error {
            s += &format!(
                "\n{}: the power analysis did not run: {e}",
                l.fidelity.name()
            );
        }
    }
    let outside: Vec<&str> = r
        .levels
        .iter()
        .filter(|l| !l.within_bound)
        .map(|l| l.fidelity.name())
        .collect();
    s += &if outside.is_empty() {
        format!(
            "\nevery level within {} pooled SE of full on every metric\n",
            r.bound_se
        )
    } else {
        format!(
            "\noutside {} pooled SE of full: {} (see the table)\n",
            r.bound_se,
            outside.join(", ")
        )
    };
    s += &format!(
        "studies, frontier.png/.svg and frontier.json in {}\n",
        r.out.display()
    );
    s
}
