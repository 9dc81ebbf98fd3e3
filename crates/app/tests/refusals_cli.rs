//! What must be refused, through the real executable: statistics on cell
//! means that overflow, a CSV naming a column twice, an FRF without input
//! power, a transfer-function fit from too few distinct frequencies, rig
//! files with absurd limits (refused alike by every command) and protocols
//! whose geometry does not fit the scene. Each case states what used to be
//! accepted.

use kilotouch_testkit as common;

use common::{json_ok, kilotouch};
use std::io::Write;

fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> String {
    let p = dir.path().join(name);
    let mut f = std::fs::File::create(&p).expect("create");
    f.write_all(text.as_bytes()).expect("write");
    p.to_string_lossy().into_owned()
}

/// Exit code 1, no panic, and stderr containing every needle.
fn refused(args: &[&str], needles: &[&str]) -> String {
    let o = kilotouch(args);
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(1), "kilotouch {args:?}: {e}");
    assert!(!e.contains("panicked"), "{e}");
    for n in needles {
        assert!(e.contains(n), "kilotouch {args:?}: stderr lacks `{n}`: {e}");
    }
    e
}

/// Cells whose values add up beyond f64 used to become NaN means that
/// Friedman ranked (χ² = 8, W = 1, exit 0); every test now refuses them,
/// naming the cell.
#[test]
fn statistics_refuse_cell_means_that_overflow() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut text = String::from("participant,condition,time_s\n");
    for p in 1..=4 {
        for (c, v) in [("V", 1e308), ("P", 2.0 + f64::from(p)), ("D", 1.0)] {
            for _ in 0..2 {
                text += &format!("P{p},{c},{v}\n");
            }
        }
    }
    let path = write(&dir, "huge.csv", &text);
    for test in ["friedman", "rm", "pairwise", "oneway", "describe"] {
        refused(
            &common::stats_args(&path, "time_s", test),
            &[
                "cell (subject `P1`, condition `V`) over 2 row(s)",
                "overflow",
            ],
        );
    }
}

/// A header naming a column twice used to read the first silently.
#[test]
fn a_csv_naming_a_column_twice_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let path = write(
        &dir,
        "dup.csv",
        "participant,condition,time_s,time_s\nP1,V,1,9\nP2,V,2,9\n",
    );
    refused(
        &common::stats_args(&path, "time_s", "describe"),
        &["dup.csv", "column `time_s` twice (columns 3 and 4)"],
    );
}

/// `frf` of the columns x → y of `path` at 8 kHz in 256-sample segments,
/// with `extra`.
fn frf_8khz_args<'a>(path: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "frf",
        path,
        "--fs",
        "8000",
        "--input",
        "x",
        "--output",
        "y",
        "--nperseg",
        "256",
    ];
    a.extend_from_slice(extra);
    a
}

/// An all-zero input used to give H1 = 0 and coherence 0, exit 0: now an
/// error; bins without input power in an otherwise good record are null.
#[test]
fn an_frf_without_input_power_is_undefined() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut zero = String::from("x,y\n");
    let mut part = String::from("x,y\n");
    for (i, y) in (0..4096).zip(common::xorshift_noise(5)) {
        zero += &format!("0,{y}\n");
        // A 1 kHz tone at fs = 8 kHz, nperseg = 256: whole periods in every
        // segment, so the Hann-windowed input has power in bins 31–33 only.
        let x = (2.0 * std::f64::consts::PI * 1000.0 * f64::from(i) / 8000.0).sin();
        part += &format!("{x},{}\n", 0.5 * x);
    }
    let zpath = write(&dir, "zero.csv", &zero);
    refused(
        &frf_8khz_args(&zpath, &[]),
        &["input column `x` has no power", "undefined"],
    );
    let ppath = write(&dir, "tone.csv", &part);
    let v = json_ok(&frf_8khz_args(&ppath, &["--json"]));
    let re = v["re"].as_array().expect("re");
    let undefined = v["undefined_bins"].as_u64().expect("count");
    assert_eq!(re.iter().filter(|x| x.is_null()).count() as u64, undefined);
    assert!(undefined > 100, "{undefined} bins without input power");
    // Where the tone is, H1 is the gain 0.5.
    let k = 32; // 1000 Hz / (8000 / 256)
    assert!(
        (re[k].as_f64().expect("defined") - 0.5).abs() < 1e-9,
        "{}",
        re[k]
    );
    assert!(
        v["undefined_reason"]
            .as_str()
            .expect("reason")
            .contains("no input power")
    );
}

/// Every point at one frequency used to give `converged: true` with a
/// 1670 % error: two equations cannot determine four unknowns.
#[test]
fn tfest_refuses_too_few_distinct_frequencies() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut text = String::from("f,re,im\n");
    for _ in 0..30 {
        text += "100,0.5,-0.25\n";
    }
    let path = write(&dir, "one_f.csv", &text);
    refused(
        &["tfest", &path, "--nb", "1", "--na", "2"],
        &[
            "too few distinct frequencies",
            "at 1 distinct frequencies",
            "4 unknowns",
        ],
    );
}

/// `rig margins` used to accept a force limit of 1e308 N that `sim press`
/// refused: the rig file is now checked once, at load, for both.
#[test]
fn rig_margins_and_sim_press_refuse_the_same_absurd_limit() {
    let dir = tempfile::tempdir().expect("tmp");
    let text = String::from_utf8(kilotouch(&["rig", "default-config"]).stdout).expect("utf8");
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("pantograph_force_max_n"))
        .expect("the limit")
        .to_owned();
    let rig = write(
        &dir,
        "rig.toml",
        &text.replace(&line, "pantograph_force_max_n = 1e308"),
    );
    let a = refused(
        &["rig", "margins", "--rig-config", &rig],
        &["limits.pantograph_force_max_n", "at most 1e6 N"],
    );
    let b = refused(
        &["sim", "press", "--rig-config", &rig, "--duration", "1"],
        &["limits.pantograph_force_max_n", "at most 1e6 N"],
    );
    let first = |s: &str| {
        s.lines()
            .find(|l| l.contains("pantograph"))
            .map(str::to_owned)
    };
    assert_eq!(first(&a), first(&b), "the same refusal");
}

/// An obstacle of 1e300 µm used to run to completion with every trial a
/// time-out: a geometry that does not fit the scene is refused at load.
#[test]
fn a_protocol_whose_geometry_does_not_fit_the_scene_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    for (body, field) in [
        (
            "[task.circling]\nobstacle_radius_um = 1e300\n",
            "task.circling.obstacle_radius_um",
        ),
        (
            "[task.circling]\nobstacle_radius_um = 9.0\nbead_radius_um = 1.5\n",
            "task.circling.obstacle_radius_um",
        ),
        (
            "[task.blind_navigation]\nstart_distance_um = 19.0\n",
            "task.blind_navigation.start_distance_um",
        ),
    ] {
        let p = write(
            &dir,
            "geo.toml",
            &format!(
                "name = \"geo\"\nparticipants = 1\nconditions = [\"P\", \"D\"]\n\
                 trials_per_session = 1\n{body}"
            ),
        );
        let out = dir.path().join("out");
        refused(
            &[
                "study",
                "simulate",
                "--protocol",
                &p,
                "--no-raw",
                "--out",
                &out.to_string_lossy(),
            ],
            &[field, "geo.toml:"],
        );
        assert!(!out.exists(), "nothing was written");
    }
}
