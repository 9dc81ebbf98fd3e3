//! `kilotouch stats` against the public test vectors of docs/REFERENCE-VALUES.md.

#![allow(clippy::unwrap_used)]

use common::kilotouch as run;
use kilotouch_testkit as common;
use serde_json::Value;

fn long_csv(dir: &tempfile::TempDir, name: &str, conds: &[(&str, &[f64])]) -> String {
    let mut t = String::from("participant,condition,score\n");
    for (c, vals) in conds {
        for (i, v) in vals.iter().enumerate() {
            t += &format!("s{i},{c},{v}\n");
        }
    }
    let p = dir.path().join(name);
    std::fs::write(&p, t).expect("write");
    p.to_string_lossy().into_owned()
}

/// `kilotouch stats PATH --dv score --within condition --subject
/// participant --test TEST`, then `extra`.
fn stats<'a>(path: &'a str, test: &'a str, extra: &[&'a str]) -> std::process::Output {
    let mut args = common::stats_args(path, "score", test);
    args.extend_from_slice(extra);
    run(&args)
}

fn stats_json(path: &str, test: &str) -> Value {
    let out = stats(path, test, &["--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("json")
}

fn near(v: &Value, k: &str, want: f64, tol: f64) {
    let got = v[k]
        .as_f64()
        .unwrap_or_else(|| panic!("missing {k} in {v}"));
    assert!((got - want).abs() <= tol, "{k}: {got} vs {want}");
}

#[test]
fn repeated_measures_reference_vector() {
    let dir = tempfile::tempdir().unwrap();
    let p = long_csv(
        &dir,
        "rm.csv",
        &[
            ("A", &[2.2, 3.1, 4.3, 4.1, 7.2]),
            ("B", &[1.1, 2.5, 4.1, 5.2, 6.4]),
            ("C", &[8.2, 4.5, 3.4, 6.2, 7.2]),
        ],
    );
    let v = stats_json(&p, "rm");
    near(&v, "F", 2.153754, 1e-6);
    near(&v, "df1", 2.0, 0.0);
    near(&v, "df2", 8.0, 0.0);
    near(&v, "p", 0.178517, 1e-6);
    near(&v, "eps_gg", 0.558775, 1e-6);
    near(&v, "p_gg", 0.211692, 1e-6);
    near(&v, "eps_hf", 0.622345, 1e-6);
    near(&v, "mauchly_w", 0.210372, 1e-6);
    near(&v, "mauchly_p", 0.09649, 1e-5);
    near(&v, "ng2", 0.202931, 1e-6);
    assert!(v["np2"].as_f64().is_some() && v["p_hf"].as_f64().is_some());
}

#[test]
fn friedman_reference_vector() {
    let dir = tempfile::tempdir().unwrap();
    let p = long_csv(
        &dir,
        "fr.csv",
        &[
            ("before", &[72.0, 96.0, 88.0, 92.0, 74.0, 76.0, 82.0]),
            (
                "immediately_after",
                &[120.0, 120.0, 132.0, 120.0, 101.0, 96.0, 112.0],
            ),
            (
                "five_min_after",
                &[76.0, 95.0, 104.0, 96.0, 84.0, 72.0, 76.0],
            ),
        ],
    );
    let v = stats_json(&p, "friedman");
    near(&v, "chi2", 10.571428571, 1e-6);
    near(&v, "p", 0.005063414, 1e-6);
    near(&v, "df", 2.0, 0.0);
    // Kendall's W = χ²/(n(k−1)) with n = 7, k = 3.
    near(&v, "kendall_w", 10.571428571 / 14.0, 1e-6);
}

#[test]
fn oneway_plantgrowth() {
    let dir = tempfile::tempdir().unwrap();
    let p = long_csv(
        &dir,
        "pg.csv",
        &[
            (
                "ctrl",
                &[4.17, 5.58, 5.18, 6.11, 4.50, 4.61, 5.17, 4.53, 5.33, 5.14],
            ),
            (
                "trt1",
                &[4.81, 4.17, 4.41, 3.59, 5.87, 3.83, 6.03, 4.89, 4.32, 4.69],
            ),
            (
                "trt2",
                &[6.31, 5.12, 5.54, 5.50, 5.37, 5.29, 4.92, 6.15, 5.80, 5.26],
            ),
        ],
    );
    let v = stats_json(&p, "oneway");
    near(&v, "F", 4.846087862, 1e-6);
    near(&v, "df1", 2.0, 0.0);
    near(&v, "df2", 27.0, 0.0);
    near(&v, "p", 0.015909958, 1e-6);
}

#[test]
fn malformed_inputs_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p.to_string_lossy().into_owned()
    };
    let check = |p: &str, needle: &str| {
        let out = stats(p, "rm", &[]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{p} should fail");
        assert!(err.contains(needle), "`{needle}` not in: {err}");
        assert!(!err.contains("panicked"), "{err}");
    };
    check(
        &write("nodv.csv", "participant,condition\ns1,A\n"),
        "no column named `score`",
    );
    check(
        &write(
            "nonnum.csv",
            "participant,condition,score\ns1,A,1\ns1,B,zz\n",
        ),
        "nonnum.csv, line 3, column `score`",
    );
    check(
        &write("ragged.csv", "participant,condition,score\ns1,A,1\ns1,B\n"),
        "ragged.csv, line 3",
    );
    // Nobody has every condition: the missing cells are named.
    check(
        &write(
            "incomplete.csv",
            "participant,condition,score\ns1,A,1\ns2,B,2\ns3,A,1\n",
        ),
        "subject `s1` lacks `B`",
    );
    check(
        &write(
            "badphase.csv",
            "participant,condition,score,phase\ns1,A,1,test\ns1,B,2,warmup\n",
        ),
        "badphase.csv, line 3, column `phase`",
    );
}

// ------------------------------------------------- a simulated study's trials.csv

/// `tests/data/study_small/trials.csv` (written by `kilotouch study simulate
/// --participants 6 --seed 1 --no-raw`) and its pingouin values
/// (`crates/study/tests/pingouin_reference.py`).
fn study_reference() -> (String, Value) {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/study_small");
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../study/tests/data/pingouin_reference.json"
    ))
    .unwrap();
    let r: Value = serde_json::from_str(&text).unwrap();
    (format!("{dir}/trials.csv"), r["study_small"].clone())
}

