//! The Results page driven through egui_kittest (CPU only) on a small study
//! folder written with the study crate's `StudyStore`: 4 participants × 3
//! conditions × 3 test trials with known values (plus practice trials and a
//! rejected trial that must not count). The statistics shown are checked
//! against textbook formulas computed here from the known cell means, and
//! against `kilotouch_study::stats` called directly.

use kilotouch_testkit as common;

use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use kilotouch::gui::env::ShellRequest;
use kilotouch::gui::pages::results::ResultsPage;
use kilotouch_study::export::{Metric, SittingTiming, StudyMeta, StudyStore, UtcTime};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::rawsig::{Channel, Dtype, RawLayout};
use kilotouch_study::results::ResultMetric;
use kilotouch_study::seeds::Phase;
use kilotouch_study::stats::{self, CellMatrix};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const N: usize = 4;
const CONDS: [&str; 3] = ["V", "P", "D"];
const TRIALS: u32 = 3;
/// Radius of the circular bead path written to P01's raw files, µm.
const RADIUS_UM: f64 = 3.0;

fn cond_index(c: Condition) -> usize {
    match c {
        Condition::V => 0,
        Condition::P => 1,
        Condition::D => 2,
    }
}

/// The known manipulation time of a test trial, s.
fn time_s(p: usize, c: usize, t: u32) -> f64 {
    40.0 + 5.0 * p as f64
        + [15.0, 5.0, 0.0][c]
        + 0.7 * f64::from(t)
        + 2.0 * ((p * p * 5 + c * c * 3 + t as usize * 7 + p * c) % 5) as f64
}

/// The known mean optical force, pN.
fn force_pn(p: usize, c: usize, t: u32) -> f64 {
    8.0 - 2.0 * c as f64 + 0.5 * p as f64 + 0.4 * ((p + c * t as usize) % 3) as f64
}

/// The one rejected test trial (participant index, condition, trial).
const REJECTED: (usize, usize, u32) = (2, 1, 2);

fn protocol() -> Protocol {
    let text = format!(
        "name = \"gui-results-test\"\nparticipants = {N}\nconditions = [\"V\", \"P\", \"D\"]\n\
         trials_per_session = {TRIALS}\n[training]\npractice_trials = 1\n\
         [task.circling]\n[seeds]\nstudy = 7\n"
    );
    Protocol::from_toml_str(&text, "<test>").expect("test setup")
}

/// Write the study folder.
fn write_study(dir: &Path) {
    let protocol = protocol();
    let mut store =
        StudyStore::open(dir, &protocol, &StudyMeta::new("sim-test")).expect("test setup");
    while let Some(planned) = store.next_pending().cloned() {
        let key = planned.key;
        let p = key.participant as usize;
        let c = cond_index(key.condition);
        let mut ticket = store
            .begin_trial(key, UtcTime::from_unix_millis(1_767_225_600_000))
            .expect("test setup");
        // P01's test trials carry raw signals: the bead goes once round a
        // circle of RADIUS_UM (channel order differs from the standard one
        // on purpose: the reader must use the sidecar's names).
        if p == 0 && key.phase == Phase::Test {
            let layout = RawLayout {
                sample_rate_hz: 10_000.0,
                dtype: Dtype::F64,
                channels: vec![
                    Channel::new("event", "code", "events"),
                    Channel::new("bead_y", "m", "bead y"),
                    Channel::new("bead_x", "m", "bead x"),
                ],
                attrs: serde_json::Map::new(),
            };
            let mut raw = store.raw_writer(&mut ticket, layout).expect("test setup");
            let n = 9000 + 1000 * key.trial as usize;
            for i in 0..n {
                let a = 2.0 * std::f64::consts::PI * i as f64 / (n - 1) as f64;
                let r = RADIUS_UM * 1e-6;
                raw.push(&[0.0, r * a.sin(), r * a.cos()])
                    .expect("test setup");
            }
            raw.finish().expect("test setup");
        }
        let mut row = ticket.row();
        row.escaped = Some(false);
        if key.phase == Phase::Practice {
            // Practice trials never enter the results.
            row.success = true;
            row.time_s = Some(5000.0);
            row.force_mean_pn = Some(5000.0);
        } else if (p, c, key.trial) == REJECTED {
            row.success = false;
            row.reject_reason = "low_contact".into();
            row.time_s = Some(999.0);
            row.force_mean_pn = Some(999.0);
        } else {
            row.success = true;
            row.time_s = Some(time_s(p, c, key.trial));
            row.force_mean_pn = Some(force_pn(p, c, key.trial));
        }
        store.commit_trial(ticket, &row).expect("test setup");
    }
    // A sitting that ran late: 40 missed blocks of 10 samples and 5 late
    // commands in 360 000 samples, 0.1125 % > the 0.1 % limit.
    store.set_timing(Some(SittingTiming::judge(
        360_000, 36_000, 40, 0.0123, 5, 10, 1e-3,
    )));
    store.close().expect("test setup");
}

