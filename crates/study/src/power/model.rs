//! The generative model fitted to a pilot (method of moments).
//!
//! For participant i, condition j and successful trial t, the dependent
//! variable is modelled as
//!
//! ```text
//! y_ijt = b_ij + e_ijt,      b_i = (b_i1 … b_ik) ~ N(μ, Σ_b),   e_ijt ~ N(0, σ²_e,j)
//! ```
//!
//! where b_ij is participant i's true mean in condition j. The usual mixed
//! model — a random participant intercept u_i ~ N(0, σ²_u) plus a
//! participant × condition effect w_ij ~ N(0, σ²_w,j) — is the special case
//! Σ_b = σ²_u 11ᵀ + diag(σ²_w,j); Σ_b is estimated unstructured so that
//! unequal variances and correlations of the pilot (non-sphericity, which
//! the Greenhouse–Geisser correction is there for) carry over to the
//! simulated studies, and the intercept/interaction summary σ²_u, σ²_w,j is
//! reported alongside.
//!
//! **Estimators (unbiased method of moments, not REML).** With n_ij ≥ 1 kept
//! trials in cell (i, j), cell means ȳ_ij, and S the sample covariance
//! (divisor n − 1) of the participants' cell-mean vectors:
//!
//! ```text
//! σ̂²_e,j = Σ_i Σ_t (y_ijt − ȳ_ij)² / Σ_i (n_ij − 1)         (pooled within-cell variance)
//! h_j    = mean_i 1/n_ij
//! Σ̂_b    = S − diag(σ̂²_e,j h_j)                             (E[S] = Σ_b + diag(σ²_e,j h_j))
//! σ̂²_u   = mean of the off-diagonal entries of Σ̂_b,   σ̂²_w,j = (Σ̂_b)_jj − σ̂²_u
//! ```
//!
//! Σ̂_b is then projected on the positive semi-definite matrices (negative
//! eigenvalues set to 0, reported as `clipped`), the only step that is not
//! unbiased. For a contrast of two conditions at the pilot's own trial
//! counts, the model's variance of the A − B cell-mean difference equals
//! the pilot's sample variance of it exactly (unless clipped).
//!
//! **Success.** Condition j's success probability varies between
//! participants as Beta(α_j, β_j) (a beta-binomial count of successes,
//! Skellam 1948), fitted by moments: p̂_j = Σx/Σm and the intra-class
//! correlation ρ̂_j by the ANOVA estimator for binary data (Ridout, Demétrio
//! & Firth 1999, eq. 2.1):
//!
//! ```text
//! MSB = (Σ x_i²/m_i − (Σx)²/M)/(N − 1),   MSW = (Σx − Σ x_i²/m_i)/(M − N)
//! m₀  = (M − Σ m_i²/M)/(N − 1),           ρ̂ = (MSB − MSW)/(MSB + (m₀ − 1) MSW)
//! α_j = p̂(1 − ρ̂)/ρ̂,  β_j = (1 − p̂)(1 − ρ̂)/ρ̂
//! ```
//!
//! clamped to 0 ≤ ρ̂ < 1 (ρ̂ = 0: every participant has p̂_j). Success and
//! the DV are drawn independently, and participants' success probabilities
//! independently across conditions.

use nalgebra::{DMatrix, SymmetricEigen};
use serde::Serialize;

use super::error::PowerError;
use super::pilot::{PilotRows, TrialCount};
use crate::stats::compensated_mean;

/// Largest intra-class correlation used (ρ → 1 makes Beta's parameters 0).
const MAX_ICC: f64 = 0.999;

/// Between-participant model of one condition's success probability.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SuccessModel {
    /// Mean success probability p̂ (successes / test trials).
    pub p: f64,
    /// Intra-class correlation ρ̂ of the outcomes (0: same p for everyone).
    pub icc: f64,
    /// Beta α of the participants' probabilities (`None` when ρ̂ = 0).
    pub beta_a: Option<f64>,
    /// Beta β.
    pub beta_b: Option<f64>,
    /// Participants with test trials in this condition.
    pub participants: usize,
    /// Test trials in this condition.
    pub trials: u64,
}

impl SuccessModel {
    /// Fit by moments (module docs) to per-participant counts.
    pub fn fit(counts: &[TrialCount]) -> Self {
        let counts: Vec<&TrialCount> = counts.iter().filter(|c| c.trials > 0).collect();
        let big_n = counts.len();
        let m: f64 = counts.iter().map(|c| f64::from(c.trials)).sum();
        let x: f64 = counts.iter().map(|c| f64::from(c.successes)).sum();
        let p = if m > 0.0 { x / m } else { 1.0 };
        let mut icc = 0.0;
        if big_n >= 2 && p > 0.0 && p < 1.0 && m > big_n as f64 {
            let sx2m: f64 = counts
                .iter()
                .map(|c| f64::from(c.successes).powi(2) / f64::from(c.trials))
                .sum();
            let sm2: f64 = counts.iter().map(|c| f64::from(c.trials).powi(2)).sum();
            let nf = big_n as f64;
            let msb = (sx2m - x * x / m) / (nf - 1.0);
            let msw = (x - sx2m) / (m - nf);
            let m0 = (m - sm2 / m) / (nf - 1.0);
            let den = msb + (m0 - 1.0) * msw;
            if den > 0.0 {
                icc = ((msb - msw) / den).clamp(0.0, MAX_ICC);
            }
        }
        Self::with_p(p, icc, big_n, m as u64)
    }

