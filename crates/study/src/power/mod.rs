//! Simulation-based power analysis from a pilot (`kilotouch study power`),
//! in the manner of R's `simr` (Green & MacLeod 2016): fit a generative
//! model to a pilot ([`model`]), simulate many studies at each candidate
//! number of participants ([`simulate`]), analyse each exactly as
//! `kilotouch stats` would, and report the fraction that reject H₀ with a
//! Clopper–Pearson interval.
//!
//! Bounds: at most [`MAX_SAMPLE_SIZES`] sample sizes, each in
//! 2..=[`MAX_N`]; 1..=[`MAX_REPLICATIONS`] replications; 1..=[`MAX_TRIALS`]
//! trials per condition.
//!
//! Equations and how to read the result: `docs/STUDY.md`, "Power analysis".

pub mod error;
pub mod model;
pub mod pilot;
pub mod simulate;

use std::path::Path;

use serde::Serialize;
use statrs::distribution::{Beta, ContinuousCDF, StudentsT};

pub use error::PowerError;
pub use model::{PilotModel, SuccessModel};
pub use pilot::{
    PilotRow, PilotRows, PilotTable, TrialCount, pilot_file, pilot_rows, read_pilot, trial_counts,
};
pub use simulate::{Analysis, Outcome, Scenario, Tally};

/// Largest number of sample sizes in one run.
pub const MAX_SAMPLE_SIZES: usize = 100;
/// Largest number of participants of a simulated study.
pub const MAX_N: u32 = 10_000;
/// Largest number of replications per sample size.
pub const MAX_REPLICATIONS: u32 = 1_000_000;
/// Largest number of trials per condition.
pub const MAX_TRIALS: u32 = 10_000;

/// The hypothesis test whose power is wanted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PowerTest {
    /// Paired t-test of condition `a` against `b` (`--contrast A-B`).
    Contrast {
        /// First condition label.
        a: String,
        /// Second condition label.
        b: String,
    },
    /// Repeated-measures ANOVA over every condition of the pilot, with the
    /// Greenhouse–Geisser correction (`--test rm`).
    Rm,
}

/// The effect the simulated studies have.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EffectSpec {
    /// The pilot's own estimate.
    Pilot,
    /// Contrast: the A − B difference of means, DV units. RM-ANOVA: the
    /// range (largest − smallest) of the condition means, the pilot's
    /// pattern scaled to it. `0` is H₀.
    Absolute(f64),
    /// The pilot's differences multiplied by this factor.
    Scale(f64),
}

/// Options of [`power`].
#[derive(Debug, Clone, PartialEq)]
pub struct PowerOptions {
    /// Dependent variable column.
    pub dv: String,
    /// Condition column.
    pub within: String,
    /// Participant column.
    pub subject: String,
    /// The test.
    pub test: PowerTest,
    /// Candidate numbers of participants.
    pub ns: Vec<u32>,
    /// Test trials per condition (`None`: the pilot's).
    pub trials: Option<u32>,
    /// Assumed effect.
    pub effect: EffectSpec,
    /// Significance level α.
    pub alpha: f64,
    /// Power wanted (for [`PowerReport::n_for_target`]).
    pub target: f64,
    /// Replications per sample size.
    pub replications: u32,
    /// Seed of the analysis.
    pub seed: u64,
    /// Worker threads (results do not depend on it).
    pub threads: usize,
}

impl PowerOptions {
    /// Options with the defaults of the CLI for `dv` and `test`.
    pub fn new(dv: &str, test: PowerTest, ns: Vec<u32>) -> Self {
        Self {
            dv: dv.to_owned(),
            within: "condition".into(),
            subject: "participant".into(),
            test,
            ns,
            trials: None,
            effect: EffectSpec::Pilot,
            alpha: 0.05,
            target: 0.8,
            replications: 1000,
            seed: 1,
            threads: 1,
        }
    }

