//! Paired comparisons: Student's t, Wilcoxon's signed-rank test, Holm's
//! step-down correction and the all-pairs post-hoc tables.
//!
//! Wilcoxon (1945); Holm (1979); the Wilcoxon method selection reproduces
//! `scipy.stats.wilcoxon` (scipy 1.17, defaults `zero_method="wilcox"`,
//! `correction=False`, `method="auto"`). Equations in `docs/theory/statistics.md`.

use serde::Serialize;

use super::anova::{negligible, unit_divisor};
use super::design::CellMatrix;
use super::dist::{normal_two_sided, t_two_sided};
use super::error::{Result, StatsError};
use super::rank::{doubled_ranks, tie_term};

fn check_finite(what: &str, x: &[f64]) -> Result<()> {
    match x.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        Some((index, &value)) => Err(StatsError::NonFiniteInput {
            what: what.to_owned(),
            index,
            value,
        }),
        None => Ok(()),
    }
}

fn differences(x: &[f64], y: &[f64]) -> Result<Vec<f64>> {
    if x.len() != y.len() {
        return Err(StatsError::LengthMismatch {
            what: "paired samples",
            left: x.len(),
            right: y.len(),
        });
    }
    check_finite("x", x)?;
    check_finite("y", y)?;
    let d: Vec<f64> = x.iter().zip(y).map(|(a, b)| a - b).collect();
    if let Some(i) = d.iter().position(|v| !v.is_finite()) {
        return Err(StatsError::Numerical {
            what: "paired differences",
            detail: format!(
                "x − y overflows a 64-bit float at pair {i} ({} − {}); rescale the variable",
                x[i], y[i]
            ),
        });
    }
    Ok(d)
}

/// Result of a one-sample or paired t-test (two-sided).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TTest {
    /// t = (mean − μ0) / (sd / √n).
    pub t: f64,
    /// Degrees of freedom n − 1.
    pub df: f64,
    /// Two-sided p-value.
    pub p: f64,
    /// Mean of the sample (of the differences x − y for a paired test).
    pub mean: f64,
    /// Sample standard deviation (n − 1 denominator).
    pub sd: f64,
    /// Cohen's d_z = (mean − μ0) / sd.
    pub cohen_d: f64,
    /// Sample size n (pairs).
    pub n: usize,
}

/// One-sample t-test of H0: E\[x\] = `mu0` (two-sided).
///
/// # Errors
/// n < 2, non-finite data, or zero sample variance.
pub fn one_sample_t(x: &[f64], mu0: f64) -> Result<TTest> {
    const TEST: &str = "t-test";
    check_finite("x", x)?;
    if !mu0.is_finite() {
        return Err(StatsError::NonFiniteInput {
            what: "mu0".into(),
            index: 0,
            value: mu0,
        });
    }
    let n = x.len();
    if n < 2 {
        return Err(StatsError::TooFewSubjects {
            test: TEST,
            needed: 2,
            got: n,
        });
    }
    let nf = n as f64;
    let scale = x.iter().fold(mu0.abs(), |a, v| a.max(v.abs()));
    // Moments of the data divided by `u` (magnitude ≤ 1): neither the sum
    // of squares nor its rounding bound overflows.
    let u = unit_divisor(scale);
    let mean = x.iter().map(|v| v / u).sum::<f64>() / nf;
    let ss: f64 = x.iter().map(|v| (v / u - mean) * (v / u - mean)).sum();
    if negligible(ss, n, scale / u) {
        return Err(StatsError::ZeroVariance {
            test: TEST,
            detail: "all values (differences) are equal, so t is unbounded or undefined".into(),
        });
    }
    let sd = (ss / (nf - 1.0)).sqrt();
    let t = (mean - mu0 / u) / (sd / nf.sqrt());
    let df = nf - 1.0;
    Ok(TTest {
        t,
        df,
        p: t_two_sided(t, df)?,
        mean: mean * u,
        sd: sd * u,
        cohen_d: (mean - mu0 / u) / sd,
        n,
    })
}

