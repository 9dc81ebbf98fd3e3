//! Statistics against the public test vectors of
//! `docs/REFERENCE-VALUES.md` (PlantGrowth one-way ANOVA,
//! the scipy Friedman example, the 5 × 3 repeated-measures example), the
//! scipy `wilcoxon` documentation example, closed forms derived here, and
//! invariants.

use kilotouch_study::stats::{
    self, CellMatrix, Design, StatsError, Test, TestReport, WilcoxonMethod, WilcoxonMethodUsed,
    WilcoxonOptions,
};
use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{Rng, SeedableRng};
use statrs::distribution::{ContinuousCDF, FisherSnedecor, StudentsT};

/// Tolerance for the printed reference digits.
const TOL: f64 = 1e-6;

fn close(got: f64, want: f64, tol: f64, what: &str) {
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got}, want {want} (tol {tol})"
    );
}

fn uniform(rng: &mut ChaCha8Rng) -> f64 {
    (rng.next_u64() >> 11) as f64 / (1_u64 << 53) as f64
}

/// Standard normal by Box–Muller (enough for test data).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1 = uniform(rng).max(1e-300);
    let u2 = uniform(rng);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

// ---------------------------------------------------------------- PlantGrowth

const CTRL: [f64; 10] = [4.17, 5.58, 5.18, 6.11, 4.50, 4.61, 5.17, 4.53, 5.33, 5.14];
const TRT1: [f64; 10] = [4.81, 4.17, 4.41, 3.59, 5.87, 3.83, 6.03, 4.89, 4.32, 4.69];
const TRT2: [f64; 10] = [6.31, 5.12, 5.54, 5.50, 5.37, 5.29, 4.92, 6.15, 5.80, 5.26];

#[test]
fn plantgrowth_one_way_anova() {
    // Between-subjects: every plant is its own subject.
    let mut rows = Vec::new();
    for (name, group) in [("ctrl", CTRL), ("trt1", TRT1), ("trt2", TRT2)] {
        for (i, &v) in group.iter().enumerate() {
            rows.push((format!("{name}-{i}"), name, v));
        }
    }
    let design = Design::from_long(rows).unwrap();
    assert!(!design.is_complete());
    let r = stats::oneway(&design).unwrap();
    close(r.f, 4.846087862, 1e-9, "F");
    assert_eq!((r.df1, r.df2), (2.0, 27.0));
    close(r.p, 0.015909958, 1e-9, "p");
    // The slice API and the within-style long format (subjects 1..10 shared
    // across groups) give the same one-way result: pairing is ignored.
    let s = stats::one_way_anova(&[&CTRL[..], &TRT1[..], &TRT2[..]]).unwrap();
    assert_eq!(s, r);
    let mut rows = Vec::new();
    for (name, group) in [("ctrl", CTRL), ("trt1", TRT1), ("trt2", TRT2)] {
        for (i, &v) in group.iter().enumerate() {
            rows.push((i.to_string(), name, v));
        }
    }
    let TestReport::Oneway(w) = stats::run_test_long(rows, Test::Oneway).unwrap() else {
        panic!("wrong report")
    };
    close(w.f, r.f, 1e-12, "F within-layout");
    // η² and the SS decomposition: SS_total from its definition.
    let all: Vec<f64> = CTRL.iter().chain(&TRT1).chain(&TRT2).copied().collect();
    let gm = all.iter().sum::<f64>() / 30.0;
    let ss_total: f64 = all.iter().map(|v| (v - gm).powi(2)).sum();
    close(r.ss_between + r.ss_within, ss_total, 1e-10, "SS partition");
    close(r.eta2, r.ss_between / ss_total, 1e-14, "eta2");
}

#[test]
fn oneway_serialises_with_cli_field_names() {
    let r = stats::one_way_anova(&[&CTRL[..], &TRT1[..], &TRT2[..]]).unwrap();
    let v = serde_json::to_value(&r).unwrap();
    for key in ["F", "df1", "df2", "p"] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    close(v["F"].as_f64().unwrap(), 4.846087862, 1e-9, "json F");
}

// ------------------------------------------------------------ Friedman (scipy)

const BEFORE: [f64; 7] = [72.0, 96.0, 88.0, 92.0, 74.0, 76.0, 82.0];
const IMMEDIATELY: [f64; 7] = [120.0, 120.0, 132.0, 120.0, 101.0, 96.0, 112.0];
const FIVE_MIN: [f64; 7] = [76.0, 95.0, 104.0, 96.0, 84.0, 72.0, 76.0];

