//! A deterministic fake session runner for the storage tests: each trial's
//! results and raw signals derive only from its seeds, as the real tasks'
//! will.

use kilotouch_rig::config::RigConfig;
use kilotouch_study::export::{StudyMeta, StudyStore, TaskKind, TrialRow, TrialTicket, UtcTime};
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::rawsig::{Channel, Dtype, NpyWriter, RawLayout};
use kilotouch_study::runner::{RunnerConfig, SessionRunner};
use kilotouch_study::seeds::{Phase, STREAM_PARTICIPANT, STREAM_RIG, TrialKey};
use kilotouch_study::task::sim_station::SimStation;
use rand_chacha::rand_core::Rng;

/// 2026-01-01T00:00:00Z.
pub const BASE_MS: i64 = 1_767_225_600_000;

/// A circling protocol with `participants`, V/P/D, `trials` per session and
/// `practice` practice trials per condition.
pub fn protocol(participants: u32, trials: u32, practice: u32, seed: u64) -> Protocol {
    let text = format!(
        "name = \"store-test\"\nparticipants = {participants}\nconditions = [\"V\", \"P\", \"D\"]\n\
         trials_per_session = {trials}\n[training]\npractice_trials = {practice}\n\
         [task.circling]\n[seeds]\nstudy = {seed}\n"
    );
    Protocol::from_toml_str(&text, "<test>").expect("test setup")
}

/// The protocol of the TOML `text`, read as the file `<test>`.
pub fn protocol_from(text: &str) -> Protocol {
    Protocol::from_toml_str(text, "<test>").expect("test setup")
}

pub fn meta() -> StudyMeta {
    StudyMeta::new("simulated-test-rig")
}

/// Uniform in [0, 1).
pub fn unit(x: u64) -> f64 {
    (x >> 11) as f64 / (1_u64 << 53) as f64
}

/// The simulated outcome of a trial.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    pub success: bool,
    pub reason: &'static str,
    pub escaped: bool,
    pub time_s: Option<f64>,
    pub force_mean_pn: f64,
    pub force_mean_n: f64,
    pub disp_err_mean_um: f64,
    pub contact_fraction: f64,
    pub samples: usize,
}

pub fn outcome(study_seed: u64, key: TrialKey) -> Outcome {
    let mut r = key.rng(study_seed, STREAM_PARTICIPANT);
    let u: Vec<f64> = (0..7).map(|_| unit(r.next_u64())).collect();
    let (t0, f0, e0) = match key.condition {
        Condition::V => (60.0, 8.0, 1.2),
        Condition::P => (45.0, 5.0, 0.8),
        Condition::D => (40.0, 4.5, 0.7),
    };
    let success = u[0] < 0.75;
    let escaped = !success && u[5] < 0.5;
    let reason = match (success, escaped) {
        (true, _) => "",
        (false, true) => "escaped",
        (false, false) => "low_contact",
    };
    let force = f0 + 2.0 * u[2];
    Outcome {
        success,
        reason,
        escaped,
        time_s: (!escaped).then_some(t0 + 20.0 * u[1]),
        force_mean_pn: force,
        force_mean_n: force * 0.01,
        disp_err_mean_um: e0 + 0.3 * u[3],
        contact_fraction: if success {
            0.5 + 0.5 * u[4]
        } else {
            0.5 * u[4]
        },
        samples: 20 + (u[6] * 30.0) as usize,
    }
}

pub fn started(seed: u64) -> UtcTime {
    UtcTime::from_unix_millis(BASE_MS + (seed % 86_400_000) as i64)
}

pub fn layout() -> RawLayout {
    RawLayout {
        sample_rate_hz: 10_000.0,
        dtype: Dtype::F64,
        channels: vec![
            Channel::new("bead_x", "m", "bead x"),
            Channel::new("bead_y", "m", "bead y"),
            Channel::new("force_bead_x", "N", "force x"),
            Channel::new("event", "code", "events"),
        ],
        attrs: serde_json::Map::new(),
    }
}

/// Raw sample `i` of a trial.
pub fn raw_rows(study_seed: u64, key: TrialKey, n: usize) -> Vec<[f64; 4]> {
    let mut r = key.rng(study_seed, STREAM_RIG);
    (0..n)
        .map(|i| {
            [
                unit(r.next_u64()) * 1e-6,
                unit(r.next_u64()) * 1e-6,
                (unit(r.next_u64()) - 0.5) * 1e-12,
                f64::from(u8::from(i == 0)),
            ]
        })
        .collect()
}

