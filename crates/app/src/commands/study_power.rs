//! `kilotouch study power`: how many participants a planned study needs,
//! simulated from a pilot (a real pilot's folder or `trials.csv`, or a
//! simulated population from `study simulate`). The numerics are
//! `kilotouch_study::power`; this file parses the arguments, shows progress
//! and prints the table, the JSON or the plot.

use std::path::PathBuf;

use anyhow::Context;
use kilotouch_study::power::{
    EffectSpec, PowerOptions, PowerReport, PowerTest, conditions_of, parse_contrast,
    parse_sample_sizes, power, read_pilot,
};

use super::progress::Progress;
use crate::output::emit;

/// Arguments of `kilotouch study power`.
#[derive(Debug, clap::Args)]
pub struct PowerArgs {
    /// The pilot: a study folder (its trials.csv) or a long-format CSV.
    #[arg(long)]
    pub pilot: PathBuf,
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
    let threads = match a.threads {
        Some(0) => anyhow::bail!("--threads must be at least 1"),
        Some(t) => t,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
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

/// Run the command.
pub fn run(a: &PowerArgs) -> anyhow::Result<()> {
    let table = read_pilot(&a.pilot, &a.dv, &a.within, &a.subject)?;
    let opts = options(a, &conditions_of(&table))?;
    let bar = std::sync::Mutex::new(Progress::new("simulated studies"));
    let report = power(&table, &opts, &|done, total| {
        if let Ok(mut b) = bar.lock() {
            b.count(done, total);
        }
        true
    })
    .with_context(|| format!("study power from {}", table.path.display()))?;
    if let Some(path) = &a.plot {
        crate::power_plot::save(&report, path)
            .map_err(|e| anyhow::anyhow!("--plot {}: {e}", path.display()))?;
    }
    if a.json {
        eprintln!("{}", report.pilot_warning());
    }
    emit(a.json, &report, || human(&report))
}