fn study_stats(path: &str, test: &str, extra: &[&str]) -> Value {
    let mut args = common::stats_args(path, "time_s", test);
    args.push("--json");
    args.extend_from_slice(extra);
    let out = run(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("json")
}

fn rel(v: &Value, k: &str, want: &Value) {
    let got = v[k]
        .as_f64()
        .unwrap_or_else(|| panic!("missing {k} in {v}"));
    let want = want.as_f64().unwrap();
    assert!(
        (got - want).abs() <= 1e-6 * want.abs().max(1.0),
        "{k}: {got} vs {want}"
    );
}

#[test]
fn study_trials_use_successful_test_rows_like_pingouin() {
    let (path, r) = study_reference();
    let v = study_stats(&path, "rm", &[]);
    rel(&v, "F", &r["F"]);
    rel(&v, "p", &r["p"]);
    assert_eq!(v["rows_used"], r["rows_used"]);
    assert_eq!(v["rows_excluded"]["practice"], r["rows_excluded_practice"]);
    assert_eq!(v["rows_excluded"]["rejected"], r["rows_excluded_rejected"]);
    // Two simulated participants never succeeded in V: dropped and named,
    // as pingouin does.
    assert_eq!(v["participants_dropped"], r["participants_dropped"]);
    assert_eq!(v["participants_used"], r["participants_used"]);
    let used = v["rows_used"].as_u64().unwrap();
    let excluded: u64 = v["rows_excluded"]
        .as_object()
        .unwrap()
        .values()
        .map(|x| x.as_u64().unwrap())
        .sum();
    assert_eq!(used + excluded, r["rows_total"].as_u64().unwrap());
    // Every row, as before the row rule: a different F (pingouin agrees).
    let all = study_stats(&path, "rm", &["--include-practice", "--include-rejected"]);
    rel(&all, "F", &r["F_all_rows"]);
    assert_eq!(all["rows_excluded"]["practice"], 0);
    let f = study_stats(&path, "friedman", &[]);
    rel(&f, "chi2", &r["friedman_q"]);
    // The human output says what was used.
    let out = run(&common::stats_args(&path, "time_s", "rm"));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains(&format!("used {used} of")) && text.contains("practice trials"),
        "{text}"
    );
    assert!(text.contains("successful test trials"), "{text}");
    assert!(
        text.contains("dropped (a condition without data): P01, P02"),
        "{text}"
    );
}

#[test]
fn participant_without_a_cell_is_dropped_and_named() {
    let (path, r) = study_reference();
    let who = r["dropped_participant"].as_str().unwrap();
    // Remove that participant's successful V test trials.
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let cols: Vec<&str> = header.split(',').collect();
    let idx = |n: &str| cols.iter().position(|c| *c == n).unwrap();
    let (pi, ci, phi, si) = (
        idx("participant"),
        idx("condition"),
        idx("phase"),
        idx("success"),
    );
    let mut out = String::from(header) + "\n";
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        if f[pi] == who && f[ci] == "V" && f[phi] == "test" && f[si] == "1" {
            continue;
        }
        out += l;
        out.push('\n');
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("trials.csv");
    std::fs::write(&p, out).unwrap();
    let p = p.to_string_lossy().into_owned();
    let v = study_stats(&p, "rm", &[]);
    assert_eq!(v["participants_dropped"], r["participants_dropped_then"]);
    rel(&v, "F", &r["F_dropped"]);
    rel(&v, "p", &r["p_dropped"]);
    let pw = study_stats(&p, "pairwise", &[]);
    assert_eq!(pw["participants_dropped"], r["participants_dropped_then"]);
    // pingouin orders the conditions alphabetically, the file by first
    // appearance: match the pairs, flipping t's sign for a reversed pair.
    let pairs = pw["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for w in r["pairs_dropped"].as_array().unwrap() {
        let g = pairs
            .iter()
            .find(|g| {
                (g["a"] == w["a"] && g["b"] == w["b"]) || (g["a"] == w["b"] && g["b"] == w["a"])
            })
            .unwrap();
        let sign = if g["a"] == w["a"] { 1.0 } else { -1.0 };
        let t = g["t"].as_f64().unwrap() * sign;
        let want = w["t"].as_f64().unwrap();
        assert!(
            (t - want).abs() <= 1e-6 * want.abs().max(1.0),
            "t {t} vs {want}"
        );
        rel(g, "p_holm", &w["p_holm"]);
    }
    let human = run(&common::stats_args(&p, "time_s", "rm"));
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(
        text.contains(&format!(
            "dropped (a condition without data): P01, P02, {who}"
        )),
        "{text}"
    );
}

