//! One-way (between-groups) and one-factor repeated-measures ANOVA.
//!
//! Formulas: Maxwell & Delaney (2004), *Designing Experiments and Analyzing
//! Data*, ch. 3 (one-way) and ch. 11 (one within factor); sphericity:
//! Mauchly (1940), Greenhouse & Geisser (1959), Huynh & Feldt (1976),
//! Lecoutre (1991); effect sizes: Olejnik & Algina (2003). See
//! `docs/theory/statistics.md` for the equations.

use nalgebra::{DMatrix, SymmetricEigen};
use serde::Serialize;

use super::design::{CellMatrix, Design};
use super::dist::{chi2_sf, f_sf};
use super::effect::eta2_ci_from_f;
use super::error::{Result, StatsError};

/// True when a sum of squares of `terms` residuals is indistinguishable from
/// rounding noise for data of magnitude `scale`: each residual carries an
/// error of a few ulps of `scale`, so SS ≤ terms·(16 ε scale)² is "zero".
pub(crate) fn negligible(ss: f64, terms: usize, scale: f64) -> bool {
    let unit = 16.0 * f64::EPSILON * scale;
    ss <= terms as f64 * unit * unit
}

/// The divisor that brings data of largest magnitude `scale` to magnitude
/// 1 (1 for all-zero data): sums of squares are formed from scaled data so
/// that neither they nor the rounding bound of [`negligible`] overflow
/// (|x| up to f64::MAX) or underflow.
pub(crate) fn unit_divisor(scale: f64) -> f64 {
    if scale > 0.0 && scale.is_finite() {
        scale
    } else {
        1.0
    }
}

/// Result of a one-way between-groups ANOVA.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OneWayAnova {
    /// F = MS_between / MS_within.
    #[serde(rename = "F")]
    pub f: f64,
    /// Numerator degrees of freedom, k − 1.
    pub df1: f64,
    /// Denominator degrees of freedom, N − k.
    pub df2: f64,
    /// P(F(df1, df2) > F).
    pub p: f64,
    /// Between-groups sum of squares Σ n_j (ȳ_j − ȳ)².
    pub ss_between: f64,
    /// Within-groups sum of squares Σ Σ (y_ij − ȳ_j)².
    pub ss_within: f64,
    /// η² = SS_between / SS_total.
    pub eta2: f64,
    /// 95 % noncentral-F interval of η² ([`super::effect`]); `None` when it
    /// cannot be computed.
    pub eta2_ci: Option<[f64; 2]>,
    /// Number of groups k.
    pub n_groups: usize,
    /// Total number of observations N.
    pub n_total: usize,
}

/// One-way between-groups ANOVA on `groups` (one slice per group).
///
/// # Errors
/// Fewer than 2 groups, an empty group, N − k < 1, non-finite values, or zero
/// within-group variance ([`StatsError::ZeroVariance`]).
pub fn one_way_anova<G: AsRef<[f64]>>(groups: &[G]) -> Result<OneWayAnova> {
    const TEST: &str = "one-way ANOVA";
    let k = groups.len();
    if k < 2 {
        return Err(StatsError::TooFewConditions {
            test: TEST,
            needed: 2,
            got: k,
        });
    }
    let mut n_total = 0;
    let mut scale = 0.0_f64;
    for (gi, g) in groups.iter().enumerate() {
        let g = g.as_ref();
        if g.is_empty() {
            return Err(StatsError::EmptyGroup {
                test: TEST,
                group: gi.to_string(),
            });
        }
        for (i, &v) in g.iter().enumerate() {
            if !v.is_finite() {
                return Err(StatsError::NonFiniteInput {
                    what: format!("group {gi}"),
                    index: i,
                    value: v,
                });
            }
            scale = scale.max(v.abs());
        }
        n_total += g.len();
    }
    if n_total <= k {
        return Err(StatsError::TooFewSubjects {
            test: TEST,
            needed: k + 1,
            got: n_total,
        });
    }
    // Sums of squares of the data divided by `u` (magnitude ≤ 1).
    let u = unit_divisor(scale);
    let grand = groups
        .iter()
        .flat_map(|g| g.as_ref())
        .map(|v| v / u)
        .sum::<f64>()
        / n_total as f64;
    let mut ss_between = 0.0;
    let mut ss_within = 0.0;
    for g in groups {
        let g = g.as_ref();
        let m = g.iter().map(|v| v / u).sum::<f64>() / g.len() as f64;
        ss_between += g.len() as f64 * (m - grand) * (m - grand);
        ss_within += g.iter().map(|&v| (v / u - m) * (v / u - m)).sum::<f64>();
    }
    if negligible(ss_within, n_total, scale / u) {
        return Err(StatsError::ZeroVariance {
            test: TEST,
            detail: "every group is constant (within-group sum of squares is zero)".into(),
        });
    }
    let df1 = (k - 1) as f64;
    let df2 = (n_total - k) as f64;
    let f = (ss_between / df1) / (ss_within / df2);
    Ok(OneWayAnova {
        f,
        df1,
        df2,
        p: f_sf(f, df1, df2)?,
        ss_between: ss_between * u * u,
        ss_within: ss_within * u * u,
        eta2: ss_between / (ss_between + ss_within),
        eta2_ci: eta2_ci_from_f(f, df1, df2).ok(),
        n_groups: k,
        n_total,
    })
}