    /// A model with mean `p` (clamped to [0, 1]) and intra-class correlation
    /// `icc`.
    pub fn with_p(p: f64, icc: f64, participants: usize, trials: u64) -> Self {
        let p = p.clamp(0.0, 1.0);
        let spread = icc > 1e-12 && p > 0.0 && p < 1.0;
        let s = (1.0 - icc) / icc;
        Self {
            p,
            icc: if spread { icc } else { 0.0 },
            beta_a: spread.then_some(p * s),
            beta_b: spread.then_some((1.0 - p) * s),
            participants,
            trials,
        }
    }
}

/// The generative model of a pilot (module docs). Variances in DV units².
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PilotModel {
    /// The DV column.
    pub dv: String,
    /// Modelled conditions, in order.
    pub conditions: Vec<String>,
    /// Complete participants the DV model was fitted to.
    pub participants: usize,
    /// Participants dropped by listwise deletion.
    pub dropped: Vec<String>,
    /// μ̂_j: mean of the participants' cell means, DV units.
    pub means: Vec<f64>,
    /// Σ̂_b (row-major k × k) after the projection, DV units².
    pub cov_participant: Vec<f64>,
    /// σ̂_u: SD of the random participant intercept.
    pub sd_participant: f64,
    /// σ̂_w,j: SD of the participant × condition effect per condition
    /// (0 where the moment estimate was negative).
    pub sd_participant_condition: Vec<f64>,
    /// σ̂_e,j: trial-level residual SD per condition.
    pub sd_residual: Vec<f64>,
    /// Harmonic mean of the kept trials per cell in the pilot.
    pub trials_per_cell: f64,
    /// The pilot's planned test trials per condition (the most common
    /// count of test rows in a cell).
    pub planned_trials: u32,
    /// Success model per condition.
    pub success: Vec<SuccessModel>,
    /// True when Σ̂_b had negative eigenvalues set to 0.
    pub clipped: bool,
    /// True when the DV is the trial outcome itself (cell value = success
    /// rate, drawn from the success model).
    pub dv_is_success: bool,
    /// Estimator used.
    pub method: &'static str,
    /// k × k factor L with L Lᵀ = Σ̂_b (row-major).
    #[serde(skip)]
    pub(crate) factor: Vec<f64>,
}

