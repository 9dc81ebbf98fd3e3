//! Friedman's rank test with Kendall's W and the Iman–Davenport F form.
//!
//! Friedman (1937); tie correction as in `scipy.stats.friedmanchisquare`
//! (Hollander & Wolfe); Kendall & Babington Smith (1939); Iman & Davenport
//! (1980). Equations in `docs/theory/statistics.md`.

use serde::Serialize;

use super::design::CellMatrix;
use super::dist::{chi2_sf, f_sf};
use super::effect::{BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, CONFIDENCE, quantile_sorted};
use super::error::{Result, StatsError};
use super::rank::doubled_ranks_into;
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{Rng, SeedableRng};

/// Result of Friedman's test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Friedman {
    /// Tie-corrected Friedman statistic χ²_F.
    pub chi2: f64,
    /// Degrees of freedom k − 1.
    pub df: f64,
    /// P(χ²(k−1) > χ²_F).
    pub p: f64,
    /// Kendall's coefficient of concordance W = χ²_F / (n (k − 1)), in [0, 1]
    /// (with ties this equals Kendall's tie-corrected W).
    pub kendall_w: f64,
    /// 95 % percentile-bootstrap interval of W over participants
    /// ([`super::effect`]); `None` when the bootstrap cannot run.
    pub kendall_w_ci: Option<[f64; 2]>,
    /// Iman–Davenport F = (n − 1) χ²_F / (n (k − 1) − χ²_F); `None` when
    /// W = 1 (perfect concordance), where F is unbounded.
    pub f_iman_davenport: Option<f64>,
    /// Numerator df of the F form, k − 1.
    pub df1_f: f64,
    /// Denominator df of the F form, (n − 1)(k − 1).
    pub df2_f: f64,
    /// P(F(df1_f, df2_f) > F); 0 when W = 1.
    pub p_f: f64,
    /// Tie correction divisor C = 1 − Σ(t³ − t) / (n k (k² − 1)) (1 = no ties).
    pub tie_correction: f64,
    /// Mean rank of each condition (column order).
    pub mean_ranks: Vec<f64>,
    /// Number of subjects (blocks) n.
    pub n_subjects: usize,
    /// Number of conditions k.
    pub n_conditions: usize,
}

/// Friedman's test on a complete subjects × conditions matrix: values are
/// ranked within each subject (average ranks for ties).
///
/// Cost: one sort of k values per subject, O(n · k log k), and the
/// bootstrap interval of W re-uses those ranks (a resample only re-adds
/// rank sums), O(B · n · k) for B resamples: no step is quadratic in n.
///
/// # Errors
/// Fewer than 2 subjects or 2 conditions; every subject's values tied
/// across all conditions ([`StatsError::ZeroVariance`]).
pub fn friedman(m: &CellMatrix) -> Result<Friedman> {
    const TEST: &str = "Friedman test";
    let (n, k) = m.require_at_least_2x2(TEST)?;
    let blocks = BlockRanks::of(m);
    let mut doubled_sums = vec![0_u64; k];
    for i in 0..n {
        for (s, &r) in doubled_sums.iter_mut().zip(blocks.row(i)) {
            *s += r;
        }
    }
    let ties: f64 = blocks.ties.iter().sum();
    let chi2 = chi2_of(n, k, &doubled_sums, ties).ok_or_else(|| StatsError::ZeroVariance {
        test: TEST,
        detail: "every subject has the same value in all conditions (all ranks tied)".into(),
    })?;
    let (nf, kf) = (n as f64, k as f64);
    let df = kf - 1.0;
    let kendall_w = (chi2 / (nf * df)).min(1.0);
    let df1_f = df;
    let df2_f = (nf - 1.0) * df;
    let den = nf * df - chi2;
    let (f_iman_davenport, p_f) = if den <= 1e-12 * nf * df {
        (None, 0.0)
    } else {
        let f = (nf - 1.0) * chi2 / den;
        (Some(f), f_sf(f, df1_f, df2_f)?)
    };
    Ok(Friedman {
        chi2,
        df,
        p: chi2_sf(chi2, df)?,
        kendall_w,
        kendall_w_ci: Some(kendall_w_ci(&blocks, n, k)),
        f_iman_davenport,
        df1_f,
        df2_f,
        p_f,
        tie_correction: 1.0 - ties / (nf * kf * (kf * kf - 1.0)),
        mean_ranks: doubled_sums.iter().map(|&r| r as f64 / 2.0 / nf).collect(),
        n_subjects: n,
        n_conditions: k,
    })
}

