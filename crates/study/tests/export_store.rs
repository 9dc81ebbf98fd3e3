//! The study output folder: creation, full runs, summaries against
//! hand-computed means, statistics equivalence, and every crash window of
//! the commit order (simulated by stopping mid-trial and by cutting files
//! exactly as a crash would leave them).

use crate::common;

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use common::{Stop, outcome, protocol, run_pending, run_trial};
use kilotouch_study::export::checksum::{crc32, sha256_hex};
use kilotouch_study::export::{
    CELLS_LONG_FILE, CELLS_WIDE_FILE, ExportError, Metric, SESSION_FILE, StudyStore,
    TRIALS_COLUMNS, TRIALS_FILE, Table, read_session, read_trials, regenerate_summaries,
    summary::trial_triples,
};
use kilotouch_study::journal::{JOURNAL_FILE, Record, read_journal};
use kilotouch_study::protocol::Condition;
use kilotouch_study::seeds::{Phase, TrialKey};
use kilotouch_study::stats::{self, Design, Test};

const SEED: u64 = 2016;

fn open(dir: &Path, participants: u32, trials: u32, practice: u32) -> StudyStore {
    StudyStore::open(
        dir,
        &protocol(participants, trials, practice, SEED),
        &common::meta(),
    )
    .expect("test setup")
}

fn try_open(dir: &Path) -> Result<StudyStore, ExportError> {
    StudyStore::open(dir, &protocol(2, 3, 1, SEED), &common::meta())
}

fn lines(path: &Path) -> Vec<String> {
    fs::read_to_string(path)
        .expect("test setup")
        .lines()
        .map(str::to_owned)
        .collect()
}

/// Removes the last line of a file (the last record written).
fn drop_last_line(path: &Path) -> Vec<u8> {
    let bytes = fs::read(path).expect("test setup");
    let end = bytes.len() - 1;
    let start = bytes[..end]
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    fs::write(path, &bytes[..start]).expect("test setup");
    bytes[start..].to_vec()
}

#[test]
fn new_folder_layout_session_json_and_plan() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("study");
    let p = protocol(3, 4, 2, SEED);
    let store = StudyStore::open(&dir, &p, &common::meta()).unwrap();
    assert!(!store.recovery().resumed);
    // 3 participants × 3 conditions × (2 practice + 4 test).
    assert_eq!(store.plan().len(), 3 * 3 * 6);
    assert_eq!(
        lines(&dir.join(TRIALS_FILE)),
        vec![TRIALS_COLUMNS.join(",")]
    );
    assert!(dir.join("raw").is_dir());

    let info = read_session(&dir.join(SESSION_FILE)).unwrap();
    assert_eq!(info.protocol, p);
    assert_eq!(
        info.protocol_sha256,
        sha256_hex(p.to_toml_string().unwrap().as_bytes())
    );
    assert_eq!(info.seeds.study, SEED);
    assert_eq!(info.rig, "simulated-test-rig");
    let table = p.assignment().unwrap();
    for (row, t) in info.order_table.iter().zip(&table.participants) {
        assert_eq!(row.participant, t.id);
        assert_eq!(row.sessions, t.sessions);
    }
    assert_eq!(info.progress.planned, 54);

    // Plan order: per participant, practice block (conditions in the
    // participant's order) then test sessions in order; session_index is
    // the position of the condition in the order, 0 for practice.
    let first: Vec<_> = store.plan().iter().take(18).collect();
    let order = &table.participants[0].sessions;
    for (i, pl) in first.iter().enumerate() {
        let (phase, block, t) = if i < 6 {
            (Phase::Practice, i / 2, i % 2 + 1)
        } else {
            (Phase::Test, (i - 6) / 4, (i - 6) % 4 + 1)
        };
        assert_eq!(
            pl.key,
            TrialKey::new(0, order[block], phase, t as u32),
            "{i}"
        );
        let expected_index = if phase == Phase::Practice {
            0
        } else {
            block as u32 + 1
        };
        assert_eq!(pl.session_index, expected_index);
        assert_eq!(pl.participant, "P01");
        assert_eq!(pl.seed, pl.key.seed(SEED));
    }
    let j = read_journal(&dir.join(JOURNAL_FILE)).unwrap();
    assert!(
        matches!(&j.entries[0].record, Record::SessionStarted(s) if !s.resumed && s.study_seed == SEED)
    );
}

