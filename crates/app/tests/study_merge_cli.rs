//! `kilotouch study simulate --shard K/N` and `kilotouch study merge`
//! through the built executable, as a cluster user runs them: the shards'
//! folders merged equal the unsharded run row for row (every column but
//! the wall-clock start time), in their summaries and raw files; merges of
//! overlapping, foreign or altered folders are refused with the reason.

#![allow(clippy::unwrap_used)]

use common::{kilotouch as run, ok, refused, rows_without_start_time as rows};
use kilotouch_testkit as common;
use std::path::Path;

use kilotouch_study::export::{TRIALS_FILE, read_session};
use kilotouch_study::fidelity::Fidelity;

/// The `study simulate` command `study` run whole into `dir/all` and as
/// `count` shards into `dir/s1` … `dir/s{count}`; every run must succeed.
fn simulate_whole_and_in_shards(study: &[&str], dir: &Path, count: u32) {
    let d = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let with = |extra: &[&str]| -> Vec<String> {
        study.iter().chain(extra).map(|s| (*s).to_owned()).collect()
    };
    ok(&with(&["--out", &d("all")]));
    for k in 1..=count {
        ok(&with(&[
            "--shard",
            &format!("{k}/{count}"),
            "--out",
            &d(&format!("s{k}")),
        ]));
    }
}

#[test]
fn shards_merged_equal_the_unsharded_run() {
    let tmp = tempfile::tempdir().unwrap();
    let d = |name: &str| tmp.path().join(name).to_string_lossy().into_owned();
    let study = [
        "study",
        "simulate",
        "--protocol",
        "blind",
        "--participants",
        "4",
        "--seed",
        "5",
        "--threads",
        "2",
    ];
    simulate_whole_and_in_shards(&study, tmp.path(), 3);
    // Shard 1 of 3 holds participants 1 and 4 only.
    let s1 = rows(&tmp.path().join("s1"));
    assert!(
        s1.iter()
            .all(|r| r.participant == "P01" || r.participant == "P04")
    );
    assert!(!s1.is_empty());
    let session = read_session(&tmp.path().join("s1/session.json")).unwrap();
    let sim = session.simulation.unwrap();
    assert_eq!(sim.fidelity, Fidelity::Scene);
    assert_eq!(sim.shard.map(|s| (s.index, s.count)), Some((1, 3)));

    ok(&[
        "study",
        "merge",
        &d("s3"),
        &d("s1"),
        &d("s2"),
        "--out",
        &d("merged"),
        "--require-complete",
    ]);
    let all = tmp.path().join("all");
    let merged = tmp.path().join("merged");
    assert_eq!(rows(&merged), rows(&all));
    for f in ["cells_long.csv", "cells_wide.csv"] {
        assert_eq!(
            std::fs::read(merged.join(f)).unwrap(),
            std::fs::read(all.join(f)).unwrap(),
            "{f}"
        );
    }
    let mut raw = 0;
    for e in std::fs::read_dir(all.join("raw")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "npy") {
            let name = p.file_name().unwrap();
            assert_eq!(
                std::fs::read(&p).unwrap(),
                std::fs::read(merged.join("raw").join(name)).unwrap()
            );
            raw += 1;
        }
    }
    assert_eq!(raw, rows(&all).len());
    let m = read_session(&merged.join("session.json")).unwrap();
    assert_eq!(m.progress.completed, m.progress.planned);
    assert_eq!(m.simulation.and_then(|s| s.shard), None);

    // Refusals: an overlap, a missing shard with --require-complete, another
    // study, an altered row, an existing output.
    refused(
        &["study", "merge", &d("s1"), &d("s1"), "--out", &d("m2")],
        "overlap",
    );
    refused(
        &[
            "study",
            "merge",
            &d("s1"),
            &d("s2"),
            "--out",
            &d("m3"),
            "--require-complete",
        ],
        "--require-complete",
    );
    ok(&[
        "study",
        "simulate",
        "--protocol",
        "blind",
        "--participants",
        "4",
        "--seed",
        "6",
        "--shard",
        "3/3",
        "--out",
        &d("other"),
    ]);
    refused(
        &["study", "merge", &d("s1"), &d("other"), "--out", &d("m4")],
        "only parts of one study",
    );
    refused(
        &["study", "merge", &d("s1"), &d("s2"), "--out", &d("all")],
        "already holds a study",
    );
    // A row edited by hand (metric changed, CRC recomputed would need the
    // tool; here the CRC no longer matches).
    let t = tmp.path().join("s2").join(TRIALS_FILE);
    let text = std::fs::read_to_string(&t).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    lines[1] = lines[1].replacen(",1,", ",0,", 1);
    std::fs::write(&t, lines.join("\n") + "\n").unwrap();
    let o = run(&[
        "study",
        "merge",
        &d("s1"),
        &d("s2"),
        &d("s3"),
        "--out",
        &d("m5"),
    ]);
    assert!(!o.status.success());
    assert!(!tmp.path().join("m5").join("session.json").exists());
}