/// The row the runner commits for a ticket.
pub fn row_for(ticket: &TrialTicket, study_seed: u64) -> TrialRow {
    let o = outcome(study_seed, ticket.key());
    let mut row = ticket.row();
    row.success = o.success;
    row.reject_reason = o.reason.into();
    row.escaped = Some(o.escaped);
    row.time_s = o.time_s;
    row.force_mean_pn = Some(o.force_mean_pn);
    row.force_mean_n = Some(o.force_mean_n);
    row.disp_err_mean_um = Some(o.disp_err_mean_um);
    row.contact_fraction = Some(o.contact_fraction);
    assert_eq!(row.task, TaskKind::Circling);
    row
}

/// How far a trial gets before a simulated crash.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stop {
    /// Run to completion.
    Complete,
    /// Crash right after `trial_started`.
    AfterBegin,
    /// Crash with the raw file half written.
    MidRaw,
    /// Crash after the raw file is finished, before the row.
    AfterRaw,
}

/// Runs one trial (begin, raw, commit) up to `stop`. With `pause_us`, sleeps
/// between raw chunks (widens the windows for the kill test).
pub fn run_trial(store: &mut StudyStore, key: TrialKey, stop: Stop, pause_us: u64) {
    let seed = store.protocol().seeds.study;
    let planned_seed = store.planned(&key).expect("test setup").seed;
    let mut ticket = store
        .begin_trial(key, started(planned_seed))
        .expect("test setup");
    if stop == Stop::AfterBegin {
        std::mem::forget(ticket);
        return;
    }
    let o = outcome(seed, key);
    let mut w: NpyWriter = store.raw_writer(&mut ticket, layout()).expect("test setup");
    let rows = raw_rows(seed, key, o.samples);
    for (i, r) in rows.iter().enumerate() {
        w.push(r).expect("test setup");
        if pause_us > 0 && i % 10 == 0 {
            std::thread::sleep(std::time::Duration::from_micros(pause_us));
        }
        if stop == Stop::MidRaw && i == rows.len() / 2 {
            drop(w);
            std::mem::forget(ticket);
            return;
        }
    }
    w.finish().expect("test setup");
    if stop == Stop::AfterRaw {
        std::mem::forget(ticket);
        return;
    }
    let row = row_for(&ticket, seed);
    store.commit_trial(ticket, &row).expect("test setup");
}

/// Runs every pending trial to completion.
pub fn run_pending(store: &mut StudyStore, pause_us: u64) {
    while let Some(p) = store.next_pending() {
        let key = p.key;
        run_trial(store, key, Stop::Complete, pause_us);
    }
}

/// Test trials of a participant/condition in the plan.
pub fn test_keys(participant: u32, c: Condition, trials: u32) -> Vec<TrialKey> {
    (1..=trials)
        .map(|t| TrialKey::new(participant, c, Phase::Test, t))
        .collect()
}

/// Every file under `dir` (relative path → bytes), excluding the journal,
/// session.json (wall-clock stamps), the writer lock (process ids) and
/// recovery copies.
pub fn data_files(dir: &std::path::Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).expect("test setup") {
            let p = e.expect("test setup").path();
            let rel = p
                .strip_prefix(dir)
                .expect("test setup")
                .to_string_lossy()
                .replace('\\', "/");
            if p.is_dir() {
                if rel != "recovery" {
                    stack.push(p);
                }
            } else if !["journal.jsonl", "session.json", "writer.lock"].contains(&rel.as_str()) {
                out.insert(rel, std::fs::read(&p).expect("test setup"));
            }
        }
    }
    out
}

/// Property-test settings: `PROPTEST_CASES` cases (256 by default).
pub fn proptest_config() -> proptest::prelude::ProptestConfig {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256);
    proptest::prelude::ProptestConfig {
        cases,
        ..proptest::prelude::ProptestConfig::default()
    }
}

/// `text` with the value of its `line`-th `key = value` line replaced.
pub fn replace_value(text: &str, line: usize, value: &str) -> String {
    let assignments: Vec<usize> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim_start().starts_with('#') && l.contains(" = "))
        .map(|(i, _)| i)
        .collect();
    let target = assignments[line % assignments.len()];
    text.lines()
        .enumerate()
        .map(|(i, l)| {
            if i == target {
                let key = l.split(" = ").next().unwrap_or_default();
                format!("{key} = {value}")
            } else {
                l.to_owned()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// A session runner on the simulated station (default rig) over `store`.
pub fn sim_runner(store: StudyStore, config: RunnerConfig) -> SessionRunner<SimStation> {
    let station = SimStation::new(&RigConfig::default()).expect("test setup");
    SessionRunner::new(store, station, config).expect("test setup")
}
