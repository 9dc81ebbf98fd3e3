//! How much a study run will write, stated before it runs, and the check
//! against the free space of the target disk.
//!
//! Almost everything a run writes is its raw-signal files: one NPY file per
//! trial of n rows × [`RAW_CHANNELS`] values (4 bytes each as `<f4`, the
//! default), n the trial's samples at its rate (10 kHz on the default rig:
//! 0.76 MB per simulated second). The rest — the trial's row in
//! `trials.csv`, its journal records, the NPY header and JSON sidecar, and
//! the study's fixed files — is a few kB per trial
//! ([`TABLE_BYTES_PER_TRIAL`], [`RAW_FILE_OVERHEAD_BYTES`],
//! [`STUDY_FIXED_BYTES`], measured on simulated studies).
//!
//! A trial's length is not known before it runs (it ends on success or at
//! the task's time-out), so the estimate needs the expected number of rows
//! per trial of each condition ([`TrialRows`]), from one of
//! ([`RowsBasis`]):
//!
//! * the raw files the folder already holds (a resumed study: its own
//!   participants' trials, [`TrialRows::from_folder`]);
//! * a *pilot*: a few of the pending trials run by the simulated
//!   participant without writing anything ([`TrialRows::pilot`]); trials
//!   are pure functions of their key, so these are exactly the trials the
//!   run will write; [`PILOT_TRIALS_PER_CONDITION`] of each condition (at
//!   most a quarter of them), spread over the participants;
//! * the task's time-out (every trial runs to it: the upper bound,
//!   [`TrialRows::time_out`]; what a GUI can state for a person at the
//!   handle before any trial ran).
//!
//! [`StudySize::timeout_bytes`] always gives that upper bound beside the
//! estimate. [`check_free_space`] refuses a run whose estimate exceeds the
//! space available to the user on the target disk ([`available_space`], the
//! nearest existing folder of the target), naming the numbers and how to
//! write less (`--no-raw`, fewer participants, shards).
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use kilotouch_study::simulate::SimulateOptions;
//! use kilotouch_study::size::{available_space, check_free_space, estimate_simulated_study};
//! let opts = SimulateOptions::new(kilotouch_study::protocol::Protocol::builtin("paper")?, "out");
//! let size = estimate_simulated_study(&opts)?;
//! println!("{}", size.describe());
//! check_free_space(&size, &opts.out, available_space(&opts.out)?)?;
//! # Ok(()) }
//! ```

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

use serde::Serialize;
use thiserror::Error;

use crate::export::session::{OrderRow, order_rows};
use crate::export::{PlannedTrial, TRIALS_FILE, TrialRow, plan_with_rows, read_trials};
use crate::protocol::{Condition, Protocol, Task};
use crate::rawsig::Dtype;
use crate::runner::{RAW_CHANNELS, RunError, RunnerConfig, TrialEngine};
use crate::seeds::{Phase, TrialKey};
use crate::simulate::{SimulateOptions, run_planned, sim_meta};
use crate::task::sim_station::SimStation;

/// One pilot trial's result: its condition, raw rows written, trial length (s).
type PilotRow = (Condition, u64, f64);

/// Bytes one trial adds to `trials.csv` and the journal (its row, ≈ 200 B,
/// and its journal records, ≈ 430 B), rounded up from a simulated study
/// (90 trials: 18.0 kB of rows, 38.5 kB of journal).
pub const TABLE_BYTES_PER_TRIAL: u64 = 650;
/// Bytes of a raw file besides its rows: the NPY header (128 B) and the
/// JSON sidecar (channel names, units, scene: ≈ 3.3 kB).
pub const RAW_FILE_OVERHEAD_BYTES: u64 = 5_000;
/// Bytes of the study's fixed files (`session.json` ≈ 4 kB, the summaries
/// ≈ 4 kB for 6 participants, `datapackage.json` ≈ 21 kB), rounded up.
pub const STUDY_FIXED_BYTES: u64 = 32_000;
/// Pilot trials run per condition ([`TrialRows::pilot`]).
pub const PILOT_TRIALS_PER_CONDITION: usize = 6;