/// Cell means (participant × condition, V P D) of a metric, from the known
/// values, skipping the rejected trial.
fn cell_means(f: fn(usize, usize, u32) -> f64) -> Vec<Vec<f64>> {
    (0..N)
        .map(|p| {
            (0..3)
                .map(|c| {
                    let v: Vec<f64> = (1..=TRIALS)
                        .filter(|&t| (p, c, t) != REJECTED)
                        .map(|t| f(p, c, t))
                        .collect();
                    v.iter().sum::<f64>() / v.len() as f64
                })
                .collect()
        })
        .collect()
}

/// Textbook one-factor RM ANOVA F and one-way ANOVA F (Maxwell & Delaney
/// ch. 3 and 11) of an n × k matrix.
fn textbook_f(y: &[Vec<f64>]) -> (f64, f64) {
    let n = y.len() as f64;
    let k = y[0].len() as f64;
    let grand = y.iter().flatten().sum::<f64>() / (n * k);
    let col = |j: usize| y.iter().map(|r| r[j]).sum::<f64>() / n;
    let row = |i: usize| y[i].iter().sum::<f64>() / k;
    let ss_cond: f64 = (0..y[0].len()).map(|j| n * (col(j) - grand).powi(2)).sum();
    let ss_subj: f64 = (0..y.len()).map(|i| k * (row(i) - grand).powi(2)).sum();
    let ss_total: f64 = y.iter().flatten().map(|v| (v - grand).powi(2)).sum();
    let ss_err = ss_total - ss_cond - ss_subj;
    let f_rm = (ss_cond / (k - 1.0)) / (ss_err / ((n - 1.0) * (k - 1.0)));
    let ss_within: f64 = (0..y[0].len())
        .map(|j| y.iter().map(|r| (r[j] - col(j)).powi(2)).sum::<f64>())
        .sum();
    let f_one = (ss_cond / (k - 1.0)) / (ss_within / (n * k - k));
    (f_rm, f_one)
}

/// Friedman χ² without ties: 12/(n k (k+1)) Σ R_j² − 3 n (k+1).
fn textbook_friedman(y: &[Vec<f64>]) -> f64 {
    let n = y.len() as f64;
    let k = y[0].len();
    let mut sums = vec![0.0; k];
    for r in y {
        for j in 0..k {
            let rank = 1.0 + r.iter().filter(|&&v| v < r[j]).count() as f64;
            sums[j] += rank;
        }
    }
    let kf = k as f64;
    12.0 / (n * kf * (kf + 1.0)) * sums.iter().map(|s| s * s).sum::<f64>() - 3.0 * n * (kf + 1.0)
}

type State = common::PageState<ResultsPage>;

fn harness(state: State) -> Harness<'static, State> {
    common::page_harness(state, 6000.0)
}

fn state(output_dir: Option<PathBuf>) -> State {
    State {
        output_dir,
        ..State::new(ResultsPage::new())
    }
}

fn open(h: &mut Harness<'_, State>, dir: &Path) {
    h.state_mut().page.set_folder(dir);
    h.step();
    h.get_by_label("Open").click();
    h.step();
    h.step();
}

