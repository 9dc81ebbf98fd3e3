//! `kilotouch study power` end to end, as a user runs it: simulate a small
//! pilot with `study simulate`, then plan from its folder (table, JSON,
//! PNG and SVG plots, thread independence, clear errors).
#![allow(clippy::unwrap_used)]

use common::{kilotouch as run, simulate_study, write_circling_protocol_timeout};
use kilotouch_testkit as common;
use serde_json::Value;
use std::path::Path;

/// A pilot: 6 simulated participants × V/P/D × 3 test trials, no raw files.
fn pilot(dir: &Path) -> String {
    let protocol = write_circling_protocol_timeout(dir, "pilot", 3, 1, 5, 60.0);
    let out = dir.join("pilot");
    let o = simulate_study(
        &protocol,
        &out,
        &["--participants", "6", "--no-raw", "--json"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out.to_string_lossy().into_owned()
}

fn power_args<'a>(pilot: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "study",
        "power",
        "--pilot",
        pilot,
        "--dv",
        "disp_err_mean_um",
        "--n",
        "3,6,12",
        "--replications",
        "300",
        "--seed",
        "9",
    ];
    a.extend_from_slice(extra);
    a
}

#[test]
fn power_from_a_simulated_pilot() {
    let tmp = tempfile::tempdir().expect("tmp");
    let pilot = pilot(tmp.path());

    // JSON: the contract's keys, sane values.
    let o = run(&power_args(
        &pilot,
        &["--contrast", "V-P", "--json", "--threads", "1"],
    ));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("noisy") && stderr.contains("95 % CI"),
        "{stderr}"
    );
    let v: Value = serde_json::from_slice(&o.stdout).expect("json");
    let points = v["points"].as_array().expect("points");
    assert_eq!(points.len(), 3);
    for (p, n) in points.iter().zip([3, 6, 12]) {
        assert_eq!(p["n"].as_u64(), Some(n));
        let pw = p["power"].as_f64().expect("power");
        let ci = p["ci"].as_array().expect("ci");
        let (lo, hi) = (ci[0].as_f64().expect("lo"), ci[1].as_f64().expect("hi"));
        assert!((0.0..=1.0).contains(&pw) && lo <= pw && pw <= hi, "{p}");
    }
    for k in ["effect", "sd_diff", "model", "n_for_target"] {
        assert!(v.get(k).is_some(), "missing {k}");
    }
    assert_eq!(v["model"]["conditions"], serde_json::json!(["V", "P"]));
    assert_eq!(v["trials_per_condition"].as_u64(), Some(3));

    // Same seed, two threads: the same bytes.
    let o2 = run(&power_args(
        &pilot,
        &["--contrast", "V-P", "--json", "--threads", "2"],
    ));
    assert!(o2.status.success());
    assert_eq!(o.stdout, o2.stdout);

    // Table and plots.
    let png = tmp.path().join("power.png");
    let svg = tmp.path().join("power.svg");
    let o = run(&power_args(
        &pilot,
        &["--test", "rm", "--plot", png.to_str().expect("utf-8")],
    ));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("repeated-measures ANOVA"), "{table}");
    assert!(
        table.contains("95 % CI") && table.contains("noisy"),
        "{table}"
    );
    assert!(
        table.lines().any(|l| l.trim_start().starts_with("12 ")),
        "{table}"
    );
    let bytes = std::fs::read(&png).expect("png");
    assert!(bytes.starts_with(b"\x89PNG") && bytes.len() > 10_000);
    let o = run(&power_args(
        &pilot,
        &[
            "--contrast",
            "V-P",
            "--effect",
            "0",
            "--plot",
            svg.to_str().expect("utf-8"),
        ],
    ));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&svg).expect("svg");
    assert!(text.starts_with("<svg") && text.contains("participants (n)"));
}

/// `study power` of `dv` for `contrast` at n = 4 with 10 replications
/// (seed 1) from the pilot at `path`.
fn small_power(path: &str, dv: &str, contrast: &str) -> std::process::Output {
    run(&[
        "study",
        "power",
        "--pilot",
        path,
        "--dv",
        dv,
        "--contrast",
        contrast,
        "--n",
        "4",
        "--replications",
        "10",
        "--seed",
        "1",
    ])
}

#[test]
fn power_errors_name_the_problem() {
    let tmp = tempfile::tempdir().expect("tmp");
    let csv = tmp.path().join("p.csv");
    std::fs::write(
        &csv,
        "participant,condition,score\ns1,A,1\ns1,B,2\ns2,A,1.5\ns2,B,x\n",
    )
    .expect("write");
    let path = csv.to_str().expect("utf-8");
    let o = small_power(path, "score", "A-B");
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("line 5") && e.contains("`x`"), "{e}");
    let o = small_power(path, "nope", "A-B");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && e.contains("`nope`") && e.contains("score"),
        "{e}"
    );
    std::fs::write(
        &csv,
        "participant,condition,score\ns1,A,1\ns1,B,2\ns2,A,1.5\ns2,B,2.1\n",
    )
    .expect("write");
    let o = small_power(path, "score", "A-C");
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("A-C"), "{e}");
}