    fn check(&self) -> Result<(), PowerError> {
        let bad = |s: String| Err(PowerError::InvalidOption(s));
        if self.ns.is_empty() || self.ns.len() > MAX_SAMPLE_SIZES {
            return bad(format!("--n: give 1 to {MAX_SAMPLE_SIZES} sample sizes"));
        }
        if let Some(n) = self.ns.iter().find(|&&n| !(2..=MAX_N).contains(&n)) {
            return bad(format!("--n {n}: each sample size must be in 2..={MAX_N}"));
        }
        if !(1..=MAX_REPLICATIONS).contains(&self.replications) {
            return bad(format!("--replications must be in 1..={MAX_REPLICATIONS}"));
        }
        if let Some(k) = self.trials
            && !(1..=MAX_TRIALS).contains(&k)
        {
            return bad(format!(
                "--trials-per-condition must be in 1..={MAX_TRIALS}"
            ));
        }
        if !(self.alpha > 0.0 && self.alpha < 1.0) {
            return bad(format!("--alpha {} must be in (0, 1)", self.alpha));
        }
        if !(self.target > 0.0 && self.target < 1.0) {
            return bad(format!("--target {} must be in (0, 1)", self.target));
        }
        match self.effect {
            EffectSpec::Absolute(x) | EffectSpec::Scale(x) if !x.is_finite() => {
                bad("--effect / --effect-scale must be finite".into())
            }
            EffectSpec::Absolute(x) if x < 0.0 && self.test == PowerTest::Rm => {
                bad("--effect for --test rm is the range of the condition means, ≥ 0".into())
            }
            _ => Ok(()),
        }
    }
}

/// Power at one number of participants.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PowerPoint {
    /// Participants per simulated study.
    pub n: u32,
    /// Fraction of replications that rejected H₀.
    pub power: f64,
    /// Clopper–Pearson 95 % interval of the power.
    pub ci: [f64; 2],
    /// Rejections.
    pub rejected: u64,
    /// Replications.
    pub replications: u64,
    /// Replications the test could analyse (the rest count as not
    /// rejecting).
    pub analysed: u64,
    /// Mean participants deleted listwise per study (a cell without a
    /// successful trial).
    pub mean_dropped: f64,
}

/// The pilot's own effect and how uncertain it is.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PilotEffect {
    /// The two conditions compared (for RM-ANOVA: the largest and the
    /// smallest mean).
    pub contrast: [String; 2],
    /// Mean of the participants' A − B cell-mean differences.
    pub estimate: f64,
    /// Its 95 % t interval.
    pub ci: [f64; 2],
    /// SD of those differences.
    pub sd_diff: f64,
    /// Complete participants.
    pub n: usize,
}

/// Result of [`power`] (the CLI's JSON).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PowerReport {
    /// The power curve.
    pub points: Vec<PowerPoint>,
    /// The effect simulated: the A − B difference (contrast) or the range
    /// of the condition means (RM-ANOVA), DV units.
    pub effect: f64,
    /// SD of the pilot's participants' A − B cell-mean differences (for
    /// RM-ANOVA: of the pair with the largest and smallest mean), DV units.
    pub sd_diff: f64,
    /// The model's SD of that difference with `trials_per_condition`
    /// successful trials in every cell.
    pub sd_diff_model: f64,
    /// The fitted model.
    pub model: PilotModel,
    /// Smallest n of the grid whose estimated power reaches the target
    /// (`None`: none does).
    pub n_for_target: Option<u32>,
    /// The pilot's effect with its confidence interval.
    pub pilot_effect: PilotEffect,
    /// `paired_t` or `rm_anova_gg`.
    pub test: &'static str,
    /// Condition means simulated.
    pub means: Vec<f64>,
    /// Test trials per condition simulated.
    pub trials_per_condition: u32,
    /// α.
    pub alpha: f64,
    /// Target power.
    pub target: f64,
    /// Replications per sample size.
    pub replications: u32,
    /// Seed.
    pub seed: u64,
    /// The pilot file.
    pub pilot: String,
}

/// Clopper–Pearson (1934) two-sided interval of level `level` for `x`
/// successes in `n` trials: the α/2 quantile of Beta(x, n − x + 1) and the
/// 1 − α/2 quantile of Beta(x + 1, n − x) (0 and 1 at the ends).
pub fn clopper_pearson(x: u64, n: u64, level: f64) -> [f64; 2] {
    if n == 0 {
        return [0.0, 1.0];
    }
    let a = 1.0 - level;
    let (xf, nf) = (x as f64, n as f64);
    let lo = if x == 0 {
        0.0
    } else {
        Beta::new(xf, nf - xf + 1.0).map_or(0.0, |b| b.inverse_cdf(a / 2.0))
    };
    let hi = if x >= n {
        1.0
    } else {
        Beta::new(xf + 1.0, nf - xf).map_or(1.0, |b| b.inverse_cdf(1.0 - a / 2.0))
    };
    [lo, hi]
}

