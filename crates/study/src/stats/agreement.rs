//! Do two runs of the same study agree? Per condition and metric, the
//! difference of the two trial means against its sampling error.
//!
//! Two runs of one protocol with one simulated cohort (the full model
//! against the scene, the simulation against hardware in the loop) should
//! differ by no more than sampling error. For each condition and metric
//! the test trials' means m_a, m_b and their variances of the mean
//! s_a²/n_a, s_b²/n_b give the pooled standard error
//! SE = √(s_a²/n_a + s_b²/n_b) (Welch's, unequal variances) and the
//! standardised difference z = (m_a − m_b)/SE; the runs agree when
//! |z| ≤ k (2.5: a two-sided 1.2 % false alarm rate per comparison for
//! normal means). The trials are treated as independent (the rows of one
//! participant are correlated, so SE is a lower bound and the check is
//! strict, not lenient).

use serde::Serialize;

use crate::export::{Metric, TrialRow};
use crate::protocol::Condition;
use crate::seeds::Phase;

/// A metric of a trial row compared by [`agreement`]: `success` (0/1) or a
/// column of `trials.csv`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compared {
    /// The trial's success, 0 or 1 (the mean is the success rate).
    Success,
    /// A metric column.
    Metric(Metric),
}

impl Compared {
    /// The five measures of a circling study: success rate, time, optical
    /// force, displacement error and contact fraction.
    pub const CIRCLING: [Compared; 5] = [
        Compared::Success,
        Compared::Metric(Metric::TimeS),
        Compared::Metric(Metric::ForceMeanPn),
        Compared::Metric(Metric::DispErrMeanUm),
        Compared::Metric(Metric::ContactFraction),
    ];

    /// Its name (a column of `trials.csv`).
    pub fn name(self) -> &'static str {
        match self {
            Compared::Success => "success",
            Compared::Metric(m) => m.column(),
        }
    }

    /// The value of `row`, when it has one.
    pub fn get(self, row: &TrialRow) -> Option<f64> {
        match self {
            Compared::Success => Some(f64::from(u8::from(row.success))),
            Compared::Metric(m) => m.get(row),
        }
    }
}

/// One condition × metric comparison.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Agreement {
    /// The condition.
    pub condition: Condition,
    /// The metric's name (`success` or a column of `trials.csv`).
    pub metric: &'static str,
    /// Trials with a value in run a and b.
    pub n_a: usize,
    /// Trials with a value in run b.
    pub n_b: usize,
    /// Mean of run a.
    pub mean_a: f64,
    /// Mean of run b.
    pub mean_b: f64,
    /// √(s_a²/n_a + s_b²/n_b), the sampling error of mean_a − mean_b.
    pub pooled_se: f64,
    /// (mean_a − mean_b)/pooled_se (0 when both are equal; ±∞ when the
    /// means differ with no variance).
    pub z: f64,
    /// |z| ≤ the bound (or equal means).
    pub agrees: bool,
}

/// Mean and variance of the mean of `x` (n ≥ 2; `None` otherwise).
fn mean_var_of_mean(x: &[f64]) -> Option<(f64, f64)> {
    if x.len() < 2 {
        return None;
    }
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let v = x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0);
    Some((m, v / n))
}

/// Compare the test trials of runs `a` and `b` per condition and metric:
/// the standardised difference of the means within `k` pooled standard
/// errors (module docs). Conditions or metrics with fewer than two values
/// in either run are left out (the caller checks the counts it needs).
pub fn agreement(a: &[TrialRow], b: &[TrialRow], metrics: &[Compared], k: f64) -> Vec<Agreement> {
    let mut out = Vec::new();
    for c in Condition::ALL {
        for &metric in metrics {
            let values = |rows: &[TrialRow]| -> Vec<f64> {
                rows.iter()
                    .filter(|r| r.condition == c && r.phase == Phase::Test)
                    .filter_map(|r| metric.get(r))
                    .filter(|v| v.is_finite())
                    .collect()
            };
            let (va, vb) = (values(a), values(b));
            let (Some((ma, sa)), Some((mb, sb))) = (mean_var_of_mean(&va), mean_var_of_mean(&vb))
            else {
                continue;
            };
            let se = (sa + sb).sqrt();
            let diff = ma - mb;
            // Equal means (to rounding) agree whatever the spread.
            let equal = diff.abs() <= 1e-12 * ma.abs().max(mb.abs());
            let z = if equal { 0.0 } else { diff / se };
            out.push(Agreement {
                condition: c,
                metric: metric.name(),
                n_a: va.len(),
                n_b: vb.len(),
                mean_a: ma,
                mean_b: mb,
                pooled_se: se,
                z,
                agrees: z.abs() <= k,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooled_se_and_z_are_welchs() {
        // a: 1, 2, 3 (mean 2, s² = 1); b: 2, 4, 6, 8 (mean 5, s² = 20/3).
        let (ma, va) = mean_var_of_mean(&[1.0, 2.0, 3.0]).unwrap();
        let (mb, vb) = mean_var_of_mean(&[2.0, 4.0, 6.0, 8.0]).unwrap();
        assert_eq!((ma, mb), (2.0, 5.0));
        let se = (va + vb).sqrt();
        assert!((se - (1.0f64 / 3.0 + 20.0 / 12.0).sqrt()).abs() < 1e-15);
        assert!(mean_var_of_mean(&[1.0]).is_none());
    }
}