#[test]
fn scipy_friedman_example() {
    let m = CellMatrix::from_columns(&[
        ("before", BEFORE),
        ("immediately_after", IMMEDIATELY),
        ("five_min_after", FIVE_MIN),
    ])
    .unwrap();
    let r = stats::friedman(&m).unwrap();
    close(r.chi2, 10.571428571, TOL, "chi2");
    close(r.p, 0.005063414, TOL, "p");
    // Derivation: no ties; rank sums (10, 21, 11), ΣR² = 662,
    // χ² = 12·662/(7·3·4) − 3·7·4 = 74/7; χ²(2) tail = exp(−χ²/2).
    let (n, k) = (7.0, 3.0);
    let chi2 = 12.0 * 662.0 / (n * k * (k + 1.0)) - 3.0 * n * (k + 1.0);
    close(chi2, 74.0 / 7.0, 1e-12, "derived chi2");
    close(r.chi2, chi2, 1e-12, "chi2 vs derivation");
    close(r.p, (-chi2 / 2.0).exp(), 1e-14, "p vs exp(-chi2/2)");
    assert_eq!(r.tie_correction, 1.0);
    assert_eq!(r.mean_ranks, vec![10.0 / 7.0, 3.0, 11.0 / 7.0]);
    // Kendall's W and the Iman–Davenport F.
    close(r.kendall_w, chi2 / (n * (k - 1.0)), 1e-14, "W");
    let f = (n - 1.0) * chi2 / (n * (k - 1.0) - chi2);
    close(r.f_iman_davenport.unwrap(), f, 1e-12, "Iman-Davenport F");
    close(f, 18.5, 1e-12, "F = 18.5 exactly");
    let pf = FisherSnedecor::new(2.0, 12.0).unwrap().sf(18.5);
    close(r.p_f, pf, 1e-12, "Iman-Davenport p");
    let v = serde_json::to_value(&r).unwrap();
    for key in ["chi2", "df", "p", "kendall_w"] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
}

// ------------------------------------------------- Repeated measures, 5 × 3

const A: [f64; 5] = [2.2, 3.1, 4.3, 4.1, 7.2];
const B: [f64; 5] = [1.1, 2.5, 4.1, 5.2, 6.4];
const C: [f64; 5] = [8.2, 4.5, 3.4, 6.2, 7.2];

fn rm_example() -> CellMatrix {
    CellMatrix::from_columns(&[("A", A), ("B", B), ("C", C)]).expect("valid matrix")
}

#[test]
fn rm_anova_reference_vector() {
    let r = stats::rm_anova(&rm_example()).unwrap();
    close(r.f, 2.153754, TOL, "F");
    assert_eq!((r.df1, r.df2), (2.0, 8.0));
    close(r.p, 0.178517, TOL, "p");
    close(r.eps_gg, 0.558775, TOL, "GG epsilon");
    close(r.p_gg, 0.211692, TOL, "p_GG");
    close(r.eps_hf, 0.622345, TOL, "HF epsilon");
    close(r.eps_lb, 0.5, 0.0, "lower bound");
    close(r.mauchly_w.unwrap(), 0.210372, TOL, "Mauchly W");
    close(
        r.mauchly_p.unwrap(),
        0.09649,
        5e-6,
        "Mauchly p (5 printed decimals)",
    );
    assert_eq!(r.mauchly_df, 2.0);
    close(r.ng2, 0.202931, TOL, "generalized eta2");
    // Corrected p-values from statrs' F distribution at the corrected df.
    for (eps, p) in [(r.eps_gg, r.p_gg), (r.eps_hf, r.p_hf), (r.eps_lb, r.p_lb)] {
        let want = FisherSnedecor::new(2.0 * eps, 8.0 * eps).unwrap().sf(r.f);
        close(p, want, 1e-10, "corrected p");
    }
}

/// The same quantities from textbook formulas written out here: the SS
/// decomposition, GG ε from the double-centred covariance, HF from GG,
/// Mauchly's W from a 2 × 2 determinant with its χ² approximation.
#[test]
fn rm_anova_matches_textbook_formulas() {
    let r = stats::rm_anova(&rm_example()).unwrap();
    let x = [A, B, C];
    let (n, k) = (5usize, 3usize);
    let (nf, kf) = (n as f64, k as f64);
    let gm = x.iter().flatten().sum::<f64>() / (nf * kf);
    let cm: Vec<f64> = x.iter().map(|c| c.iter().sum::<f64>() / nf).collect();
    let sm: Vec<f64> = (0..n)
        .map(|i| x.iter().map(|c| c[i]).sum::<f64>() / kf)
        .collect();
    let ss_cond = nf * cm.iter().map(|m| (m - gm).powi(2)).sum::<f64>();
    let ss_subj = kf * sm.iter().map(|m| (m - gm).powi(2)).sum::<f64>();
    let ss_tot: f64 = x.iter().flatten().map(|v| (v - gm).powi(2)).sum();
    let ss_err = ss_tot - ss_cond - ss_subj;
    close(r.ss_conditions, ss_cond, 1e-12, "SS cond");
    close(r.ss_subjects, ss_subj, 1e-12, "SS subj");
    close(r.ss_error, ss_err, 1e-12, "SS err");
    close(r.f, (ss_cond / 2.0) / (ss_err / 8.0), 1e-12, "F");
    close(r.np2, ss_cond / (ss_cond + ss_err), 1e-14, "np2");
    close(r.ng2, ss_cond / ss_tot, 1e-14, "ng2");

    // Covariance matrix of the conditions, then double-centred.
    let mut s = [[0.0; 3]; 3];
    for a in 0..k {
        for b in 0..k {
            s[a][b] = (0..n)
                .map(|i| (x[a][i] - cm[a]) * (x[b][i] - cm[b]))
                .sum::<f64>()
                / (nf - 1.0);
        }
    }
    let row: Vec<f64> = (0..k).map(|a| s[a].iter().sum::<f64>() / kf).collect();
    let all = row.iter().sum::<f64>() / kf;
    let mut trace = 0.0;
    let mut sumsq = 0.0;
    for a in 0..k {
        for b in 0..k {
            let d = s[a][b] - row[a] - row[b] + all;
            sumsq += d * d;
            if a == b {
                trace += d;
            }
        }
    }
    let gg = trace * trace / ((kf - 1.0) * sumsq);
    close(r.eps_gg, gg, 1e-12, "GG from double-centred covariance");
    let p = kf - 1.0;
    let hf = (nf * p * gg - 2.0) / (p * (nf - 1.0 - p * gg));
    close(r.eps_hf, hf, 1e-12, "HF formula");

    // Mauchly: contrasts c1 = (1,−1,0)/√2, c2 = (1,1,−2)/√6.
    let c1 = [1.0 / 2f64.sqrt(), -1.0 / 2f64.sqrt(), 0.0];
    let c2 = [1.0 / 6f64.sqrt(), 1.0 / 6f64.sqrt(), -2.0 / 6f64.sqrt()];
    let quad = |u: &[f64; 3], v: &[f64; 3]| {
        (0..3)
            .flat_map(|a| (0..3).map(move |b| (a, b)))
            .map(|(a, b)| u[a] * s[a][b] * v[b])
            .sum::<f64>()
    };
    let (s11, s12, s22) = (quad(&c1, &c1), quad(&c1, &c2), quad(&c2, &c2));
    let det = s11 * s22 - s12 * s12;
    let w = det / ((s11 + s22) / 2.0).powi(2);
    close(r.mauchly_w.unwrap(), w, 1e-12, "W from determinant");
    let f = 1.0 - (2.0 * p * p + p + 2.0) / (6.0 * p * (nf - 1.0));
    let chi2 = -(nf - 1.0) * f * w.ln();
    close(r.mauchly_chi2.unwrap(), chi2, 1e-10, "Mauchly chi2");
    // χ²(2) tail is exp(−x/2).
    close(
        r.mauchly_p.unwrap(),
        (-chi2 / 2.0).exp(),
        1e-12,
        "Mauchly p",
    );
}