/// Where the expected trial lengths come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum RowsBasis {
    /// The raw files already in the folder.
    Folder {
        /// Raw files measured.
        files: usize,
    },
    /// Pending trials run by the simulated participant.
    Pilot {
        /// Trials run.
        trials: usize,
    },
    /// Every trial runs to the task's time-out (upper bound).
    TimeOut,
}

/// Expected raw rows per trial of each condition, and the rate of those
/// rows (for the time-out bound).
#[derive(Debug, Clone, PartialEq)]
pub struct TrialRows {
    /// Mean rows per trial by condition.
    pub mean_rows: BTreeMap<Condition, f64>,
    /// Rows per second of a trial (the station's rate over the trial's
    /// decimation), by condition.
    pub rate_hz: BTreeMap<Condition, f64>,
    /// Where the numbers come from.
    pub basis: RowsBasis,
}

/// The estimated size of a run ([module docs](self)).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StudySize {
    /// Trials the run will write.
    pub trials: usize,
    /// Raw files it will write (0 without raw signals).
    pub raw_files: usize,
    /// Bytes of the raw files.
    pub raw_bytes: u64,
    /// Bytes of `trials.csv`, the journal and the study's fixed files.
    pub table_bytes: u64,
    /// Estimated total, bytes.
    pub bytes: u64,
    /// The same run without raw signals (`--no-raw`), bytes.
    pub no_raw_bytes: u64,
    /// Upper bound: every trial runs to its time-out, bytes.
    pub timeout_bytes: u64,
    /// Expected length of a trial, mean over the run's trials, s.
    pub mean_trial_s: f64,
    /// Where the trial lengths come from.
    pub basis: RowsBasis,
}

/// A size in B, kB, MB, GB or TB (decimal prefixes, 2–3 significant
/// digits), e.g. `4.0 GB`.
pub fn format_bytes(bytes: u64) -> String {
    let b = bytes as f64;
    for (p, unit) in [(1e12, "TB"), (1e9, "GB"), (1e6, "MB"), (1e3, "kB")] {
        if b >= p {
            let v = b / p;
            return if v < 10.0 {
                format!("{v:.1} {unit}")
            } else {
                format!("{v:.0} {unit}")
            };
        }
    }
    format!("{bytes} B")
}

impl StudySize {
    /// One sentence, e.g. "about 4.0 GB: 624 trials with raw files of
    /// ≈ 6.4 MB (8.4 s each on average, from a pilot of 18 trials);
    /// without raw files 0.7 MB; at most 57 GB if every trial ran to its
    /// time-out".
    pub fn describe(&self) -> String {
        let basis = match self.basis {
            RowsBasis::Folder { files } => format!("from the {files} raw files already written"),
            RowsBasis::Pilot { trials } => {
                format!("from a pilot of {trials} trials by the simulated participant")
            }
            RowsBasis::TimeOut => "if every trial ran to its time-out".to_owned(),
        };
        if self.raw_files > 0 && self.basis == RowsBasis::TimeOut {
            return format!(
                "at most {}: {} trials with raw files of at most {} (every trial run to its \
                 {:.0} s time-out); without raw files {}",
                format_bytes(self.bytes),
                self.trials,
                format_bytes(self.raw_bytes / self.raw_files.max(1) as u64),
                self.mean_trial_s,
                format_bytes(self.no_raw_bytes)
            );
        }
        if self.raw_files == 0 {
            return format!(
                "about {} for {} trials (no raw files)",
                format_bytes(self.bytes),
                self.trials
            );
        }
        format!(
            "about {}: {} trials with raw files of ≈ {} ({:.1} s each on average, {basis}); \
             without raw files {}; at most {} if every trial ran to its time-out",
            format_bytes(self.bytes),
            self.trials,
            format_bytes(self.raw_bytes / self.raw_files.max(1) as u64),
            self.mean_trial_s,
            format_bytes(self.no_raw_bytes),
            format_bytes(self.timeout_bytes)
        )
    }
}

