//! `kilotouch study power`: how many participants a planned study needs,
//! simulated from a pilot (a real pilot's folder or `trials.csv`, or a
//! simulated population from `study simulate`). The numerics are
//! `kilotouch_study::power`; this file parses the arguments, shows progress
//! and prints the table, the JSON or the plot.
//!
//! With `--simulate N` the pilot is simulated here: N participants of
//! `--protocol` at `--fidelity` (default `draft`, the fastest level; see
//! `kilotouch bench fidelity` for what each level costs and changes). When
//! the search ran below `scene`, the same cohort is simulated again at
//! `scene` and the whole curve recomputed from it (the power simulation is
//! cheap next to the pilot's): the final check of the chosen n, reported
//! side by side with the search.

use std::path::PathBuf;

use anyhow::Context;
use kilotouch_study::fidelity::Fidelity;
use kilotouch_study::frontier::simulate_level;
use kilotouch_study::power::{
    EffectSpec, PowerOptions, PowerReport, PowerTest, conditions_of, parse_contrast,
    parse_sample_sizes, power, read_pilot,
};
use serde::Serialize;

use super::progress::Progress;
use crate::output::emit;

/// Largest simulated pilot, participants.
pub const MAX_SIMULATED_PILOT: u32 = 256;

/// Arguments of `kilotouch study power`.
#[derive(Debug, clap::Args)]
pub struct PowerArgs {
    /// The pilot: a study folder (its trials.csv) or a long-format CSV.
    #[arg(
        long,
        required_unless_present = "simulate",
        conflicts_with = "simulate"
    )]
    pub pilot: Option<PathBuf>,
    /// Simulate the pilot instead: this many participants of `--protocol`
    /// (study seed `--pilot-seed`) at `--fidelity`, with a final check at
    /// `scene` fidelity when the search ran at `draft`.
    #[arg(long, value_name = "PARTICIPANTS")]
    pub simulate: Option<u32>,
    /// `--simulate`: the protocol (a TOML file or `paper`, `blind`).
    #[arg(long, default_value = "paper", requires = "simulate")]
    pub protocol: String,
    /// `--simulate`: the pilot's study seed (default: `--seed`).
    #[arg(long, requires = "simulate")]
    pub pilot_seed: Option<u64>,
    /// `--simulate`: fidelity of the search's pilot (`draft`, `scene`,
    /// `full`).
    #[arg(long, default_value = "draft", requires = "simulate")]
    pub fidelity: Fidelity,
    /// `--simulate`: keep the simulated pilot folders here (default: a
    /// temporary folder, removed at the end).
    #[arg(long, requires = "simulate")]
    pub pilot_out: Option<PathBuf>,
    /// Dependent variable column (e.g. disp_err_mean_um, time_s, success).
    #[arg(long)]
    pub dv: String,
    /// Condition column.
    #[arg(long, default_value = "condition")]
    pub within: String,
    /// Participant column.
    #[arg(long, default_value = "participant")]
    pub subject: String,
    /// Paired t-test of two conditions, e.g. `P-D`.
    #[arg(long, conflicts_with = "test", required_unless_present = "test")]
    pub contrast: Option<String>,
    /// Omnibus test over every condition: `rm` (repeated-measures ANOVA,
    /// Greenhouse–Geisser corrected).
    #[arg(long, value_parser = ["rm"])]
    pub test: Option<String>,
    /// Numbers of participants to try: a comma list and/or ranges
    /// `FROM:TO:STEP`, e.g. `4,8,12,16` or `4:40:4`.
    #[arg(long, required = true)]
    pub n: String,
    /// Test trials per condition (default: the pilot's).
    #[arg(long)]
    pub trials_per_condition: Option<u32>,
    /// Assumed effect in DV units: the A−B difference (contrast) or the
    /// range of the condition means (rm). 0 = no effect (checks α).
    #[arg(long, allow_hyphen_values = true, conflicts_with = "effect_scale")]
    pub effect: Option<f64>,
    /// Multiply the pilot's effect by this factor.
    #[arg(long)]
    pub effect_scale: Option<f64>,
    /// Significance level.
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
    /// Power wanted.
    #[arg(long, default_value_t = 0.8)]
    pub target: f64,
    /// Simulated studies per number of participants.
    #[arg(long)]
    pub replications: u32,
    /// Seed of the simulation (results depend only on it, not on --threads).
    #[arg(long)]
    pub seed: u64,
    /// Worker threads (default: available cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Write the power curve to this PNG or SVG file.
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