#[test]
fn rows_round_trip_and_match_the_simulated_outcomes() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 2, 3, 1);
    run_pending(&mut store, 0);
    assert!(store.next_pending().is_none());
    store.close().unwrap();
    let read = read_trials(&tmp.path().join(TRIALS_FILE)).unwrap();
    assert_eq!(read.rows.len(), 2 * 3 * 4);
    assert!(read.torn.is_none());
    for row in &read.rows {
        let idx: u32 = row.participant[1..].parse::<u32>().unwrap() - 1;
        let key = row.key(idx);
        let o = outcome(SEED, key);
        assert_eq!(row.seed, key.seed(SEED));
        assert_eq!(row.success, o.success);
        assert_eq!(row.reject_reason, o.reason);
        assert_eq!(row.time_s, o.time_s);
        assert_eq!(
            row.disp_err_mean_um,
            Some(o.disp_err_mean_um),
            "exact f64 round trip"
        );
        assert_eq!(row.started_utc, common::started(row.seed));
        // Raw file: referenced, present, and holding the simulated signals.
        let raw = kilotouch_study::rawsig::read_npy(&tmp.path().join(&row.raw_file)).unwrap();
        let expected = common::raw_rows(SEED, key, o.samples);
        assert_eq!(raw.rows as usize, expected.len());
        assert_eq!(
            raw.row(raw.rows as usize - 1),
            &expected[expected.len() - 1]
        );
    }
    let j = read_journal(&tmp.path().join(JOURNAL_FILE)).unwrap();
    let completed = j
        .entries
        .iter()
        .filter(|e| matches!(e.record, Record::TrialCompleted { .. }))
        .count();
    assert_eq!(completed, 24);
    assert!(matches!(
        j.entries.last().unwrap().record,
        Record::SessionDone {
            completed: 24,
            planned: 24,
            timing: None,
        }
    ));
}

/// Naive mean (plain sum / n): the independent reference.
fn naive_mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