#[test]
fn rm_anova_json_fields() {
    let r = stats::rm_anova(&rm_example()).unwrap();
    let v = serde_json::to_value(&r).unwrap();
    for key in [
        "F",
        "df1",
        "df2",
        "p",
        "eps_gg",
        "p_gg",
        "eps_hf",
        "p_hf",
        "mauchly_w",
        "mauchly_p",
        "np2",
        "ng2",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
}

/// Friedman with a tie (subject 5: A = C = 7.2): ranks (2,1,3), (2,1,3),
/// (3,2,1), (1,2,3), (2.5,1,2.5); R = (10.5, 7, 12.5); ΣR² = 315.5;
/// uncorrected χ² = 12·315.5/60 − 60 = 3.1; C = 1 − (2³−2)/(5·3·8) = 0.95;
/// χ² = 3.1/0.95 (scipy: 3.263157894736844).
#[test]
fn friedman_with_ties_uses_the_correction() {
    let r = stats::friedman(&rm_example()).unwrap();
    close(r.tie_correction, 0.95, 1e-15, "C");
    close(r.chi2, 3.1 / 0.95, 1e-12, "chi2");
    close(r.chi2, 3.263157894736844, 1e-12, "scipy chi2");
    close(r.p, (-r.chi2 / 2.0).exp(), 1e-14, "p");
    // Kendall's W with Kendall's own tie correction:
    // W = 12 S / (n²(k³ − k) − n Σ(t³ − t)), S = Σ (R_j − n(k+1)/2)².
    let s: f64 = [10.5_f64, 7.0, 12.5]
        .iter()
        .map(|r| (r - 10.0).powi(2))
        .sum();
    let w = 12.0 * s / (25.0 * 24.0 - 5.0 * 6.0);
    close(r.kendall_w, w, 1e-14, "Kendall W (tie-corrected)");
    close(
        r.kendall_w,
        r.chi2 / (5.0 * 2.0),
        1e-14,
        "W = chi2/(n(k-1))",
    );
}

// --------------------------------------------------------------- post-hoc

#[test]
fn pairwise_t_on_the_rm_example() {
    let m = rm_example();
    let rows = stats::pairwise_t(&m).unwrap();
    assert_eq!(rows.len(), 3);
    let names: Vec<(&str, &str)> = rows.iter().map(|r| (&*r.a, &*r.b)).collect();
    assert_eq!(names, [("A", "B"), ("A", "C"), ("B", "C")]);
    let t4 = StudentsT::new(0.0, 1.0, 4.0).unwrap();
    for (row, (x, y)) in rows.iter().zip([(A, B), (A, C), (B, C)]) {
        let d: Vec<f64> = x.iter().zip(&y).map(|(a, b)| a - b).collect();
        let mean = d.iter().sum::<f64>() / 5.0;
        let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 4.0).sqrt();
        let t = mean / (sd / 5f64.sqrt());
        close(row.statistic, t, 1e-12, "t");
        close(row.p, 2.0 * t4.sf(t.abs()), 1e-12, "p");
        assert_eq!(row.df, Some(4.0));
    }
    // scipy.stats.ttest_rel(A, B): t = 0.833491617712997, p = 0.4514452532391544.
    close(rows[0].statistic, 0.833491617712997, 1e-12, "scipy t");
    close(rows[0].p, 0.4514452532391544, 1e-12, "scipy p");
    let raw: Vec<f64> = rows.iter().map(|r| r.p).collect();
    let holm = stats::holm(&raw).unwrap();
    for (r, h) in rows.iter().zip(holm) {
        assert_eq!(r.p_holm, h);
    }
}