/// The options of the study crate from the command line, given the pilot's
/// condition labels.
fn options(a: &PowerArgs, available: &[String]) -> anyhow::Result<PowerOptions> {
    let test = match (&a.contrast, &a.test) {
        (Some(c), _) => {
            let (x, y) = parse_contrast(c, available)?;
            PowerTest::Contrast { a: x, b: y }
        }
        (None, _) => PowerTest::Rm,
    };
    let threads = super::protocol_arg::threads(a.threads)?;
    let mut o = PowerOptions::new(&a.dv, test, parse_sample_sizes(&a.n)?);
    o.within.clone_from(&a.within);
    o.subject.clone_from(&a.subject);
    o.trials = a.trials_per_condition;
    o.effect = match (a.effect, a.effect_scale) {
        (Some(x), _) => EffectSpec::Absolute(x),
        (None, Some(s)) => EffectSpec::Scale(s),
        (None, None) => EffectSpec::Pilot,
    };
    o.alpha = a.alpha;
    o.target = a.target;
    o.replications = a.replications;
    o.seed = a.seed;
    o.threads = threads;
    Ok(o)
}

/// The readable table.
pub fn human(r: &PowerReport) -> String {
    let m = &r.model;
    let mut s = String::new();
    let what = match r.test {
        "paired_t" => format!("paired t-test of {} − {}", m.conditions[0], m.conditions[1]),
        _ => format!(
            "repeated-measures ANOVA (Greenhouse–Geisser) over {}",
            m.conditions.join(", ")
        ),
    };
    s += &format!("power of the {what} on `{}` (α = {})\n", m.dv, r.alpha);
    s += &format!(
        "pilot: {} ({} complete participants{}), {} test trials per condition simulated\n",
        r.pilot,
        m.participants,
        if m.dropped.is_empty() {
            String::new()
        } else {
            format!(", {} dropped for a missing cell", m.dropped.len())
        },
        r.trials_per_condition
    );
    s += &format!(
        "assumed effect {:.4} ({}); SD of the participants' differences: pilot {:.4}, model {:.4}\n",
        r.effect,
        if r.test == "paired_t" {
            "difference of means"
        } else {
            "range of the condition means"
        },
        r.sd_diff,
        r.sd_diff_model
    );
    let succ: Vec<String> = m
        .conditions
        .iter()
        .zip(&m.success)
        .map(|(c, p)| format!("{c} {:.2} (ICC {:.2})", p.p, p.icc))
        .collect();
    s += &format!("success rates: {}\n", succ.join(", "));
    s += &r.pilot_warning();
    s += "\n\n   n    power   95 % CI            dropped/study\n";
    for p in &r.points {
        s += &format!(
            "{:>4}   {:>6.3}   [{:.3}, {:.3}]     {:>5.2}\n",
            p.n, p.power, p.ci[0], p.ci[1], p.mean_dropped
        );
    }
    s += &match r.n_for_target {
        Some(n) => format!(
            "\nn for power ≥ {}: {n} participants ({} simulated studies per n, seed {})\n",
            r.target, r.replications, r.seed
        ),
        None => format!(
            "\npower {} is not reached at any n tried (largest {}); try larger n or more trials\n",
            r.target,
            r.points.last().map_or(0, |p| p.n)
        ),
    };
    s
}

/// A simulated pilot: where, at which fidelity, at what cost.
#[derive(Debug, Clone, Serialize)]
pub struct SimulatedPilot {
    /// Participants.
    pub participants: u32,
    /// Protocol name.
    pub protocol: String,
    /// Study seed.
    pub seed: u64,
    /// Fidelity it ran at.
    pub fidelity: Fidelity,
    /// Its study folder (removed at the end unless `--pilot-out`).
    pub folder: PathBuf,
    /// Process CPU time of the simulation, s.
    pub cpu_s: f64,
}