/// Paired t-test of x against y: the one-sample t-test of d = x − y
/// against 0.
///
/// # Errors
/// As [`one_sample_t`], plus a length mismatch.
pub fn paired_t(x: &[f64], y: &[f64]) -> Result<TTest> {
    one_sample_t(&differences(x, y)?, 0.0)
}

/// How the p-value of Wilcoxon's test is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WilcoxonMethod {
    /// scipy's `method="auto"`: exact when the sample (zeros included) has
    /// at most 50 differences and no ties or zeros; the exact conditional
    /// (permutation) distribution when there are ties or zeros and at most
    /// 13 differences; otherwise the normal approximation.
    #[default]
    Auto,
    /// Exact null distribution of R⁺ given the observed (mid-)ranks, by
    /// enumerating all 2^m sign patterns through a convolution (equals the
    /// classical Wilcoxon distribution without ties). Cost O(m³) time and
    /// O(m²) memory, so above [`EXACT_MAX_N`] non-zero differences the
    /// normal approximation is used instead (reported in
    /// [`WilcoxonTest::method`]).
    Exact,
    /// Normal approximation with tie-corrected variance.
    Asymptotic,
}

/// Largest number of non-zero differences for which
/// [`WilcoxonMethod::Exact`] computes the exact distribution.
pub const EXACT_MAX_N: usize = 1000;

/// Options of [`wilcoxon_signed_rank`] (defaults = scipy's defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct WilcoxonOptions {
    /// p-value method.
    pub method: WilcoxonMethod,
    /// Continuity correction (±½) in the normal approximation.
    pub continuity: bool,
}

/// The method actually used for a Wilcoxon p-value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WilcoxonMethodUsed {
    /// Exact distribution (no ties, no zeros).
    Exact,
    /// Exact conditional (permutation) distribution given tied ranks/zeros.
    ExactConditional,
    /// Normal approximation.
    Normal,
}

/// Result of Wilcoxon's signed-rank test (two-sided).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WilcoxonTest {
    /// min(R⁺, R⁻), the statistic scipy reports for a two-sided test.
    pub statistic: f64,
    /// Sum of the ranks of positive differences.
    pub r_plus: f64,
    /// Sum of the ranks of negative differences.
    pub r_minus: f64,
    /// Number of non-zero differences ranked.
    pub n_nonzero: usize,
    /// Number of zero differences (discarded, Wilcoxon's convention).
    pub n_zero: usize,
    /// Whether non-zero |d| had ties.
    pub ties: bool,
    /// z of the normal approximation (continuity-corrected if requested),
    /// `None` for an exact p.
    pub z: Option<f64>,
    /// Two-sided p-value.
    pub p: f64,
    /// Method used.
    pub method: WilcoxonMethodUsed,
}

/// Wilcoxon's signed-rank test of the paired samples `x`, `y` (d = x − y).
///
/// # Errors
/// Length mismatch, non-finite values, no pair, or all differences zero.
pub fn wilcoxon_signed_rank(x: &[f64], y: &[f64], opts: WilcoxonOptions) -> Result<WilcoxonTest> {
    wilcoxon_signed_rank_diffs(&differences(x, y)?, opts)
}

/// Exact two-sided p of R⁺ (doubled ranks `dr`, observed doubled sum `obs`)
/// under independent fair signs: 2·min(P(T ≤ obs), P(T ≥ obs)), capped at 1.
fn exact_p(dr: &[u64], obs: u64) -> f64 {
    let total: u64 = dr.iter().sum();
    let len = usize::try_from(total)
        .unwrap_or(usize::MAX)
        .saturating_add(1);
    let mut pmf = vec![0.0_f64; len];
    pmf[0] = 1.0;
    let mut reach = 0_usize;
    for &r in dr {
        let r = usize::try_from(r).unwrap_or(usize::MAX);
        // Convolve with ½(δ0 + δr), from the top down to stay in place.
        for s in (0..=reach).rev() {
            let v = pmf[s] * 0.5;
            pmf[s] = v;
            pmf[s + r] += v;
        }
        reach += r;
    }
    let obs = usize::try_from(obs).unwrap_or(usize::MAX).min(len - 1);
    let lower: f64 = pmf[..=obs].iter().sum();
    let upper: f64 = pmf[obs..].iter().sum();
    (2.0 * lower.min(upper)).min(1.0)
}