#[test]
fn paired_t_equals_one_sample_t_on_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for n in [2usize, 3, 7, 40] {
        let x: Vec<f64> = (0..n).map(|_| normal(&mut rng)).collect();
        let y: Vec<f64> = (0..n).map(|_| 0.3 + normal(&mut rng)).collect();
        let d: Vec<f64> = x.iter().zip(&y).map(|(a, b)| a - b).collect();
        let paired = stats::paired_t(&x, &y).unwrap();
        let one = stats::one_sample_t(&d, 0.0).unwrap();
        assert_eq!(paired, one);
        // Shifting the null: t-test of d against μ0 equals t-test of d − μ0.
        let shifted: Vec<f64> = d.iter().map(|v| v - 0.25).collect();
        let a = stats::one_sample_t(&d, 0.25).unwrap();
        let b = stats::one_sample_t(&shifted, 0.0).unwrap();
        close(a.t, b.t, 1e-12, "shifted t");
        close(a.p, b.p, 1e-12, "shifted p");
    }
}

/// With k = 2 sphericity holds trivially and the RM ANOVA F is the square of
/// the paired t.
#[test]
fn two_conditions_sphericity_is_trivial_and_f_is_t_squared() {
    let m = CellMatrix::from_columns(&[("A", A), ("C", C)]).unwrap();
    let r = stats::rm_anova(&m).unwrap();
    assert_eq!(r.eps_gg, 1.0);
    assert_eq!(r.eps_hf, 1.0);
    assert_eq!(r.eps_lb, 1.0);
    assert_eq!(r.mauchly_w, Some(1.0));
    assert_eq!(r.mauchly_p, Some(1.0));
    assert_eq!(r.mauchly_df, 0.0);
    let t = stats::paired_t(&A, &C).unwrap();
    close(r.f, t.t * t.t, 1e-12, "F = t²");
    close(r.p, t.p, 1e-12, "same p");
    close(r.p_gg, r.p, 0.0, "no correction");
}

// ------------------------------------------------------------ Wilcoxon

/// The options for `method`, with or without the continuity correction.
fn options(method: WilcoxonMethod, continuity: bool) -> WilcoxonOptions {
    WilcoxonOptions { method, continuity }
}

/// The signed-rank test of the differences `d` with `method`.
fn wilcoxon_with(d: &[f64], method: WilcoxonMethod, continuity: bool) -> stats::WilcoxonTest {
    stats::wilcoxon_signed_rank_diffs(d, options(method, continuity)).expect("wilcoxon")
}

/// Brute-force two-sided exact p over all 2^m sign patterns of `ranks`.
fn brute_force_p(ranks: &[f64], r_plus: f64) -> f64 {
    let m = ranks.len();
    let total = 1u64 << m;
    let (mut le, mut ge) = (0u64, 0u64);
    for mask in 0..total {
        let s: f64 = (0..m)
            .filter(|i| mask >> i & 1 == 1)
            .map(|i| ranks[i])
            .sum();
        if s <= r_plus + 1e-9 {
            le += 1;
        }
        if s >= r_plus - 1e-9 {
            ge += 1;
        }
    }
    (2.0 * le.min(ge) as f64 / total as f64).min(1.0)
}

#[test]
fn scipy_wilcoxon_documentation_example() {
    let d = [
        6.0, 8.0, 14.0, 16.0, 23.0, 24.0, 28.0, 29.0, 41.0, -48.0, 49.0, 56.0, 60.0, -67.0, 75.0,
    ];
    let r = stats::wilcoxon_signed_rank_diffs(&d, WilcoxonOptions::default()).unwrap();
    assert_eq!(r.method, WilcoxonMethodUsed::Exact);
    assert_eq!(r.statistic, 24.0);
    assert_eq!(r.r_minus, 24.0); // ranks of −48 (10) and −67 (14)
    close(r.p, 0.041259765625, 1e-12, "scipy exact p");
    let ranks: Vec<f64> = (1..=15).map(f64::from).collect();
    close(r.p, brute_force_p(&ranks, r.r_plus), 1e-14, "brute force");

    // Normal approximation: z = (R⁺ − n(n+1)/4)/√(n(n+1)(2n+1)/24).
    let asym = wilcoxon_with(&d, WilcoxonMethod::Asymptotic, false);
    let se = (15.0 * 16.0 * 31.0 / 24.0_f64).sqrt();
    let z = (96.0 - 60.0) / se;
    close(asym.z.unwrap(), z, 1e-12, "z");
    close(
        asym.p,
        statrs::function::erf::erfc(z / 2f64.sqrt()),
        1e-14,
        "p",
    );
    close(asym.p, 0.04088813291185591, 1e-10, "scipy asymptotic");
    let cc = wilcoxon_with(&d, WilcoxonMethod::Asymptotic, true);
    close(cc.z.unwrap(), z - 0.5 / se, 1e-12, "continuity z");
    close(cc.p, 0.043772323763041174, 1e-10, "scipy correction=True");
}

