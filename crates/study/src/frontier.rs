//! The simulation's fidelity levels as a frontier of speed against error
//! (`kilotouch bench fidelity`).
//!
//! The same cohort (one protocol, one study seed) is simulated at each
//! level of [`Fidelity`] — `full` (the reference), `scene` and `draft` — one
//! level after the other. For each level [`measure`] gives:
//!
//! * the process's CPU time ([`process_cpu_ns`], all worker threads
//!   together, so the figure does not depend on the thread count) per trial
//!   (practice and test) and per participant, and the speed ratio to
//!   `full` (full's CPU time over the level's);
//! * per condition and metric (success, time, optical force, displacement
//!   error, contact fraction), the difference of the level's test-trial mean
//!   from full's in pooled standard errors ([`crate::stats::agreement`]),
//!   and the largest |difference|;
//! * the answer a power analysis gives when the level's study is the pilot
//!   ([`crate::power`] on its `trials.csv`: a paired contrast of one
//!   dependent variable, the smallest n reaching the target power).
//!
//! [`simulate_level`] is also how `study power --simulate` simulates its
//! pilots.

use std::path::{Path, PathBuf};
use std::time::Instant;

use kilotouch_rig::realtime::{load_average, process_cpu_ns};
use serde::Serialize;
use thiserror::Error;

use crate::error::RunError;
use crate::export::{ExportError, TRIALS_FILE, TrialRow, read_trials};
use crate::fidelity::Fidelity;
use crate::power::{
    PowerError, PowerOptions, PowerPoint, PowerReport, PowerTest, conditions_of, parse_contrast,
    power, read_pilot,
};
use crate::protocol::{Condition, Protocol};
use crate::runner::RunnerConfig;
use crate::seeds::Phase;
use crate::simulate::{SimulateOptions, simulate};
use crate::stats::agreement::{Agreement, Compared, agreement};

/// The levels in the order they run and are reported: the reference first.
pub const LEVELS: [Fidelity; 3] = [Fidelity::Full, Fidelity::Scene, Fidelity::Draft];

/// The bound of the frontier plot and of `within_bound`, pooled SE: a
/// level's metric further than this from full's differs beyond sampling
/// error (two-sided 0.27 % per comparison for normal means).
pub const BOUND_SE: f64 = 3.0;

/// Largest number of participants per level (each runs three times).
pub const MAX_PARTICIPANTS: u32 = 256;

/// The frontier plot's file name under the output folder (PNG; an SVG of
/// the same stem beside it).
pub const FRONTIER_PNG: &str = "frontier.png";