/// Parses `A-B` into two labels of `available` (labels may themselves
/// contain `-`: every split point is tried).
///
/// # Errors
/// [`PowerError::BadContrast`] unless exactly one split gives two different
/// known labels.
pub fn parse_contrast(spec: &str, available: &[String]) -> Result<(String, String), PowerError> {
    let found: Vec<(String, String)> = spec
        .match_indices('-')
        .map(|(i, _)| (spec[..i].trim().to_owned(), spec[i + 1..].trim().to_owned()))
        .filter(|(a, b)| a != b && available.contains(a) && available.contains(b))
        .collect();
    match found.as_slice() {
        [one] => Ok(one.clone()),
        _ => Err(PowerError::BadContrast(
            spec.to_owned(),
            available.join(", "),
        )),
    }
}

/// Parses a list of sample sizes (`--n`): comma-separated integers and
/// `FROM:TO:STEP` ranges, sorted and deduplicated; at most 100 values.
///
/// # Errors
/// [`PowerError::InvalidOption`] for a malformed item, a zero step, an
/// empty list or more than 100 values.
pub fn parse_sample_sizes(spec: &str) -> Result<Vec<u32>, PowerError> {
    let invalid = |m: String| PowerError::InvalidOption(m);
    let mut out = Vec::new();
    for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let bad = || invalid(format!("--n: `{item}` is not a number or FROM:TO:STEP"));
        let parts: Vec<&str> = item.split(':').collect();
        match parts.as_slice() {
            [one] => out.push(one.parse().map_err(|_| bad())?),
            [a, b, s] => {
                let (a, b, s): (u32, u32, u32) = (
                    a.parse().map_err(|_| bad())?,
                    b.parse().map_err(|_| bad())?,
                    s.parse().map_err(|_| bad())?,
                );
                if s == 0 {
                    return Err(invalid(format!("--n: `{item}` has a zero step")));
                }
                let mut v = a;
                while v <= b {
                    out.push(v);
                    if out.len() > 100 {
                        return Err(invalid("--n: more than 100 sample sizes".into()));
                    }
                    v = v.saturating_add(s);
                    if v == u32::MAX {
                        break;
                    }
                }
            }
            _ => return Err(bad()),
        }
    }
    out.sort_unstable();
    out.dedup();
    if out.is_empty() {
        return Err(invalid(
            "--n: give at least one number of participants".into(),
        ));
    }
    Ok(out)
}

impl PowerReport {
    /// The caution printed with every report: the pilot's effect with its
    /// 95 % CI, and the advice to plan for the smallest effect worth
    /// detecting rather than for the pilot's noisy estimate.
    pub fn pilot_warning(&self) -> String {
        let e = &self.pilot_effect;
        format!(
            "note: the pilot's {}−{} effect is {:.4} with 95 % CI [{:.4}, {:.4}] from {} \
             participants; a pilot's effect is noisy, so plan for the smallest effect worth \
             detecting (--effect) rather than for the pilot's estimate",
            e.contrast[0], e.contrast[1], e.estimate, e.ci[0], e.ci[1], e.n
        )
    }
}

/// Condition labels of a pilot's test rows, in order of first appearance.
pub fn conditions_of(table: &PilotTable) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for r in table.rows.iter().filter(|r| r.test) {
        if !out.contains(&r.condition) {
            out.push(r.condition.clone());
        }
    }
    out
}

fn pilot_effect(
    model: &PilotModel,
    rows: &PilotRows,
    a: usize,
    b: usize,
) -> Result<PilotEffect, PowerError> {
    let m = rows.design.cell_matrix()?;
    let d: Vec<f64> = (0..m.n_subjects())
        .map(|i| m.row(i)[a] - m.row(i)[b])
        .collect();
    let n = d.len();
    let mean = d.iter().sum::<f64>() / n as f64;
    let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0)).sqrt();
    let q = StudentsT::new(0.0, 1.0, n as f64 - 1.0).map_or(f64::NAN, |t| t.inverse_cdf(0.975));
    let half = q * sd / (n as f64).sqrt();
    Ok(PilotEffect {
        contrast: [model.conditions[a].clone(), model.conditions[b].clone()],
        estimate: mean,
        ci: [mean - half, mean + half],
        sd_diff: sd,
        n,
    })
}