fn close_rel(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

#[test]
fn cell_means_equal_hand_computed_means_and_wide_matches_long() {
    let tmp = tempfile::tempdir().unwrap();
    let (n_p, n_t) = (4_u32, 6_u32);
    let mut store = open(tmp.path(), n_p, n_t, 2);
    run_pending(&mut store, 0);
    store.close().unwrap();
    let long_path = tmp.path().join(CELLS_LONG_FILE);
    let long = Table::read(&long_path).unwrap();
    let wide = Table::read(&tmp.path().join(CELLS_WIDE_FILE)).unwrap();
    assert_eq!(long.records.len(), (n_p * 3) as usize);
    assert_eq!(
        long.header,
        [
            "participant",
            "condition",
            "session_index",
            "n_trials",
            "n_success",
            "success_rate",
            "n_escaped",
            "time_s",
            "force_mean_pn",
            "force_mean_n",
            "disp_err_mean_um",
            "contact_fraction"
        ]
    );
    let orders = store_orders(tmp.path());
    for (i, rec) in long.records.iter().enumerate() {
        let pid = &rec[0];
        let idx: u32 = pid[1..].parse::<u32>().unwrap() - 1;
        let c = match rec[1].as_str() {
            "V" => Condition::V,
            "P" => Condition::P,
            _ => Condition::D,
        };
        // Hand computation from the simulated outcomes of the test trials
        // (practice trials must not count).
        let outs: Vec<_> = common::test_keys(idx, c, n_t)
            .into_iter()
            .map(|k| outcome(SEED, k))
            .collect();
        let ok: Vec<_> = outs.iter().filter(|o| o.success).collect();
        let num = |col: &str| long.number(&long_path, i, col).unwrap();
        assert_eq!(num("n_trials"), Some(f64::from(n_t)));
        assert_eq!(num("n_success"), Some(ok.len() as f64));
        assert_eq!(num("success_rate"), Some(ok.len() as f64 / f64::from(n_t)));
        assert_eq!(
            num("n_escaped"),
            Some(outs.iter().filter(|o| o.escaped).count() as f64)
        );
        let pos = orders[idx as usize].iter().position(|&x| x == c).unwrap();
        assert_eq!(num("session_index"), Some(pos as f64 + 1.0));
        let expect: [(&str, Vec<f64>); 5] = [
            ("time_s", ok.iter().filter_map(|o| o.time_s).collect()),
            (
                "force_mean_pn",
                ok.iter().map(|o| o.force_mean_pn).collect(),
            ),
            ("force_mean_n", ok.iter().map(|o| o.force_mean_n).collect()),
            (
                "disp_err_mean_um",
                ok.iter().map(|o| o.disp_err_mean_um).collect(),
            ),
            (
                "contact_fraction",
                ok.iter().map(|o| o.contact_fraction).collect(),
            ),
        ];
        for (col, values) in expect {
            match (num(col), naive_mean(&values)) {
                (Some(a), Some(b)) => assert!(close_rel(a, b), "{pid} {c} {col}: {a} vs {b}"),
                (None, None) => {}
                (a, b) => panic!("{pid} {c} {col}: {a:?} vs {b:?}"),
            }
        }
        // Wide: the same text in column `{col}_{condition}` of the
        // participant's row.
        let w = wide.records.iter().find(|r| &r[0] == pid).unwrap();
        for (j, col) in long.header.iter().enumerate().skip(2) {
            let wj = wide.column(&format!("{col}_{}", rec[1])).unwrap();
            assert_eq!(w[wj], rec[j], "{pid} {col}_{}", rec[1]);
        }
    }
    assert_eq!(wide.records.len(), n_p as usize);
    assert_eq!(wide.header.len(), 1 + 10 * 3);
    assert_eq!(
        &wide.header[1..4],
        ["session_index_V", "session_index_P", "session_index_D"]
    );
}

fn store_orders(dir: &Path) -> Vec<Vec<Condition>> {
    read_session(&dir.join(SESSION_FILE))
        .expect("test setup")
        .order_table
        .into_iter()
        .map(|o| o.sessions)
        .collect()
}

#[test]
fn statistics_on_cells_long_reproduce_statistics_on_trials() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 6, 8, 0);
    run_pending(&mut store, 0);
    store.close().unwrap();
    let rows = read_trials(&tmp.path().join(TRIALS_FILE)).unwrap().rows;
    let long_path = tmp.path().join(CELLS_LONG_FILE);
    let long = Table::read(&long_path).unwrap();
    for metric in [Metric::TimeS, Metric::ForceMeanPn, Metric::DispErrMeanUm] {
        let from_trials = Design::from_long(trial_triples(&rows, metric)).unwrap();
        let from_cells =
            Design::from_long(long.long_triples(&long_path, metric.column()).unwrap()).unwrap();
        let order = ["V", "P", "D"];
        let a = from_trials.with_condition_order(&order).unwrap();
        let b = from_cells.with_condition_order(&order).unwrap();
        let mut tests = vec![Test::Oneway];
        if a.is_complete() {
            tests.extend([Test::Rm, Test::Friedman]);
        }
        for t in tests {
            let ra = stats::run_test(&a, t).unwrap();
            let rb = stats::run_test(&b, t).unwrap();
            // Same cell means bit for bit (same compensated sum, shortest
            // round-trip text), hence identical reports.
            assert_eq!(ra, rb, "{metric:?} {t:?}");
        }
    }
}

