//! Power analysis (`kilotouch_study::power`) against the noncentral-t closed
//! form (scipy.stats.nct reference values, `data/power_reference.py`), the
//! type-I error at `--effect 0`, monotonicity, thread independence and
//! the Clopper–Pearson interval (scipy.stats.beta).
//!
//! Monte Carlo comparisons use the 99.9 % Clopper–Pearson interval of the
//! simulated rate (not the 95 % one the report prints): the file makes
//! about 30 such comparisons, so at 95 % one would fail by chance every
//! other run of a changed seed; at 99.9 % the family-wise chance of a false
//! failure is ≈ 3 %.
#![allow(clippy::unwrap_used)]

use kilotouch_study::power::{
    EffectSpec, PilotRow, PilotTable, PowerOptions, PowerReport, PowerTest, clopper_pearson, power,
};
use serde_json::Value;

fn reference() -> Value {
    let text = include_str!("data/power_reference.json");
    serde_json::from_str(text).expect("reference json")
}

fn never_cancel(_: usize, _: usize) -> bool {
    true
}

/// `count` numbers with exactly the sample mean `mean` and SD `sd`
/// (n − 1 divisor), from a deterministic irregular sequence.
fn exact_sample(count: usize, mean: f64, sd: f64, phase: f64) -> Vec<f64> {
    let g: Vec<f64> = (0..count)
        .map(|i| (i as f64 * 2.3 + phase).sin() + 0.3 * (i as f64 * 0.7 + phase).cos())
        .collect();
    let m = g.iter().sum::<f64>() / count as f64;
    let s = (g.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (count as f64 - 1.0)).sqrt();
    g.iter().map(|x| mean + sd * (x - m) / s).collect()
}

/// A pilot: `cell_means[i][j]` for participant i, condition j; `trials`
/// test trials per cell whose values average exactly to the cell mean
/// (pairs cell ± c); `success(i, j, t)` says whether trial t succeeded
/// (a rejected trial's DV cell is empty, as in trials.csv).
fn pilot(
    conditions: &[&str],
    cell_means: &[Vec<f64>],
    trials: u32,
    resid: f64,
    success: impl Fn(usize, usize, u32) -> bool,
) -> PilotTable {
    let mut rows = Vec::new();
    let mut line = 2;
    for (i, means) in cell_means.iter().enumerate() {
        for (j, c) in conditions.iter().enumerate() {
            // Kept trials come in ± pairs so the kept mean is the cell mean.
            let mut kept = 0;
            for t in 0..trials {
                let ok = success(i, j, t);
                let value = ok.then(|| {
                    let c = resid * (0.6 + 0.1 * f64::from(kept / 2));
                    let v = if kept % 2 == 0 {
                        means[j] + c
                    } else {
                        means[j] - c
                    };
                    kept += 1;
                    v
                });
                rows.push(PilotRow {
                    line,
                    subject: format!("P{:02}", i + 1),
                    condition: (*c).to_owned(),
                    test: true,
                    success: Some(ok),
                    value,
                });
                line += 1;
            }
        }
    }
    PilotTable {
        path: "memory.csv".into(),
        dv: "disp_err_mean_um".into(),
        rows,
    }
}

/// 12 participants, A − B differences with mean exactly 0.5 and SD exactly
/// 1 (dz = 0.5), participant intercepts of SD ≈ 3, within-cell SD ≈ 0.5, 10
/// trials per cell, every trial successful.
fn paired_pilot() -> PilotTable {
    let n = 12;
    let d = exact_sample(n, 0.5, 1.0, 0.0);
    let u = exact_sample(n, 0.0, 3.0, 1.1);
    let means: Vec<Vec<f64>> = (0..n)
        .map(|i| vec![10.0 + u[i] + d[i], 10.0 + u[i]])
        .collect();
    pilot(&["A", "B"], &means, 10, 0.5, |_, _, _| true)
}

fn contrast() -> PowerTest {
    PowerTest::Contrast {
        a: "A".into(),
        b: "B".into(),
    }
}

fn opts(test: PowerTest, ns: &[u32], reps: u32, seed: u64) -> PowerOptions {
    let mut o = PowerOptions::new("disp_err_mean_um", test, ns.to_vec());
    o.replications = reps;
    o.seed = seed;
    o.threads = 2;
    o
}