#[test]
fn wilcoxon_with_ties_and_zero_small_n_is_exact_conditional() {
    // scipy.stats.wilcoxon([1,2,2,3,-1,4,0,5]) = (1.5, 0.046875).
    let d = [1.0, 2.0, 2.0, 3.0, -1.0, 4.0, 0.0, 5.0];
    let r = stats::wilcoxon_signed_rank_diffs(&d, WilcoxonOptions::default()).unwrap();
    assert_eq!(r.method, WilcoxonMethodUsed::ExactConditional);
    assert_eq!((r.n_zero, r.n_nonzero), (1, 7));
    assert!(r.ties);
    assert_eq!(r.statistic, 1.5);
    // Mid-ranks of |d| without the zero: 1.5 3.5 3.5 5 1.5 6 7.
    let ranks = [1.5, 3.5, 3.5, 5.0, 1.5, 6.0, 7.0];
    close(r.p, brute_force_p(&ranks, r.r_plus), 1e-14, "brute force");
    close(r.p, 0.046875, 1e-15, "scipy");
}

#[test]
fn wilcoxon_with_ties_large_n_is_normal_with_tie_corrected_variance() {
    // 17 differences with ties and no zero → scipy uses the normal
    // approximation (p = 0.0038716561985912908).
    let d = [
        1.0, 2.0, 2.0, 3.0, -1.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, -12.0, 13.0, 14.0, 15.0,
    ];
    let r = stats::wilcoxon_signed_rank_diffs(&d, WilcoxonOptions::default()).unwrap();
    assert_eq!(r.method, WilcoxonMethodUsed::Normal);
    let n = 17.0_f64;
    // Tie groups |1| × 2 and |2| × 2: Σ(t³ − t) = 12.
    let var = (n * (n + 1.0) * (2.0 * n + 1.0) - 12.0 / 2.0) / 24.0;
    let r_minus = 1.5 + 14.0;
    let r_plus = n * (n + 1.0) / 2.0 - r_minus;
    let z = (r_plus - n * (n + 1.0) / 4.0) / var.sqrt();
    close(r.z.unwrap(), z, 1e-12, "z");
    close(r.p, 0.0038716561985912908, 1e-12, "scipy p");
    // Forcing the exact conditional distribution differs only slightly.
    let ex = wilcoxon_with(&d, WilcoxonMethod::Exact, false);
    assert_eq!(ex.method, WilcoxonMethodUsed::ExactConditional);
    let mut ranks = vec![1.5, 3.5, 3.5];
    ranks.extend((5..=17).map(f64::from));
    ranks.push(1.5);
    ranks.sort_by(f64::total_cmp);
    close(
        ex.p,
        brute_force_p(&ranks, r_plus),
        1e-12,
        "brute force 2^17",
    );
}

#[test]
fn wilcoxon_large_sample_without_ties_switches_to_normal() {
    let d: Vec<f64> = (1..=60)
        .map(|i| {
            if i % 3 == 0 {
                -f64::from(i)
            } else {
                f64::from(i)
            }
        })
        .collect();
    let r = stats::wilcoxon_signed_rank_diffs(&d, WilcoxonOptions::default()).unwrap();
    assert_eq!(r.method, WilcoxonMethodUsed::Normal);
    let ex = wilcoxon_with(&d, WilcoxonMethod::Exact, false);
    assert_eq!(ex.method, WilcoxonMethodUsed::Exact);
    // At n = 60 the normal approximation is good to a few per cent.
    assert!((r.p - ex.p).abs() < 0.05 * ex.p, "{} vs {}", r.p, ex.p);
}

#[test]
fn wilcoxon_exact_request_is_capped_for_huge_samples() {
    let m = stats::EXACT_MAX_N + 1;
    let d: Vec<f64> = (1..=m)
        .map(|i| {
            if i % 2 == 0 {
                i as f64
            } else {
                -(i as f64) * 0.999
            }
        })
        .collect();
    let opts = options(WilcoxonMethod::Exact, false);
    let r = stats::wilcoxon_signed_rank_diffs(&d, opts).unwrap();
    assert_eq!(r.method, WilcoxonMethodUsed::Normal);
    let r = stats::wilcoxon_signed_rank_diffs(&d[..stats::EXACT_MAX_N], opts).unwrap();
    assert_eq!(r.method, WilcoxonMethodUsed::Exact);
    assert!(r.p > 0.0 && r.p <= 1.0);
}

/// Hard case: a huge common offset (1e8, e.g. positions in nm from a far
/// origin) with effects of order 1e-2 must not change F, ε or Friedman.
#[test]
fn large_offsets_do_not_destroy_precision() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let m = random_matrix(&mut rng, 12, 3);
    let small: Vec<f64> = m.values().iter().map(|v| 0.01 * v).collect();
    let offset: Vec<f64> = small.iter().map(|v| 1e8 + v).collect();
    let a = CellMatrix::new(m.subjects().to_vec(), m.conditions().to_vec(), small).unwrap();
    let b = CellMatrix::new(m.subjects().to_vec(), m.conditions().to_vec(), offset).unwrap();
    let (ra, rb) = (stats::rm_anova(&a).unwrap(), stats::rm_anova(&b).unwrap());
    close(rb.f, ra.f, 1e-5 * ra.f, "F with offset");
    close(rb.eps_gg, ra.eps_gg, 1e-5, "GG with offset");
    close(rb.p, ra.p, 1e-5, "p with offset");
    let oa = stats::one_way_anova(&[a.column(0), a.column(1), a.column(2)]).unwrap();
    let ob = stats::one_way_anova(&[b.column(0), b.column(1), b.column(2)]).unwrap();
    close(ob.f, oa.f, 1e-5 * oa.f, "oneway F with offset");
}