#[test]
fn missing_cells_are_na_in_wide_and_absent_in_long() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 2, 2, 0);
    // Only participant 1's plan, and participant 2's first session.
    let keys: Vec<TrialKey> = store.plan().iter().map(|p| p.key).collect();
    for k in &keys[..6 + 2] {
        run_trial(&mut store, *k, Stop::Complete, 0);
    }
    let files = store.regenerate_summaries().unwrap();
    assert_eq!(files.summary.cells.len(), 4);
    let wide = Table::read(&files.cells_wide).unwrap();
    let p2 = wide.records.iter().find(|r| r[0] == "P02").unwrap();
    let first = keys[6].condition;
    for c in Condition::ALL {
        let j = wide.column(&format!("n_trials_{c}")).unwrap();
        let expected = if c == first { "2" } else { "" };
        assert_eq!(p2[j], expected, "{c}");
    }
}

/// How a simulated crash leaves the files of trial k.
#[derive(Debug, Clone, Copy)]
enum Crash {
    /// Crash in the trial (before its row).
    During(Stop),
    /// Row written and fsynced, crash before `trial_completed`.
    BetweenRowAndRecord,
    /// Crash mid-way through the row (torn, no record).
    TornRow,
    /// Row complete but its bytes zero-filled (power loss).
    ZeroedRow,
    /// Row complete, `trial_completed` torn.
    TornRecord,
}

#[test]
fn resume_after_a_crash_in_every_window_gives_the_uninterrupted_files() {
    let tmp = tempfile::tempdir().unwrap();
    let reference = tmp.path().join("reference");
    let mut store = open(&reference, 2, 3, 1);
    run_pending(&mut store, 0);
    store.close().unwrap();
    let expected = common::data_files(&reference);
    assert!(expected.keys().any(|k| k.ends_with(".npy")));

    let crashes = [
        Crash::During(Stop::AfterBegin),
        Crash::During(Stop::MidRaw),
        Crash::During(Stop::AfterRaw),
        Crash::BetweenRowAndRecord,
        Crash::TornRow,
        Crash::ZeroedRow,
        Crash::TornRecord,
    ];
    for (n, crash) in crashes.into_iter().enumerate() {
        // Crash at the first trial, mid-participant and at the last trial:
        // each window at one of them in turn, the crashes inside a trial at
        // all three.
        let positions: &[usize] = match crash {
            Crash::During(_) => &[0, 7, 23],
            _ => &[[0, 7, 23][n % 3]],
        };
        for &at in positions {
            let dir = tmp.path().join(format!("crash-{n}-{at}"));
            let mut store = open(&dir, 2, 3, 1);
            let keys: Vec<TrialKey> = store.plan().iter().map(|p| p.key).collect();
            for &k in &keys[..at] {
                run_trial(&mut store, k, Stop::Complete, 0);
            }
            let k = keys[at];
            let stop = match crash {
                Crash::During(s) => s,
                _ => Stop::Complete,
            };
            run_trial(&mut store, k, stop, 0);
            drop(store); // killed: no close
            let trials = dir.join(TRIALS_FILE);
            let journal = dir.join(JOURNAL_FILE);
            match crash {
                Crash::During(_) => {}
                Crash::BetweenRowAndRecord => {
                    drop_last_line(&journal);
                }
                Crash::TornRow => {
                    drop_last_line(&journal);
                    let row = drop_last_line(&trials);
                    let mut b = fs::read(&trials).unwrap();
                    b.extend_from_slice(&row[..row.len() / 2]);
                    fs::write(&trials, b).unwrap();
                }
                Crash::ZeroedRow => {
                    drop_last_line(&journal);
                    let row = drop_last_line(&trials);
                    let mut b = fs::read(&trials).unwrap();
                    b.extend(std::iter::repeat_n(0_u8, row.len()));
                    fs::write(&trials, b).unwrap();
                }
                Crash::TornRecord => {
                    let rec = drop_last_line(&journal);
                    let mut b = fs::read(&journal).unwrap();
                    b.extend_from_slice(&rec[..rec.len() - 7]);
                    fs::write(&journal, b).unwrap();
                }
            }
            let mut store = open(&dir, 2, 3, 1);
            let rec = store.recovery().clone();
            assert!(rec.resumed);
            assert!(rec.previous_sitting_unclosed, "{crash:?}");
            let row_kept = matches!(crash, Crash::BetweenRowAndRecord | Crash::TornRecord);
            assert_eq!(
                rec.completed,
                at + usize::from(row_kept),
                "{crash:?} at {at}"
            );
            if row_kept {
                assert_eq!(rec.adopted, vec![k], "{crash:?}");
                assert!(rec.interrupted.is_empty());
            } else {
                assert_eq!(rec.interrupted, vec![k], "{crash:?}");
                assert!(rec.adopted.is_empty());
                assert_eq!(
                    store.next_pending().unwrap().key,
                    k,
                    "resume at the first unfinished trial"
                );
            }
            assert_eq!(
                rec.trials_torn.is_some(),
                matches!(crash, Crash::TornRow | Crash::ZeroedRow),
                "{crash:?}"
            );
            assert_eq!(
                rec.journal_torn.is_some(),
                matches!(crash, Crash::TornRecord)
            );
            for t in [&rec.trials_torn, &rec.journal_torn].into_iter().flatten() {
                assert!(t.saved_to.as_ref().unwrap().is_file());
            }
            assert!(!rec.is_clean());
            assert!(rec.to_string().contains(&k.to_string()), "{rec}");
            run_pending(&mut store, 0);
            store.close().unwrap();
            let got = common::data_files(&dir);
            assert_eq!(
                got.keys().collect::<Vec<_>>(),
                expected.keys().collect::<Vec<_>>(),
                "{crash:?} at {at}"
            );
            for (name, bytes) in &expected {
                assert!(got[name] == *bytes, "{crash:?} at {at}: {name} differs");
            }
            // Journal: every trial completed exactly once; the crash is on
            // record.
            let j = read_journal(&journal).unwrap();
            let mut done: BTreeMap<TrialKey, usize> = BTreeMap::new();
            for e in &j.entries {
                if let Record::TrialCompleted { trial, .. } = &e.record {
                    *done.entry(*trial).or_default() += 1;
                }
            }
            assert_eq!(done.len(), 24);
            assert!(done.values().all(|&n| n == 1));
            assert!(
                j.entries
                    .iter()
                    .any(|e| matches!(e.record, Record::Recovered(_)))
            );
            // A second, clean reopen finds nothing to repair.
            let again = open(&dir, 2, 3, 1);
            assert!(again.recovery().is_clean(), "{}", again.recovery());
            assert!(!again.recovery().previous_sitting_unclosed);
        }
    }
}

