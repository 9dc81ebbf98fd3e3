//! What guards a study folder, through the real executable: one writer at
//! a time (a second `study simulate` on a folder in use is refused at once,
//! the first completes, the folder resumes), a resume that checks what it
//! resumes (another rig file or raw recording is refused with the
//! difference named, unless the change is recorded; a damaged raw file is
//! reported by name and quarantined), and bounded plans and inputs.

#![allow(clippy::unwrap_used)]

use common::{bin, kilotouch as run, simulate_study};
use kilotouch_testkit as common;
use std::path::Path;
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

use kilotouch_study::export::journal::{JOURNAL_FILE, Record, read_journal};
use kilotouch_study::export::lock::LOCK_FILE;
use kilotouch_study::export::{QUARANTINE_DIR, RECOVERY_DIR, TRIALS_FILE, read_trials};
use serde_json::Value;

fn stderr(o: &Output) -> String {
    common::stderr_text(o)
}

/// `rig default-config`'s text and its `k_1 = …` line.
fn default_rig_file_and_k_1() -> (String, String) {
    let text = String::from_utf8(run(&["rig", "default-config"]).stdout).unwrap();
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("k_1 ="))
        .unwrap()
        .to_owned();
    (text, line)
}

fn write_protocol(dir: &Path, trials: u32) -> String {
    common::write_circling_protocol(dir, "guard-test", trials, 0, 7)
}

fn simulate(proto: &str, out: &Path, extra: &[&str]) -> Vec<String> {
    let mut a: Vec<String> = [
        "study",
        "simulate",
        "--protocol",
        proto,
        "--threads",
        "1",
        "--out",
        &out.to_string_lossy(),
    ]
    .iter()
    .map(|s| (*s).to_owned())
    .collect();
    a.extend(extra.iter().map(|s| (*s).to_owned()));
    a
}

/// A second writer is refused at once naming the first's PID and host; the
/// first completes; the folder then resumes with nothing left to run, and
/// no row is duplicated.
#[test]
fn a_second_writer_is_refused_at_once_and_the_folder_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 12);
    let out = tmp.path().join("study");
    let mut first = bin()
        .args(simulate(&proto, &out, &["--participants", "3", "--no-raw"]))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until the first writer holds the folder (its record is in the
    // lock file) and has committed a row.
    let t0 = Instant::now();
    loop {
        let locked = std::fs::read_to_string(out.join(LOCK_FILE)).is_ok_and(|s| !s.is_empty());
        let rows = std::fs::read_to_string(out.join(TRIALS_FILE))
            .map(|s| s.lines().count().saturating_sub(1))
            .unwrap_or(0);
        if locked && rows >= 1 {
            break;
        }
        assert!(
            first.try_wait().unwrap().is_none(),
            "the first run ended before the second could start"
        );
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(5));
    }
    let t = Instant::now();
    let second = run(&simulate(
        &proto,
        &out,
        &["--participants", "3", "--no-raw", "--resume"],
    ));
    let refused_in = t.elapsed();
    assert_eq!(second.status.code(), Some(1), "{}", stderr(&second));
    let e = stderr(&second);
    assert!(
        e.contains("in use by another writer") && e.contains(&format!("PID {}", first.id())),
        "{e}"
    );
    assert!(e.contains("on host `"), "{e}");
    assert!(refused_in < Duration::from_secs(3), "{refused_in:?}");
    assert!(
        first.try_wait().unwrap().is_none(),
        "the refusal came while the first writer was still running"
    );
    let o = first.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(rows.len(), 3 * 3 * 12);
    // Released: the lock file is gone and the folder resumes (nothing left).
    assert!(
        !out.join(LOCK_FILE).exists(),
        "a clean end removes writer.lock"
    );
    let o = run(&simulate(
        &proto,
        &out,
        &["--participants", "3", "--no-raw", "--resume", "--json"],
    ));
    assert!(o.status.success(), "{}", stderr(&o));
    let j: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["ran"].as_u64(), Some(0));
    assert_eq!(read_trials(&out.join(TRIALS_FILE)).unwrap().rows.len(), 108);
}

