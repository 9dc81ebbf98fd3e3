//! Descriptive statistics per condition over the participants' cell means.

use serde::Serialize;

use super::design::{CellMatrix, compensated_mean};
use super::effect::quantile_sorted;
use super::error::{Result, StatsError};

/// One condition's descriptives (in the unit of the dependent variable).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ConditionSummary {
    /// Condition label.
    pub condition: String,
    /// Participants (cell means) summarised.
    pub n: usize,
    /// Mean of the cell means.
    pub mean: f64,
    /// Sample standard deviation (n − 1 denominator); `None` for n = 1.
    pub sd: Option<f64>,
    /// Median.
    pub median: f64,
    /// First quartile (linear interpolation, numpy / pandas default).
    pub q1: f64,
    /// Third quartile.
    pub q3: f64,
    /// Interquartile range q3 − q1.
    pub iqr: f64,
    /// Smallest cell mean.
    pub min: f64,
    /// Largest cell mean.
    pub max: f64,
}

/// Descriptives of every condition (column order).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Describe {
    /// One entry per condition.
    pub conditions: Vec<ConditionSummary>,
}

/// Summary of one sample (non-empty, finite).
pub fn summarize_sample(condition: &str, values: &[f64]) -> ConditionSummary {
    let n = values.len();
    let mean = compensated_mean(values);
    let sd = (n > 1).then(|| {
        let ss: f64 = values.iter().map(|v| (v - mean) * (v - mean)).sum();
        (ss / (n as f64 - 1.0)).sqrt()
    });
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    let (q1, median, q3) = (
        quantile_sorted(&s, 0.25),
        quantile_sorted(&s, 0.5),
        quantile_sorted(&s, 0.75),
    );
    ConditionSummary {
        condition: condition.to_owned(),
        n,
        mean,
        sd,
        median,
        q1,
        q3,
        iqr: q3 - q1,
        min: s[0],
        max: s[n - 1],
    }
}

/// Per-condition descriptives of the cell means of `m`.
///
/// # Errors
/// [`StatsError::Numerical`] when a summary of finite values overflows
/// `f64` (values near ±1.8·10³⁰⁸), naming the condition.
pub fn describe(m: &CellMatrix) -> Result<Describe> {
    let conditions: Vec<ConditionSummary> = m
        .conditions()
        .iter()
        .enumerate()
        .map(|(j, c)| summarize_sample(c, &m.column(j)))
        .collect();
    if let Some(c) = conditions.iter().find(|c| {
        ![c.mean, c.median, c.q1, c.q3, c.iqr]
            .iter()
            .chain(c.sd.iter())
            .all(|x| x.is_finite())
    }) {
        return Err(StatsError::Numerical {
            what: "describe",
            detail: format!(
                "the mean, SD or quartiles of condition `{}` overflow a 64-bit float; rescale \
                 the variable",
                c.condition
            ),
        });
    }
    Ok(Describe { conditions })
}