#[test]
fn a_journaled_row_missing_from_trials_csv_is_refused_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 2, 3, 1);
    let keys: Vec<TrialKey> = store.plan().iter().map(|p| p.key).collect();
    for &k in &keys[..5] {
        run_trial(&mut store, k, Stop::Complete, 0);
    }
    drop(store);
    drop_last_line(&tmp.path().join(TRIALS_FILE));
    // Also a torn journal tail and a torn row: even these are not cut when
    // the folder is refused.
    for f in [JOURNAL_FILE, TRIALS_FILE] {
        let mut b = fs::read(tmp.path().join(f)).expect("read");
        b.extend_from_slice(b"{\"seq\":99,\"ut");
        fs::write(tmp.path().join(f), b).expect("write");
    }
    let before =
        [TRIALS_FILE, JOURNAL_FILE, SESSION_FILE].map(|f| fs::read(tmp.path().join(f)).unwrap());
    let err = try_open(tmp.path()).unwrap_err();
    assert!(matches!(err, ExportError::Inconsistent { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains(&keys[4].to_string()) && msg.contains("no such row"),
        "{msg}"
    );
    let after =
        [TRIALS_FILE, JOURNAL_FILE, SESSION_FILE].map(|f| fs::read(tmp.path().join(f)).unwrap());
    assert_eq!(before, after, "nothing modified");
    assert!(!tmp.path().join("recovery").exists());
}

/// Replaces line `n` (1-based) of trials.csv by `f(line)`, optionally
/// recomputing its checksum.
fn edit_row(path: &Path, n: usize, recrc: bool, f: impl Fn(&str) -> String) {
    let mut ls = lines(path);
    let mut l = f(&ls[n - 1]);
    if recrc {
        let (content, _) = l.rsplit_once(',').expect("test setup");
        l = format!("{content},{:08x}", crc32(content.as_bytes()));
    }
    ls[n - 1] = l;
    fs::write(path, format!("{}\n", ls.join("\n"))).expect("test setup");
}

fn four_rows(dir: &Path) -> Vec<TrialKey> {
    let mut store = open(dir, 2, 3, 1);
    let keys: Vec<TrialKey> = store.plan().iter().map(|p| p.key).collect();
    for &k in &keys[..4] {
        run_trial(&mut store, k, Stop::Complete, 0);
    }
    store.close().expect("test setup");
    keys
}

#[test]
fn damaged_or_edited_rows_are_errors_naming_line_and_column() {
    let tmp = tempfile::tempdir().unwrap();
    // A changed digit in line 3 (of 5): checksum error, not a torn tail.
    let d = tmp.path().join("a");
    four_rows(&d);
    edit_row(&d.join(TRIALS_FILE), 3, false, |l| {
        l.replacen(",1,", ",2,", 1)
    });
    let err = try_open(&d).unwrap_err();
    assert!(
        matches!(&err, ExportError::Checksum { at, .. } if at.line == 3),
        "{err}"
    );
    assert!(
        err.to_string().contains("line 3, column `row_crc32`"),
        "{err}"
    );
    assert!(read_trials(&d.join(TRIALS_FILE)).is_err());

    // Edited with a recomputed checksum: the journal's row hash disagrees.
    let d = tmp.path().join("b");
    four_rows(&d);
    edit_row(&d.join(TRIALS_FILE), 4, true, |l| {
        let mut cells: Vec<String> = l.split(',').map(str::to_owned).collect();
        cells[12] = "0.5".into(); // disp_err_mean_um
        cells.join(",")
    });
    let err = try_open(&d).unwrap_err();
    assert!(matches!(err, ExportError::Inconsistent { .. }), "{err}");
    assert!(
        err.to_string().contains("line 4") && err.to_string().contains("differs from the journal"),
        "{err}"
    );

    // A cell that does not parse (valid checksum), even on the last line,
    // is an error naming line and column — never cut as a torn tail.
    let d = tmp.path().join("c");
    four_rows(&d);
    let n = lines(&d.join(TRIALS_FILE)).len();
    edit_row(&d.join(TRIALS_FILE), n, true, |l| {
        let mut cells: Vec<String> = l.split(',').map(str::to_owned).collect();
        cells[12] = "1.2.3".into(); // disp_err_mean_um
        cells.join(",")
    });
    let err = try_open(&d).unwrap_err();
    assert!(
        err.to_string()
            .contains(&format!("line {n}, column `disp_err_mean_um`")),
        "{err}"
    );

    // Duplicate row.
    let d = tmp.path().join("d");
    four_rows(&d);
    let mut ls = lines(&d.join(TRIALS_FILE));
    ls.push(ls[2].clone());
    fs::write(d.join(TRIALS_FILE), format!("{}\n", ls.join("\n"))).unwrap();
    let err = try_open(&d).unwrap_err();
    assert!(
        err.to_string().contains("duplicate row") && err.to_string().contains("first at line 3"),
        "{err}"
    );

    // A row of another seed (checksum recomputed): refused.
    let d = tmp.path().join("e");
    four_rows(&d);
    edit_row(&d.join(TRIALS_FILE), 2, true, |l| {
        let mut cells: Vec<String> = l.split(',').map(str::to_owned).collect();
        cells[14] = "0x0000000000000001".into();
        cells.join(",")
    });
    let err = try_open(&d).unwrap_err();
    assert!(err.to_string().contains("column `seed`"), "{err}");
}

#[test]
fn a_different_header_or_protocol_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    four_rows(tmp.path());
    let path = tmp.path().join(TRIALS_FILE);
    let good = fs::read(&path).unwrap();

    let text = String::from_utf8(good.clone()).unwrap();
    fs::write(
        &path,
        text.replacen("session_order,condition", "condition,session_order", 1),
    )
    .unwrap();
    let err = try_open(tmp.path()).unwrap_err();
    assert!(matches!(err, ExportError::HeaderMismatch { .. }), "{err}");
    assert!(
        err.to_string()
            .contains("column 3 is `condition`, expected `session_order`"),
        "{err}"
    );

    // An older layout without row_crc32.
    fs::write(&path, text.replacen(",row_crc32\n", "\n", 1)).unwrap();
    let err = try_open(tmp.path()).unwrap_err();
    assert!(
        err.to_string().contains("first missing `row_crc32`"),
        "{err}"
    );

    fs::write(&path, &good).unwrap();
    let other = protocol(2, 4, 1, SEED);
    let err = StudyStore::open(tmp.path(), &other, &common::meta()).unwrap_err();
    assert!(matches!(err, ExportError::ProtocolMismatch { .. }), "{err}");
    let other = protocol(2, 3, 1, SEED + 1);
    assert!(StudyStore::open(tmp.path(), &other, &common::meta()).is_err());
    assert_eq!(fs::read(&path).unwrap(), good);
    assert!(try_open(tmp.path()).unwrap().recovery().is_clean());

    // Files of a study without session.json.
    let d = tmp.path().join("foreign");
    fs::create_dir(&d).unwrap();
    fs::write(d.join(TRIALS_FILE), "a,b\n").unwrap();
    assert!(matches!(
        try_open(&d),
        Err(ExportError::NotAStudyFolder { .. })
    ));
}

