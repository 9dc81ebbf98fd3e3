//! Property tests of the statistics on hostile cell matrices — ties,
//! values near the ends of `f64` (1e-308 … 1e308, subnormals), a single
//! repeated value, non-finite values: every test refuses or answers, never
//! panics, and an answer is never wrong: Friedman equals a naive counting
//! reference (no sort), the ANOVAs are invariant to exact rescaling (a
//! power of two), every p lies in [0, 1], every statistic is finite, and
//! descriptives lie within the data.
//!
//! Cases per property: `PROPTEST_CASES` (default 256, what CI runs; the
//! closing-note figures were run with 100 000).

#![allow(clippy::unwrap_used)]

use kilotouch_study::stats::{
    CellMatrix, Design, StatsError, WilcoxonOptions, describe, friedman, oneway, pairwise_tests,
    rm_anova,
};
use proptest::prelude::*;

use crate::common::proptest_config as config;

/// A value of a hostile matrix.
fn value() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => (0_i32..5).prop_map(f64::from),
        4 => -1e3_f64..1e3,
        1 => prop_oneof![Just(1e308), Just(-1e308), Just(1.7e308), Just(5e-324), Just(1e-308)],
        1 => -1e300_f64..1e300,
        1 => any::<f64>(),
    ]
}

/// n subjects × k conditions of values (row-major).
fn matrix() -> impl Strategy<Value = (usize, usize, Vec<f64>)> {
    (2_usize..12, 2_usize..6)
        .prop_flat_map(|(n, k)| (Just(n), Just(k), prop::collection::vec(value(), n * k)))
}

fn cell_matrix(n: usize, k: usize, v: Vec<f64>) -> Result<CellMatrix, StatsError> {
    CellMatrix::new(
        (0..n).map(|i| format!("s{i}")).collect(),
        (0..k).map(|j| format!("c{j}")).collect(),
        v,
    )
}

/// Friedman's χ² by counting (mid-rank = 1 + #below + (#equal − 1)/2),
/// with the tie correction: an independent O(n k²) reference.
fn naive_friedman(n: usize, k: usize, v: &[f64]) -> Option<f64> {
    let mut sums = vec![0.0; k];
    let mut ties = 0.0;
    for i in 0..n {
        let row = &v[i * k..(i + 1) * k];
        for (j, x) in row.iter().enumerate() {
            let below = row.iter().filter(|y| *y < x).count() as f64;
            let equal = row.iter().filter(|y| *y == x).count() as f64;
            sums[j] += 1.0 + below + (equal - 1.0) / 2.0;
            // Each tie group of size t adds t³ − t once: t² − 1 per member.
            ties += equal * equal - 1.0;
        }
    }
    let (nf, kf) = (n as f64, k as f64);
    let c = 1.0 - ties / (nf * kf * (kf * kf - 1.0));
    if c <= 0.0 {
        return None;
    }
    let ss: f64 = sums.iter().map(|r| r * r).sum();
    Some(((12.0 / (nf * kf * (kf + 1.0)) * ss - 3.0 * nf * (kf + 1.0)) / c).max(0.0))
}