/// Wilcoxon's signed-rank test on differences `d` (zeros discarded).
///
/// # Errors
/// Non-finite values, no difference, or all differences zero.
pub fn wilcoxon_signed_rank_diffs(d: &[f64], opts: WilcoxonOptions) -> Result<WilcoxonTest> {
    const TEST: &str = "Wilcoxon signed-rank test";
    check_finite("differences", d)?;
    let n_total = d.len();
    let nonzero: Vec<f64> = d.iter().copied().filter(|&v| v != 0.0).collect();
    let n_zero = n_total - nonzero.len();
    let m = nonzero.len();
    if m == 0 {
        return Err(StatsError::ZeroVariance {
            test: TEST,
            detail: if n_total == 0 {
                "no paired observation".into()
            } else {
                "all differences are zero".into()
            },
        });
    }
    let abs: Vec<f64> = nonzero.iter().map(|v| v.abs()).collect();
    let (dr, ties) = doubled_ranks(&abs);
    let plus2: u64 = dr
        .iter()
        .zip(&nonzero)
        .filter(|&(_, &v)| v > 0.0)
        .map(|(&r, _)| r)
        .sum();
    let total2: u64 = dr.iter().sum();
    let r_plus = plus2 as f64 / 2.0;
    let r_minus = (total2 - plus2) as f64 / 2.0;
    let has_ties = !ties.is_empty();

    let method = match opts.method {
        WilcoxonMethod::Exact if m > EXACT_MAX_N => WilcoxonMethodUsed::Normal,
        WilcoxonMethod::Exact if has_ties || n_zero > 0 => WilcoxonMethodUsed::ExactConditional,
        WilcoxonMethod::Exact => WilcoxonMethodUsed::Exact,
        WilcoxonMethod::Asymptotic => WilcoxonMethodUsed::Normal,
        WilcoxonMethod::Auto => {
            if n_total > 50 {
                WilcoxonMethodUsed::Normal
            } else if !has_ties && n_zero == 0 {
                WilcoxonMethodUsed::Exact
            } else if n_total <= 13 {
                WilcoxonMethodUsed::ExactConditional
            } else {
                WilcoxonMethodUsed::Normal
            }
        }
    };

    let (z, p) = match method {
        WilcoxonMethodUsed::Exact | WilcoxonMethodUsed::ExactConditional => {
            (None, exact_p(&dr, plus2))
        }
        WilcoxonMethodUsed::Normal => {
            let mf = m as f64;
            let mean = mf * (mf + 1.0) / 4.0;
            let var = (mf * (mf + 1.0) * (2.0 * mf + 1.0) - tie_term(&ties) / 2.0) / 24.0;
            if var <= 0.0 {
                return Err(StatsError::ZeroVariance {
                    test: TEST,
                    detail: "the rank variance is zero".into(),
                });
            }
            let se = var.sqrt();
            let mut z = (r_plus - mean) / se;
            if opts.continuity && z != 0.0 {
                z -= z.signum() * 0.5 / se;
            }
            (Some(z), normal_two_sided(z)?)
        }
    };
    Ok(WilcoxonTest {
        statistic: r_plus.min(r_minus),
        r_plus,
        r_minus,
        n_nonzero: m,
        n_zero,
        ties: has_ties,
        z,
        p,
        method,
    })
}