#[test]
fn misuse_is_a_typed_error() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 2, 3, 1);
    let k0 = store.plan()[0].key;
    let k1 = store.plan()[1].key;
    let t0 = common::started(1);
    let ticket = store.begin_trial(k0, t0).unwrap();
    // Another trial while one is open.
    assert!(matches!(
        store.begin_trial(k1, t0),
        Err(ExportError::Trial { .. })
    ));
    // Unknown trial.
    let unknown = TrialKey::new(9, Condition::V, Phase::Test, 1);
    store.abort_trial(ticket, "testing abort").unwrap();
    assert!(store.begin_trial(unknown, t0).is_err());
    let unknown = TrialKey::new(0, Condition::V, Phase::Test, 99);
    assert!(store.begin_trial(unknown, t0).is_err());

    type Edit = Box<dyn Fn(&mut kilotouch_study::export::TrialRow)>;
    let cases: Vec<(Edit, &str)> = vec![
        (
            Box::new(|r| r.time_s = Some(f64::NAN)),
            "column `time_s`: non-finite",
        ),
        (
            Box::new(|r| r.force_mean_n = Some(f64::INFINITY)),
            "non-finite",
        ),
        (
            Box::new(|r| {
                r.success = true;
                r.reject_reason = "escaped".into();
            }),
            "successful trial has no reject reason",
        ),
        (
            Box::new(|r| {
                r.success = false;
                r.reject_reason.clear();
            }),
            "needs a reason",
        ),
        (Box::new(|r| r.reject_reason = "a\nb".into()), "line break"),
        (Box::new(|r| r.seed ^= 1), "column `seed`"),
        (Box::new(|r| r.trial += 1), "column `trial`"),
        (
            Box::new(|r| r.raw_file = "raw/none.npy".into()),
            "column `raw_file`",
        ),
    ];
    for (edit, needle) in cases {
        let mut ticket = store.begin_trial(k0, t0).unwrap();
        let w = store.raw_writer(&mut ticket, common::layout()).unwrap();
        w.finish().unwrap();
        let mut row = common::row_for(&ticket, SEED);
        if row.success {
            row.success = false;
            row.reject_reason = "low_contact".into();
        }
        edit(&mut row);
        let err = store.commit_trial(ticket, &row).unwrap_err();
        assert!(err.to_string().contains(needle), "{needle}: {err}");
        assert_eq!(store.completed_count(), 0);
        // Nothing was written; the trial is still open until aborted.
        assert_eq!(store.open_trial(), Some(k0));
        assert!(store.begin_trial(k1, t0).is_err());
        assert_eq!(store.abort_open_trial("bad row").unwrap(), Some(k0));
        assert_eq!(store.abort_open_trial("nothing open").unwrap(), None);
    }
    // Completed trials cannot be begun again; closing with an open trial is
    // refused.
    run_trial(&mut store, k0, Stop::Complete, 0);
    assert!(store.begin_trial(k0, t0).is_err());
    let _open = store.begin_trial(k1, t0).unwrap();
    assert!(matches!(store.close(), Err(ExportError::Trial { .. })));
    // Nothing of the failed commits reached trials.csv.
    assert_eq!(
        read_trials(&tmp.path().join(TRIALS_FILE))
            .unwrap()
            .rows
            .len(),
        1
    );
}