#[test]
fn pairwise_wilcoxon_matches_single_tests() {
    let m = rm_example();
    let rows = stats::pairwise_wilcoxon(&m, WilcoxonOptions::default()).unwrap();
    // scipy: (A,B) 0.625, (A,C) 0.25, (B,C) 0.125. A − C has a zero
    // difference (7.2 − 7.2), so scipy (and we) use the exact conditional
    // (permutation) distribution there; the others are exact. Note that
    // 2.2 − 1.1 and 4.1 − 5.2 differ in the last bit, so |d| has no tie.
    let methods = [
        WilcoxonMethodUsed::Exact,
        WilcoxonMethodUsed::ExactConditional,
        WilcoxonMethodUsed::Exact,
    ];
    for ((row, want), method) in rows.iter().zip([0.625, 0.25, 0.125]).zip(methods) {
        close(row.p, want, 1e-15, "scipy wilcoxon p");
        assert_eq!(row.method, Some(method));
    }
    let adj = stats::holm(&[0.625, 0.25, 0.125]).unwrap();
    for (row, h) in rows.iter().zip(adj) {
        assert_eq!(row.p_holm, h);
    }
}

// --------------------------------------------------------------- Holm

/// Holm's procedure at level α rejects H_(1..r) where r is the first j with
/// p_(j) > α/(m − j + 1). The adjusted p-values must reproduce exactly that
/// rejection set for every α.
#[test]
fn holm_adjusted_p_reproduce_the_step_down_procedure() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for trial in 0..200 {
        let m = 1 + trial % 12;
        let p: Vec<f64> = (0..m)
            .map(|_| {
                let u = uniform(&mut rng);
                if trial % 3 == 0 { u * 0.05 } else { u }
            })
            .collect();
        let adj = stats::holm(&p).unwrap();
        let mut order: Vec<usize> = (0..m).collect();
        order.sort_by(|&a, &b| p[a].total_cmp(&p[b]));
        for (i, (&pi, &ai)) in p.iter().zip(&adj).enumerate() {
            assert!(ai >= pi, "adjusted below raw");
            assert!(ai <= 1.0);
            for (j, &pj) in p.iter().enumerate() {
                if pj < pi {
                    assert!(adj[j] <= ai, "not monotone at {i},{j}");
                }
            }
        }
        for &alpha in &[0.001, 0.01, 0.05, 0.1, 0.3] {
            let mut rejected = vec![false; m];
            for (j, &i) in order.iter().enumerate() {
                if p[i] <= alpha / (m - j) as f64 {
                    rejected[i] = true;
                } else {
                    break;
                }
            }
            for i in 0..m {
                assert_eq!(adj[i] <= alpha, rejected[i], "alpha {alpha}, p {p:?}");
            }
        }
    }
}

// ------------------------------------------------------------ invariants

fn random_matrix(rng: &mut ChaCha8Rng, n: usize, k: usize) -> CellMatrix {
    // Subject effects, condition effects and a non-spherical error.
    let mut cols = Vec::new();
    let subj: Vec<f64> = (0..n).map(|_| 3.0 * normal(rng)).collect();
    let shared: Vec<f64> = (0..n).map(|_| normal(rng)).collect();
    for j in 0..k {
        let col: Vec<f64> = (0..n)
            .map(|i| {
                subj[i]
                    + 0.2 * j as f64
                    + (j as f64 * 0.7) * shared[i]
                    + (1.0 + j as f64) * normal(rng)
            })
            .collect();
        cols.push((format!("c{j}"), col));
    }
    CellMatrix::from_columns(&cols).expect("valid matrix")
}

#[test]
fn epsilon_bounds_and_hf_not_below_gg() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for trial in 0..300 {
        let k = 2 + trial % 6;
        let n = 2 + (trial / 6) % 12;
        let m = random_matrix(&mut rng, n, k);
        let r = stats::rm_anova(&m).unwrap();
        let lb = 1.0 / (k - 1) as f64;
        assert!(
            r.eps_gg >= lb - 1e-12 && r.eps_gg <= 1.0 + 1e-12,
            "GG {}",
            r.eps_gg
        );
        assert!(
            r.eps_hf >= r.eps_gg - 1e-12 && r.eps_hf <= 1.0,
            "HF {}",
            r.eps_hf
        );
        // Shrinking both df makes the test more conservative once F is
        // clearly above 1 (for F ≲ 1.7 the tail need not be monotone in ε).
        if r.f >= 2.0 {
            assert!(r.p <= r.p_hf + 1e-12 && r.p_hf <= r.p_gg + 1e-12);
            assert!(r.p_gg <= r.p_lb + 1e-12);
        }
        assert!((0.0..=1.0).contains(&r.np2) && r.ng2 <= r.np2);
        match r.mauchly_w {
            Some(w) => {
                assert!((0.0..=1.0 + 1e-12).contains(&w));
                assert!(n > k - 1 || k == 2);
            }
            None => assert!(n - 1 < k - 1),
        }
    }
}