#[test]
fn results_page_shows_bars_and_statistics_that_match_the_references() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("study");
    write_study(&dir);

    let mut h = harness(state(None));
    h.step();
    open(&mut h, &dir);
    assert_eq!(h.state().page.error(), None);
    // Another folder than the shell's: remembered through the shell.
    assert!(
        h.state()
            .requests
            .iter()
            .any(|r| matches!(r, ShellRequest::SetOutputDir(p) if p == &dir))
    );
    // 4 × 3 × 3 test trials (practice rows are read but not counted).
    h.get_by_label_contains("4 participants, conditions V, P, D, 36 test trials (48 rows)");
    // The late sitting is flagged with its numbers (from session.json).
    h.get_by_label_contains(
        "on sim-test: LATE: 0.11 % of samples late (limit 0.10 %), 40 missed block(s), worst 12.3 ms late, 5 late command(s)",
    );

    // Manipulation time (the default metric).
    let y = cell_means(time_s);
    let (f_rm, f_one) = textbook_f(&y);
    let chi2 = textbook_friedman(&y);
    let page_stats = h.state().page.stats().unwrap().clone();
    assert_eq!(page_stats.metric, "time_s");
    assert_eq!(page_stats.conditions, CONDS);
    let rm = page_stats.rm_anova.as_ref().unwrap();
    let one = page_stats.oneway.as_ref().unwrap();
    let fr = page_stats.friedman.as_ref().unwrap();
    assert!((rm.f / f_rm - 1.0).abs() < 1e-10, "{} vs {f_rm}", rm.f);
    assert!((one.f / f_one - 1.0).abs() < 1e-10, "{} vs {f_one}", one.f);
    assert!((fr.chi2 - chi2).abs() < 1e-10, "{} vs {chi2}", fr.chi2);
    assert!((fr.kendall_w - chi2 / (N as f64 * 2.0)).abs() < 1e-12);
    assert_eq!((rm.df1, rm.df2), (2.0, 6.0));
    assert_eq!((one.df1, one.df2), (2.0, 9.0));
    // The same numbers as the study crate on the cell-mean matrix.
    let m = CellMatrix::new(
        (1..=N).map(|i| format!("P{i:02}")).collect(),
        CONDS.iter().map(|s| s.to_string()).collect(),
        y.iter().flatten().copied().collect(),
    )
    .unwrap();
    let direct_rm = stats::rm_anova(&m).unwrap();
    assert!((direct_rm.p_gg - rm.p_gg).abs() < 1e-12);
    assert!((direct_rm.p_hf - rm.p_hf).abs() < 1e-12);
    assert!((direct_rm.p - rm.p).abs() < 1e-12);
    let direct_pairs = stats::pairwise_t(&m).unwrap();
    let direct_w = stats::pairwise_wilcoxon(&m, stats::WilcoxonOptions::default()).unwrap();
    let pairs = &page_stats.pairwise.as_ref().unwrap().pairs;
    assert_eq!(pairs.len(), 3);
    for ((a, b), w) in pairs.iter().zip(&direct_pairs).zip(&direct_w) {
        assert_eq!((&a.a, &a.b), (&b.a, &b.b));
        assert!((a.p_holm.unwrap() - b.p_holm).abs() < 1e-12);
        assert!((a.wilcoxon_p_holm.unwrap() - w.p_holm).abs() < 1e-12);
        // Holm never lowers a p-value.
        assert!(a.p_holm.unwrap() >= a.p.unwrap());
    }
    // The rows used are stated: 36 successful test trials of 4 × 3 × 3,
    // one rejected, plus the practice trials.
    assert_eq!(page_stats.rows.excluded(stats::Exclusion::Rejected), 1);
    assert!(page_stats.rows.excluded(stats::Exclusion::Practice) > 0);
    h.get_by_label_contains(&format!(
        "rows of trials.csv: used {} of",
        page_stats.rows.rows_used
    ));
    // …and they are on the page.
    h.get_by_label(&format!("{:.4}", rm.f));
    h.get_by_label(&format!("{:.4}", one.f));
    h.get_by_label(&format!("Kendall's W = {:.4}", fr.kendall_w));

    // Per-condition bars (Fig. 12): mean ± SD of the participants' cell means.
    let res = h.state().page.results().unwrap().clone();
    let bars = res.per_condition(ResultMetric::Column(Metric::TimeS));
    assert_eq!(bars.conditions, CONDS);
    for (j, v) in bars.values.iter().enumerate() {
        let col: Vec<f64> = y.iter().map(|r| r[j]).collect();
        let mean = col.iter().sum::<f64>() / N as f64;
        let sd = (col.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (N as f64 - 1.0)).sqrt();
        let (m, s) = v.unwrap();
        assert!((m - mean).abs() < 1e-12 && (s.unwrap() - sd).abs() < 1e-12);
        h.get_by_label_contains(&format!("{}: {mean:.4} ± {sd:.4} (n = 4)", CONDS[j]));
    }
    // Per-participant bars (Fig. 11): mean ± SD over that cell's trials.
    let pb = res.per_participant(ResultMetric::Column(Metric::TimeS));
    assert_eq!(pb.participants, ["P01", "P02", "P03", "P04"]);
    let (m, s) = pb.values[1][2].unwrap(); // condition P, P03: one trial rejected
    let t: Vec<f64> = [1, 3].iter().map(|&t| time_s(2, 1, t)).collect();
    assert!((m - (t[0] + t[1]) / 2.0).abs() < 1e-12);
    assert!((s.unwrap() - (t[0] - t[1]).abs() / 2f64.sqrt()).abs() < 1e-12);
    // Success counts: 3 everywhere but the rejected cell.
    let sc = res.per_participant(ResultMetric::SuccessCount);
    assert_eq!(sc.values[1][2], Some((2.0, None)));
    assert_eq!(sc.values[0][0], Some((3.0, None)));

    // Switch the metric through the combo box: mean optical force.
    h.get_by_label("Metric").click();
    h.run();
    h.get_by_label("mean optical force (pN)").click();
    h.run();
    let yf = cell_means(force_pn);
    let (f_rm_force, _) = textbook_f(&yf);
    let st = h.state().page.stats().unwrap();
    assert_eq!(st.metric, "force_mean_pn");
    assert!((st.rm_anova.as_ref().unwrap().f / f_rm_force - 1.0).abs() < 1e-10);
    // P − D is the same for every participant: that pair's t-test is
    // undefined, and the page says why while the other pairs keep theirs.
    let pw = &st.pairwise.as_ref().unwrap().pairs;
    let pd = pw.iter().find(|p| p.a == "P" && p.b == "D").unwrap();
    assert!(pd.t.is_none() && pd.undefined.iter().any(|u| u.starts_with("t-test")));
    assert_eq!(pw.iter().filter(|p| p.t.is_some()).count(), 2);
    assert!(pw.iter().all(|p| p.wilcoxon_p.is_some()));
    h.get_by_label_contains("undefined: t-test");

    // Export: stats.csv / stats.json next to the data, every metric.
    h.get_by_label("Export statistics (stats.csv, stats.json)")
        .click();
    h.run();
    assert!(
        h.state().page.error().is_none(),
        "{:?}",
        h.state().page.error()
    );
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("stats.json")).unwrap()).unwrap();
    let tables = json.as_array().unwrap();
    let names: Vec<&str> = tables
        .iter()
        .map(|t| t["metric"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["n_success", "time_s", "force_mean_pn"]);
    let f_json = tables[1]["rm_anova"]["F"].as_f64().unwrap();
    assert!((f_json / f_rm - 1.0).abs() < 1e-10);
    let csv_text = std::fs::read_to_string(dir.join("stats.csv")).unwrap();
    let line = csv_text
        .lines()
        .find(|l| l.starts_with("time_s,oneway_anova,"))
        .unwrap();
    let f_csv: f64 = line.split(',').nth(4).unwrap().parse().unwrap();
    assert!((f_csv / f_one - 1.0).abs() < 1e-10);

    // Regenerate the summaries: cells_long.csv comes back with the means.
    std::fs::remove_file(dir.join("cells_long.csv")).unwrap();
    h.get_by_label("Regenerate summaries").click();
    h.run();
    let long = std::fs::read_to_string(dir.join("cells_long.csv")).unwrap();
    let mut lines = long.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let ti = header.iter().position(|c| *c == "time_s").unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 12);
    for r in rows {
        let p: usize = r[0][1..].parse::<usize>().unwrap() - 1;
        let c = CONDS.iter().position(|x| *x == r[1]).unwrap();
        let v: f64 = r[ti].parse().unwrap();
        assert!((v - y[p][c]).abs() < 1e-12);
    }

    // Trajectories (Fig. 10): P01 in V has raw files.
    h.get_by_label("Trajectories (Fig. 10)").click();
    h.step();
    h.get_by_label("Load trajectories").click();
    let t0 = Instant::now();
    while h.state().page.trajectories().is_none() {
        assert!(
            h.state().page.trajectory_error().is_none(),
            "{:?}",
            h.state().page.trajectory_error()
        );
        assert!(t0.elapsed() < Duration::from_secs(60));
        h.step();
        std::thread::sleep(Duration::from_millis(10));
    }
    let tr = h.state().page.trajectories().unwrap().to_vec();
    assert_eq!(tr.len(), TRIALS as usize);
    for t in &tr {
        assert!(t.bead_um.len() <= 4000 && t.bead_um.len() > 100);
        for p in &t.bead_um {
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            assert!((r - RADIUS_UM).abs() < 1e-9, "r = {r}");
        }
        // Starts at (R, 0) (x = cos, y = sin), ends there too (kept by the decimation).
        let (a, b) = (t.bead_um[0], *t.bead_um.last().unwrap());
        assert!((a[0] - RADIUS_UM).abs() < 1e-9 && a[1].abs() < 1e-9);
        assert!((b[0] - RADIUS_UM).abs() < 1e-9 && b[1].abs() < 1e-6);
    }
    // P02 has no raw files: the page says what is missing.
    h.state_mut().page.set_trajectory_selection("P02", "D");
    h.step();
    h.get_by_label("Load trajectories").click();
    h.step();
    h.step();
    h.get_by_label_contains("reference no raw-signal file");
}

