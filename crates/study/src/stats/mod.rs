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
//! * [`pairwise_t`], [`pairwise_wilcoxon`] — post-hoc paired tests with
//!   [`holm`] correction.
//!
//! Degenerate designs (one subject, one condition, zero variance, missing
//! cells, non-finite values) give a [`StatsError`], never a silent NaN.
//! Equations and references: `docs/THEORY.md`.

mod anova;
mod design;
mod dist;
mod error;
mod friedman;
mod pairwise;
mod rank;

use std::str::FromStr;

use serde::Serialize;

pub use anova::{OneWayAnova, RmAnova, one_way_anova, oneway, rm_anova};
pub use design::{CellMatrix, Design, compensated_mean};
pub use error::{MissingCell, Result, StatsError};
pub use friedman::{Friedman, friedman};
pub use pairwise::{
    EXACT_MAX_N, PairwiseComparison, TTest, WilcoxonMethod, WilcoxonMethodUsed, WilcoxonOptions,
    WilcoxonTest, holm, one_sample_t, paired_t, pairwise_t, pairwise_wilcoxon,
    wilcoxon_signed_rank, wilcoxon_signed_rank_diffs,
};

/// The omnibus tests the CLI offers (`--test oneway|rm|friedman`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Test {
    /// One-way between-groups ANOVA on cell means ([`oneway`]).
    Oneway,
    /// Repeated-measures ANOVA ([`rm_anova`]).
    Rm,
    /// Friedman's test ([`friedman`]).
    Friedman,
}

impl FromStr for Test {
    type Err = StatsError;

    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "oneway" | "one-way" | "anova" => Ok(Self::Oneway),
            "rm" | "rm_anova" | "rm-anova" => Ok(Self::Rm),
            "friedman" => Ok(Self::Friedman),
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
    })
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