/// One-way ANOVA across the conditions of `design`, treating the
/// participants' cell means of each condition as an independent group — the
/// analysis the paper reports (§4.3, Fig. 12). Missing cells are allowed
/// (a condition simply has fewer means), so between-subject data work too.
///
/// # Errors
/// As [`one_way_anova`]; an empty group is named by its condition label;
/// [`StatsError::NonFiniteCell`] for a cell mean that overflows.
pub fn oneway(design: &Design) -> Result<OneWayAnova> {
    design.check_cell_means()?;
    let groups = design.condition_groups();
    if let Some((label, _)) = groups.iter().find(|(_, v)| v.is_empty()) {
        return Err(StatsError::EmptyGroup {
            test: "one-way ANOVA",
            group: label.clone(),
        });
    }
    let values: Vec<&[f64]> = groups.iter().map(|(_, v)| v.as_slice()).collect();
    one_way_anova(&values)
}

/// Result of a one-factor repeated-measures ANOVA with sphericity checks.
///
/// Field names follow the CLI's JSON (`F`, `df1`, …, pingouin-like).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RmAnova {
    /// F = MS_conditions / MS_error.
    #[serde(rename = "F")]
    pub f: f64,
    /// Uncorrected numerator degrees of freedom, k − 1.
    pub df1: f64,
    /// Uncorrected denominator degrees of freedom, (n − 1)(k − 1).
    pub df2: f64,
    /// Uncorrected p-value P(F(df1, df2) > F).
    pub p: f64,
    /// Greenhouse–Geisser ε̂ ∈ [1/(k−1), 1].
    pub eps_gg: f64,
    /// p-value with both df multiplied by ε̂_GG.
    pub p_gg: f64,
    /// Huynh–Feldt ε̃ (with g = 1 group it coincides with Lecoutre's
    /// correction), capped at 1.
    pub eps_hf: f64,
    /// p-value with both df multiplied by ε̃_HF.
    pub p_hf: f64,
    /// Lower-bound ε = 1/(k − 1) (Greenhouse & Geisser's conservative test).
    pub eps_lb: f64,
    /// p-value with both df multiplied by the lower bound.
    pub p_lb: f64,
    /// Mauchly's W ∈ [0, 1]; `None` when n − 1 < k − 1 (the sample
    /// covariance of the contrasts is singular by construction and the test
    /// is undefined). `Some(1.0)` for k = 2.
    pub mauchly_w: Option<f64>,
    /// Mauchly's χ² statistic; `None` when undefined or unbounded (W = 0).
    pub mauchly_chi2: Option<f64>,
    /// Degrees of freedom of Mauchly's χ², (k−1)k/2 − 1.
    pub mauchly_df: f64,
    /// p-value of Mauchly's test (small = sphericity violated); `Some(0.0)`
    /// when W = 0 with enough subjects, `None` when undefined.
    pub mauchly_p: Option<f64>,
    /// Partial η² = SS_cond / (SS_cond + SS_error).
    pub np2: f64,
    /// 95 % noncentral-F interval of partial η² from the uncorrected F and
    /// df ([`super::effect`]); `None` when it cannot be computed.
    pub np2_ci: Option<[f64; 2]>,
    /// Generalised η² (Olejnik & Algina 2003) for one manipulated within
    /// factor: SS_cond / (SS_cond + SS_subjects + SS_error).
    pub ng2: f64,
    /// SS of the condition effect, n Σ_j (ȳ_.j − ȳ)².
    pub ss_conditions: f64,
    /// SS of the subject effect, k Σ_i (ȳ_i. − ȳ)².
    pub ss_subjects: f64,
    /// Residual (subject × condition) SS, Σ (y_ij − ȳ_i. − ȳ_.j + ȳ)².
    pub ss_error: f64,
    /// Number of subjects n.
    pub n_subjects: usize,
    /// Number of conditions k.
    pub n_conditions: usize,
}