/// A resumed shard must stay the same shard and fidelity.
#[test]
fn a_shard_resumes_only_as_itself() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s").to_string_lossy().into_owned();
    let base = [
        "study",
        "simulate",
        "--protocol",
        "blind",
        "--participants",
        "2",
        "--seed",
        "3",
        "--no-raw",
        "--out",
        &out,
    ];
    ok(&[&base[..], &["--shard", "1/2"]].concat());
    refused(
        &[&base[..], &["--shard", "2/2", "--resume"]].concat(),
        "shard 1/2",
    );
    refused(
        &[
            &base[..],
            &["--shard", "1/2", "--resume", "--fidelity", "full"],
        ]
        .concat(),
        "--fidelity scene",
    );
    ok(&[&base[..], &["--shard", "1/2", "--resume"]].concat());
    refused(&[&base[..], &["--shard", "0/2"]].concat(), "shard number");
}

/// Extra practice trials (`training.practice_retries`) across shards: with
/// a 1 s time-out every practice trial is unsuccessful and earns its
/// extras; each shard plans its own participants' extras, and the merged
/// folder equals the unsharded run row for row, complete.
#[test]
fn shards_with_extra_practice_trials_merge_to_the_unsharded_run() {
    let tmp = tempfile::tempdir().unwrap();
    let d = |name: &str| tmp.path().join(name).to_string_lossy().into_owned();
    let proto = tmp.path().join("retry.toml");
    std::fs::write(
        &proto,
        "name = \"retry\"\nparticipants = 3\nconditions = [\"P\", \"D\"]\n\
         trials_per_session = 1\n[training]\npractice_trials = 1\npractice_retries = 1\n\
         [task.circling]\ntimeout_s = 1.0\n[seeds]\nstudy = 9\n",
    )
    .unwrap();
    let study = [
        "study",
        "simulate",
        "--protocol",
        proto.to_str().unwrap(),
        "--no-raw",
        "--threads",
        "2",
    ];
    simulate_whole_and_in_shards(&study, tmp.path(), 2);
    ok(&[
        "study",
        "merge",
        &d("s1"),
        &d("s2"),
        "--out",
        &d("merged"),
        "--require-complete",
    ]);
    let all = rows(&tmp.path().join("all"));
    // 3 participants × 2 conditions × (1 practice + 1 extra + 1 test).
    assert_eq!(all.len(), 18);
    assert_eq!(
        all.iter()
            .filter(|r| r.phase == kilotouch_study::seeds::Phase::Practice && r.trial == 2)
            .count(),
        6,
        "one extra practice trial per participant and condition"
    );
    assert_eq!(rows(&tmp.path().join("merged")), all);
    let m = read_session(&tmp.path().join("merged/session.json")).unwrap();
    assert_eq!((m.progress.completed, m.progress.planned), (18, 18));
}