fn run(table: &PilotTable, o: &PowerOptions) -> PowerReport {
    power(table, o, &never_cancel).expect("power")
}

#[test]
fn paired_contrast_matches_the_noncentral_t_closed_form() {
    let r = reference();
    let curve = &r["paired_t_power"][0];
    assert_eq!(curve["dz"].as_f64(), Some(0.5));
    let ns: Vec<u32> = curve["n"]
        .as_array()
        .expect("n")
        .iter()
        .map(|v| v.as_u64().expect("n") as u32)
        .collect();
    let want: Vec<f64> = curve["power"]
        .as_array()
        .expect("power")
        .iter()
        .map(|v| v.as_f64().expect("p"))
        .collect();
    let table = paired_pilot();
    let rep = run(&table, &opts(contrast(), &ns, 4000, 17));
    // The pilot's own estimates, and the model reproduces them at K = 10.
    assert!((rep.pilot_effect.estimate - 0.5).abs() < 1e-9);
    assert!((rep.pilot_effect.sd_diff - 1.0).abs() < 1e-9);
    assert!(
        (rep.sd_diff_model - 1.0).abs() < 1e-9,
        "{}",
        rep.sd_diff_model
    );
    assert!((rep.effect - 0.5).abs() < 1e-9);
    assert!(!rep.model.clipped);
    assert_eq!(rep.trials_per_condition, 10);
    for (p, w) in rep.points.iter().zip(&want) {
        let ci = clopper_pearson(p.rejected, p.replications, 0.999);
        assert!(
            ci[0] <= *w && *w <= ci[1],
            "n = {}: simulated {} (99.9 % CI {ci:?}), noncentral t {w}",
            p.n,
            p.power
        );
        assert_eq!(p.analysed, p.replications);
    }
}

#[test]
fn larger_assumed_effect_matches_the_closed_form_too() {
    let r = reference();
    let curve = &r["paired_t_power"][1];
    assert_eq!(curve["dz"].as_f64(), Some(0.8));
    let table = paired_pilot();
    let mut o = opts(contrast(), &[6, 12, 24], 4000, 5);
    o.effect = EffectSpec::Absolute(0.8);
    let rep = run(&table, &o);
    for p in &rep.points {
        let idx = [4, 6, 8, 12, 16, 24, 32]
            .iter()
            .position(|&n| n == p.n)
            .expect("n in reference");
        let w = curve["power"][idx].as_f64().expect("p");
        let ci = clopper_pearson(p.rejected, p.replications, 0.999);
        assert!(ci[0] <= w && w <= ci[1], "n = {}: {} vs {w}", p.n, p.power);
    }
}

/// A pilot with rejected trials whose rate varies by participant and
/// condition, three conditions with unequal variances.
fn messy_pilot() -> PilotTable {
    let n = 10;
    let u = exact_sample(n, 0.0, 2.0, 0.3);
    let w1 = exact_sample(n, 0.0, 0.5, 2.0);
    let w2 = exact_sample(n, 0.0, 1.5, 4.0);
    let means: Vec<Vec<f64>> = (0..n)
        .map(|i| vec![5.0 + u[i], 5.6 + u[i] + w1[i], 6.5 + u[i] + w2[i]])
        .collect();
    pilot(&["D", "P", "V"], &means, 10, 0.8, |i, j, t| {
        // V loses more trials, and some participants more than others.
        let fail_every = [7, 9, 3][j] + (i % 3) as u32;
        t % fail_every != fail_every - 1
    })
}

#[test]
fn effect_zero_rejects_at_alpha_at_every_n() {
    let table = messy_pilot();
    let ns = [3, 4, 6, 8, 12, 16, 24];
    for test in [
        PowerTest::Contrast {
            a: "P".into(),
            b: "V".into(),
        },
        PowerTest::Rm,
    ] {
        let mut o = opts(test.clone(), &ns, 4000, 99);
        o.effect = EffectSpec::Absolute(0.0);
        let rep = run(&table, &o);
        assert_eq!(rep.effect, 0.0);
        for p in &rep.points {
            let ci = clopper_pearson(p.rejected, p.replications, 0.999);
            assert!(
                ci[0] <= 0.05 && 0.05 <= ci[1],
                "{test:?} n = {}: rejection rate {} (99.9 % CI {ci:?})",
                p.n,
                p.power
            );
        }
    }
}