impl PilotModel {
    /// Fits the model to the kept rows and the per-participant trial counts
    /// (one vector per condition, in the order of `rows.design`).
    ///
    /// # Errors
    /// [`PowerError::TooFewParticipants`] with fewer than 2 complete
    /// participants; statistics errors of the cell matrix.
    pub fn fit(
        dv: &str,
        rows: &PilotRows,
        counts: &[Vec<TrialCount>],
        dv_is_success: bool,
    ) -> Result<Self, PowerError> {
        let design = &rows.design;
        let m = design.cell_matrix()?;
        let (n, k) = (m.n_subjects(), m.n_conditions());
        if n < 2 {
            return Err(PowerError::TooFewParticipants { got: n });
        }
        // Pooled within-cell variance per condition.
        let subj = design.subjects();
        let conds = design.conditions();
        let mut ss = vec![0.0; k];
        let mut df = vec![0.0; k];
        let mut cells: Vec<Vec<Vec<f64>>> = vec![vec![Vec::new(); k]; n];
        for (s, c, v) in &rows.rows {
            let (Some(i), Some(j)) = (
                subj.iter().position(|x| x == s),
                conds.iter().position(|x| x == c),
            ) else {
                continue;
            };
            cells[i][j].push(*v);
        }
        for row in &cells {
            for (j, cell) in row.iter().enumerate() {
                if cell.len() >= 2 {
                    let mean = compensated_mean(cell);
                    ss[j] += cell.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
                    df[j] += (cell.len() - 1) as f64;
                }
            }
        }
        let var_e: Vec<f64> = (0..k)
            .map(|j| if df[j] > 0.0 { ss[j] / df[j] } else { 0.0 })
            .collect();
        let h: Vec<f64> = (0..k)
            .map(|j| {
                (0..n)
                    .map(|i| 1.0 / design.cell_count(i, j).max(1) as f64)
                    .sum::<f64>()
                    / n as f64
            })
            .collect();
        let x = DMatrix::from_row_slice(n, k, m.values());
        let means: Vec<f64> = (0..k).map(|j| x.column(j).mean()).collect();
        let mut centred = x.clone();
        for (j, mut col) in centred.column_iter_mut().enumerate() {
            col.add_scalar_mut(-means[j]);
        }
        let mut s = (centred.transpose() * &centred) / (n as f64 - 1.0);
        for j in 0..k {
            s[(j, j)] -= var_e[j] * h[j];
        }
        let eig = SymmetricEigen::new(s);
        let lmax = eig.eigenvalues.iter().fold(0.0_f64, |a, l| a.max(l.abs()));
        let clipped = eig
            .eigenvalues
            .iter()
            .any(|&l| l < -1e-12 * lmax.max(f64::MIN_POSITIVE));
        let sqrt_l = DMatrix::from_diagonal(&eig.eigenvalues.map(|l| l.max(0.0).sqrt()));
        let factor = &eig.eigenvectors * sqrt_l;
        let cov = &factor * factor.transpose();
        let sd_u2 = if k >= 2 {
            let mut sum = 0.0;
            for a in 0..k {
                for b in 0..k {
                    if a != b {
                        sum += cov[(a, b)];
                    }
                }
            }
            sum / (k * (k - 1)) as f64
        } else {
            0.0
        };
        let total_cells: f64 = h.iter().sum::<f64>() / k as f64;
        let mut counts_all: Vec<u32> = counts.iter().flatten().map(|c| c.trials).collect();
        counts_all.sort_unstable();
        let planned_trials = mode(&counts_all).unwrap_or(1).max(1);
        Ok(Self {
            dv: dv.to_owned(),
            conditions: conds.to_vec(),
            participants: n,
            dropped: rows.dropped.clone(),
            means,
            cov_participant: (0..k * k).map(|q| cov[(q / k, q % k)]).collect(),
            sd_participant: sd_u2.max(0.0).sqrt(),
            sd_participant_condition: (0..k)
                .map(|j| (cov[(j, j)] - sd_u2).max(0.0).sqrt())
                .collect(),
            sd_residual: var_e.iter().map(|v| v.sqrt()).collect(),
            trials_per_cell: 1.0 / total_cells,
            planned_trials,
            success: counts.iter().map(|c| SuccessModel::fit(c)).collect(),
            clipped,
            dv_is_success,
            method: "method of moments (unbiased; Σ_b projected to PSD)",
            factor: (0..k * k).map(|q| factor[(q / k, q % k)]).collect(),
        })
    }

    /// Number of modelled conditions k.
    pub fn k(&self) -> usize {
        self.conditions.len()
    }

    /// The model's variance of the cell-mean difference of conditions `a`
    /// and `b` (indices) when every cell has `trials` kept trials, DV units².
    pub fn var_diff(&self, a: usize, b: usize, trials: f64) -> f64 {
        let k = self.k();
        let c = &self.cov_participant;
        let se = |j: usize| self.sd_residual[j].powi(2) / trials;
        c[a * k + a] + c[b * k + b] - 2.0 * c[a * k + b] + se(a) + se(b)
    }
}

/// Most common value of a sorted slice (the largest on ties).
fn mode(sorted: &[u32]) -> Option<u32> {
    let mut best: Option<(usize, u32)> = None;
    let mut i = 0;
    while i < sorted.len() {
        let v = sorted[i];
        let run = sorted[i..].iter().take_while(|&&x| x == v).count();
        if best.is_none_or(|(r, _)| run >= r) {
            best = Some((run, v));
        }
        i += run;
    }
    best.map(|(_, v)| v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn beta_binomial_icc_is_zero_for_equal_rates_and_large_for_split_rates() {
        let same: Vec<TrialCount> = (0..8)
            .map(|_| TrialCount {
                trials: 10,
                successes: 7,
            })
            .collect();
        let s = SuccessModel::fit(&same);
        assert!((s.p - 0.7).abs() < 1e-12);
        assert_eq!(s.icc, 0.0);
        let split: Vec<TrialCount> = (0..8)
            .map(|i| TrialCount {
                trials: 10,
                successes: if i % 2 == 0 { 10 } else { 4 },
            })
            .collect();
        let s = SuccessModel::fit(&split);
        assert!((s.p - 0.7).abs() < 1e-12);
        // By hand: Σx²/m = 46.4, (Σx)²/M = 39.2, MSB = 7.2/7, MSW = 9.6/72,
        // m₀ = 10, ρ̂ = (MSB − MSW)/(MSB + 9 MSW) = 0.401709…
        assert!((s.icc - 0.401_709).abs() < 1e-6, "{s:?}");
        let a = s.beta_a.unwrap_or(0.0);
        let b = s.beta_b.unwrap_or(0.0);
        assert!((a / (a + b) - 0.7).abs() < 1e-12);
        assert!((1.0 / (a + b + 1.0) - s.icc).abs() < 1e-12);
    }

    #[test]
    fn mode_prefers_the_most_common_count() {
        assert_eq!(mode(&[8, 9, 10, 10, 10]), Some(10));
        assert_eq!(mode(&[]), None);
    }
}