fn timeout_s(protocol: &Protocol) -> f64 {
    match &protocol.task {
        Task::Circling(t) => t.timeout_s,
        Task::BlindNavigation(t) => t.timeout_s,
    }
}

impl TrialRows {
    /// Every trial runs to the task's time-out at `fs` rows per second
    /// (the upper bound).
    pub fn time_out(protocol: &Protocol, fs: f64) -> Self {
        let rows = (timeout_s(protocol) * fs).ceil();
        TrialRows {
            mean_rows: protocol.conditions.iter().map(|&c| (c, rows)).collect(),
            rate_hz: protocol.conditions.iter().map(|&c| (c, fs)).collect(),
            basis: RowsBasis::TimeOut,
        }
    }

    /// From the raw files of the folder `out` (rows = (file size − NPY
    /// header) / row size, the header length read from the file), by
    /// condition; `None` when a condition of the protocol has none.
    pub fn from_folder(out: &Path, protocol: &Protocol, fs: f64, dtype: Dtype) -> Option<Self> {
        let read = read_trials(&out.join(TRIALS_FILE)).ok()?;
        let row_bytes = (RAW_CHANNELS * dtype.size()) as f64;
        let mut sums: BTreeMap<Condition, (f64, usize)> = BTreeMap::new();
        for r in read.rows.iter().filter(|r| !r.raw_file.is_empty()) {
            let path = out.join(&r.raw_file);
            let Some(rows) = npy_rows(&path, row_bytes) else {
                continue;
            };
            let e = sums.entry(r.condition).or_insert((0.0, 0));
            e.0 += rows;
            e.1 += 1;
        }
        if protocol.conditions.iter().any(|c| !sums.contains_key(c)) {
            return None;
        }
        let files = sums.values().map(|s| s.1).sum();
        Some(TrialRows {
            mean_rows: sums.iter().map(|(c, s)| (*c, s.0 / s.1 as f64)).collect(),
            rate_hz: protocol.conditions.iter().map(|&c| (c, fs)).collect(),
            basis: RowsBasis::Folder { files },
        })
    }

    /// A pilot: up to `per_condition` of the `pending` trials of each
    /// condition (evenly spread over them) run by the simulated participant
    /// on the simulated rig of `opts`, writing nothing, on `opts.threads`
    /// threads.
    ///
    /// # Errors
    /// Station and operator errors, an invalid rig or calibration.
    pub fn pilot(
        opts: &SimulateOptions,
        pending: &[PlannedTrial],
        per_condition: usize,
    ) -> Result<Self, RunError> {
        let sample = pilot_sample(pending, &opts.protocol.conditions, per_condition);
        let (_, chain) = sim_meta(&opts.rig, opts.calibration.as_deref(), false, None)?;
        let runner = RunnerConfig {
            raw: None,
            ..opts.runner
        };
        let threads = opts.threads.clamp(1, sample.len().max(1));
        let chunks: Vec<&[PlannedTrial]> = sample
            .chunks(sample.len().div_ceil(threads).max(1))
            .collect();
        let results: Vec<Result<Vec<PilotRow>, RunError>> = std::thread::scope(|scope| {
            let handles: Vec<_> = chunks
                .into_iter()
                .map(|chunk| {
                    let chain = chain.clone();
                    let work = move || -> Result<Vec<(Condition, u64, f64)>, RunError> {
                        let mut station = SimStation::with_chain(&opts.rig, chain)?;
                        station.set_fidelity(opts.fidelity);
                        let mut engine = TrialEngine::new(station, runner)?;
                        let nowhere = Path::new("");
                        chunk
                            .iter()
                            .map(|p| {
                                let (_, o) = run_planned(&mut engine, &opts.protocol, p, nowhere)?;
                                Ok((p.key.condition, o.samples, o.sample_rate_hz))
                            })
                            .collect()
                    };
                    std::thread::Builder::new()
                        .name("kilotouch-pilot".into())
                        .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
                        .spawn_scoped(scope, work)
                })
                .collect();
            handles
                .into_iter()
                .map(|h| match h {
                    Ok(h) => h
                        .join()
                        .unwrap_or_else(|_| Err(RunError::State("a pilot thread panicked".into()))),
                    Err(e) => Err(RunError::State(format!(
                        "could not start a pilot thread: {e}"
                    ))),
                })
                .collect()
        });
        // A trial that writes no raw file may run at a lower rate (scene
        // fidelity runs V at the participant's control rate); a raw file
        // records every sample of the station's rate: rows = seconds × f_s.
        let fs = opts.rig.rig.sample_rate_hz;
        let mut sums: BTreeMap<Condition, (f64, usize)> = BTreeMap::new();
        let mut trials = 0;
        for r in results {
            for (c, samples, rate) in r? {
                let e = sums.entry(c).or_insert((0.0, 0));
                if rate > 0.0 {
                    e.0 += samples as f64 / rate * fs;
                }
                e.1 += 1;
                trials += 1;
            }
        }
        Ok(TrialRows {
            mean_rows: sums.iter().map(|(c, s)| (*c, s.0 / s.1 as f64)).collect(),
            rate_hz: sums.keys().map(|c| (*c, fs)).collect(),
            basis: RowsBasis::Pilot { trials },
        })
    }
}