/// Holm's (1979) step-down adjusted p-values, in the input order.
///
/// With p_(1) ≤ … ≤ p_(m): p̃_(i) = min(1, max_{j ≤ i} (m − j + 1) p_(j)).
/// The adjusted values are ≥ the raw ones and monotone in the raw order.
///
/// # Errors
/// [`StatsError::InvalidPValue`] for a value outside [0, 1] or NaN.
pub fn holm(p: &[f64]) -> Result<Vec<f64>> {
    if let Some((index, &value)) = p
        .iter()
        .enumerate()
        .find(|(_, v)| !(0.0..=1.0).contains(*v))
    {
        return Err(StatsError::InvalidPValue { index, value });
    }
    let m = p.len();
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| p[a].total_cmp(&p[b]));
    let mut adjusted = vec![0.0; m];
    let mut running = 0.0_f64;
    for (rank, &i) in order.iter().enumerate() {
        running = running.max(((m - rank) as f64 * p[i]).min(1.0));
        adjusted[i] = running;
    }
    Ok(adjusted)
}

/// One row of a post-hoc table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairwiseComparison {
    /// First condition (x in d = x − y).
    pub a: String,
    /// Second condition.
    pub b: String,
    /// `"paired_t"` or `"wilcoxon"`.
    pub test: &'static str,
    /// t, or min(R⁺, R⁻) for Wilcoxon.
    pub statistic: f64,
    /// Degrees of freedom (t-test only).
    pub df: Option<f64>,
    /// Mean (t-test) or median (Wilcoxon) of the differences a − b.
    pub estimate: f64,
    /// Unadjusted two-sided p-value.
    pub p: f64,
    /// Holm-adjusted p-value over all k(k−1)/2 pairs.
    pub p_holm: f64,
    /// Wilcoxon p-value method (Wilcoxon only).
    pub method: Option<WilcoxonMethodUsed>,
}

fn pairs(k: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..k).flat_map(move |i| (i + 1..k).map(move |j| (i, j)))
}

fn with_holm(mut rows: Vec<PairwiseComparison>) -> Result<Vec<PairwiseComparison>> {
    let p: Vec<f64> = rows.iter().map(|r| r.p).collect();
    for (row, adj) in rows.iter_mut().zip(holm(&p)?) {
        row.p_holm = adj;
    }
    Ok(rows)
}

fn name_pair(e: StatsError, a: &str, b: &str) -> StatsError {
    match e {
        StatsError::ZeroVariance { test, detail } => StatsError::ZeroVariance {
            test,
            detail: format!("pair `{a}` vs `{b}`: {detail}"),
        },
        other => other,
    }
}