/// A writer killed with SIGKILL leaves its record but no lock: the next
/// run takes the folder and reports the previous writer by PID.
#[test]
fn the_lock_of_a_killed_writer_is_recognised_as_stale() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 12);
    let out = tmp.path().join("study");
    let mut child = bin()
        .args(simulate(&proto, &out, &["--no-raw"]))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !std::fs::read_to_string(out.join(LOCK_FILE)).is_ok_and(|s| !s.is_empty()) {
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(2));
    }
    let pid = child.id();
    child.kill().unwrap();
    child.wait().unwrap();
    let o = run(&simulate(&proto, &out, &["--no-raw", "--resume"]));
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains(&format!("the previous writer, PID {pid}"))
            && text.contains("ended without releasing the folder"),
        "{text}"
    );
}

/// A writer that died after taking the folder but before creating the
/// study leaves only its lock record: the next run, which creates the
/// study, still names it (the state the killed-writer test can hit on a
/// busy machine, made deterministic).
#[test]
fn a_stale_lock_in_a_folder_without_a_study_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 1);
    let out = tmp.path().join("study");
    std::fs::create_dir(&out).unwrap();
    let dead = kilotouch_study::export::lock::Holder {
        pid: 999_999,
        host: "elsewhere".into(),
        program: "kilotouch 0.0.1".into(),
        since_utc: kilotouch_study::export::UtcTime::from_unix_millis(0),
    };
    std::fs::write(out.join(LOCK_FILE), serde_json::to_vec(&dead).unwrap()).unwrap();
    let o = run(&simulate(&proto, &out, &["--no-raw", "--resume"]));
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("new study folder")
            && text.contains("the previous writer, PID 999999")
            && text.contains("ended without releasing the folder"),
        "{text}"
    );
    assert!(!out.join(LOCK_FILE).exists(), "released cleanly");
}

/// A resume with another rig file or without raw recording is refused,
/// naming the difference; `--new-sitting REASON` records the change in the
/// journal and proceeds.
#[test]
fn a_resume_with_another_rig_file_or_raw_setting_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 2);
    let out = tmp.path().join("study");
    let o = run(&simulate(&proto, &out, &[]));
    assert!(o.status.success(), "{}", stderr(&o));
    let rig = tmp.path().join("rig.toml");
    // A different plant: the Pantograph's spring 10 % stiffer.
    let (text, line) = default_rig_file_and_k_1();
    let v: f64 = line.split('=').nth(1).unwrap().trim().parse().unwrap();
    let changed = text.replace(&line, &format!("k_1 = {}", v * 1.1));
    std::fs::write(&rig, changed).unwrap();
    let rig_arg = rig.to_string_lossy().into_owned();
    let o = run(&simulate(
        &proto,
        &out,
        &["--resume", "--rig-config", &rig_arg],
    ));
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("rig file was content hash"), "{e}");
    assert!(e.contains("--new-sitting"), "{e}");
    let o = run(&simulate(&proto, &out, &["--resume", "--no-raw"]));
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("raw signal recording was on, now off"), "{e}");
    // The same set-up resumes; the recorded change proceeds and is journaled.
    assert!(run(&simulate(&proto, &out, &["--resume"])).status.success());
    let o = run(&simulate(
        &proto,
        &out,
        &[
            "--resume",
            "--rig-config",
            &rig_arg,
            "--new-sitting",
            "spring replaced",
        ],
    ));
    assert!(o.status.success(), "{}", stderr(&o));
    let j = read_journal(&out.join(JOURNAL_FILE)).unwrap();
    let note = j.entries.iter().find_map(|e| match &e.record {
        Record::Note { text } if text.starts_with("settings_changed") => Some(text.clone()),
        _ => None,
    });
    let note = note.expect("the change is journaled");
    assert!(
        note.contains("rig file was") && note.contains("spring replaced"),
        "{note}"
    );
    // From now on the new rig file is the study's.
    assert!(
        run(&simulate(
            &proto,
            &out,
            &["--resume", "--rig-config", &rig_arg]
        ))
        .status
        .success()
    );
}