#[test]
fn power_is_monotone_in_n_and_in_the_effect() {
    let table = messy_pilot();
    let ns = [3, 5, 8, 13, 21];
    for test in [
        PowerTest::Contrast {
            a: "P".into(),
            b: "V".into(),
        },
        PowerTest::Rm,
    ] {
        let rep = run(&table, &opts(test.clone(), &ns, 2000, 3));
        for w in rep.points.windows(2) {
            assert!(
                w[1].power > w[0].power || w[1].power >= 0.999,
                "{test:?}: power {} at n = {} then {} at n = {}",
                w[0].power,
                w[0].n,
                w[1].power,
                w[1].n
            );
        }
        let mut last = -1.0;
        for scale in [0.0, 0.5, 1.0, 1.5] {
            let mut o = opts(test.clone(), &[8], 2000, 4);
            o.effect = EffectSpec::Scale(scale);
            let p = run(&table, &o).points[0].power;
            assert!(
                p > last,
                "{test:?}: power {p} at scale {scale} after {last}"
            );
            last = p;
        }
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let table = messy_pilot();
    let mut o = opts(PowerTest::Rm, &[4, 9], 700, 11);
    o.threads = 1;
    let one = run(&table, &o);
    o.threads = 5;
    let five = run(&table, &o);
    assert_eq!(one, five);
    o.seed = 12;
    assert_ne!(one.points, run(&table, &o).points);
}

#[test]
fn rejected_trials_drop_participants_as_the_beta_binomial_predicts() {
    // Every participant succeeds with probability 0.5 in B (no spread)
    // and always in A: with K = 2 trials, a participant loses B's cell with
    // probability 0.25 (independent, analytic).
    let n = 12;
    let d = exact_sample(n, 0.5, 1.0, 0.0);
    let means: Vec<Vec<f64>> = (0..n).map(|i| vec![1.0 + d[i], 1.0]).collect();
    let table = pilot(&["A", "B"], &means, 8, 0.3, |_, j, t| j == 0 || t % 2 == 0);
    let mut o = opts(contrast(), &[20], 4000, 8);
    o.trials = Some(2);
    let rep = run(&table, &o);
    let s = &rep.model.success[1];
    assert!((s.p - 0.5).abs() < 1e-12 && s.icc == 0.0, "{s:?}");
    let dropped = rep.points[0].mean_dropped / 20.0;
    // SE of the mean of 80 000 Bernoulli(0.25) = 0.0015.
    assert!((dropped - 0.25).abs() < 0.006, "dropped fraction {dropped}");
}

#[test]
fn clopper_pearson_matches_scipy_beta_quantiles() {
    let r = reference();
    for c in r["clopper_pearson_95"].as_array().expect("cp") {
        let (x, n) = (c["x"].as_u64().expect("x"), c["n"].as_u64().expect("n"));
        let ci = clopper_pearson(x, n, 0.95);
        let (lo, hi) = (c["lo"].as_f64().expect("lo"), c["hi"].as_f64().expect("hi"));
        assert!((ci[0] - lo).abs() < 1e-9, "{x}/{n}: lo {} vs {lo}", ci[0]);
        assert!((ci[1] - hi).abs() < 1e-9, "{x}/{n}: hi {} vs {hi}", ci[1]);
    }
}

#[test]
fn bad_options_and_pilots_are_refused_with_clear_errors() {
    let table = paired_pilot();
    let o = opts(
        PowerTest::Contrast {
            a: "A".into(),
            b: "X".into(),
        },
        &[4],
        10,
        1,
    );
    let e = power(&table, &o, &never_cancel).expect_err("unknown condition");
    assert!(e.to_string().contains("`X`"), "{e}");
    let e = power(&table, &opts(contrast(), &[1], 10, 1), &never_cancel).expect_err("n = 1");
    assert!(e.to_string().contains("--n 1"), "{e}");
    let e = power(&table, &opts(contrast(), &[4], 0, 1), &never_cancel).expect_err("0 reps");
    assert!(e.to_string().contains("--replications"), "{e}");
    let cancelled = power(&table, &opts(contrast(), &[4, 8], 100_000, 1), &|_, _| {
        false
    });
    assert!(cancelled.is_err());
}