#[test]
fn the_shell_folder_opens_by_itself_and_bad_folders_give_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("study");
    write_study(&dir);

    // The shell's folder is opened on the first frame; no SetOutputDir.
    let mut h = harness(state(Some(dir.clone())));
    h.step();
    h.step();
    assert!(
        h.state().page.results().is_some(),
        "{:?}",
        h.state().page.error()
    );
    assert!(h.state().requests.is_empty());

    // A folder without trials.csv.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    open(&mut h, &empty);
    assert!(h.state().page.error().unwrap().contains("no trials.csv"));
    h.get_by_label_contains("no trials.csv");
    assert!(h.state().page.results().is_none());

    // A damaged line followed by valid ones: the study crate's file:line
    // error, shown, no crash.
    let bad = tmp.path().join("bad");
    std::fs::create_dir(&bad).unwrap();
    let text = std::fs::read_to_string(dir.join("trials.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    // Line 3 (1-based, header = line 1): change one cell, keep the CRC.
    let cells: Vec<&str> = lines[2].split(',').collect();
    let ti = 9; // time_s
    let mut changed: Vec<String> = cells.iter().map(|s| s.to_string()).collect();
    changed[ti] = "123.456".into();
    lines[2] = changed.join(",");
    std::fs::write(bad.join("trials.csv"), lines.join("\n") + "\n").unwrap();
    open(&mut h, &bad);
    let e = h.state().page.error().unwrap().to_owned();
    assert!(e.contains("line 3") && e.contains("trials.csv"), "{e}");
    h.get_by_label_contains("line 3");

    // A foreign header.
    std::fs::write(bad.join("trials.csv"), "a,b,c\n1,2,3\n").unwrap();
    open(&mut h, &bad);
    assert!(h.state().page.error().unwrap().contains("header"));

    // Not a number in a numeric cell (CRC recomputed so only the cell is
    // wrong): the error names line and column.
    let bad_cell = text.lines().nth(1).unwrap().to_owned();
    let mut cells: Vec<String> = bad_cell.split(',').map(str::to_owned).collect();
    cells[ti] = "1.2.3".into();
    let body = cells[..cells.len() - 1].join(",");
    let crc = crc32(body.as_bytes());
    let fixed = format!("{body},{crc:08x}");
    let header = text.lines().next().unwrap();
    std::fs::write(bad.join("trials.csv"), format!("{header}\n{fixed}\n")).unwrap();
    open(&mut h, &bad);
    let e = h.state().page.error().unwrap().to_owned();
    assert!(e.contains("line 2") && e.contains("time_s"), "{e}");

    // Reload of the good folder works again.
    open(&mut h, &dir);
    assert!(h.state().page.error().is_none());
    h.get_by_label("Reload").click();
    h.step();
    assert!(h.state().page.results().is_some());
}

/// CRC-32 (IEEE 802.3, reflected, as `row_crc32`), bitwise.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ 0xedb8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
}
