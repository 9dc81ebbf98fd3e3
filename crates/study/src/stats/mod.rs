//! Statistics of the psychophysics study.
//!
//! Everything is computed on participant × condition **cell means** (repeated
//! rows averaged, as pingouin and R's `ez` do), built from long-format data
//! by [`Design`]:
//!
//! * [`oneway`] / [`one_way_anova`] — one-way ANOVA across conditions, the
//!   analysis of the paper (§4.3, Fig. 12), which treats the conditions as
//!   independent groups of cell means;
//! * [`rm_anova`] — repeated-measures ANOVA (one within factor) with
//!   Mauchly's test, Greenhouse–Geisser / Huynh–Feldt / lower-bound
//!   corrections, partial and generalised η²;
//! * [`friedman`] — Friedman's test (χ² and Iman–Davenport F, tie-corrected)
//!   with Kendall's W;
//! * [`pairwise_tests`] — the post-hoc table: paired t and Wilcoxon per
//!   condition pair, each family [`holm`]-corrected, with d_z and the mean
//!   difference and their intervals; a pair where a test is undefined keeps
//!   its row ([`pairwise_t`], [`pairwise_wilcoxon`] are the strict single
//!   families);
//! * [`describe()`] — per-condition n, mean, SD, median, quartiles;
//! * [`agreement::agreement`] — do two runs of one study (simulation and
//!   hardware in the loop, scene and full model) agree within sampling error;
//! * effect-size intervals ([`effect`]): noncentral-F intervals of η² and
//!   partial η², a bootstrap interval of Kendall's W, d_z's interval.
//!
//! Which rows of a trial table enter the cell means is decided in one place,
//! [`rows`] ([`RowRule`]: successful test trials by default); within-subject
//! tests drop participants lacking a condition ([`analyse`], listwise
//! deletion as pingouin does) and name them.
//!
//! Degenerate designs (one subject, one condition, zero variance, missing
//! cells, non-finite values) give a [`StatsError`], never a silent NaN.
//! Equations and references: `docs/theory/statistics.md`.

pub mod agreement;
mod anova;
mod describe;
mod design;
mod dist;
pub mod effect;
mod error;
mod friedman;
mod pairwise;
mod rank;
pub mod rows;

use std::str::FromStr;

use serde::Serialize;

pub use anova::{OneWayAnova, RmAnova, one_way_anova, oneway, rm_anova};
pub use describe::{ConditionSummary, Describe, describe, summarize_sample};
pub use design::{CellMatrix, Design, compensated_mean};
pub use error::{MissingCell, Result, StatsError};
pub use friedman::{Friedman, friedman};
pub use pairwise::{
    EXACT_MAX_N, PairTest, PairwiseComparison, PairwiseTests, TTest, WilcoxonMethod,
    WilcoxonMethodUsed, WilcoxonOptions, WilcoxonTest, holm, one_sample_t, paired_t, pairwise_t,
    pairwise_tests, pairwise_wilcoxon, wilcoxon_signed_rank, wilcoxon_signed_rank_diffs,
};
pub use rows::{Exclusion, LongRow, RowCounts, RowRule, select_rows};

/// The tests the CLI offers (`--test oneway|rm|friedman|pairwise|describe`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Test {
    /// One-way between-groups ANOVA on cell means ([`oneway`]).
    Oneway,
    /// Repeated-measures ANOVA ([`rm_anova`]).
    Rm,
    /// Friedman's test ([`friedman`]).
    Friedman,
    /// Post-hoc paired t and Wilcoxon tests ([`pairwise_tests`]).
    Pairwise,
    /// Per-condition descriptives ([`describe()`]).
    Describe,
}

impl Test {
    /// Whether the test needs every participant in every condition (the
    /// within-subject tests; [`analyse`] drops incomplete participants).
    pub fn is_within(self) -> bool {
        !matches!(self, Test::Oneway)
    }
}

impl FromStr for Test {
    type Err = StatsError;

    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "oneway" | "one-way" | "anova" => Ok(Self::Oneway),
            "rm" | "rm_anova" | "rm-anova" => Ok(Self::Rm),
            "friedman" => Ok(Self::Friedman),
            "pairwise" | "posthoc" => Ok(Self::Pairwise),
            "describe" | "descriptives" => Ok(Self::Describe),
            _ => Err(StatsError::UnknownTest(s.to_owned())),
        }
    }
}

/// Result of [`run_test`]; serialises as the bare result struct.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum TestReport {
    /// See [`OneWayAnova`].
    Oneway(OneWayAnova),
    /// See [`RmAnova`].
    Rm(RmAnova),
    /// See [`Friedman`].
    Friedman(Friedman),
    /// See [`PairwiseTests`].
    Pairwise(PairwiseTests),
    /// See [`Describe`].
    Describe(Describe),
}

/// Runs `test` on `design` (the CLI entry point). Within-subject tests need
/// a complete design; the one-way ANOVA does not.
///
/// # Errors
/// Those of the selected test, including [`StatsError::IncompleteDesign`].
pub fn run_test(design: &Design, test: Test) -> Result<TestReport> {
    Ok(match test {
        Test::Oneway => TestReport::Oneway(oneway(design)?),
        Test::Rm => TestReport::Rm(rm_anova(&design.cell_matrix()?)?),
        Test::Friedman => TestReport::Friedman(friedman(&design.cell_matrix()?)?),
        Test::Pairwise => TestReport::Pairwise(pairwise_tests(
            &design.cell_matrix()?,
            WilcoxonOptions::default(),
        )?),
        Test::Describe => TestReport::Describe(describe(&design.cell_matrix()?)?),
    })
}

/// [`run_test`] after listwise deletion: a within-subject test drops the
/// participants lacking a condition (as pingouin's `rm_anova`,
/// `friedman` and `pairwise_tests` do) and returns their labels, in data
/// order; the one-way ANOVA keeps everyone.
///
/// # Errors
/// [`StatsError::Empty`] when no participant has every condition; those of
/// the test.
pub fn analyse(design: &Design, test: Test) -> Result<(TestReport, Vec<String>)> {
    if !test.is_within() {
        return Ok((run_test(design, test)?, Vec::new()));
    }
    let (complete, dropped) = match design.complete_subjects_only() {
        Ok(c) => c,
        // Nobody has every condition: name what is missing.
        Err(StatsError::Empty) => {
            return Err(design.cell_matrix().err().unwrap_or(StatsError::Empty));
        }
        Err(e) => return Err(e),
    };
    Ok((run_test(&complete, test)?, dropped))
}

/// Convenience: long-format rows `(subject, condition, value)` → [`run_test`].
///
/// # Errors
/// Those of [`Design::from_long`] and [`run_test`].
pub fn run_test_long<I, S, C>(rows: I, test: Test) -> Result<TestReport>
where
    I: IntoIterator<Item = (S, C, f64)>,
    S: AsRef<str>,
    C: AsRef<str>,
{
    run_test(&Design::from_long(rows)?, test)
}