/// The final check of a search at a lower fidelity: the same cohort at
/// `scene`, the same power question.
#[derive(Debug, Clone, Serialize)]
pub struct FinalCheck {
    /// The pilot of the check.
    pub pilot: SimulatedPilot,
    /// The search's chosen n (`None`: the search reached no n).
    pub n_checked: Option<u32>,
    /// Power at that n with the check's pilot.
    pub power_at_n: Option<f64>,
    /// Its Clopper–Pearson 95 % interval.
    pub ci_at_n: Option<[f64; 2]>,
    /// The search's n reaches the target with the check's pilot too (and
    /// both found one).
    pub confirmed: bool,
    /// The check's whole report (its pilot effect `report.effect`, its own
    /// smallest n `report.n_for_target`).
    pub report: PowerReport,
}

/// `kilotouch study power --json`: the report, and with `--simulate` the
/// pilot and the final check.
#[derive(Serialize)]
struct PowerOutput<'a> {
    #[serde(flatten)]
    report: &'a PowerReport,
    #[serde(skip_serializing_if = "Option::is_none")]
    simulated_pilot: Option<&'a SimulatedPilot>,
    #[serde(skip_serializing_if = "Option::is_none")]
    final_check: Option<&'a FinalCheck>,
}

/// The power analysis of `table` with a progress bar.
fn analyse(
    table: &kilotouch_study::power::PilotTable,
    a: &PowerArgs,
    what: &'static str,
) -> anyhow::Result<PowerReport> {
    let opts = options(a, &conditions_of(table))?;
    let bar = std::sync::Mutex::new(Progress::new(what));
    power(table, &opts, &|done, total| {
        if let Ok(mut b) = bar.lock() {
            b.count(done, total);
        }
        true
    })
    .with_context(|| format!("study power from {}", table.path.display()))
}

/// Simulate the pilot of `--simulate` at `fidelity` into `root`.
fn simulate_pilot(
    a: &PowerArgs,
    participants: u32,
    fidelity: Fidelity,
    root: &std::path::Path,
) -> anyhow::Result<SimulatedPilot> {
    if !(2..=MAX_SIMULATED_PILOT).contains(&participants) {
        anyhow::bail!(
            "--simulate must be 2 ..= {MAX_SIMULATED_PILOT} participants (a power analysis needs \
             at least two to see how participants vary), got {participants}"
        );
    }
    let protocol = super::protocol_arg::load_protocol_with(
        &a.protocol,
        Some(participants),
        Some(a.pilot_seed.unwrap_or(a.seed)),
    )?;
    let folder = root.join(format!("pilot-{fidelity}"));
    if folder.exists() {
        anyhow::bail!(
            "{} exists: give --pilot-out an empty or new folder",
            folder.display()
        );
    }
    let threads = super::protocol_arg::threads(a.threads)?;
    eprintln!(
        "kilotouch: simulating a {participants}-participant pilot of `{}` at {fidelity} fidelity",
        protocol.name
    );
    let mut bar = Progress::new("pilot trials");
    let run = simulate_level(&protocol, fidelity, &folder, threads, &mut |d, t| {
        bar.count(d, t)
    })?;
    Ok(SimulatedPilot {
        participants,
        protocol: protocol.name.clone(),
        seed: protocol.seeds.study,
        fidelity,
        folder,
        cpu_s: run.cpu_s,
    })
}

/// The search and the check side by side.
fn human_check(search: &PowerReport, pilot: &SimulatedPilot, c: &FinalCheck) -> String {
    let (fs, fc) = (pilot.fidelity.name(), c.pilot.fidelity.name());
    let mut s = format!(
        "\nfinal check: the same cohort at {fc} fidelity (pilot CPU {:.1} s at {fs}, {:.1} s at {fc})\n",
        pilot.cpu_s, c.pilot.cpu_s
    );
    s += &format!(
        "pilot effect: {:.4} at {fs}, {:.4} at {fc}\n\n",
        search.effect, c.report.effect
    );
    s += &format!("   n   power at {fs:<6} 95 % CI          power at {fc:<6} 95 % CI\n");
    for (p, q) in search.points.iter().zip(&c.report.points) {
        s += &format!(
            "{:>4}   {:>12.3}   [{:.3}, {:.3}]   {:>12.3}   [{:.3}, {:.3}]\n",
            p.n, p.power, p.ci[0], p.ci[1], q.power, q.ci[0], q.ci[1]
        );
    }
    let n = |n: Option<u32>| n.map_or_else(|| "not reached".to_owned(), |n| n.to_string());
    s += &format!(
        "\nn for power ≥ {}: {} at {fs}, {} at {fc}; ",
        search.target,
        n(search.n_for_target),
        n(c.report.n_for_target)
    );
    s += &match (c.n_checked, c.power_at_n) {
        (Some(k), Some(p)) if c.confirmed => {
            format!("the search's n = {k} is confirmed at {fc} (power {p:.3})\n")
        }
        (Some(k), Some(p)) => format!(
            "the search's n = {k} is NOT confirmed at {fc} (power {p:.3}): plan with {fc}'s answer\n"
        ),
        _ => match c.report.n_for_target {
            Some(k) => format!(
                "the answer changed: {fs} reaches the target at no n tried, {fc} at n = {k}; \
                 {fs} cannot answer this question, plan with {fc}'s answer\n"
            ),
            None => format!("neither {fs} nor {fc} reaches the target at any n tried\n"),
        },
    };
    s
}