/// A truncated raw file of a finished trial is reported by name on resume
/// and moved to recovery/quarantine/; a deleted one is reported too.
#[test]
fn a_damaged_raw_file_is_reported_by_name_and_quarantined() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 2);
    let out = tmp.path().join("study");
    assert!(run(&simulate(&proto, &out, &[])).status.success());
    let rows = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    let (cut, gone) = (rows[1].raw_file.clone(), rows[3].raw_file.clone());
    let cut_path = out.join(&cut);
    let len = std::fs::metadata(&cut_path).unwrap().len();
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(&cut_path)
        .unwrap();
    f.set_len(len - 100).unwrap();
    drop(f);
    std::fs::remove_file(out.join(&gone)).unwrap();
    // A flipped byte in the data, size unchanged: the checksum finds it.
    let flipped = rows[4].raw_file.clone();
    let mut bytes = std::fs::read(out.join(&flipped)).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x40;
    std::fs::write(out.join(&flipped), bytes).unwrap();

    let o = run(&simulate(&proto, &out, &["--resume"]));
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    for (name, why) in [
        (&cut, "needs"),
        (&gone, "cannot be read"),
        (&flipped, "data checksum"),
    ] {
        assert!(
            text.contains(&format!("DAMAGED raw file {name}")) && text.contains(why),
            "{name}: {text}"
        );
    }
    let q = out.join(RECOVERY_DIR).join(QUARANTINE_DIR);
    let moved: Vec<String> = std::fs::read_dir(&q)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    let base = |p: &str| {
        Path::new(p)
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned()
    };
    assert!(moved.iter().any(|m| m.ends_with(&base(&cut))), "{moved:?}");
    assert!(
        moved.iter().any(|m| m.ends_with(&base(&flipped))),
        "{moved:?}"
    );
    assert!(!cut_path.exists());
    // Each quarantine is journaled, and the rows now name where the files
    // went (empty for the one that was missing): trials.csv no longer
    // points to files that are not there.
    let quarantined = |out: &Path| {
        read_journal(&out.join(JOURNAL_FILE))
            .unwrap()
            .entries
            .iter()
            .filter(|e| matches!(&e.record, Record::RawQuarantined { .. }))
            .count()
    };
    assert_eq!(quarantined(&out), 3);
    let after = read_trials(&out.join(TRIALS_FILE)).unwrap().rows;
    assert_eq!(after.len(), rows.len());
    for (i, r) in after.iter().enumerate() {
        match i {
            1 | 4 => {
                assert!(
                    r.raw_file.starts_with("recovery/quarantine/") && !r.has_trusted_raw(),
                    "{}",
                    r.raw_file
                );
                assert!(out.join(&r.raw_file).is_file(), "{}", r.raw_file);
            }
            3 => assert_eq!(r.raw_file, "", "a missing file is no longer named"),
            _ => {
                assert_eq!(r.raw_file, rows[i].raw_file);
                assert!(r.has_trusted_raw());
            }
        }
    }
    // A second resume finds the folder consistent and nothing left to
    // quarantine.
    let o = run(&simulate(&proto, &out, &["--resume"]));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!String::from_utf8_lossy(&o.stdout).contains("DAMAGED"));
    assert_eq!(quarantined(&out), 3);
    assert_eq!(read_trials(&out.join(TRIALS_FILE)).unwrap().rows, after);
}