/// Rows of an NPY file of `row_bytes` per row: (size − header) / row size,
/// the header length from the file's preamble (NPY v1: u16 at byte 8, v2/3:
/// u32).
fn npy_rows(path: &Path, row_bytes: f64) -> Option<f64> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).ok()?;
    let size = f.metadata().ok()?.len();
    let mut pre = [0u8; 12];
    f.read_exact(&mut pre).ok()?;
    if &pre[..6] != b"\x93NUMPY" {
        return None;
    }
    let header = match pre[6] {
        1 => 10 + u64::from(u16::from_le_bytes([pre[8], pre[9]])),
        _ => 12 + u64::from(u32::from_le_bytes([pre[8], pre[9], pre[10], pre[11]])),
    };
    Some(size.saturating_sub(header) as f64 / row_bytes)
}

/// Up to `per_condition` trials of each condition (and at most a quarter
/// of them), evenly spread over the pending trials of that condition
/// (first, …, last), in plan order.
fn pilot_sample(
    pending: &[PlannedTrial],
    conditions: &[Condition],
    per_condition: usize,
) -> Vec<PlannedTrial> {
    let mut out = Vec::new();
    for &c in conditions {
        let of_c: Vec<&PlannedTrial> = pending.iter().filter(|p| p.key.condition == c).collect();
        // At most a quarter of the condition's trials: a small study is
        // not run twice to be measured.
        let k = per_condition.min(of_c.len().div_ceil(4));
        if k == 0 {
            continue;
        }
        let mut last = usize::MAX;
        for j in 0..k {
            let i = if k == 1 {
                0
            } else {
                j * (of_c.len() - 1) / (k - 1)
            };
            if i != last {
                out.push(of_c[i].clone());
                last = i;
            }
        }
    }
    out
}

/// The trials of `protocol` not yet in the folder `out` (all of them for a
/// new folder), restricted to `participants` when given (a shard's),
/// without opening the folder for writing. An unreadable `trials.csv`
/// counts as no trial done (the store repairs it when it opens).
///
/// # Errors
/// An invalid protocol.
pub fn pending_trials(
    protocol: &Protocol,
    out: &Path,
    participants: Option<&dyn Fn(u32) -> bool>,
) -> Result<Vec<PlannedTrial>, RunError> {
    let table = protocol
        .assignment()
        .map_err(|e| RunError::Config(format!("protocol: {e}")))?;
    let orders = order_rows(&table);
    let rows = folder_rows(out);
    let all = plan_with_rows(protocol, &orders, &rows);
    let done = done_keys(&orders, &rows);
    Ok(all
        .into_iter()
        .filter(|p| !done.contains(&p.key))
        .filter(|p| participants.is_none_or(|f| f(p.key.participant)))
        .collect())
}