/// Orthonormal Helmert contrasts: row r (0-based) compares the mean of
/// conditions 0..=r with condition r + 1. Rows are orthonormal and
/// orthogonal to the unit vector, as Mauchly's test requires.
fn helmert(k: usize) -> DMatrix<f64> {
    let p = k - 1;
    DMatrix::from_fn(p, k, |r, j| {
        let norm = (((r + 1) * (r + 2)) as f64).sqrt();
        if j <= r {
            1.0 / norm
        } else if j == r + 1 {
            -((r + 1) as f64) / norm
        } else {
            0.0
        }
    })
}

/// Eigenvalues (≥ 0, scaled so the largest is of order 1) of the sample
/// covariance of the orthonormal contrasts of the rows of `m`.
fn contrast_eigenvalues(m: &CellMatrix) -> Vec<f64> {
    let (n, k) = (m.n_subjects(), m.n_conditions());
    let x = DMatrix::from_row_slice(n, k, m.values());
    let mut y = x * helmert(k).transpose(); // n × (k−1)
    for mut col in y.column_iter_mut() {
        let mean = col.mean();
        col.add_scalar_mut(-mean);
    }
    let scale = y.amax();
    if scale > 0.0 {
        y /= scale;
    }
    let s = (y.transpose() * &y) / ((n - 1) as f64);
    SymmetricEigen::new(s)
        .eigenvalues
        .iter()
        .map(|&l| l.max(0.0))
        .collect()
}