/// Errors of [`measure`] and [`simulate_level`].
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum FrontierError {
    /// A setting out of range.
    #[error("{0}")]
    Invalid(String),
    /// A level's study folder exists already (nothing is overwritten).
    #[error("{} exists: give --out an empty or new folder", .0.display())]
    Exists(PathBuf),
    /// A level's simulation failed.
    #[error("study simulate --fidelity {fidelity} into {}: {source}", folder.display())]
    Simulate {
        /// The level.
        fidelity: Fidelity,
        /// Its folder.
        folder: PathBuf,
        /// Why.
        #[source]
        source: Box<RunError>,
    },
    /// A level's `trials.csv` could not be read back.
    #[error("reading the trials of {}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: Box<ExportError>,
    },
    /// The power question does not fit the protocol (e.g. a contrast of a
    /// condition the protocol lacks).
    #[error(transparent)]
    Power(#[from] PowerError),
    /// Creating the output folder.
    #[error("creating {}: {source}", path.display())]
    Io {
        /// The folder.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
}

/// The power question every level answers (the options of `study power`).
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

/// The frontier (`kilotouch bench fidelity --json`, `frontier.json`).
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
/// its process CPU time. Used by [`measure`] and by `study power
/// --simulate`.
///
/// # Errors
/// The simulation's errors, naming the level and the folder.
pub fn simulate_level(
    protocol: &Protocol,
    fidelity: Fidelity,
    folder: &Path,
    threads: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<LevelRun, FrontierError> {
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
    let report = simulate(&opts, progress).map_err(|e| FrontierError::Simulate {
        fidelity,
        folder: folder.to_path_buf(),
        source: Box::new(e),
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
) -> Result<PowerOptions, PowerError> {
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
pub fn power_of(
    folder: &Path,
    q: &PowerQuestion,
    threads: usize,
) -> Result<PowerReport, PowerError> {
    let table = read_pilot(folder, &q.dv, "condition", "participant")?;
    let opts = power_options(q, &conditions_of(&table), threads)?;
    power(&table, &opts, &|_, _| true)
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

/// Run every level of [`LEVELS`] of `protocol` (participants and study
/// seed set) into `out/<level>` and build the report (module docs).
/// `progress(level, done, total)` is called after each trial.
///
/// # Errors
/// An existing level folder, a power question the protocol cannot serve,
/// simulation and file errors.
pub fn measure(
    protocol: &Protocol,
    question: &PowerQuestion,
    out: &Path,
    threads: usize,
    progress: &mut dyn FnMut(Fidelity, usize, usize),
) -> Result<FidelityReport, FrontierError> {
    if !(1..=MAX_PARTICIPANTS).contains(&protocol.participants) {
        return Err(FrontierError::Invalid(format!(
            "--participants must be 1 ..= {MAX_PARTICIPANTS}, got {}",
            protocol.participants
        )));
    }
    // The question must fit the protocol's conditions before anything runs.
    let codes: Vec<String> = protocol
        .conditions
        .iter()
        .map(|c| c.code().to_owned())
        .collect();
    parse_contrast(&question.contrast, &codes)?;
    for f in LEVELS {
        let d = out.join(f.name());
        if d.exists() {
            return Err(FrontierError::Exists(d));
        }
    }
    std::fs::create_dir_all(out).map_err(|source| FrontierError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let mut runs = Vec::new();
    for f in LEVELS {
        let folder = out.join(f.name());
        runs.push(simulate_level(
            protocol,
            f,
            &folder,
            threads,
            &mut |d, t| {
                progress(f, d, t);
            },
        )?);
    }
    let rows: Vec<Vec<TrialRow>> = runs
        .iter()
        .map(|r| {
            let path = r.folder.join(TRIALS_FILE);
            read_trials(&path)
                .map(|t| t.rows)
                .map_err(|e| FrontierError::Read {
                    path,
                    source: Box::new(e),
                })
        })
        .collect::<Result<_, _>>()?;
    let levels = LEVELS
        .into_iter()
        .zip(&runs)
        .zip(&rows)
        .map(|((f, run), level_rows)| {
            level_report(
                f,
                run,
                level_rows,
                &rows[0],
                runs[0].cpu_s,
                protocol.participants,
                question,
                threads,
            )
        })
        .collect();
    Ok(FidelityReport {
        protocol: protocol.name.clone(),
        participants: protocol.participants,
        test_trials_per_condition: test_trials_per_condition(&rows[0], protocol.participants),
        seed: protocol.seeds.study,
        threads,
        load_average: load_average(),
        bound_se: BOUND_SE,
        question: question.clone(),
        levels,
        out: out.to_path_buf(),
        plot: out.join(FRONTIER_PNG),
    })
}

/// One level's row of the report: its cost, its differences from full's
/// rows and its power answer.
#[allow(clippy::too_many_arguments)]
fn level_report(
    fidelity: Fidelity,
    run: &LevelRun,
    rows: &[TrialRow],
    full_rows: &[TrialRow],
    full_cpu_s: f64,
    participants: u32,
    question: &PowerQuestion,
    threads: usize,
) -> LevelReport {
    let differences = agreement(rows, full_rows, &Compared::CIRCLING, BOUND_SE);
    let max_abs_z = differences.iter().map(|d| d.z.abs()).fold(0.0, f64::max);
    let (n_for_target, pilot_effect, power, power_error) =
        match power_of(&run.folder, question, threads) {
            Ok(p) => (
                p.n_for_target,
                Some(p.pilot_effect.estimate),
                p.points,
                None,
            ),
            Err(e) => (None, None, Vec::new(), Some(e.to_string())),
        };
    LevelReport {
        fidelity,
        folder: run.folder.clone(),
        trials: run.trials,
        cpu_s: run.cpu_s,
        wall_s: run.wall_s,
        cpu_ms_per_trial: run.cpu_s * 1e3 / run.trials.max(1) as f64,
        cpu_s_per_participant: run.cpu_s / f64::from(participants.max(1)),
        speedup_vs_full: full_cpu_s / run.cpu_s.max(f64::MIN_POSITIVE),
        within_bound: differences.iter().all(|d| d.agrees),
        differences,
        max_abs_z,
        n_for_target,
        pilot_effect,
        power,
        power_error,
    }
}