/// [`pending_trials`] and every extra practice trial they may still earn
/// (`training.practice_retries` per participant and condition), for an
/// upper bound: in the worst case every practice trial is unsuccessful.
/// A participant with no pending trial earns none.
///
/// # Errors
/// As [`pending_trials`].
pub fn pending_trials_at_most(
    protocol: &Protocol,
    out: &Path,
    participants: Option<&dyn Fn(u32) -> bool>,
) -> Result<Vec<PlannedTrial>, RunError> {
    let mut pending = pending_trials(protocol, out, participants)?;
    let retries = protocol.training.practice_retries;
    if retries == 0 {
        return Ok(pending);
    }
    let table = protocol
        .assignment()
        .map_err(|e| RunError::Config(format!("protocol: {e}")))?;
    let done = done_keys(&order_rows(&table), &folder_rows(out));
    let planned: HashSet<TrialKey> = pending.iter().map(|p| p.key).collect();
    let n = protocol.training.practice_trials;
    let mut extra = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for p in &pending {
        let cell = (p.key.participant, p.key.condition);
        if !seen.insert(cell) {
            continue;
        }
        for t in n + 1..=n + retries {
            let key = TrialKey::new(cell.0, cell.1, Phase::Practice, t);
            if !done.contains(&key) && !planned.contains(&key) {
                extra.push(PlannedTrial {
                    key,
                    seed: key.seed(protocol.seeds.study),
                    ..p.clone()
                });
            }
        }
    }
    pending.extend(extra);
    Ok(pending)
}

/// The rows of the folder `out`'s `trials.csv`. A damaged file (a writer
/// killed while creating it) is the store's to repair when it opens; until
/// then it counts as no row (an upper bound).
fn folder_rows(out: &Path) -> Vec<TrialRow> {
    read_trials(&out.join(TRIALS_FILE)).map_or_else(|_| Vec::new(), |r| r.rows)
}

/// The trials `rows` hold.
fn done_keys(orders: &[OrderRow], rows: &[TrialRow]) -> HashSet<TrialKey> {
    rows.iter()
        .filter_map(|r| {
            orders
                .iter()
                .find(|o| o.participant == r.participant)
                .map(|o| r.key(o.index))
        })
        .collect()
}

/// The size of writing `pending` with raw files of `raw` (`None`: no raw
/// files), the trial lengths from `rows` ([module docs](self)).
pub fn estimate_study_size(
    protocol: &Protocol,
    raw: Option<Dtype>,
    pending: &[PlannedTrial],
    rows: &TrialRows,
) -> StudySize {
    let fallback_rate = rows.rate_hz.values().copied().fold(0.0, f64::max);
    let mut raw_bytes = 0f64;
    let mut timeout_raw = 0f64;
    let mut seconds = 0f64;
    let row_bytes = raw.map_or(0, |d| RAW_CHANNELS * d.size()) as f64;
    for p in pending {
        let c = p.key.condition;
        let rate = rows.rate_hz.get(&c).copied().unwrap_or(fallback_rate);
        let n = rows.mean_rows.get(&c).copied().unwrap_or_else(|| {
            // A condition the basis did not see: the mean of the others.
            rows.mean_rows.values().sum::<f64>() / rows.mean_rows.len().max(1) as f64
        });
        if rate > 0.0 {
            seconds += n / rate;
        }
        if raw.is_some() {
            raw_bytes += n * row_bytes + RAW_FILE_OVERHEAD_BYTES as f64;
            timeout_raw +=
                (timeout_s(protocol) * rate).ceil() * row_bytes + RAW_FILE_OVERHEAD_BYTES as f64;
        }
    }
    let trials = pending.len();
    let table_bytes = TABLE_BYTES_PER_TRIAL * trials as u64 + STUDY_FIXED_BYTES;
    StudySize {
        trials,
        raw_files: if raw.is_some() { trials } else { 0 },
        raw_bytes: raw_bytes.ceil() as u64,
        table_bytes,
        bytes: raw_bytes.ceil() as u64 + table_bytes,
        no_raw_bytes: table_bytes,
        timeout_bytes: timeout_raw.ceil() as u64 + table_bytes,
        mean_trial_s: if trials > 0 {
            seconds / trials as f64
        } else {
            0.0
        },
        basis: rows.basis,
    }
}