#[test]
fn condition_permutation_and_affine_invariance() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let m = random_matrix(&mut rng, 9, 4);
    let r = stats::rm_anova(&m).unwrap();
    let fr = stats::friedman(&m).unwrap();
    let perm = [2, 0, 3, 1];
    let pm = m.permute_conditions(&perm).unwrap();
    let rp = stats::rm_anova(&pm).unwrap();
    let fp = stats::friedman(&pm).unwrap();
    for (a, b, w) in [
        (r.f, rp.f, "F"),
        (r.p, rp.p, "p"),
        (r.eps_gg, rp.eps_gg, "GG"),
        (r.eps_hf, rp.eps_hf, "HF"),
        (r.mauchly_w.unwrap(), rp.mauchly_w.unwrap(), "W"),
        (r.ng2, rp.ng2, "ng2"),
        (fr.chi2, fp.chi2, "chi2"),
        (fr.kendall_w, fp.kendall_w, "Kendall W"),
    ] {
        close(a, b, 1e-10 * a.abs().max(1.0), w);
    }
    let pairs = stats::pairwise_t(&m).unwrap();
    let ppairs = stats::pairwise_t(&pm).unwrap();
    for row in &pairs {
        let other = ppairs
            .iter()
            .find(|o| (o.a == row.a && o.b == row.b) || (o.a == row.b && o.b == row.a))
            .unwrap();
        close(other.p, row.p, 1e-12, "pairwise p");
        close(other.p_holm, row.p_holm, 1e-12, "pairwise Holm");
        close(other.statistic.abs(), row.statistic.abs(), 1e-12, "|t|");
    }
    // Oneway through the long format with a different condition order.
    let rows: Vec<(String, String, f64)> = (0..m.n_subjects())
        .flat_map(|i| {
            let m = &m;
            (0..m.n_conditions()).map(move |j| {
                (
                    m.subjects()[i].clone(),
                    m.conditions()[j].clone(),
                    m.row(i)[j],
                )
            })
        })
        .collect();
    let d = Design::from_long(rows).unwrap();
    let o1 = stats::oneway(&d).unwrap();
    let o2 = stats::oneway(&d.with_condition_order(&["c3", "c1", "c0", "c2"]).unwrap()).unwrap();
    close(o1.f, o2.f, 1e-10, "oneway F");
    // Affine change of units (e.g. µm → nm, offset): F and ε unchanged;
    // monotone transform: Friedman unchanged exactly.
    let scaled: Vec<f64> = m.values().iter().map(|v| 1000.0 * v - 7.0).collect();
    let sm = CellMatrix::new(m.subjects().to_vec(), m.conditions().to_vec(), scaled).unwrap();
    let rs = stats::rm_anova(&sm).unwrap();
    close(rs.f, r.f, 1e-9 * r.f, "affine F");
    close(rs.eps_gg, r.eps_gg, 1e-9, "affine GG");
    let cubed: Vec<f64> = m.values().iter().map(|v| v * v * v + v).collect();
    let cm = CellMatrix::new(m.subjects().to_vec(), m.conditions().to_vec(), cubed).unwrap();
    assert_eq!(stats::friedman(&cm).unwrap().chi2, fr.chi2);
}

#[test]
fn kendall_w_relation_and_perfect_concordance() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for trial in 0..100 {
        let m = random_matrix(&mut rng, 3 + trial % 10, 2 + trial % 5);
        let f = stats::friedman(&m).unwrap();
        let (n, k) = (m.n_subjects() as f64, m.n_conditions() as f64);
        close(f.kendall_w, f.chi2 / (n * (k - 1.0)), 1e-12, "W relation");
        assert!((0.0..=1.0).contains(&f.kendall_w));
    }
    // Every subject ranks the conditions identically: W = 1, χ² = n(k − 1),
    // the Iman–Davenport F is unbounded (None) and its p is 0.
    let m = CellMatrix::from_columns(&[
        ("a", [1.0, 2.0, 3.0, 4.0]),
        ("b", [5.0, 6.0, 7.0, 8.0]),
        ("c", [9.0, 10.0, 11.0, 12.0]),
    ])
    .unwrap();
    let f = stats::friedman(&m).unwrap();
    assert_eq!(f.kendall_w, 1.0);
    close(f.chi2, 8.0, 1e-12, "chi2 = n(k-1)");
    assert_eq!(f.f_iman_davenport, None);
    assert_eq!(f.p_f, 0.0);
}

// ------------------------------------------------------------ degenerate