/// Runs the power analysis on a pilot file or folder.
///
/// # Errors
/// Reading and option errors, a pilot too small to fit, a cancelled run
/// ([`PowerError::InvalidOption`] "cancelled").
pub fn power_from_path(
    pilot: &Path,
    opts: &PowerOptions,
    progress: &(dyn Fn(usize, usize) -> bool + Sync),
) -> Result<PowerReport, PowerError> {
    let table = read_pilot(pilot, &opts.dv, &opts.within, &opts.subject)?;
    power(&table, opts, progress)
}

/// Runs the power analysis on a pilot table (module docs).
///
/// # Errors
/// As [`power_from_path`].
pub fn power(
    table: &PilotTable,
    opts: &PowerOptions,
    progress: &(dyn Fn(usize, usize) -> bool + Sync),
) -> Result<PowerReport, PowerError> {
    opts.check()?;
    let (conditions, analysis) = analysed_conditions(&opts.test, conditions_of(table))?;
    let rows = pilot_rows(table, &conditions)?;
    let counts = trial_counts(table, &conditions);
    let model = PilotModel::fit(&opts.dv, &rows, &counts, table.dv_is_success())?;
    let pilot_means: Vec<f64> = if model.dv_is_success {
        model.success.iter().map(|s| s.p).collect()
    } else {
        model.means.clone()
    };
    let (ia, ib) = reported_pair(analysis, &pilot_means);
    let means = simulated_means(analysis, opts.effect, &pilot_means, ia, ib)?;
    let effect = means[ia] - means[ib];
    let (sim_means, success) = if model.dv_is_success {
        let s = model
            .success
            .iter()
            .zip(&means)
            .map(|(s, &p)| SuccessModel::with_p(p, s.icc, s.participants, s.trials))
            .collect();
        (model.means.clone(), s)
    } else {
        (means.clone(), model.success.clone())
    };
    let trials = opts.trials.unwrap_or(model.planned_trials);
    let scenario = Scenario {
        model: &model,
        means: sim_means,
        success,
        analysis,
        alpha: opts.alpha,
    };
    let tallies = scenario
        .run_grid(
            &opts.ns,
            trials,
            opts.replications,
            opts.seed,
            opts.threads,
            progress,
        )
        .ok_or_else(|| PowerError::InvalidOption("cancelled".into()))?;
    let points = power_points(&opts.ns, &tallies);
    let n_for_target = points
        .iter()
        .filter(|p| p.power >= opts.target)
        .map(|p| p.n)
        .min();
    let pilot_effect = pilot_effect(&model, &rows, ia, ib)?;
    let sd_diff_model = if model.dv_is_success {
        pilot_effect.sd_diff
    } else {
        model.var_diff(ia, ib, f64::from(trials)).sqrt()
    };
    Ok(PowerReport {
        points,
        effect,
        sd_diff: pilot_effect.sd_diff,
        sd_diff_model,
        n_for_target,
        pilot_effect,
        test: match analysis {
            Analysis::PairedT => "paired_t",
            Analysis::RmGg => "rm_anova_gg",
        },
        means,
        trials_per_condition: trials,
        alpha: opts.alpha,
        target: opts.target,
        replications: opts.replications,
        seed: opts.seed,
        pilot: table.path.display().to_string(),
        model,
    })
}

/// The conditions a test compares, in order, and its analysis: the
/// contrast's two labels (each must be among the pilot's `available`
/// conditions) or all of them.
fn analysed_conditions(
    test: &PowerTest,
    available: Vec<String>,
) -> Result<(Vec<String>, Analysis), PowerError> {
    match test {
        PowerTest::Contrast { a, b } => {
            for l in [a, b] {
                if !available.contains(l) {
                    return Err(PowerError::UnknownCondition {
                        label: l.clone(),
                        available: available.clone(),
                    });
                }
            }
            Ok((vec![a.clone(), b.clone()], Analysis::PairedT))
        }
        PowerTest::Rm => Ok((available, Analysis::RmGg)),
    }
}

/// The pair of conditions whose difference is reported: A, B for a
/// contrast, the largest and smallest pilot means for RM-ANOVA.
fn reported_pair(analysis: Analysis, pilot_means: &[f64]) -> (usize, usize) {
    match analysis {
        Analysis::PairedT => (0, 1),
        Analysis::RmGg => {
            let by = |f: fn(f64, f64) -> bool| {
                (0..pilot_means.len()).fold(0, |best, j| {
                    if f(pilot_means[j], pilot_means[best]) {
                        j
                    } else {
                        best
                    }
                })
            };
            (by(|x, y| x > y), by(|x, y| x < y))
        }
    }
}