/// The estimate for `kilotouch study simulate` with `opts`: its pending
/// trials (the shard's), their lengths from the folder's raw files when it
/// holds some of every condition, else from a pilot
/// ([`PILOT_TRIALS_PER_CONDITION`] per condition).
///
/// # Errors
/// As [`pending_trials`] and [`TrialRows::pilot`].
pub fn estimate_simulated_study(opts: &SimulateOptions) -> Result<StudySize, RunError> {
    let shard = opts.shard;
    let in_shard = move |p: u32| shard.is_none_or(|s| s.contains(p));
    estimate_pending(opts, &in_shard)
}

/// The estimate for a sitting on the real-time engine (the Study page):
/// the pending trials of the 0-based participant `only` (every
/// participant: `None`) of the study `opts` describes, on the same bases as
/// [`estimate_simulated_study`] (the folder's raw files, else a pilot by
/// the simulated participant: for a person at the handle, what the
/// simulated participant would take).
///
/// # Errors
/// As [`estimate_simulated_study`].
pub fn estimate_sitting(opts: &SimulateOptions, only: Option<u32>) -> Result<StudySize, RunError> {
    let keep = move |p: u32| only.is_none_or(|o| o == p);
    estimate_pending(opts, &keep)
}

/// The upper bound for the same sitting as [`estimate_sitting`]: every
/// pending trial runs to the task's time-out ([`TrialRows::time_out`]; no
/// pilot, only `trials.csv` is read), and every extra practice trial the
/// protocol allows is earned ([`pending_trials_at_most`]). A sitting whose bound is small needs
/// no better estimate.
///
/// # Errors
/// As [`pending_trials`].
pub fn bound_sitting(opts: &SimulateOptions, only: Option<u32>) -> Result<StudySize, RunError> {
    let keep = move |p: u32| only.is_none_or(|o| o == p);
    let pending = pending_trials_at_most(&opts.protocol, &opts.out, Some(&keep))?;
    let rows = TrialRows::time_out(&opts.protocol, opts.rig.rig.sample_rate_hz);
    Ok(estimate_study_size(
        &opts.protocol,
        opts.runner.raw,
        &pending,
        &rows,
    ))
}

/// [`estimate_simulated_study`] for the pending trials of the participants
/// `keep` accepts.
fn estimate_pending(
    opts: &SimulateOptions,
    keep: &dyn Fn(u32) -> bool,
) -> Result<StudySize, RunError> {
    let pending = pending_trials(&opts.protocol, &opts.out, Some(keep))?;
    let raw = opts.runner.raw;
    let rows = match (raw, opts.resume) {
        (None, _) => TrialRows::time_out(&opts.protocol, opts.rig.rig.sample_rate_hz),
        (Some(d), true) => {
            match TrialRows::from_folder(&opts.out, &opts.protocol, opts.rig.rig.sample_rate_hz, d)
            {
                Some(r) => r,
                None => TrialRows::pilot(opts, &pending, PILOT_TRIALS_PER_CONDITION)?,
            }
        }
        (Some(_), false) => TrialRows::pilot(opts, &pending, PILOT_TRIALS_PER_CONDITION)?,
    };
    let mut size = estimate_study_size(&opts.protocol, raw, &pending, &rows);
    if raw.is_none() {
        // Nothing scales with the trial length: no pilot was needed.
        size.mean_trial_s = f64::NAN;
    }
    Ok(size)
}