/// All pairwise paired t-tests between the conditions of `m` (pairs in
/// column order), Holm-corrected.
///
/// # Errors
/// As [`paired_t`]; a zero-variance pair is named.
pub fn pairwise_t(m: &CellMatrix) -> Result<Vec<PairwiseComparison>> {
    let c = m.conditions();
    let mut rows = Vec::new();
    for (i, j) in pairs(m.n_conditions()) {
        let t = paired_t(&m.column(i), &m.column(j)).map_err(|e| name_pair(e, &c[i], &c[j]))?;
        rows.push(PairwiseComparison {
            a: c[i].clone(),
            b: c[j].clone(),
            test: "paired_t",
            statistic: t.t,
            df: Some(t.df),
            estimate: t.mean,
            p: t.p,
            p_holm: f64::NAN,
            method: None,
        });
    }
    with_holm(rows)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// All pairwise Wilcoxon signed-rank tests between the conditions of `m`,
/// Holm-corrected.
///
/// # Errors
/// As [`wilcoxon_signed_rank`]; a pair whose differences are all zero is
/// named.
pub fn pairwise_wilcoxon(m: &CellMatrix, opts: WilcoxonOptions) -> Result<Vec<PairwiseComparison>> {
    let c = m.conditions();
    let mut rows = Vec::new();
    for (i, j) in pairs(m.n_conditions()) {
        let (x, y) = (m.column(i), m.column(j));
        let w = wilcoxon_signed_rank(&x, &y, opts).map_err(|e| name_pair(e, &c[i], &c[j]))?;
        rows.push(PairwiseComparison {
            a: c[i].clone(),
            b: c[j].clone(),
            test: "wilcoxon",
            statistic: w.statistic,
            df: None,
            estimate: median(x.iter().zip(&y).map(|(a, b)| a - b).collect()),
            p: w.p,
            p_holm: f64::NAN,
            method: Some(w.method),
        });
    }
    with_holm(rows)
}

/// One condition pair of [`pairwise_tests`]: the paired t-test and
/// Wilcoxon's signed-rank test of d = a − b over participants, with effect
/// sizes. A statistic that is undefined for this pair (zero variance of the
/// differences, all differences zero) is `None` and its reason is in
/// `undefined`; the other pairs are unaffected.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairTest {
    /// First condition (x in d = x − y).
    pub a: String,
    /// Second condition.
    pub b: String,
    /// Participants (pairs).
    pub n: usize,
    /// Paired t.
    pub t: Option<f64>,
    /// Degrees of freedom n − 1.
    pub df: Option<f64>,
    /// Two-sided p of the t-test.
    pub p: Option<f64>,
    /// Holm-adjusted p over the pairs whose t is defined.
    pub p_holm: Option<f64>,
    /// Wilcoxon's statistic min(R⁺, R⁻) (scipy's two-sided statistic).
    pub wilcoxon_w: Option<f64>,
    /// Two-sided p of Wilcoxon's test (scipy defaults).
    pub wilcoxon_p: Option<f64>,
    /// Holm-adjusted Wilcoxon p over the pairs whose test is defined.
    pub wilcoxon_p_holm: Option<f64>,
    /// How the Wilcoxon p was computed.
    pub wilcoxon_method: Option<WilcoxonMethodUsed>,
    /// Cohen's d_z = mean(d) / sd(d).
    pub dz: Option<f64>,
    /// 95 % interval of d_z ([`super::effect::dz_ci`]).
    pub dz_ci: Option<[f64; 2]>,
    /// Mean difference mean(a − b), in the unit of the dependent variable.
    pub mean_diff: f64,
    /// 95 % t interval of the mean difference: mean ± t₀.₉₇₅(n−1) sd/√n.
    pub mean_diff_ci: Option<[f64; 2]>,
    /// Why a statistic of this pair is undefined (empty: all defined).
    pub undefined: Vec<String>,
}

/// All condition pairs of a complete cell matrix (the post-hoc table).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PairwiseTests {
    /// Pairs in column order: (0,1), (0,2), …, (1,2), …
    pub pairs: Vec<PairTest>,
}

/// Holm over the defined entries of `p` (undefined ones stay `None`).
fn holm_defined(p: &[Option<f64>]) -> Result<Vec<Option<f64>>> {
    let defined: Vec<f64> = p.iter().flatten().copied().collect();
    let mut adj = holm(&defined)?.into_iter();
    Ok(p.iter().map(|v| v.and_then(|_| adj.next())).collect())
}