/// One-factor repeated-measures ANOVA on a complete cell-mean matrix.
///
/// # Errors
/// Fewer than 2 subjects or 2 conditions; zero residual variance (every
/// subject shows exactly the same condition effect), where F is unbounded.
pub fn rm_anova(m: &CellMatrix) -> Result<RmAnova> {
    const TEST: &str = "repeated-measures ANOVA";
    let (n, k) = m.require_at_least_2x2(TEST)?;
    let scale = m.values().iter().fold(0.0_f64, |a, &v| a.max(v.abs()));
    // Sums of squares of the data divided by `u` (magnitude ≤ 1), row-major.
    let u = unit_divisor(scale);
    let values: Vec<f64> = m.values().iter().map(|v| v / u).collect();
    let row = |i: usize| &values[i * k..(i + 1) * k];
    let grand = values.iter().sum::<f64>() / (n * k) as f64;
    let row_means: Vec<f64> = (0..n)
        .map(|i| row(i).iter().sum::<f64>() / k as f64)
        .collect();
    let col_means: Vec<f64> = (0..k)
        .map(|j| (0..n).map(|i| row(i)[j]).sum::<f64>() / n as f64)
        .collect();
    let ss_conditions = n as f64 * col_means.iter().map(|c| (c - grand).powi(2)).sum::<f64>();
    let ss_subjects = k as f64 * row_means.iter().map(|r| (r - grand).powi(2)).sum::<f64>();
    let mut ss_error = 0.0;
    for (i, rm) in row_means.iter().enumerate() {
        for (j, cm) in col_means.iter().enumerate() {
            let e = row(i)[j] - rm - cm + grand;
            ss_error += e * e;
        }
    }
    if negligible(ss_error, n * k, scale / u) {
        return Err(StatsError::ZeroVariance {
            test: TEST,
            detail: "the residual (subject × condition) sum of squares is zero: every subject \
                     shows exactly the same condition effect, so F is unbounded"
                .into(),
        });
    }
    let df1 = (k - 1) as f64;
    let df2 = ((n - 1) * (k - 1)) as f64;
    let f = (ss_conditions / df1) / (ss_error / df2);
    let p = f_sf(f, df1, df2)?;

    // Sphericity: eigenvalues λ of the contrast covariance (p = k − 1).
    let pk = k - 1;
    let pf = pk as f64;
    let lambda = contrast_eigenvalues(m);
    let sum: f64 = lambda.iter().sum();
    let sum_sq: f64 = lambda.iter().map(|l| l * l).sum();
    // ε̂_GG = (Σλ)² / (p Σλ²) (Greenhouse & Geisser 1959; Box 1954).
    let eps_lb = 1.0 / pf;
    let eps_gg = if sum_sq > 0.0 {
        (sum * sum / (pf * sum_sq)).clamp(eps_lb, 1.0)
    } else {
        1.0
    };
    // ε̃_HF (Huynh & Feldt 1976; = Lecoutre 1991 for one group):
    // (n p ε̂ − 2) / (p (n − 1 − p ε̂)), capped at 1. It is ≥ ε̂ whenever
    // the denominator is positive (p ε̂ ≥ 1).
    let nf = n as f64;
    let den = pf * (nf - 1.0 - pf * eps_gg);
    let eps_hf = if den > 0.0 {
        ((nf * pf * eps_gg - 2.0) / den).min(1.0)
    } else {
        1.0
    };

    // Mauchly (1940), with Anderson's correction factor for the χ².
    let mauchly_df = pf * (pf + 1.0) / 2.0 - 1.0;
    let (mauchly_w, mauchly_chi2, mauchly_p) = if pk == 1 {
        (Some(1.0), Some(0.0), Some(1.0))
    } else if n - 1 < pk {
        (None, None, None)
    } else {
        let lmax = lambda.iter().fold(0.0_f64, |a, &l| a.max(l));
        let lmin = lambda.iter().fold(f64::INFINITY, |a, &l| a.min(l));
        if lmin <= 1e-12 * lmax {
            (Some(0.0), None, Some(0.0))
        } else {
            let ln_w = lambda.iter().map(|l| l.ln()).sum::<f64>() - pf * (sum / pf).ln();
            let ln_w = ln_w.min(0.0);
            let corr = 1.0 - (2.0 * pf * pf + pf + 2.0) / (6.0 * pf * (nf - 1.0));
            let chi2 = (-(nf - 1.0) * corr * ln_w).max(0.0);
            (
                Some(ln_w.exp()),
                Some(chi2),
                Some(chi2_sf(chi2, mauchly_df)?),
            )
        }
    };

    Ok(RmAnova {
        f,
        df1,
        df2,
        p,
        eps_gg,
        p_gg: f_sf(f, eps_gg * df1, eps_gg * df2)?,
        eps_hf,
        p_hf: f_sf(f, eps_hf * df1, eps_hf * df2)?,
        eps_lb,
        p_lb: f_sf(f, eps_lb * df1, eps_lb * df2)?,
        mauchly_w,
        mauchly_chi2,
        mauchly_df,
        mauchly_p,
        np2: ss_conditions / (ss_conditions + ss_error),
        np2_ci: eta2_ci_from_f(f, df1, df2).ok(),
        ng2: ss_conditions / (ss_conditions + ss_subjects + ss_error),
        ss_conditions: ss_conditions * u * u,
        ss_subjects: ss_subjects * u * u,
        ss_error: ss_error * u * u,
        n_subjects: n,
        n_conditions: k,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn helmert_rows_are_orthonormal_contrasts() {
        for k in 2..=6 {
            let h = helmert(k);
            let g = &h * h.transpose();
            assert!((g - DMatrix::identity(k - 1, k - 1)).amax() < 1e-15);
            for r in 0..k - 1 {
                assert!(h.row(r).sum().abs() < 1e-15);
            }
        }
    }

    /// SS_error = (n − 1)·tr(S) for the orthonormal contrast covariance S, an
    /// identity linking the univariate and multivariate computations.
    #[test]
    fn error_ss_equals_trace_of_contrast_covariance() {
        let m = CellMatrix::from_columns(&[
            ("A", vec![2.2, 3.1, 4.3, 4.1, 7.2]),
            ("B", vec![1.1, 2.5, 4.1, 5.2, 6.4]),
            ("C", vec![8.2, 4.5, 3.4, 6.2, 7.2]),
        ])
        .unwrap();
        let r = rm_anova(&m).unwrap();
        let x = DMatrix::from_row_slice(5, 3, m.values());
        let mut y = x * helmert(3).transpose();
        for mut col in y.column_iter_mut() {
            let mean = col.mean();
            col.add_scalar_mut(-mean);
        }
        let trace = (y.transpose() * &y).trace();
        assert!((trace - r.ss_error).abs() < 1e-12 * trace);
    }

    /// F, t and p are scale-free: data multiplied by 10^±200 (where the
    /// squares over- or underflow) give the statistics of the unscaled data,
    /// and the reported moments scale with them.
    #[test]
    fn statistics_do_not_depend_on_the_data_scale() {
        let a = [5.1, 4.9, 6.2, 5.8, 6.0];
        let b = [6.3, 5.2, 7.1, 6.6, 6.4];
        let c = [7.0, 6.1, 7.9, 7.7, 6.8];
        let close = |x: f64, y: f64| (x - y).abs() <= 1e-12 * y.abs().max(1e-300);
        let base_rm =
            rm_anova(&CellMatrix::from_columns(&[("a", a), ("b", b), ("c", c)]).unwrap()).unwrap();
        let base_ow = one_way_anova(&[a, b, c]).unwrap();
        let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
        let base_t = super::super::pairwise::one_sample_t(&d, 0.0).unwrap();
        for s in [1e200, 1e-200, -1e300] {
            let sc = |x: [f64; 5]| x.map(|v| v * s);
            let m = CellMatrix::from_columns(&[("a", sc(a)), ("b", sc(b)), ("c", sc(c))]).unwrap();
            let r = rm_anova(&m).unwrap();
            assert!(close(r.f, base_rm.f) && close(r.p, base_rm.p), "{s}: {r:?}");
            assert!(close(r.eps_gg, base_rm.eps_gg) && close(r.np2, base_rm.np2));
            let o = one_way_anova(&[sc(a), sc(b), sc(c)]).unwrap();
            assert!(close(o.f, base_ow.f) && close(o.p, base_ow.p), "{s}: {o:?}");
            let ds: Vec<f64> = d.iter().map(|v| v * s).collect();
            let t = super::super::pairwise::one_sample_t(&ds, 0.0).unwrap();
            assert!(
                close(t.t, base_t.t * s.signum()) && close(t.p, base_t.p),
                "{s}: {t:?}"
            );
            assert!(close(t.mean, base_t.mean * s) && close(t.sd, base_t.sd * s.abs()));
        }
    }

    #[test]
    fn negligible_scales_with_data() {
        assert!(negligible(0.0, 10, 1.0));
        assert!(negligible(1e-40, 10, 1.0));
        assert!(!negligible(1e-20, 10, 1.0));
        assert!(negligible(1e-20, 10, 1e8));
    }
}