/// Run the command.
pub fn run(a: &PowerArgs) -> anyhow::Result<()> {
    let (report, pilot, check) = match (a.simulate, &a.pilot) {
        (Some(n), _) => {
            let (root, temporary) = match &a.pilot_out {
                Some(p) => (p.clone(), false),
                None => (
                    std::env::temp_dir().join(format!(
                        "kilotouch-power-pilot-{}-{}",
                        std::process::id(),
                        std::time::SystemTime::now()
                            .duration_since(std::time::UNIX_EPOCH)
                            .map_or(0, |d| d.as_nanos())
                    )),
                    true,
                ),
            };
            let result = run_simulated(a, n, &root);
            if temporary {
                let _ = std::fs::remove_dir_all(&root);
            }
            let (r, p, c) = result?;
            (r, Some(p), c)
        }
        (None, Some(path)) => {
            let table = read_pilot(path, &a.dv, &a.within, &a.subject)?;
            (analyse(&table, a, "simulated studies")?, None, None)
        }
        (None, None) => anyhow::bail!("give --pilot DIR|FILE or --simulate PARTICIPANTS"),
    };
    if let Some(path) = &a.plot {
        crate::power_plot::save(
            &report,
            check.as_ref().map(|c| (c.pilot.fidelity, &c.report)),
            path,
        )
        .map_err(|e| anyhow::anyhow!("--plot {}: {e}", path.display()))?;
    }
    if a.json {
        eprintln!("{}", report.pilot_warning());
    }
    let out = PowerOutput {
        report: &report,
        simulated_pilot: pilot.as_ref(),
        final_check: check.as_ref(),
    };
    emit(a.json, &out, || {
        let mut s = human(&report);
        if let (Some(p), Some(c)) = (&pilot, &check) {
            s += &human_check(&report, p, c);
        }
        s
    })
}

/// `--simulate`: the search at `--fidelity`, then the check at `scene`
/// when the search ran at `draft`.
fn run_simulated(
    a: &PowerArgs,
    participants: u32,
    root: &std::path::Path,
) -> anyhow::Result<(PowerReport, SimulatedPilot, Option<FinalCheck>)> {
    let search_pilot = simulate_pilot(a, participants, a.fidelity, root)?;
    let table = read_pilot(&search_pilot.folder, &a.dv, &a.within, &a.subject)?;
    let search = analyse(&table, a, "simulated studies (search)")?;
    if a.fidelity != Fidelity::Draft {
        return Ok((search, search_pilot, None));
    }
    let check_pilot = simulate_pilot(a, participants, Fidelity::Scene, root)?;
    let table = read_pilot(&check_pilot.folder, &a.dv, &a.within, &a.subject)?;
    let check = analyse(&table, a, "simulated studies (check)")?;
    let at = search
        .n_for_target
        .and_then(|n| check.points.iter().find(|p| p.n == n));
    let check = FinalCheck {
        n_checked: search.n_for_target,
        power_at_n: at.map(|p| p.power),
        ci_at_n: at.map(|p| p.ci),
        confirmed: at.is_some_and(|p| p.power >= check.target),
        pilot: check_pilot,
        report: check,
    };
    Ok((search, search_pilot, Some(check)))
}