/// Paired t and Wilcoxon tests for every pair of conditions of `m`, each
/// family Holm-corrected, with d_z and the mean difference and their 95 %
/// intervals. A pair where a test is undefined keeps its row with `None`
/// values and the reason (reference: pingouin `pairwise_tests(...,
/// padjust="holm")`, scipy `wilcoxon`).
///
/// # Errors
/// Fewer than 2 subjects or conditions.
pub fn pairwise_tests(m: &CellMatrix, opts: WilcoxonOptions) -> Result<PairwiseTests> {
    m.require_at_least_2x2("pairwise tests")?;
    let c = m.conditions();
    let n = m.n_subjects();
    let q = t_quantile_975(n as f64 - 1.0)?;
    let mut rows = Vec::new();
    for (i, j) in pairs(m.n_conditions()) {
        let (x, y) = (m.column(i), m.column(j));
        let d = differences(&x, &y)?;
        let mut row = PairTest {
            a: c[i].clone(),
            b: c[j].clone(),
            n,
            t: None,
            df: None,
            p: None,
            p_holm: None,
            wilcoxon_w: None,
            wilcoxon_p: None,
            wilcoxon_p_holm: None,
            wilcoxon_method: None,
            dz: None,
            dz_ci: None,
            mean_diff: super::design::compensated_mean(&d),
            mean_diff_ci: None,
            undefined: Vec::new(),
        };
        if !row.mean_diff.is_finite() {
            return Err(StatsError::Numerical {
                what: "pairwise tests",
                detail: format!(
                    "the mean difference of `{}` − `{}` overflows a 64-bit float; rescale the \
                     variable",
                    row.a, row.b
                ),
            });
        }
        match one_sample_t(&d, 0.0) {
            Ok(t) => {
                let half = q * t.sd / (n as f64).sqrt();
                row.t = Some(t.t);
                row.df = Some(t.df);
                row.p = Some(t.p);
                row.dz = Some(t.cohen_d);
                row.dz_ci = Some(super::effect::dz_ci(t.cohen_d, n));
                row.mean_diff_ci = Some([t.mean - half, t.mean + half]);
            }
            Err(e) => row.undefined.push(format!("t-test: {e}")),
        }
        match wilcoxon_signed_rank_diffs(&d, opts) {
            Ok(w) => {
                row.wilcoxon_w = Some(w.statistic);
                row.wilcoxon_p = Some(w.p);
                row.wilcoxon_method = Some(w.method);
            }
            Err(e) => row.undefined.push(format!("Wilcoxon: {e}")),
        }
        rows.push(row);
    }
    let pt: Vec<Option<f64>> = rows.iter().map(|r| r.p).collect();
    let pw: Vec<Option<f64>> = rows.iter().map(|r| r.wilcoxon_p).collect();
    for ((r, a), b) in rows
        .iter_mut()
        .zip(holm_defined(&pt)?)
        .zip(holm_defined(&pw)?)
    {
        r.p_holm = a;
        r.wilcoxon_p_holm = b;
    }
    Ok(PairwiseTests { pairs: rows })
}

/// t₀.₉₇₅ of Student's t with `df` degrees of freedom.
fn t_quantile_975(df: f64) -> Result<f64> {
    use statrs::distribution::{ContinuousCDF, StudentsT};
    let t = StudentsT::new(0.0, 1.0, df).map_err(|e| StatsError::Numerical {
        what: "t distribution",
        detail: e.to_string(),
    })?;
    // statrs inverts numerically; one Newton step on the accurate tail
    // function polishes the root: f(q) = p(|T| > q) − 0.05.
    let mut q = t.inverse_cdf(0.975);
    for _ in 0..3 {
        let f = t_two_sided(q, df)? - 0.05;
        let dens = 2.0 * statrs::distribution::Continuous::pdf(&t, q);
        if dens > 0.0 {
            q += f / dens;
        }
    }
    Ok(q)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_p_without_ties_is_the_wilcoxon_distribution() {
        // n = 3, ranks 1..3: sums over 8 sign patterns
        // 0,1,2,3,3,4,5,6 -> P(T <= 0) = 1/8.
        let dr = [2, 4, 6];
        assert!((exact_p(&dr, 0) - 0.25).abs() < 1e-15);
        assert!((exact_p(&dr, 12) - 0.25).abs() < 1e-15);
        assert_eq!(exact_p(&dr, 6), 1.0);
    }

    #[test]
    fn holm_small_example() {
        // Sorted 0.01, 0.02, 0.04 with m = 3: 0.03, 0.04, 0.04.
        let adj = holm(&[0.04, 0.01, 0.02]).unwrap();
        let want = [0.04, 0.03, 0.04];
        for (a, w) in adj.iter().zip(want) {
            assert!((a - w).abs() < 1e-15);
        }
        assert!(holm(&[]).unwrap().is_empty());
        assert!(matches!(
            holm(&[0.5, f64::NAN]),
            Err(StatsError::InvalidPValue { index: 1, .. })
        ));
        assert!(holm(&[1.5]).is_err());
    }
}