#[test]
fn notes_pauses_and_sittings_are_journaled() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 1, 2, 0);
    store.note("participant wears glasses").unwrap();
    store.pause("break").unwrap();
    store.resume().unwrap();
    let k = store.plan()[0].key;
    run_trial(&mut store, k, Stop::Complete, 0);
    drop(store); // crash
    let mut store = open(tmp.path(), 1, 2, 0);
    run_pending(&mut store, 0);
    store.close().unwrap();
    let info = read_session(&tmp.path().join(SESSION_FILE)).unwrap();
    assert_eq!(info.sittings.len(), 2);
    assert!(info.sittings[0].done_utc.is_none());
    assert!(info.sittings[1].done_utc.is_some() && info.sittings[1].resumed);
    assert_eq!(info.progress.completed, 6);
    let j = read_journal(&tmp.path().join(JOURNAL_FILE)).unwrap();
    let types: Vec<&str> = j
        .entries
        .iter()
        .map(|e| match &e.record {
            Record::SessionStarted(_) => "session_started",
            Record::Note { .. } => "note",
            Record::Paused { .. } => "paused",
            Record::Resumed => "resumed",
            Record::TrialStarted { .. } => "trial_started",
            Record::TrialCompleted { .. } => "trial_completed",
            Record::SessionDone { .. } => "session_done",
            _ => "other",
        })
        .collect();
    assert_eq!(
        &types[..7],
        [
            "session_started",
            "note",
            "paused",
            "resumed",
            "trial_started",
            "trial_completed",
            "session_started"
        ]
    );
    assert_eq!(types.last(), Some(&"session_done"));
}

