//! `kilotouch stats` against the public test vectors of docs/REFERENCE-VALUES.md.

use serde_json::Value;
use std::process::Command;

fn run(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kilotouch"))
        .args(args)
        .output()
        .expect("run kilotouch")
}

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
    let mut args = vec![
        "stats",
        path,
        "--dv",
        "score",
        "--within",
        "condition",
        "--subject",
        "participant",
        "--test",
        test,
    ];
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
        "nonnum.csv:3",
    );
    check(
        &write("ragged.csv", "participant,condition,score\ns1,A,1\ns1,B\n"),
        "ragged.csv:3",
    );
    check(
        &write(
            "incomplete.csv",
            "participant,condition,score\ns1,A,1\ns1,B,2\ns2,A,3\ns3,A,1\ns3,B,5\n",
        ),
        "s2",
    );
}