/// A symbolic link in place of `writer.lock`, `trials.csv`,
/// `journal.jsonl`, `session.json` or `raw/` is refused naming it, on a
/// new folder and on resume, and the link's target outside the folder is
/// left exactly as it was.
#[cfg(unix)]
#[test]
fn a_symbolic_link_in_a_study_folder_is_refused_and_never_written_through() {
    use std::os::unix::fs::symlink;
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 1);
    let names = [
        LOCK_FILE,
        TRIALS_FILE,
        JOURNAL_FILE,
        kilotouch_study::export::SESSION_FILE,
        kilotouch_study::export::RAW_DIR,
    ];
    let snapshot = |p: &Path| -> Vec<(String, Vec<u8>)> {
        if p.is_dir() {
            let mut v: Vec<_> = std::fs::read_dir(p)
                .unwrap()
                .map(|e| {
                    let e = e.unwrap();
                    (
                        e.file_name().to_string_lossy().into_owned(),
                        std::fs::read(e.path()).unwrap(),
                    )
                })
                .collect();
            v.sort();
            v
        } else {
            vec![(String::new(), std::fs::read(p).unwrap())]
        }
    };
    for (i, name) in names.into_iter().enumerate() {
        // On a new folder: the link is the only entry.
        let outside = tmp.path().join(format!("outside-{i}"));
        if name == kilotouch_study::export::RAW_DIR {
            std::fs::create_dir(&outside).unwrap();
            std::fs::write(outside.join("keep.npy"), b"outside data").unwrap();
        } else {
            std::fs::write(&outside, b"outside data\n").unwrap();
        }
        let before = snapshot(&outside);
        let out = tmp.path().join(format!("new-{i}"));
        std::fs::create_dir(&out).unwrap();
        symlink(&outside, out.join(name)).unwrap();
        let o = run(&simulate(&proto, &out, &[]));
        assert_eq!(o.status.code(), Some(1), "{name}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(
            e.contains(&format!("{name}: is a symbolic link")),
            "{name}: {e}"
        );
        assert_eq!(
            snapshot(&outside),
            before,
            "{name}: the target is untouched"
        );

        // On resume: a finished study whose file is swapped for a link to a
        // copy outside.
        let out = tmp.path().join(format!("resume-{i}"));
        assert!(run(&simulate(&proto, &out, &[])).status.success());
        let copy = tmp.path().join(format!("copy-{i}"));
        let inside = out.join(name);
        if name == LOCK_FILE {
            std::fs::write(&copy, b"outside data\n").unwrap();
        } else {
            std::fs::rename(&inside, &copy).unwrap();
        }
        symlink(&copy, &inside).unwrap();
        let before = snapshot(&copy);
        let o = run(&simulate(&proto, &out, &["--resume"]));
        assert_eq!(o.status.code(), Some(1), "{name}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("is a symbolic link"),
            "{name}: {}",
            stderr(&o)
        );
        assert_eq!(snapshot(&copy), before, "{name}: the target is untouched");
    }
}

/// Fields of `session.json` edited in a folder are refused on resume,
/// naming the field: the study seed, the protocol (re-derived from its
/// text, which its SHA-256 covers), the protocol text itself, and any
/// other field (covered by the per-field checksums).
/// An edit of `session.json`.
type Edit = fn(&mut Value);