fn unit(p: f64) -> bool {
    (0.0..=1.0).contains(&p)
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn friedman_refuses_or_equals_the_counting_reference((n, k, v) in matrix()) {
        let finite = v.iter().all(|x| x.is_finite());
        let m = match cell_matrix(n, k, v.clone()) {
            Ok(m) => m,
            Err(e) => {
                prop_assert!(!finite, "finite matrix refused: {e}");
                return Ok(());
            }
        };
        prop_assert!(finite, "a non-finite cell was accepted");
        match (friedman(&m), naive_friedman(n, k, &v)) {
            (Ok(r), Some(chi2)) => {
                prop_assert!((r.chi2 - chi2).abs() <= 1e-9 * chi2.max(1.0), "{} vs {chi2}", r.chi2);
                prop_assert!(unit(r.p) && unit(r.p_f) && unit(r.kendall_w), "{r:?}");
                let ci = r.kendall_w_ci.unwrap();
                prop_assert!(ci[0] <= ci[1] && unit(ci[0]) && unit(ci[1]), "{ci:?}");
            }
            (Err(StatsError::ZeroVariance { .. }), None) => {}
            (r, naive) => prop_assert!(false, "friedman {r:?} vs reference {naive:?}"),
        }
    }

    #[test]
    fn rm_anova_refuses_or_answers_scale_invariantly((n, k, v) in matrix(), shift in 1_i32..8) {
        let Ok(m) = cell_matrix(n, k, v.clone()) else { return Ok(()); };
        let Ok(r) = rm_anova(&m) else { return Ok(()); };
        prop_assert!(r.f.is_finite() && r.f >= 0.0, "{r:?}");
        for p in [r.p, r.p_gg, r.p_hf, r.p_lb] {
            prop_assert!(unit(p), "{r:?}");
        }
        // F is a ratio of sums of squares: exact rescaling by 2^-shift (no
        // rounding unless subnormal) leaves it unchanged.
        let s = 2_f64.powi(-shift);
        if v.iter().all(|x| *x == 0.0 || (x * s).abs() >= f64::MIN_POSITIVE) {
            let scaled = cell_matrix(n, k, v.iter().map(|x| x * s).collect()).unwrap();
            let r2 = rm_anova(&scaled);
            prop_assert!(r2.is_ok(), "scaled refused: {r2:?}");
            let f2 = r2.unwrap().f;
            prop_assert!((f2 - r.f).abs() <= 1e-6 * r.f.max(1.0), "{} vs {f2}", r.f);
        }
    }

    #[test]
    fn oneway_on_long_rows_refuses_or_answers_scale_invariantly(
        (n, k, v) in matrix(),
        reps in 1_usize..3,
    ) {
        let rows: Vec<(String, String, f64)> = (0..n * k)
            .flat_map(|i| (0..reps).map(move |_| i))
            .map(|i| (format!("s{}", i / k), format!("c{}", i % k), v[i]))
            .collect();
        let Ok(d) = Design::from_long(rows.clone()) else {
            prop_assert!(v.iter().any(|x| !x.is_finite()));
            return Ok(());
        };
        let Ok(r) = oneway(&d) else { return Ok(()); };
        prop_assert!(r.f.is_finite() && r.f >= 0.0 && unit(r.p), "{r:?}");
        let s = 0.5;
        if v.iter().all(|x| *x == 0.0 || (x * s).abs() >= f64::MIN_POSITIVE) {
            let scaled: Vec<_> = rows.into_iter().map(|(a, b, x)| (a, b, x * s)).collect();
            let r2 = oneway(&Design::from_long(scaled).unwrap());
            prop_assert!(r2.is_ok(), "scaled refused: {r2:?}");
            let f2 = r2.unwrap().f;
            prop_assert!((f2 - r.f).abs() <= 1e-6 * r.f.max(1.0), "{} vs {f2}", r.f);
        }
    }

    #[test]
    fn pairwise_and_describe_refuse_or_answer_within_range((n, k, v) in matrix()) {
        let Ok(m) = cell_matrix(n, k, v.clone()) else { return Ok(()); };
        if let Ok(t) = pairwise_tests(&m, WilcoxonOptions::default()) {
            for p in &t.pairs {
                for q in [p.p, p.p_holm, p.wilcoxon_p, p.wilcoxon_p_holm].into_iter().flatten() {
                    prop_assert!(unit(q), "{p:?}");
                }
                for x in [p.t, p.dz].into_iter().flatten() {
                    prop_assert!(x.is_finite(), "{p:?}");
                }
                prop_assert!(p.mean_diff.is_finite(), "{p:?}");
            }
        }
        if let Ok(d) = describe(&m) {
            for (j, c) in d.conditions.iter().enumerate() {
                let col = m.column(j);
                let lo = col.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = col.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                prop_assert!(c.min == lo && c.max == hi, "{c:?}");
                for x in [c.mean, c.median, c.q1, c.q3] {
                    prop_assert!(x >= lo && x <= hi, "{c:?}");
                }
                if let Some(sd) = c.sd {
                    prop_assert!(sd.is_finite() && sd >= 0.0, "{c:?}");
                }
            }
        }
    }
}