#[test]
fn summaries_regenerate_from_trials_csv_alone_ignoring_a_torn_tail() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = open(tmp.path(), 2, 3, 0);
    run_pending(&mut store, 0);
    let files = store.close().unwrap();
    let long = fs::read(&files.cells_long).unwrap();
    let wide = fs::read(&files.cells_wide).unwrap();
    fs::remove_file(&files.cells_long).unwrap();
    fs::remove_file(&files.cells_wide).unwrap();
    let path = tmp.path().join(TRIALS_FILE);
    let mut b = fs::read(&path).unwrap();
    b.extend_from_slice(b"P02,3,VPD,D,test,4,circ");
    fs::write(&path, &b).unwrap();
    let again = regenerate_summaries(tmp.path()).unwrap();
    assert!(again.ignored_tail.is_some());
    assert_eq!(fs::read(&again.cells_long).unwrap(), long);
    assert_eq!(fs::read(&again.cells_wide).unwrap(), wide);
    assert_eq!(fs::read(&path).unwrap(), b, "read-only on trials.csv");
}

#[test]
fn open_existing_resumes_with_the_recorded_protocol() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let mut store = open(tmp.path(), 2, 3, 1);
    let k = store.plan()[0].key;
    run_trial(&mut store, k, Stop::Complete, 0);
    drop(store);
    let store = StudyStore::open_existing(tmp.path(), &common::meta()).unwrap();
    assert_eq!(store.protocol(), &protocol(2, 3, 1, SEED));
    assert_eq!(store.completed_count(), 1);
    assert!(store.is_completed(&k));
    let empty = tmp.path().join("empty");
    assert!(matches!(
        StudyStore::open_existing(&empty, &common::meta()),
        Err(ExportError::NotAStudyFolder { .. })
    ));
}