/// The condition means simulated: for a contrast, the pilot's centre ± half
/// the assumed difference; for RM-ANOVA, the pilot means scaled about their
/// grand mean so that the reported pair (`ia`, `ib`) differs by the assumed
/// effect.
///
/// # Errors
/// [`PowerError::NoPilotEffect`] for an absolute RM-ANOVA effect when the
/// pilot means do not differ.
fn simulated_means(
    analysis: Analysis,
    effect: EffectSpec,
    pilot_means: &[f64],
    ia: usize,
    ib: usize,
) -> Result<Vec<f64>, PowerError> {
    let effect_now = pilot_means[ia] - pilot_means[ib];
    Ok(match analysis {
        Analysis::PairedT => {
            let d = match effect {
                EffectSpec::Pilot => effect_now,
                EffectSpec::Absolute(x) => x,
                EffectSpec::Scale(s) => s * effect_now,
            };
            let c = 0.5 * (pilot_means[0] + pilot_means[1]);
            vec![c + 0.5 * d, c - 0.5 * d]
        }
        Analysis::RmGg => {
            let grand = pilot_means.iter().sum::<f64>() / pilot_means.len() as f64;
            let f = match effect {
                EffectSpec::Pilot => 1.0,
                EffectSpec::Scale(s) => s,
                EffectSpec::Absolute(0.0) => 0.0,
                EffectSpec::Absolute(x) => {
                    if effect_now <= 0.0 {
                        return Err(PowerError::NoPilotEffect);
                    }
                    x / effect_now
                }
            };
            pilot_means
                .iter()
                .map(|m| grand + f * (m - grand))
                .collect()
        }
    })
}

/// The power curve: per sample size, the share of replications that
/// rejected, with its Clopper–Pearson 95 % interval.
fn power_points(ns: &[u32], tallies: &[Tally]) -> Vec<PowerPoint> {
    ns.iter()
        .zip(tallies)
        .map(|(&n, t)| PowerPoint {
            n,
            power: t.rejected as f64 / t.replications.max(1) as f64,
            ci: clopper_pearson(t.rejected, t.replications, 0.95),
            rejected: t.rejected,
            replications: t.replications,
            analysed: t.analysed,
            mean_dropped: t.dropped as f64 / t.replications.max(1) as f64,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reference values: `scipy.stats.beta.ppf` (the Clopper–Pearson
    /// definition), see `tests/data/power_reference.py`.
    #[test]
    fn clopper_pearson_edges() {
        assert_eq!(clopper_pearson(0, 10, 0.95)[0], 0.0);
        assert_eq!(clopper_pearson(10, 10, 0.95)[1], 1.0);
        // x = 0: upper = 1 − (α/2)^(1/n) exactly.
        let hi = clopper_pearson(0, 10, 0.95)[1];
        assert!((hi - (1.0 - 0.025_f64.powf(0.1))).abs() < 1e-10);
    }

    #[test]
    fn sample_sizes_parse_lists_and_ranges() {
        assert_eq!(parse_sample_sizes("4,8,12").ok(), Some(vec![4, 8, 12]));
        assert_eq!(
            parse_sample_sizes("4:12:4, 6").ok(),
            Some(vec![4, 6, 8, 12])
        );
        assert!(parse_sample_sizes("4:12:0").is_err());
        assert!(parse_sample_sizes("x").is_err());
        assert!(parse_sample_sizes("").is_err());
        assert!(parse_sample_sizes("1:1000:1").is_err());
    }

    #[test]
    fn contrast_parsing_handles_dashes_in_labels() {
        let av: Vec<String> = ["V", "P", "D", "P-2"]
            .iter()
            .map(|s| (*s).to_owned())
            .collect();
        assert_eq!(
            parse_contrast("P-D", &av).ok(),
            Some(("P".into(), "D".into()))
        );
        assert_eq!(
            parse_contrast("P-2-D", &av).ok(),
            Some(("P-2".into(), "D".into()))
        );
        assert!(parse_contrast("P-X", &av).is_err());
        assert!(parse_contrast("P-P", &av).is_err());
    }
}
