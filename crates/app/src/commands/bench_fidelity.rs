//! `kilotouch bench fidelity`: the simulation's fidelity levels as a
//! frontier of speed against error. The measurement is
//! [`kilotouch_study::frontier`]; this file parses the arguments, shows
//! progress, prints the table or the JSON and writes the plot
//! ([`crate::fidelity_plot`]) and `frontier.json` under `--out`.

use std::path::PathBuf;

use anyhow::Context;
use kilotouch_study::fidelity::Fidelity;
use kilotouch_study::frontier::{FidelityReport, LEVELS, LevelReport, PowerQuestion, measure};
use kilotouch_study::power::parse_sample_sizes;
use kilotouch_study::protocol::Condition;
use kilotouch_study::stats::agreement::Compared;

use super::progress::Progress;
use crate::output::emit;

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

/// Run the benchmark.
///
/// # Errors
/// Bad arguments, an existing study folder under `--out`, simulation and
/// file errors.
pub fn run(a: &FidelityArgs) -> anyhow::Result<()> {
    let report = frontier(a)?;
    emit(a.json, &report, || human(&report))
}

/// Runs every level, draws the frontier and writes the JSON.
///
/// # Errors
/// As [`run`].
pub fn frontier(a: &FidelityArgs) -> anyhow::Result<FidelityReport> {
    let threads = super::protocol_arg::threads(a.threads)?;
    let question = PowerQuestion {
        dv: a.dv.clone(),
        contrast: a.contrast.clone(),
        n: parse_sample_sizes(&a.n)?,
        replications: a.replications,
        target: a.target,
        alpha: 0.05,
        seed: a.seed,
    };
    let protocol =
        super::protocol_arg::load_protocol_with(&a.protocol, Some(a.participants), Some(a.seed))?;
    let out = a.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!(
            "kilotouch-bench-fidelity-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs())
        ))
    });
    let mut bar = Progress::stages();
    let mut tick = |f: Fidelity, done: usize, total: usize| {
        let k = LEVELS.iter().position(|&l| l == f).unwrap_or(0);
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
    let report = measure(&protocol, &question, &out, threads, &mut tick)?;
    drop(bar);
    crate::fidelity_plot::save(&report, &report.plot, &report.plot.with_extension("svg"))
        .map_err(|e| anyhow::anyhow!("the frontier plot: {e}"))?;
    if let Some(figure) = &a.figure {
        std::fs::copy(&report.plot, figure)
            .with_context(|| format!("--figure: copying the frontier to {}", figure.display()))?;
    }
    let json_path = out.join("frontier.json");
    let json = serde_json::to_string_pretty(&report)?;
    std::fs::write(&json_path, json + "\n")
        .with_context(|| format!("writing {}", json_path.display()))?;
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