/// The within-subject ranks of a matrix: doubled mid-ranks (exact
/// integers) row-major, and each subject's tie term Σ (t³ − t).
struct BlockRanks {
    k: usize,
    doubled: Vec<u64>,
    ties: Vec<f64>,
}

impl BlockRanks {
    fn of(m: &CellMatrix) -> Self {
        let (n, k) = (m.n_subjects(), m.n_conditions());
        let mut doubled = vec![0_u64; n * k];
        let mut ties = Vec::with_capacity(n);
        let mut order = Vec::with_capacity(k);
        for (i, out) in doubled.chunks_exact_mut(k).enumerate() {
            ties.push(doubled_ranks_into(m.row(i), &mut order, out));
        }
        Self { k, doubled, ties }
    }

    fn row(&self, i: usize) -> &[u64] {
        &self.doubled[i * self.k..(i + 1) * self.k]
    }
}

/// Tie-corrected χ²_F from the doubled rank sums of n subjects × k
/// conditions and the summed tie term; `None` when every rank is tied
/// (tie correction C ≤ 0).
fn chi2_of(n: usize, k: usize, doubled_sums: &[u64], ties: f64) -> Option<f64> {
    let (nf, kf) = (n as f64, k as f64);
    let c = 1.0 - ties / (nf * kf * (kf * kf - 1.0));
    if c <= 0.0 {
        return None;
    }
    let ssbn: f64 = doubled_sums
        .iter()
        .map(|&s| {
            let r = s as f64 / 2.0;
            r * r
        })
        .sum();
    let raw = 12.0 / (nf * kf * (kf + 1.0)) * ssbn - 3.0 * nf * (kf + 1.0);
    Some((raw / c).max(0.0))
}

/// Percentile-bootstrap interval of Kendall's W: participants (rows)
/// resampled with replacement, [`BOOTSTRAP_RESAMPLES`] times with the fixed
/// seed [`BOOTSTRAP_SEED`]; a resample in which every participant ties all
/// conditions counts as W = 0. A resampled participant keeps its ranks, so
/// a resample only adds up precomputed rank rows.
fn kendall_w_ci(blocks: &BlockRanks, n: usize, k: usize) -> [f64; 2] {
    let mut rng = ChaCha8Rng::seed_from_u64(BOOTSTRAP_SEED);
    let mut ws = Vec::with_capacity(BOOTSTRAP_RESAMPLES);
    let mut sums = vec![0_u64; k];
    let df = k as f64 - 1.0;
    for _ in 0..BOOTSTRAP_RESAMPLES {
        sums.fill(0);
        let mut ties = 0.0;
        for _ in 0..n {
            // Modulo bias < n / 2⁶⁴: negligible.
            let s = usize::try_from(rng.next_u64() % n as u64).unwrap_or(0);
            for (acc, &r) in sums.iter_mut().zip(blocks.row(s)) {
                *acc += r;
            }
            ties += blocks.ties[s];
        }
        ws.push(chi2_of(n, k, &sums, ties).map_or(0.0, |chi2| (chi2 / (n as f64 * df)).min(1.0)));
    }
    ws.sort_by(f64::total_cmp);
    let alpha = 1.0 - CONFIDENCE;
    [
        quantile_sorted(&ws, alpha / 2.0),
        quantile_sorted(&ws, 1.0 - alpha / 2.0),
    ]
}
