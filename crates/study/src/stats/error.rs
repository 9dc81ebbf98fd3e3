//! Typed errors of the statistics module.

use std::fmt::Write as _;

use thiserror::Error;

/// A (subject, condition) cell without any observation.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct MissingCell {
    /// Subject (participant) label as it appears in the data.
    pub subject: String,
    /// Condition label as it appears in the data.
    pub condition: String,
}

/// Every fallible operation of [`crate::stats`] returns this error.
///
/// Degenerate designs are reported here instead of producing `NaN`:
/// one subject, one condition, zero variance, missing cells, non-finite
/// input.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum StatsError {
    /// No observation at all.
    #[error("no observations")]
    Empty,
    /// A row of long-format data carries a NaN or infinite value.
    #[error("non-finite value {value} in row {row} (subject `{subject}`, condition `{condition}`)")]
    NonFinite {
        /// Zero-based index of the offending row.
        row: usize,
        /// Subject label of the row.
        subject: String,
        /// Condition label of the row.
        condition: String,
        /// The offending value.
        value: f64,
    },
    /// The mean of a (subject, condition) cell is not finite: its values,
    /// each finite, add up beyond the range of `f64` (|sum| > 1.8e308).
    #[error(
        "the mean of cell (subject `{subject}`, condition `{condition}`) over {rows} row(s) is \
         {value}: its values overflow a 64-bit float; rescale the variable"
    )]
    NonFiniteCell {
        /// Subject label of the cell.
        subject: String,
        /// Condition label of the cell.
        condition: String,
        /// Rows averaged into the cell.
        rows: usize,
        /// The mean computed.
        value: f64,
    },
    /// A slice argument carries a NaN or infinite value.
    #[error("non-finite value {value} at index {index} of {what}")]
    NonFiniteInput {
        /// Which argument (e.g. `"x"`, `"group 2"`).
        what: String,
        /// Zero-based index of the offending value.
        index: usize,
        /// The offending value.
        value: f64,
    },
    /// Not enough subjects (or observations) for the test.
    #[error("{test} needs at least {needed} subjects (or paired observations), got {got}")]
    TooFewSubjects {
        /// Name of the test.
        test: &'static str,
        /// Minimum number required.
        needed: usize,
        /// Number supplied.
        got: usize,
    },
    /// Not enough conditions (groups) for the test.
    #[error("{test} needs at least {needed} conditions, got {got}")]
    TooFewConditions {
        /// Name of the test.
        test: &'static str,
        /// Minimum number required.
        needed: usize,
        /// Number supplied.
        got: usize,
    },
    /// A group of a between-groups analysis has no observation.
    #[error("{test}: group `{group}` has no observation")]
    EmptyGroup {
        /// Name of the test.
        test: &'static str,
        /// Label (or index) of the empty group.
        group: String,
    },
    /// Some subjects lack some conditions; a within-subject analysis needs
    /// every cell.
    #[error("incomplete design: {}", describe_missing(.missing))]
    IncompleteDesign {
        /// Every missing (subject, condition) cell, subjects in data order.
        missing: Vec<MissingCell>,
    },
    /// The error (or within-group) variance is zero, so the statistic is
    /// unbounded or undefined.
    #[error("{test}: zero variance: {detail}")]
    ZeroVariance {
        /// Name of the test.
        test: &'static str,
        /// What exactly has no variance.
        detail: String,
    },
    /// Two paired samples differ in length, or a matrix has the wrong size.
    #[error("length mismatch: {what}: {left} vs {right}")]
    LengthMismatch {
        /// What was being compared.
        what: &'static str,
        /// First length.
        left: usize,
        /// Second length.
        right: usize,
    },
    /// A p-value outside [0, 1] (or NaN) was given to a correction.
    #[error("invalid p-value {value} at index {index}: must be in [0, 1]")]
    InvalidPValue {
        /// Zero-based index of the offending p-value.
        index: usize,
        /// The offending value.
        value: f64,
    },
    /// A condition label that is not in the data.
    #[error("unknown condition `{0}`")]
    UnknownCondition(String),
    /// A label listed twice where each must appear once.
    #[error("{what} `{label}` appears more than once")]
    DuplicateLabel {
        /// `"condition"` or `"subject"`.
        what: &'static str,
        /// The duplicated label.
        label: String,
    },
    /// A condition ordering that does not list every condition exactly once.
    #[error("condition order must list each of the {expected} conditions once, got {got}")]
    BadConditionOrder {
        /// Number of conditions in the data.
        expected: usize,
        /// Number of labels supplied.
        got: usize,
    },
    /// The name of a test (CLI `--test`) is not recognised.
    #[error("unknown test `{0}`: expected `oneway`, `rm` or `friedman`")]
    UnknownTest(String),
    /// A special function failed (argument outside its domain).
    #[error("numerical failure in {what}: {detail}")]
    Numerical {
        /// Which computation failed.
        what: &'static str,
        /// Details from the underlying routine.
        detail: String,
    },
}

/// "subject `s3` lacks `P`, `D`; subject `s5` lacks `V`".
fn describe_missing(missing: &[MissingCell]) -> String {
    let mut out = String::new();
    let mut i = 0;
    while i < missing.len() {
        let subject = &missing[i].subject;
        if !out.is_empty() {
            out.push_str("; ");
        }
        let _ = write!(out, "subject `{subject}` lacks ");
        let mut first = true;
        while i < missing.len() && &missing[i].subject == subject {
            if !first {
                out.push_str(", ");
            }
            let _ = write!(out, "`{}`", missing[i].condition);
            first = false;
            i += 1;
        }
    }
    out
}

/// Result alias of the statistics module.
pub type Result<T> = std::result::Result<T, StatsError>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_cells_are_grouped_by_subject() {
        let missing = vec![
            MissingCell {
                subject: "s3".into(),
                condition: "P".into(),
            },
            MissingCell {
                subject: "s3".into(),
                condition: "D".into(),
            },
            MissingCell {
                subject: "s5".into(),
                condition: "V".into(),
            },
        ];
        let msg = StatsError::IncompleteDesign { missing }.to_string();
        assert_eq!(
            msg,
            "incomplete design: subject `s3` lacks `P`, `D`; subject `s5` lacks `V`"
        );
    }
}