/// Bytes available to the user on the disk that holds `target` (or its
/// nearest existing parent folder, for a folder not yet made).
///
/// # Errors
/// No existing parent; the file system's query failed.
pub fn available_space(target: &Path) -> std::io::Result<u64> {
    let abs = std::path::absolute(target)?;
    let existing = abs.ancestors().find(|p| p.exists()).ok_or_else(|| {
        std::io::Error::other(format!("no existing folder above {}", abs.display()))
    })?;
    fs4::available_space(existing)
}

/// A run that would not fit on its disk.
#[derive(Debug, Clone, PartialEq, Error)]
#[error(
    "not enough disk space: the run would write {} to {} and the disk has {} free. {}",
    format_bytes(size.bytes),
    target.display(),
    format_bytes(*available),
    advice(size)
)]
pub struct SpaceError {
    /// The estimate.
    pub size: StudySize,
    /// The target folder.
    pub target: PathBuf,
    /// Bytes available.
    pub available: u64,
}

fn advice(size: &StudySize) -> String {
    let per_trial = size.bytes / size.trials.max(1) as u64;
    if size.raw_files > 0 {
        format!(
            "Free some space, write without raw signals (--no-raw: about {}), or run fewer \
             participants (about {} per trial; --participants N, or --shard K/N onto several \
             disks).",
            format_bytes(size.no_raw_bytes),
            format_bytes(per_trial)
        )
    } else {
        "Free some space or choose a folder on another disk.".to_owned()
    }
}