#[test]
fn an_edited_session_json_is_refused_naming_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 2);
    let cases: [(&str, Edit); 5] = [
        ("seeds.study", |j| j["seeds"]["study"] = 8.into()),
        ("protocol.trials_per_session", |j| {
            j["protocol"]["trials_per_session"] = 3.into();
        }),
        ("protocol_toml", |j| {
            let t = j["protocol_toml"]
                .as_str()
                .unwrap()
                .replace("trials_per_session = 2", "trials_per_session = 3");
            j["protocol_toml"] = t.into();
        }),
        ("`rig`", |j| j["rig"] = "another rig".into()),
        ("`integrity`", |j| {
            j.as_object_mut().unwrap().remove("integrity");
            j["integrity"] = serde_json::json!({});
        }),
    ];
    for (i, (field, edit)) in cases.into_iter().enumerate() {
        let out = tmp.path().join(format!("s{i}"));
        assert!(run(&simulate(&proto, &out, &["--no-raw"])).status.success());
        let path = out.join(kilotouch_study::export::SESSION_FILE);
        let mut j: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        edit(&mut j);
        std::fs::write(&path, serde_json::to_vec_pretty(&j).unwrap()).unwrap();
        let journal = std::fs::read(out.join(JOURNAL_FILE)).unwrap();
        let o = run(&simulate(&proto, &out, &["--no-raw", "--resume"]));
        assert_eq!(o.status.code(), Some(1), "{field}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(
            e.contains(field) && e.contains("was changed after it was written"),
            "{field}: {e}"
        );
        assert_eq!(
            std::fs::read(out.join(JOURNAL_FILE)).unwrap(),
            journal,
            "{field}: nothing was written"
        );
    }
    // Unedited (only re-formatted), the folder resumes.
    let out = tmp.path().join("s0-clean");
    assert!(run(&simulate(&proto, &out, &["--no-raw"])).status.success());
    let path = out.join(kilotouch_study::export::SESSION_FILE);
    let j: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    std::fs::write(&path, serde_json::to_vec(&j).unwrap()).unwrap();
    let o = run(&simulate(&proto, &out, &["--no-raw", "--resume"]));
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Absurd counts and endless inputs end in a clear error naming the limit,
/// exit code 1, no abort.
#[test]
fn absurd_counts_and_endless_inputs_are_refused_with_the_limit() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("s");
    let o = run(&[
        "study",
        "simulate",
        "--participants",
        "4294967295",
        "--out",
        &out.to_string_lossy(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("participants") && e.contains("at most 10000"),
        "{e}"
    );

    let p = tmp.path().join("huge.toml");
    std::fs::write(
        &p,
        "name = \"huge\"\nparticipants = 2\nconditions = [\"V\", \"P\"]\n\
         trials_per_session = 4294967295\n[task.circling]\n",
    )
    .unwrap();
    let o = simulate_study(&p.to_string_lossy(), &out, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("trials_per_session")
            && e.contains("at most 10000")
            && e.contains("huge.toml:4:"),
        "{e}"
    );

    std::fs::write(
        &p,
        "name = \"t\"\nparticipants = 2\nconditions = [\"V\", \"P\"]\n\
         trials_per_session = 2\n[task.circling]\ntimeout_s = 1e300\n",
    )
    .unwrap();
    let o = simulate_study(&p.to_string_lossy(), &out, &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("task.circling.timeout_s") && e.contains("at most 600"),
        "{e}"
    );

    let t = Instant::now();
    let o = run(&[
        "study",
        "simulate",
        "--rig-config",
        "/dev/zero",
        "--out",
        &out.to_string_lossy(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    let e = stderr(&o);
    assert!(
        e.contains("/dev/zero") && e.contains("16777216 bytes"),
        "{e}"
    );
    assert!(!out.exists(), "nothing was written");
}

/// `sim frf` with an absurd plant stiffness names the field and fails.
#[test]
fn an_absurd_rig_value_is_refused_naming_the_field() {
    let tmp = tempfile::tempdir().unwrap();
    let (text, line) = default_rig_file_and_k_1();
    let rig = tmp.path().join("rig.toml");
    std::fs::write(&rig, text.replace(&line, "k_1 = 1e308")).unwrap();
    let o = run(&[
        "sim",
        "frf",
        "--channel",
        "low",
        "--freqs",
        "100,200",
        "--rig-config",
        &rig.to_string_lossy(),
        "--json",
    ]);
    assert_eq!(
        o.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let e = stderr(&o);
    assert!(e.contains("plant.k_1") && e.contains("at most 1e10"), "{e}");
}

/// Errors print each cause once; `--json` with a non-UTF-8 `--out` still
/// prints one valid JSON object.
#[cfg(unix)]
#[test]
fn json_output_survives_a_non_utf8_folder_name() {
    use std::os::unix::ffi::OsStrExt;
    let tmp = tempfile::tempdir().unwrap();
    let proto = write_protocol(tmp.path(), 1);
    let out = tmp.path().join(std::ffi::OsStr::from_bytes(b"st\xffudy"));
    let o = simulate_study(&proto, &out, &["--no-raw", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j: Value = serde_json::from_slice(&o.stdout).expect("one valid JSON object");
    assert!(j["out"].as_str().unwrap().contains("st\u{fffd}udy"), "{j}");
    // A failing resume of it: each cause once.
    let o = simulate_study(&proto, &out, &["--no-raw"]);
    let e = stderr(&o);
    let first = e.lines().next().unwrap_or_default().to_owned();
    for line in e.lines().skip(1) {
        let cause = line.trim_start().trim_start_matches("caused by: ");
        assert!(!first.contains(cause), "printed twice: {e}");
    }
}