/// The 8 × 3 case of the reference file as a long CSV: V–P differ by a
/// constant (t undefined), the others are ordinary.
fn constant_pair_csv(dir: &tempfile::TempDir) -> (String, Value) {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../study/tests/data/pingouin_reference.json"
    ))
    .unwrap();
    let r: Value = serde_json::from_str(&text).unwrap();
    let case = r["cases"]["n8_constant_pair"].clone();
    let conds = case["matrix"]["conditions"].as_array().unwrap();
    let mut t = String::from("participant,condition,score\n");
    for (i, row) in case["matrix"]["values"]
        .as_array()
        .unwrap()
        .iter()
        .enumerate()
    {
        for (c, v) in conds.iter().zip(row.as_array().unwrap()) {
            t += &format!("s{i},{},{}\n", c.as_str().unwrap(), v.as_f64().unwrap());
        }
    }
    let p = dir.path().join("pairs.csv");
    std::fs::write(&p, t).unwrap();
    (p.to_string_lossy().into_owned(), case)
}

#[test]
fn pairwise_reports_every_pair_and_an_undefined_one() {
    let dir = tempfile::tempdir().unwrap();
    let (p, case) = constant_pair_csv(&dir);
    let v = stats_json(&p, "pairwise");
    let pairs = v["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for key in [
        "a",
        "b",
        "t",
        "df",
        "p",
        "p_holm",
        "wilcoxon_w",
        "wilcoxon_p",
        "wilcoxon_p_holm",
        "dz",
        "dz_ci",
        "mean_diff",
        "mean_diff_ci",
    ] {
        assert!(pairs[0].get(key).is_some(), "key {key} in {}", pairs[0]);
    }
    for (g, w) in pairs.iter().zip(case["pairs"].as_array().unwrap()) {
        for k in ["t", "p", "p_holm", "wilcoxon_p", "wilcoxon_p_holm", "dz"] {
            if w[k].is_null() {
                assert!(g[k].is_null(), "{k}: {g}");
            } else {
                rel(g, k, &w[k]);
            }
        }
        if let Some(ci) = w["mean_diff_ci"].as_array() {
            let got = g["mean_diff_ci"].as_array().unwrap();
            assert!((got[0].as_f64().unwrap() - ci[0].as_f64().unwrap()).abs() < 1e-6);
            assert!((got[1].as_f64().unwrap() - ci[1].as_f64().unwrap()).abs() < 1e-6);
            let dz = g["dz_ci"].as_array().unwrap();
            let d = g["dz"].as_f64().unwrap();
            assert!(dz[0].as_f64().unwrap() < d && d < dz[1].as_f64().unwrap());
        }
    }
    // V–P: t undefined (constant difference), named; Wilcoxon defined.
    assert!(pairs[0]["t"].is_null());
    assert!(pairs[0]["wilcoxon_p"].is_number());
    assert!(
        pairs[0]["undefined"][0]
            .as_str()
            .unwrap()
            .contains("t-test")
    );
    let human = stats(&p, "pairwise", &[]);
    let text = String::from_utf8_lossy(&human.stdout);
    assert!(text.contains("V–P undefined: t-test"), "{text}");
}

#[test]
fn describe_gives_per_condition_summaries() {
    let dir = tempfile::tempdir().unwrap();
    let (p, case) = constant_pair_csv(&dir);
    let v = stats_json(&p, "describe");
    for (g, w) in v["conditions"]
        .as_array()
        .unwrap()
        .iter()
        .zip(case["describe"].as_array().unwrap())
    {
        assert_eq!(g["condition"], w["condition"]);
        assert_eq!(g["n"], w["n"]);
        for k in ["mean", "sd", "median", "q1", "q3", "iqr"] {
            rel(g, k, &w[k]);
        }
    }
    let rm = stats_json(&p, "rm");
    let ci = rm["np2_ci"].as_array().unwrap();
    let np2 = rm["np2"].as_f64().unwrap();
    assert!(ci[0].as_f64().unwrap() <= np2 && np2 <= ci[1].as_f64().unwrap());
    rel(&rm, "F", &case["rm"]["F"]);
    let want = case["rm"]["np2_ci"].as_array().unwrap();
    assert!((ci[0].as_f64().unwrap() - want[0].as_f64().unwrap()).abs() < 1e-6);
    assert!((ci[1].as_f64().unwrap() - want[1].as_f64().unwrap()).abs() < 1e-6);
}