/// Refuses a run whose estimate exceeds `available` bytes (module docs).
///
/// # Errors
/// [`SpaceError`] with the numbers and how to write less.
pub fn check_free_space(size: &StudySize, target: &Path, available: u64) -> Result<(), SpaceError> {
    if size.bytes > available {
        return Err(SpaceError {
            size: size.clone(),
            target: target.to_path_buf(),
            available,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::plan;

    #[test]
    fn bytes_read_like_a_file_manager() {
        assert_eq!(format_bytes(999), "999 B");
        assert_eq!(format_bytes(4_012_000_000), "4.0 GB");
        assert_eq!(format_bytes(57_300_000_000), "57 GB");
        assert_eq!(format_bytes(6_400_000), "6.4 MB");
    }

    #[test]
    fn the_bound_counts_every_extra_practice_trial_the_protocol_allows() {
        let mut protocol = Protocol::builtin("paper").unwrap();
        protocol.training.practice_retries = 0;
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("new");
        let plain = pending_trials(&protocol, &out, None).unwrap();
        assert_eq!(
            pending_trials_at_most(&protocol, &out, None).unwrap(),
            plain,
            "no extra practice without practice_retries"
        );
        protocol.training.practice_retries = 2;
        let most = pending_trials_at_most(&protocol, &out, None).unwrap();
        // 8 participants × 3 conditions × 2 extra trials.
        assert_eq!(most.len(), plain.len() + 8 * 3 * 2);
        let extra = &most[plain.len()..];
        assert!(extra.iter().all(|p| p.key.phase == Phase::Practice
            && (4..=5).contains(&p.key.trial)
            && p.seed == p.key.seed(protocol.seeds.study)));
        // Only the kept participants.
        let one = |p: u32| p == 3;
        let most = pending_trials_at_most(&protocol, &out, Some(&one)).unwrap();
        assert_eq!(most.len(), 3 * (10 + 3 + 2));
    }

    #[test]
    fn estimate_counts_rows_overheads_and_the_time_out_bound() {
        let protocol = Protocol::builtin("paper").unwrap();
        let table = protocol.assignment().unwrap();
        let all = plan(&protocol, &order_rows(&table));
        let rows = TrialRows {
            mean_rows: protocol.conditions.iter().map(|&c| (c, 80_000.0)).collect(),
            rate_hz: protocol.conditions.iter().map(|&c| (c, 10_000.0)).collect(),
            basis: RowsBasis::Pilot { trials: 3 },
        };
        let s = estimate_study_size(&protocol, Some(Dtype::F32), &all, &rows);
        let n = all.len() as u64;
        assert_eq!(s.trials as u64, n);
        assert_eq!(s.raw_bytes, n * (80_000 * 19 * 4 + RAW_FILE_OVERHEAD_BYTES));
        assert_eq!(
            s.bytes,
            s.raw_bytes + n * TABLE_BYTES_PER_TRIAL + STUDY_FIXED_BYTES
        );
        assert!((s.mean_trial_s - 8.0).abs() < 1e-12);
        assert_eq!(
            s.timeout_bytes - s.table_bytes,
            n * (1_200_000 * 19 * 4 + RAW_FILE_OVERHEAD_BYTES)
        );
        let no_raw = estimate_study_size(&protocol, None, &all, &rows);
        assert_eq!(no_raw.bytes, s.no_raw_bytes);
        assert_eq!(no_raw.raw_files, 0);
        // The refusal names both numbers and the ways out.
        let e = check_free_space(&s, Path::new("/data/study"), 1_000_000_000).unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("1.0 GB free") && m.contains("--no-raw") && m.contains("--participants"),
            "{m}"
        );
        assert!(check_free_space(&s, Path::new("/x"), s.bytes).is_ok());
    }

    /// The bound of one participant's sitting in a new folder: that
    /// participant's trials, each to the time-out (120 s at 10 kHz), stated
    /// as a bound.
    #[test]
    fn a_sittings_bound_counts_its_participants_trials_to_the_time_out() {
        let protocol = Protocol::builtin("paper").unwrap();
        let dir = std::env::temp_dir().join(format!("kt-size-bound-{}", std::process::id()));
        let opts = SimulateOptions::new(protocol.clone(), &dir);
        let all = plan(&protocol, &order_rows(&protocol.assignment().unwrap()));
        let b = bound_sitting(&opts, Some(1)).unwrap();
        // The plan's trials and every extra practice trial allowed (3 per
        // condition in the built-in protocol).
        let extra = 3 * protocol.training.practice_retries as usize;
        assert_eq!(extra, 9);
        let n = all.iter().filter(|p| p.key.participant == 1).count() + extra;
        assert_eq!(b.trials, n);
        assert_eq!(b.basis, RowsBasis::TimeOut);
        assert_eq!(b.bytes, b.timeout_bytes);
        assert_eq!(
            b.raw_bytes,
            n as u64 * (1_200_000 * 19 * 4 + RAW_FILE_OVERHEAD_BYTES)
        );
        assert!(b.describe().starts_with("at most "), "{}", b.describe());
        let every = bound_sitting(&opts, None).unwrap();
        assert_eq!(every.trials, all.len() + 8 * extra);
    }

    #[test]
    fn pilot_sample_spreads_over_each_condition() {
        let protocol = Protocol::builtin("paper").unwrap();
        let all = plan(&protocol, &order_rows(&protocol.assignment().unwrap()));
        let s = pilot_sample(&all, &protocol.conditions, 4);
        assert_eq!(s.len(), 12);
        // A quarter at most: 13 trials of a condition → 4.
        let one: Vec<_> = all
            .iter()
            .filter(|p| p.key.participant == 0)
            .cloned()
            .collect();
        assert_eq!(pilot_sample(&one, &protocol.conditions, 6).len(), 3 * 4);
        for c in &protocol.conditions {
            let of_c: Vec<_> = all.iter().filter(|p| p.key.condition == *c).collect();
            let picked: Vec<_> = s.iter().filter(|p| p.key.condition == *c).collect();
            assert_eq!(picked.first().unwrap().key, of_c.first().unwrap().key);
            assert_eq!(picked.last().unwrap().key, of_c.last().unwrap().key);
        }
        assert!(pilot_sample(&all[..2], &protocol.conditions, 4).len() <= 2);
    }
}
