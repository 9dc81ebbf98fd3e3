//! The binary's CLI contract (README "Headless commands"), exercised through
//! the real executable. Expected values come from analytic results and
//! docs/REFERENCE-VALUES.md, not from earlier runs.

use kilotouch_testkit as common;

use common::{json_ok, kilotouch};
use serde_json::Value;
use std::f64::consts::PI;
use std::io::Write;

fn fails_with(args: &[&str], needle: &str) {
    let out = kilotouch(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "kilotouch {args:?} should fail");
    assert!(
        err.contains(needle),
        "stderr of {args:?} lacks `{needle}`: {err}"
    );
    assert!(
        !err.contains("panicked"),
        "kilotouch {args:?} panicked: {err}"
    );
}

fn write_csv(dir: &tempfile::TempDir, name: &str, text: &str) -> String {
    let p = dir.path().join(name);
    let mut f = std::fs::File::create(&p).expect("create csv");
    f.write_all(text.as_bytes()).expect("write csv");
    p.to_string_lossy().into_owned()
}

fn arr(v: &Value, k: &str) -> Vec<f64> {
    v[k].as_array()
        .unwrap_or_else(|| panic!("`{k}` is not an array"))
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

#[test]
fn help_lists_the_commands() {
    // Without arguments kilotouch opens the GUI; --help prints the commands.
    let out = kilotouch(&["--help"]);
    assert!(out.status.success());
    let s = String::from_utf8_lossy(&out.stdout);
    for cmd in ["crossover", "psd", "frf", "tfest", "bench", "gui"] {
        assert!(s.contains(cmd), "help lacks {cmd}: {s}");
    }
}

#[test]
fn crossover_lr4_matches_reference_values() {
    // docs/REFERENCE-VALUES.md: |L(fc)| = |H(fc)| = −6.0206 dB, in phase at fc, |L+H| = 1.
    let v = json_ok(&[
        "crossover",
        "--fs",
        "10000",
        "--fc",
        "200",
        "--order",
        "4",
        "--freqs",
        "20,200,2000",
        "--json",
    ]);
    let pts = v["points"].as_array().expect("points");
    assert_eq!(pts.len(), 3);
    let at_fc = &pts[1];
    assert_eq!(at_fc["f"].as_f64(), Some(200.0));
    for k in ["low_db", "high_db"] {
        let d = at_fc[k].as_f64().expect(k);
        assert!((d + 6.0206).abs() < 1e-3, "{k} = {d}");
    }
    let dphi = at_fc["low_deg"].as_f64().unwrap() - at_fc["high_deg"].as_f64().unwrap();
    assert!(
        dphi.abs() < 1e-6 || (dphi.abs() - 360.0).abs() < 1e-6,
        "L, H in phase: {dphi}"
    );
    for p in pts {
        assert!(
            p["sum_db"].as_f64().unwrap().abs() < 1e-9,
            "allpass sum: {p}"
        );
        for k in ["low_deg", "high_deg", "sum_deg"] {
            let d = p[k].as_f64().unwrap();
            assert!(d > -180.0 && d <= 180.0, "{k} = {d} not wrapped");
        }
    }
    // A decade above fc the LR4 low-pass is ≈ −80 dB/decade below its pass band
    // (analytic |L| = 1/(1 + (f/fc)^4) for the prewarped design at the digital fc).
    let low_2k = pts[2]["low_db"].as_f64().unwrap();
    assert!(
        low_2k < -75.0 && low_2k > -90.0,
        "LR4 low at 10 fc: {low_2k}"
    );
}

#[test]
fn crossover_rejects_bad_arguments() {
    let words = |s: &'static str| s.split(' ').collect::<Vec<_>>();
    fails_with(
        &words("crossover --fs 10000 --fc 200 --order 3 --freqs 1"),
        "order",
    );
    fails_with(
        &words("crossover --fs 10000 --fc 6000 --order 4 --freqs 1"),
        "fc",
    );
    fails_with(
        &words("crossover --fs 10000 --fc 200 --freqs 1,x"),
        "--freqs",
    );
}

#[test]
fn psd_of_white_noise_is_two_over_fs() {
    // Unit-variance white noise: one-sided density 2/fs (docs/REFERENCE-VALUES.md).
    // A deterministic LCG keeps the test independent of the library's RNG.
    let dir = tempfile::tempdir().unwrap();
    let mut state: u64 = 12345;
    let mut text = String::from("t,x\n");
    let n = 65536;
    let mut uniform = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    for i in 0..n {
        // Box–Muller.
        let (u1, u2) = (uniform(), uniform());
        let g = (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos();
        text += &format!("{i},{g}\n");
    }
    let path = write_csv(&dir, "noise.csv", &text);
    let fs = 1000.0;
    let v = json_ok(&[
        "psd",
        &path,
        "--fs",
        "1000",
        "--column",
        "x",
        "--nperseg",
        "256",
        "--json",
    ]);
    let f = arr(&v, "f");
    let p = arr(&v, "psd");
    assert_eq!(f.len(), 129);
    assert!((f[1] - fs / 256.0).abs() < 1e-12);
    let mean: f64 = p[1..128].iter().sum::<f64>() / 127.0;
    // 511 half-overlapping segments: the mean over 127 bins has a relative SD of about 0.5 %.
    assert!(
        (mean / (2.0 / fs) - 1.0).abs() < 0.03,
        "mean density {mean}"
    );
}

#[test]
fn frf_recovers_a_known_gain_and_delay() {
    // y[n] = 0.5 x[n−1]: H(f) = 0.5 e^{−j2πf/fs}, coherence 1 (up to the segment edge effects).
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::from("force,acc\n");
    let mut prev = 0.0;
    for x in common::xorshift_noise(7).take(16384) {
        text += &format!("{x},{}\n", 0.5 * prev);
        prev = x;
    }
    let path = write_csv(&dir, "io.csv", &text);
    let v = json_ok(&[
        "frf",
        &path,
        "--fs",
        "10000",
        "--input",
        "force",
        "--output",
        "acc",
        "--nperseg",
        "1024",
        "--json",
    ]);
    let f = arr(&v, "f");
    let re = arr(&v, "re");
    let im = arr(&v, "im");
    let coh = arr(&v, "coherence");
    for k in (10..500).step_by(37) {
        let w = 2.0 * PI * f[k] / 10000.0;
        let (er, ei) = (0.5 * w.cos(), -0.5 * w.sin());
        assert!(
            (re[k] - er).abs() < 0.01 && (im[k] - ei).abs() < 0.01,
            "H1 at {} Hz",
            f[k]
        );
        assert!(coh[k] > 0.99, "coherence at {} Hz = {}", f[k], coh[k]);
    }
}

#[test]
fn tfest_recovers_the_papers_haptuator_model() {
    // G_H(s) = (250 s + 6.40e5)/(s² + 2135 s + 4.56e6) (paper eq. 2), exact data.
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::from("f,re,im,weight\n");
    for i in 0..120 {
        let f = 10.0 * (500.0f64).powf(i as f64 / 119.0);
        let s = num_s(f);
        let h = div(
            add(mul(s, (250.0, 0.0)), (6.40e5, 0.0)),
            add(add(mul(s, s), mul(s, (2135.0, 0.0))), (4.56e6, 0.0)),
        );
        text += &format!("{f},{},{},1\n", h.0, h.1);
    }
    let path = write_csv(&dir, "frf.csv", &text);
    let v = json_ok(&["tfest", &path, "--nb", "1", "--na", "2", "--json"]);
    let num = arr(&v, "num");
    let den = arr(&v, "den");
    let scale = den[0];
    let want_num = [250.0, 6.40e5];
    let want_den = [1.0, 2135.0, 4.56e6];
    for (g, w) in num.iter().zip(want_num) {
        assert!((g / scale / w - 1.0).abs() < 1e-6, "num {num:?}");
    }
    for (g, w) in den.iter().zip(want_den) {
        assert!((g / scale / w - 1.0).abs() < 1e-6, "den {den:?}");
    }
    assert!(v["condition_number"].as_f64().unwrap().is_finite());

    fn num_s(f: f64) -> (f64, f64) {
        (0.0, 2.0 * PI * f)
    }
    fn add(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
        (a.0 + b.0, a.1 + b.1)
    }
    fn mul(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
        (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0)
    }
    fn div(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
        let d = b.0 * b.0 + b.1 * b.1;
        ((a.0 * b.0 + a.1 * b.1) / d, (a.1 * b.0 - a.0 * b.1) / d)
    }
}

#[test]
fn malformed_csv_gets_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let ok = write_csv(&dir, "ok.csv", "x,y\n1,2\n3,4\n");
    fails_with(
        &[
            "psd",
            &ok,
            "--fs",
            "1",
            "--column",
            "nope",
            "--nperseg",
            "2",
        ],
        "no column named `nope`",
    );
    let bad = write_csv(&dir, "bad.csv", "x,y\n1,2\n3,oops\n");
    fails_with(
        &[
            "frf",
            &bad,
            "--fs",
            "1",
            "--input",
            "x",
            "--output",
            "y",
            "--nperseg",
            "2",
        ],
        "bad.csv, line 3",
    );
    let empty = write_csv(&dir, "empty.csv", "");
    fails_with(
        &[
            "psd",
            &empty,
            "--fs",
            "1",
            "--column",
            "x",
            "--nperseg",
            "2",
        ],
        "empty file",
    );
    let ragged = write_csv(&dir, "ragged.csv", "f,re,im\n1,2,3\n4,5\n");
    fails_with(
        &["tfest", &ragged, "--nb", "0", "--na", "1"],
        "ragged.csv, line 3",
    );
    fails_with(
        &[
            "psd",
            "/nonexistent/file.csv",
            "--fs",
            "1",
            "--column",
            "x",
            "--nperseg",
            "2",
        ],
        "cannot read",
    );
    // Too long a segment is reported by name, not a panic.
    fails_with(
        &["psd", &ok, "--fs", "1", "--column", "x", "--nperseg", "64"],
        "nperseg",
    );
}

#[test]
fn bench_reports_the_contract_keys() {
    let v = json_ok(&["bench", "--reps", "1", "--json"]);
    for k in ["chain_ns_per_sample", "welch_1e6_ms"] {
        let x = v[k].as_f64().unwrap_or_else(|| panic!("missing {k}"));
        assert!(x.is_finite() && x > 0.0, "{k} = {x}");
    }
}

/// `bench --paced 2 --json`: the soak report with its counters and
/// verdict on stdout, and progress as plain lines (no carriage returns)
/// on a stderr that is not a terminal.
#[test]
fn paced_bench_reports_the_soak_and_logs_plain_progress_lines() {
    let o = kilotouch(&["bench", "--paced", "2", "--json"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON report");
    assert_eq!(v["seconds"].as_f64(), Some(2.0));
    assert!(v["blocks"].as_u64().unwrap() >= 1900, "{v}");
    assert_eq!(v["overruns"].as_u64(), Some(0), "{v}");
    assert_eq!(v["telemetry_dropped"].as_u64(), Some(0), "{v}");
    assert!(v["reference_blocks"].as_u64().unwrap() > 0, "{v}");
    assert!(!err.contains('\r'), "{err:?}");
    let lines: Vec<&str> = err
        .lines()
        .filter(|l| l.contains("of the paced run"))
        .collect();
    assert!(
        lines.first().is_some_and(|l| l.starts_with("[  0%]"))
            && lines.last().is_some_and(|l| l.starts_with("[100%] 2/2")),
        "{err}"
    );
}