#[test]
fn degenerate_designs_are_typed_errors() {
    // One subject.
    let one = CellMatrix::from_columns(&[("a", [1.0]), ("b", [2.0]), ("c", [4.0])]).unwrap();
    assert!(matches!(
        stats::rm_anova(&one),
        Err(StatsError::TooFewSubjects { .. })
    ));
    assert!(matches!(
        stats::friedman(&one),
        Err(StatsError::TooFewSubjects { .. })
    ));
    assert!(stats::pairwise_t(&one).is_err());
    // One condition.
    let single = CellMatrix::from_columns(&[("a", [1.0, 2.0, 3.0])]).unwrap();
    assert!(matches!(
        stats::rm_anova(&single),
        Err(StatsError::TooFewConditions { .. })
    ));
    assert!(matches!(
        stats::friedman(&single),
        Err(StatsError::TooFewConditions { .. })
    ));
    assert!(matches!(
        stats::one_way_anova(&[[1.0, 2.0]]),
        Err(StatsError::TooFewConditions { .. })
    ));
    // Zero variance: constant data; additive data (no interaction: x_ij =
    // s_i + c_j exactly in binary, 0.1-style values in decimal).
    let constant = CellMatrix::from_columns(&[("a", [3.0; 4]), ("b", [3.0; 4])]).unwrap();
    assert!(matches!(
        stats::rm_anova(&constant),
        Err(StatsError::ZeroVariance { .. })
    ));
    assert!(matches!(
        stats::friedman(&constant),
        Err(StatsError::ZeroVariance { .. })
    ));
    let subj = [0.1, 0.7, 1.3, 2.9];
    let cols: Vec<(String, Vec<f64>)> = [0.0, 0.3, 1.1]
        .iter()
        .enumerate()
        .map(|(j, c)| (format!("c{j}"), subj.iter().map(|s| s + c).collect()))
        .collect();
    let additive = CellMatrix::from_columns(&cols).unwrap();
    let err = stats::rm_anova(&additive).unwrap_err();
    assert!(matches!(err, StatsError::ZeroVariance { .. }), "{err:?}");
    assert!(matches!(
        stats::one_way_anova(&[[1.0, 1.0], [2.0, 2.0]]),
        Err(StatsError::ZeroVariance { .. })
    ));
    assert!(matches!(
        stats::one_way_anova(&[vec![1.0, 2.0], vec![]]),
        Err(StatsError::EmptyGroup { .. })
    ));
    assert!(matches!(
        stats::one_way_anova(&[[1.0], [2.0]]),
        Err(StatsError::TooFewSubjects { .. })
    ));
    // Paired tests with constant differences; all-zero differences.
    let err = stats::paired_t(&[1.0, 2.0, 3.0], &[0.0, 1.0, 2.0]).unwrap_err();
    assert!(matches!(err, StatsError::ZeroVariance { .. }));
    let err = stats::wilcoxon_signed_rank(&[1.0, 2.0], &[1.0, 2.0], WilcoxonOptions::default())
        .unwrap_err();
    assert!(matches!(err, StatsError::ZeroVariance { .. }));
    let err = stats::pairwise_t(
        &CellMatrix::from_columns(&[("X", [1.0, 2.0]), ("Y", [2.0, 3.0])]).unwrap(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("`X` vs `Y`"), "{err}");
    assert!(matches!(
        stats::paired_t(&[1.0, 2.0], &[1.0]),
        Err(StatsError::LengthMismatch { .. })
    ));
    // Non-finite input.
    assert!(matches!(
        stats::paired_t(&[1.0, f64::NAN, 3.0], &[0.0, 1.0, 2.5]),
        Err(StatsError::NonFiniteInput { .. })
    ));
    assert!(matches!(
        stats::one_way_anova(&[[1.0, f64::INFINITY], [2.0, 3.0]]),
        Err(StatsError::NonFiniteInput { .. })
    ));
    assert!(matches!(
        stats::wilcoxon_signed_rank_diffs(&[1.0, f64::NAN], WilcoxonOptions::default()),
        Err(StatsError::NonFiniteInput { .. })
    ));
    // Missing cells → incomplete design for within-subject tests, by name.
    let rows = vec![
        ("p1", "V", 1.0),
        ("p1", "P", 2.0),
        ("p2", "V", 1.5),
        ("p2", "P", 2.5),
        ("p2", "D", 3.5),
        ("p1", "V", 1.2),
    ];
    let d = Design::from_long(rows).unwrap();
    for test in [Test::Rm, Test::Friedman] {
        let err = stats::run_test(&d, test).unwrap_err();
        assert_eq!(err.to_string(), "incomplete design: subject `p1` lacks `D`");
    }
    assert!("anova2".parse::<Test>().is_err());
    assert_eq!("RM".parse::<Test>().unwrap(), Test::Rm);
}

/// Rank-deficient designs: fewer subjects than conditions makes Mauchly's
/// test undefined (None) but the ANOVA is still valid; exactly collinear
/// contrasts (two conditions identical for everyone, as with ceiling
/// counts) give W = 0, p = 0 and ε_GG at its lower bound.
#[test]
fn mauchly_undefined_or_zero_in_rank_deficient_designs() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let m = random_matrix(&mut rng, 3, 5);
    let r = stats::rm_anova(&m).unwrap();
    assert_eq!(
        (r.mauchly_w, r.mauchly_chi2, r.mauchly_p),
        (None, None, None)
    );
    assert!(r.p.is_finite() && r.eps_hf >= r.eps_gg && r.eps_hf <= 1.0);

    let v = [3.0, 5.0, 4.0, 6.0, 2.0, 5.0, 7.0, 3.0];
    let pd = [10.0, 9.0, 10.0, 8.0, 10.0, 9.0, 10.0, 10.0];
    let m = CellMatrix::from_columns(&[("V", v), ("P", pd), ("D", pd)]).unwrap();
    let r = stats::rm_anova(&m).unwrap();
    assert_eq!(r.mauchly_w, Some(0.0));
    assert_eq!(r.mauchly_chi2, None);
    assert_eq!(r.mauchly_p, Some(0.0));
    close(r.eps_gg, 0.5, 1e-12, "GG at lower bound");
    let json = serde_json::to_string(&r).unwrap();
    assert!(!json.contains("NaN") && !json.contains("inf"), "{json}");
}
