//! The study output folder: crash-safe trial storage, resume, summaries.
//!
//! A [`StudyStore`] owns one output folder per study:
//!
//! ```text
//! <folder>/
//!   session.json      protocol, seeds, order table, software, rig, calibration, sittings
//!   trials.csv        one row per finished trial (append-only, CRC per row)
//!   journal.jsonl     append-only session journal (CRC per line)
//!   cells_long.csv    participant × condition means (regenerated)
//!   cells_wide.csv    one row per participant (regenerated)
//!   raw/<P>_<C>_<phase>_<trial>.npy + .json   full-rate signals per trial
//!   recovery/         copies of torn tails cut on resume
//! ```
//!
//! # Commit order (per trial)
//!
//! 1. journal `trial_started` (fsync);
//! 2. raw signals streamed to `raw/…npy`; [`NpyWriter::finish`] patches the
//!    header, fsyncs the file, writes the sidecar, fsyncs the directory;
//! 3. the row is appended to `trials.csv` in one `write`, then `fdatasync`;
//! 4. journal `trial_completed` with the row's CRC (fsync);
//! 5. only then does [`StudyStore::commit_trial`] return and the next trial
//!    may start.
//!
//! `trials.csv` is the record of truth; the journal is the log that makes a
//! crash at any point recoverable:
//!
//! | crash during / after | found on [`StudyStore::open`] | action |
//! |---|---|---|
//! | 1–2 | `trial_started` without completion | reported *interrupted*, journaled `trial_aborted`, run again (same seeds → same row) |
//! | 3 (partial row) | last line without `\n` / bad CRC | cut (copy in `recovery/`), trial run again |
//! | between 3 and 4 | complete, checksummed row without `trial_completed` | row *adopted*: kept, `trial_completed` journaled now |
//! | 4 (partial record) | torn last journal line | cut (copy in `recovery/`); row adopted as above |
//!
//! Anything a crash cannot produce — a journaled completion whose row is
//! missing, a row whose CRC differs from its journal record, a damaged line
//! followed by valid ones, duplicate rows, rows of another protocol or
//! seed — is an error and nothing is modified.
//!
//! [`NpyWriter::finish`]: crate::rawsig::NpyWriter::finish

pub mod checksum;
pub mod journal;
pub mod session;
pub mod summary;
pub mod trials;

pub use crate::storage::{error, fsutil, utc};

use std::collections::HashMap;
use std::fmt;
use std::fs;
use std::path::{Path, PathBuf};

pub use error::{ExportError, Position, Result};
pub use fsutil::TornTail;
pub use session::{
    CalibrationRef, OrderRow, Progress, SESSION_FILE, SessionInfo, Sitting, read_session,
};
pub use summary::{CELLS_LONG_FILE, CELLS_WIDE_FILE, Summary, Table, summarize};
pub use trials::{
    Metric, ReadOptions, TRIALS_COLUMNS, TRIALS_FILE, TaskKind, TrialRow, TrialsRead, read_trials,
    read_trials_with,
};
pub use utc::UtcTime;

use crate::protocol::{Location, Protocol, ProtocolError};
use crate::rawsig::{NpyWriter, RawLayout};
use crate::seeds::{Phase, TrialKey, format_seed};
use crate::storage::error::io_err;
use crate::storage::fsutil::{
    append_durable, create_dir_durable, cut_torn_tail, open_append, parent_of, sync_dir,
    write_atomic,
};
use journal::{JOURNAL_FILE, Journal, Record, RecoveryRecord, SessionStart};

/// Folder of the raw-signal files.
pub const RAW_DIR: &str = "raw";
/// Folder of the copies of cut torn tails.
pub const RECOVERY_DIR: &str = "recovery";

/// Software version recorded by default.
pub const SOFTWARE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Identity of the writer and the hardware, recorded with every sitting.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StudyMeta {
    /// Software name (default `kilotouch`).
    pub software_name: String,
    /// Software version (default [`SOFTWARE_VERSION`]).
    pub software_version: String,
    /// Rig identity (e.g. `simulated`, or the Pantograph serial number).
    pub rig: String,
    /// Calibration file in use.
    pub calibration: Option<CalibrationRef>,
}

impl StudyMeta {
    /// Meta with this crate's version and no calibration.
    pub fn new(rig: &str) -> Self {
        Self {
            software_name: "kilotouch".into(),
            software_version: SOFTWARE_VERSION.into(),
            rig: rig.into(),
            calibration: None,
        }
    }
}

/// One trial of the protocol's plan, with the identity columns of its row.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedTrial {
    /// Identity.
    pub key: TrialKey,
    /// Participant id (`P01`).
    pub participant: String,
    /// `session_index` column (0 for practice).
    pub session_index: u32,
    /// `session_order` column.
    pub session_order: String,
    /// Trial seed.
    pub seed: u64,
}

/// Plan of a protocol: for each participant in index order, the practice
/// block (each condition in the participant's order, `training.practice_trials`
/// trials each), then the test sessions in the participant's order
/// (`trials_per_session` trials each).
pub fn plan(protocol: &Protocol, orders: &[OrderRow]) -> Vec<PlannedTrial> {
    let seed = protocol.seeds.study;
    let mut out = Vec::new();
    for o in orders {
        let order = o.order_string();
        let mut push = |key: TrialKey, session_index: u32| {
            out.push(PlannedTrial {
                key,
                participant: o.participant.clone(),
                session_index,
                session_order: order.clone(),
                seed: key.seed(seed),
            });
        };
        for &c in &o.sessions {
            for t in 1..=protocol.training.practice_trials {
                push(TrialKey::new(o.index, c, Phase::Practice, t), 0);
            }
        }
        for (i, &c) in o.sessions.iter().enumerate() {
            for t in 1..=protocol.trials_per_session {
                push(
                    TrialKey::new(o.index, c, Phase::Test, t),
                    u32::try_from(i + 1).unwrap_or(u32::MAX),
                );
            }
        }
    }
    out
}

/// Relative path (with `/`) of a trial's raw file.
pub fn raw_file_name(planned: &PlannedTrial) -> String {
    format!(
        "{RAW_DIR}/{}_{}_{}_{:03}.npy",
        planned.participant, planned.key.condition, planned.key.phase, planned.key.trial
    )
}

/// `layout` with the trial identity added to its attributes (participant,
/// condition, phase, trial, session_index, seed, started_utc), as
/// [`StudyStore::raw_writer`] writes it.
pub fn raw_layout_for(
    planned: &PlannedTrial,
    started_utc: UtcTime,
    layout: RawLayout,
) -> RawLayout {
    let mut layout = layout;
    let p = planned;
    let attrs = [
        (
            "participant",
            serde_json::Value::from(p.participant.clone()),
        ),
        ("condition", p.key.condition.code().into()),
        ("phase", p.key.phase.as_str().into()),
        ("trial", p.key.trial.into()),
        ("session_index", p.session_index.into()),
        ("seed", format_seed(p.seed).into()),
        ("started_utc", started_utc.to_string().into()),
    ];
    for (k, v) in attrs {
        layout.attrs.insert(k.to_owned(), v);
    }
    layout
}

/// What [`StudyStore::open`] found and repaired.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recovery {
    /// The folder already held a study.
    pub resumed: bool,
    /// Torn journal tail that was cut.
    pub journal_torn: Option<TornTail>,
    /// Torn `trials.csv` tail that was cut.
    pub trials_torn: Option<TornTail>,
    /// Rows kept although their `trial_completed` record was missing.
    pub adopted: Vec<TrialKey>,
    /// Trials started but not finished by an earlier sitting (to be run
    /// again).
    pub interrupted: Vec<TrialKey>,
    /// The previous sitting ended without `session_done` (crash, kill, or
    /// a runner that dropped the store without closing it).
    pub previous_sitting_unclosed: bool,
    /// Completed trials after recovery.
    pub completed: usize,
    /// Trials still to run.
    pub pending: usize,
}

impl Recovery {
    /// True when nothing had to be repaired or adopted.
    pub fn is_clean(&self) -> bool {
        self.journal_torn.is_none()
            && self.trials_torn.is_none()
            && self.adopted.is_empty()
            && self.interrupted.is_empty()
    }
}

impl fmt::Display for Recovery {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.resumed {
            return write!(f, "new study folder, {} trial(s) planned", self.pending);
        }
        write!(
            f,
            "resumed: {} trial(s) complete, {} pending",
            self.completed, self.pending
        )?;
        if self.previous_sitting_unclosed {
            f.write_str("; the previous sitting ended without closing (crash or kill)")?;
        }
        for t in [&self.journal_torn, &self.trials_torn]
            .into_iter()
            .flatten()
        {
            write!(
                f,
                "; cut {} torn byte(s) at line {} of {} ({})",
                t.len,
                t.line,
                t.file.display(),
                t.reason
            )?;
        }
        if !self.adopted.is_empty() {
            let list: Vec<String> = self.adopted.iter().map(ToString::to_string).collect();
            write!(
                f,
                "; adopted row(s) without journal record: {}",
                list.join(", ")
            )?;
        }
        if !self.interrupted.is_empty() {
            let list: Vec<String> = self.interrupted.iter().map(ToString::to_string).collect();
            write!(
                f,
                "; interrupted trial(s) to run again: {}",
                list.join(", ")
            )?;
        }
        Ok(())
    }
}

/// Proof that a trial was begun ([`StudyStore::begin_trial`]); consumed by
/// [`StudyStore::commit_trial`] or [`StudyStore::abort_trial`].
#[derive(Debug)]
pub struct TrialTicket {
    planned: PlannedTrial,
    task: TaskKind,
    started_utc: UtcTime,
    raw_file: Option<String>,
}

impl TrialTicket {
    /// The trial.
    pub fn key(&self) -> TrialKey {
        self.planned.key
    }

    /// Its plan entry.
    pub fn planned(&self) -> &PlannedTrial {
        &self.planned
    }

    /// Start time given to `begin_trial`.
    pub fn started_utc(&self) -> UtcTime {
        self.started_utc
    }

    /// A row with the identity columns filled (participant, session, order,
    /// condition, phase, trial, task, seed, start time, raw file) and every
    /// result empty: `success = false`, metrics NA. The runner fills in the
    /// results.
    pub fn row(&self) -> TrialRow {
        let p = &self.planned;
        TrialRow {
            participant: p.participant.clone(),
            session_index: p.session_index,
            session_order: p.session_order.clone(),
            condition: p.key.condition,
            phase: p.key.phase,
            trial: p.key.trial,
            task: self.task,
            success: false,
            reject_reason: String::new(),
            time_s: None,
            force_mean_pn: None,
            force_mean_n: None,
            disp_err_mean_um: None,
            contact_fraction: None,
            seed: p.seed,
            started_utc: self.started_utc,
            escaped: None,
            time_to_collision_s: None,
            peak_force_pn: None,
            retreat_angle_err_deg: None,
            raw_file: self.raw_file.clone().unwrap_or_default(),
        }
    }
}

/// Where the summaries were written.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryFiles {
    /// `cells_long.csv`.
    pub cells_long: PathBuf,
    /// `cells_wide.csv`.
    pub cells_wide: PathBuf,
    /// The summary written.
    pub summary: Summary,
    /// Torn tail of `trials.csv` ignored while reading, if any.
    pub ignored_tail: Option<TornTail>,
}

/// Regenerates `cells_long.csv` and `cells_wide.csv` of `dir` from its
/// `trials.csv` (read-only on `trials.csv`; a torn tail is ignored and
/// reported). Both files are replaced atomically.
///
/// # Errors
/// Those of [`read_trials`] and [`summarize`]; I/O errors.
pub fn regenerate_summaries(dir: &Path) -> Result<SummaryFiles> {
    let read = read_trials(&dir.join(TRIALS_FILE))?;
    let summary = summarize(&read.rows)?;
    let long = summary::csv_text(&summary.long_header(), &summary.long_records())?;
    let wide = summary::csv_text(&summary.wide_header(), &summary.wide_records())?;
    let cells_long = dir.join(CELLS_LONG_FILE);
    let cells_wide = dir.join(CELLS_WIDE_FILE);
    write_atomic(&cells_long, long.as_bytes())?;
    write_atomic(&cells_wide, wide.as_bytes())?;
    Ok(SummaryFiles {
        cells_long,
        cells_wide,
        summary,
        ignored_tail: read.torn,
    })
}

/// Sittings recorded in a journal.
fn sittings(entries: &[journal::Entry]) -> Vec<Sitting> {
    let mut out: Vec<Sitting> = Vec::new();
    for e in entries {
        match &e.record {
            Record::SessionStarted(s) => out.push(Sitting {
                journal_seq: e.seq,
                started_utc: e.utc,
                done_utc: None,
                software_version: s.software_version.clone(),
                rig: s.rig.clone(),
                calibration: s.calibration.clone(),
                resumed: s.resumed,
            }),
            Record::SessionDone { .. } => {
                if let Some(last) = out.last_mut() {
                    last.done_utc = Some(e.utc);
                }
            }
            _ => {}
        }
    }
    out
}

/// An open study output folder (see the module documentation).
#[derive(Debug)]
pub struct StudyStore {
    dir: PathBuf,
    protocol: Protocol,
    task: TaskKind,
    orders: Vec<OrderRow>,
    plan: Vec<PlannedTrial>,
    plan_index: HashMap<TrialKey, usize>,
    completed: HashMap<TrialKey, u32>,
    open_trial: Option<TrialKey>,
    journal: Journal,
    trials: trials::TrialsWriter,
    recovery: Recovery,
    info: SessionInfo,
    poisoned: Option<String>,
    /// Test hook: fail the journal append of the next commit (simulates a
    /// crash between the row and its record).
    #[cfg(test)]
    fail_completion_record: bool,
}

impl StudyStore {
    /// Opens the output folder `dir` for `protocol`: creates it (with
    /// `session.json`, an empty `trials.csv` with its header, the journal
    /// and `raw/`) or resumes it — repairs torn tails, reconciles
    /// `trials.csv` with the journal (see the module documentation) — and
    /// journals `session_started`.
    ///
    /// # Errors
    /// [`ExportError::Protocol`] for an invalid protocol,
    /// [`ExportError::ProtocolMismatch`] when the folder holds another
    /// protocol, [`ExportError::NotAStudyFolder`],
    /// [`ExportError::HeaderMismatch`], [`ExportError::Inconsistent`],
    /// [`ExportError::Checksum`], [`ExportError::Format`], I/O errors.
    pub fn open(dir: &Path, protocol: &Protocol, meta: &StudyMeta) -> Result<Self> {
        protocol.validate().map_err(|invalid| {
            ExportError::Protocol(ProtocolError::Invalid {
                location: Location {
                    file: format!("<protocol `{}`>", protocol.name),
                    line: None,
                    column: None,
                },
                invalid,
            })
        })?;
        let (protocol_toml, protocol_sha256) = session::protocol_identity(protocol)?;
        let table = protocol.assignment()?;
        let orders = session::order_rows(&table);
        let plan = plan(protocol, &orders);
        let plan_index: HashMap<TrialKey, usize> =
            plan.iter().enumerate().map(|(i, p)| (p.key, i)).collect();
        let session_path = dir.join(SESSION_FILE);
        let trials_path = dir.join(TRIALS_FILE);
        let journal_path = dir.join(JOURNAL_FILE);
        let recovery_dir = dir.join(RECOVERY_DIR);
        let now = UtcTime::now();

        let resumed = session_path.exists();
        let mut info = if resumed {
            let info = read_session(&session_path)?;
            if info.format != session::FORMAT {
                return Err(ExportError::NotAStudyFolder {
                    path: session_path,
                    reason: format!("format `{}` is not `{}`", info.format, session::FORMAT),
                });
            }
            // Equal hashes, or an equal protocol whose canonical TOML text
            // changed with a newer `toml` crate.
            if info.protocol_sha256 != protocol_sha256 && info.protocol != *protocol {
                return Err(ExportError::ProtocolMismatch {
                    path: session_path,
                    expected_name: protocol.name.clone(),
                    expected_sha256: protocol_sha256,
                    found_name: info.protocol.name.clone(),
                    found_sha256: info.protocol_sha256.clone(),
                });
            }
            info
        } else {
            for p in [&trials_path, &journal_path] {
                if p.exists() {
                    return Err(ExportError::NotAStudyFolder {
                        path: dir.to_path_buf(),
                        reason: format!(
                            "`{}` exists but `{SESSION_FILE}` does not: not a kilotouch study \
                             folder (or its session.json was removed)",
                            p.file_name()
                                .map(|n| n.to_string_lossy())
                                .unwrap_or_default()
                        ),
                    });
                }
            }
            create_dir_durable(dir)?;
            let info = SessionInfo {
                format: session::FORMAT.into(),
                software: session::Software {
                    name: meta.software_name.clone(),
                    version: meta.software_version.clone(),
                },
                protocol: protocol.clone(),
                protocol_toml,
                protocol_sha256: protocol_sha256.clone(),
                seeds: session::SeedInfo {
                    study: protocol.seeds.study,
                    trial_derivation: session::TRIAL_DERIVATION.into(),
                },
                order_table: orders.clone(),
                order_balance: table.summary.clone(),
                rig: meta.rig.clone(),
                calibration: meta.calibration.clone(),
                created_utc: now,
                updated_utc: now,
                sittings: Vec::new(),
                progress: Progress {
                    planned: plan.len() as u64,
                    completed: 0,
                },
            };
            write_session(&session_path, &info)?;
            info
        };
        // Read and check everything before modifying anything: an error
        // leaves the folder exactly as it was.
        let journal_bytes = journal::read_bytes(&journal_path)?;
        let mut jread = journal::parse_journal(&journal_path, &journal_bytes)?;
        for (e, line) in jread.entries.iter().zip(&jread.lines) {
            if let Record::SessionStarted(s) = &e.record
                && s.protocol_sha256 != info.protocol_sha256
            {
                return Err(ExportError::Inconsistent {
                    path: journal_path,
                    message: format!(
                        "line {line}: sitting with protocol sha256 {} but session.json records {}",
                        s.protocol_sha256, info.protocol_sha256
                    ),
                });
            }
        }
        let header = trials::header_line();
        let trials_bytes = if trials_path.exists() {
            Some(fs::read(&trials_path).map_err(io_err(&trials_path, "read"))?)
        } else {
            None
        };
        // A file holding a strict prefix of the header: crash while it was
        // being created (there cannot be any row); written again below.
        let rewrite_header = trials_bytes
            .as_ref()
            .is_some_and(|b| b.len() < header.len() && header.as_bytes().starts_with(b));
        let mut tread = match &trials_bytes {
            Some(b) if !rewrite_header => Some(trials::parse_trials(
                &trials_path,
                b,
                ReadOptions::default(),
            )?),
            _ => None,
        };
        let rows = tread
            .as_ref()
            .map(|r| (r.rows.clone(), r.crcs.clone(), r.lines.clone()))
            .unwrap_or_default();

        // Reconcile.
        let by_id: HashMap<&str, &OrderRow> =
            orders.iter().map(|o| (o.participant.as_str(), o)).collect();
        let mut journal_done: HashMap<TrialKey, (u32, u64)> = HashMap::new();
        let mut started: HashMap<TrialKey, u64> = HashMap::new();
        for (e, &line) in jread.entries.iter().zip(&jread.lines) {
            match &e.record {
                Record::TrialStarted { trial, .. } => {
                    started.insert(*trial, line);
                }
                Record::TrialAborted { trial, .. } => {
                    started.remove(trial);
                }
                Record::TrialCompleted {
                    trial, row_crc32, ..
                } => {
                    started.remove(trial);
                    let crc = checksum::parse_crc32_hex(row_crc32).ok_or_else(|| {
                        ExportError::Inconsistent {
                            path: journal_path.clone(),
                            message: format!("line {line}: malformed row_crc32 `{row_crc32}`"),
                        }
                    })?;
                    if journal_done.insert(*trial, (crc, line)).is_some() {
                        return Err(ExportError::Inconsistent {
                            path: journal_path.clone(),
                            message: format!("line {line}: trial {trial} completed twice"),
                        });
                    }
                }
                _ => {}
            }
        }
        let mut completed: HashMap<TrialKey, u32> = HashMap::new();
        let mut adopted = Vec::new();
        let (rows, crcs, lines) = rows;
        for ((row, &crc), &line) in rows.iter().zip(&crcs).zip(&lines) {
            let incon = |message: String| ExportError::Inconsistent {
                path: trials_path.clone(),
                message: format!("line {line}: {message}"),
            };
            let order = by_id.get(row.participant.as_str()).ok_or_else(|| {
                incon(format!(
                    "participant `{}` is not in the protocol's order table",
                    row.participant
                ))
            })?;
            let key = row.key(order.index);
            let planned = plan_index
                .get(&key)
                .map(|&i| &plan[i])
                .ok_or_else(|| incon(format!("trial {key} is not in the protocol's plan")))?;
            let checks: [(&str, String, String); 4] = [
                ("seed", format_seed(planned.seed), format_seed(row.seed)),
                (
                    "session_index",
                    planned.session_index.to_string(),
                    row.session_index.to_string(),
                ),
                (
                    "session_order",
                    planned.session_order.clone(),
                    row.session_order.clone(),
                ),
                (
                    "task",
                    TaskKind::of(&protocol.task).as_str().to_owned(),
                    row.task.as_str().to_owned(),
                ),
            ];
            for (column, expected, found) in checks {
                if expected != found {
                    return Err(incon(format!(
                        "trial {key}: column `{column}` is `{found}`, the protocol gives \
                         `{expected}` (row of another study or seed?)"
                    )));
                }
            }
            match journal_done.remove(&key) {
                Some((jcrc, jline)) if jcrc != crc => {
                    return Err(incon(format!(
                        "trial {key}: row_crc32 {crc:08x} differs from the journal's {jcrc:08x} \
                         ({JOURNAL_FILE} line {jline}): the row was changed after it was written"
                    )));
                }
                Some(_) => {}
                None => adopted.push(key),
            }
            started.remove(&key);
            completed.insert(key, crc);
        }
        if let Some((key, (crc, line))) = journal_done.iter().min_by_key(|(_, (_, l))| *l) {
            return Err(ExportError::Inconsistent {
                path: trials_path,
                message: format!(
                    "{JOURNAL_FILE} line {line} records trial {key} as completed (row_crc32 \
                     {crc:08x}) but {TRIALS_FILE} has no such row: rows were lost or removed; \
                     nothing was changed"
                ),
            });
        }
        let mut interrupted: Vec<(u64, TrialKey)> =
            started.into_iter().map(|(k, l)| (l, k)).collect();
        interrupted.sort();
        let interrupted: Vec<TrialKey> = interrupted.into_iter().map(|(_, k)| k).collect();

        // Checks passed: repair (cut torn tails, keeping copies) and open
        // for appending.
        create_dir_durable(&dir.join(RAW_DIR))?;
        let mut trials_torn = None;
        if let (Some(read), Some(bytes)) = (tread.as_mut(), &trials_bytes)
            && let Some(torn) = read.torn.as_mut()
        {
            let tail = &bytes[torn.offset as usize..];
            torn.saved_to = Some(cut_torn_tail(&trials_path, torn, tail, &recovery_dir)?);
            trials_torn = Some(torn.clone());
        }
        let trials_file = if rewrite_header {
            let mut f = fs::OpenOptions::new()
                .write(true)
                .open(&trials_path)
                .map_err(io_err(&trials_path, "open"))?;
            f.set_len(0).map_err(io_err(&trials_path, "truncate"))?;
            std::io::Write::write_all(&mut f, header.as_bytes())
                .map_err(io_err(&trials_path, "write"))?;
            f.sync_all().map_err(io_err(&trials_path, "fsync"))?;
            drop(f);
            open_append(&trials_path)?
        } else if tread.is_some() {
            open_append(&trials_path)?
        } else {
            create_trials_file(&trials_path)?
        };
        let mut journal =
            Journal::resume(&journal_path, &mut jread, &journal_bytes, &recovery_dir)?;

        let past = sittings(&jread.entries);
        let previous_sitting_unclosed = past.last().is_some_and(|s| s.done_utc.is_none());
        let recovery = Recovery {
            resumed,
            journal_torn: jread.torn.clone(),
            trials_torn,
            adopted,
            interrupted,
            previous_sitting_unclosed,
            completed: completed.len(),
            pending: plan.len() - completed.len(),
        };

        journal.append(Record::SessionStarted(SessionStart {
            protocol_name: protocol.name.clone(),
            protocol_sha256: info.protocol_sha256.clone(),
            software_version: meta.software_version.clone(),
            study_seed: protocol.seeds.study,
            rig: meta.rig.clone(),
            calibration: meta.calibration.clone(),
            orders: orders.clone(),
            resumed,
        }))?;
        if !recovery.is_clean() {
            journal.append(Record::Recovered(RecoveryRecord {
                journal_torn_bytes: recovery.journal_torn.as_ref().map_or(0, |t| t.len),
                trials_torn_bytes: recovery.trials_torn.as_ref().map_or(0, |t| t.len),
                adopted: recovery.adopted.clone(),
                interrupted: recovery.interrupted.clone(),
            }))?;
            for key in &recovery.adopted {
                journal.append(Record::TrialCompleted {
                    trial: *key,
                    row_crc32: checksum::crc32_hex(completed[key]),
                    adopted: true,
                })?;
            }
            for key in &recovery.interrupted {
                journal.append(Record::TrialAborted {
                    trial: *key,
                    reason: "interrupted: the sitting ended during the trial (crash or kill); \
                             it will be run again with the same seeds"
                        .into(),
                })?;
            }
        }

        let trials_writer = trials::TrialsWriter::from_file(trials_path, trials_file);
        let mut store = Self {
            dir: dir.to_path_buf(),
            protocol: protocol.clone(),
            task: TaskKind::of(&protocol.task),
            orders,
            plan,
            plan_index,
            completed,
            open_trial: None,
            journal,
            trials: trials_writer,
            recovery,
            info: {
                info.updated_utc = now;
                info
            },
            poisoned: None,
            #[cfg(test)]
            fail_completion_record: false,
        };
        store.write_session_info()?;
        Ok(store)
    }

    /// Resumes an existing folder with the protocol recorded in its
    /// `session.json` (see [`StudyStore::open`]).
    ///
    /// # Errors
    /// [`ExportError::NotAStudyFolder`] without `session.json`; those of
    /// [`read_session`] and [`StudyStore::open`].
    pub fn open_existing(dir: &Path, meta: &StudyMeta) -> Result<Self> {
        let path = dir.join(SESSION_FILE);
        if !path.is_file() {
            return Err(ExportError::NotAStudyFolder {
                path: dir.to_path_buf(),
                reason: format!("no `{SESSION_FILE}`"),
            });
        }
        let info = read_session(&path)?;
        Self::open(dir, &info.protocol, meta)
    }

    fn write_session_info(&mut self) -> Result<()> {
        let jread = journal::read_journal(self.journal.path())?;
        self.info.sittings = sittings(&jread.entries);
        self.info.updated_utc = UtcTime::now();
        self.info.progress = Progress {
            planned: self.plan.len() as u64,
            completed: self.completed.len() as u64,
        };
        write_session(&self.dir.join(SESSION_FILE), &self.info)
    }

    fn check_usable(&self, key: TrialKey) -> Result<()> {
        match &self.poisoned {
            Some(why) => Err(ExportError::Trial {
                key,
                message: format!(
                    "the store is unusable after a failed write ({why}); reopen the folder to \
                     repair it"
                ),
            }),
            None => Ok(()),
        }
    }

    fn poison<T>(&mut self, r: Result<T>) -> Result<T> {
        if let Err(e) = &r {
            self.poisoned = Some(e.to_string());
        }
        r
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The protocol.
    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    /// Participant → order table.
    pub fn orders(&self) -> &[OrderRow] {
        &self.orders
    }

    /// Content of `session.json`.
    pub fn info(&self) -> &SessionInfo {
        &self.info
    }

    /// What opening found and repaired.
    pub fn recovery(&self) -> &Recovery {
        &self.recovery
    }

    /// The complete plan, in run order ([`plan`]).
    pub fn plan(&self) -> &[PlannedTrial] {
        &self.plan
    }

    /// Plan entry of a trial.
    pub fn planned(&self, key: &TrialKey) -> Option<&PlannedTrial> {
        self.plan_index.get(key).map(|&i| &self.plan[i])
    }

    /// Whether a trial's row is in `trials.csv`.
    pub fn is_completed(&self, key: &TrialKey) -> bool {
        self.completed.contains_key(key)
    }

    /// Number of completed trials.
    pub fn completed_count(&self) -> usize {
        self.completed.len()
    }

    /// Trials still to run, in plan order.
    pub fn pending(&self) -> impl Iterator<Item = &PlannedTrial> {
        self.plan
            .iter()
            .filter(|p| !self.completed.contains_key(&p.key))
    }

    /// The first unfinished trial in plan order (where a resumed session
    /// continues), or `None` when the study is complete.
    pub fn next_pending(&self) -> Option<&PlannedTrial> {
        self.pending().next()
    }

    /// Path of a file of the folder given relative to it.
    pub fn path_of(&self, relative: &str) -> PathBuf {
        self.dir.join(relative)
    }

    /// Starts a trial: journals `trial_started` (fsync) and returns its
    /// ticket. `started_utc` is written to the row (pass
    /// [`UtcTime::now`] in a real session).
    ///
    /// # Errors
    /// [`ExportError::Trial`] when the trial is not in the plan, already
    /// completed, or another trial is open; I/O errors.
    pub fn begin_trial(&mut self, key: TrialKey, started_utc: UtcTime) -> Result<TrialTicket> {
        self.check_usable(key)?;
        if let Some(open) = self.open_trial {
            return Err(ExportError::Trial {
                key,
                message: format!("trial {open} is still open: commit or abort it first"),
            });
        }
        let planned = self
            .planned(&key)
            .cloned()
            .ok_or_else(|| ExportError::Trial {
                key,
                message: "not in the protocol's plan".into(),
            })?;
        if self.is_completed(&key) {
            return Err(ExportError::Trial {
                key,
                message: "already completed (its row is in trials.csv)".into(),
            });
        }
        let r = self.journal.append(Record::TrialStarted {
            trial: key,
            seed: format_seed(planned.seed),
            started_utc,
        });
        self.poison(r)?;
        self.open_trial = Some(key);
        Ok(TrialTicket {
            planned,
            task: self.task,
            started_utc,
            raw_file: None,
        })
    }

    /// Creates the raw-signal writer of the ticket's trial
    /// (`raw/<P>_<C>_<phase>_<trial>.npy`, truncating a partial file left by
    /// an interrupted run) and records its path in the ticket, so
    /// [`TrialTicket::row`] fills `raw_file`. The sidecar's `attrs` get the
    /// trial identity. Call [`NpyWriter::finish`] before
    /// [`StudyStore::commit_trial`].
    ///
    /// # Errors
    /// Those of [`NpyWriter::create`].
    pub fn raw_writer(&self, ticket: &mut TrialTicket, layout: RawLayout) -> Result<NpyWriter> {
        let rel = raw_file_name(&ticket.planned);
        let layout = raw_layout_for(&ticket.planned, ticket.started_utc, layout);
        let w = NpyWriter::create(&self.dir.join(&rel), layout)?;
        ticket.raw_file = Some(rel);
        Ok(w)
    }

    /// Records in the ticket a raw file that was written before the trial
    /// was begun in the store (by a worker thread that ran the trial, with
    /// [`raw_layout_for`] and the same start time), so [`TrialTicket::row`]
    /// fills `raw_file`. The file must be finished.
    ///
    /// # Errors
    /// [`ExportError::Trial`] when the file or its sidecar does not exist.
    pub fn attach_raw(&self, ticket: &mut TrialTicket) -> Result<()> {
        let rel = raw_file_name(&ticket.planned);
        let path = self.dir.join(&rel);
        if !path.is_file() || !crate::rawsig::sidecar_path(&path).is_file() {
            return Err(ExportError::Trial {
                key: ticket.key(),
                message: format!("raw file `{rel}` or its sidecar does not exist"),
            });
        }
        ticket.raw_file = Some(rel);
        Ok(())
    }

    /// Commits a finished trial: checks the row against its ticket and
    /// the validity rules ([`TrialRow::validate`]), appends it to
    /// `trials.csv` (one write + fdatasync), then journals
    /// `trial_completed` (fsync). When this returns `Ok` the row is on
    /// stable storage and the next trial may begin. Returns the row's CRC.
    ///
    /// # Errors
    /// [`ExportError::Trial`] when the row's identity columns differ from
    /// the ticket or the raw file it names does not exist;
    /// [`ExportError::InvalidRow`]. Nothing is written then and the trial
    /// stays open ([`StudyStore::abort_open_trial`]). I/O errors, after
    /// which the store refuses further writes until reopened (reopening
    /// repairs a torn row).
    pub fn commit_trial(&mut self, ticket: TrialTicket, row: &TrialRow) -> Result<u32> {
        let key = ticket.key();
        self.check_usable(key)?;
        let expected = ticket.row();
        let identity: [(&str, String, String); 10] = [
            (
                "participant",
                expected.participant.clone(),
                row.participant.clone(),
            ),
            (
                "session_index",
                expected.session_index.to_string(),
                row.session_index.to_string(),
            ),
            (
                "session_order",
                expected.session_order.clone(),
                row.session_order.clone(),
            ),
            (
                "condition",
                expected.condition.to_string(),
                row.condition.to_string(),
            ),
            ("phase", expected.phase.to_string(), row.phase.to_string()),
            ("trial", expected.trial.to_string(), row.trial.to_string()),
            (
                "task",
                expected.task.as_str().into(),
                row.task.as_str().into(),
            ),
            ("seed", format_seed(expected.seed), format_seed(row.seed)),
            (
                "started_utc",
                expected.started_utc.to_string(),
                row.started_utc.to_string(),
            ),
            ("raw_file", expected.raw_file.clone(), row.raw_file.clone()),
        ];
        for (column, e, f) in identity {
            if e != f {
                return Err(ExportError::Trial {
                    key,
                    message: format!(
                        "column `{column}` is `{f}` but the ticket gives `{e}` (build rows with \
                         TrialTicket::row)"
                    ),
                });
            }
        }
        row.validate(key)?;
        if !row.raw_file.is_empty() && !self.dir.join(&row.raw_file).is_file() {
            return Err(ExportError::Trial {
                key,
                message: format!(
                    "raw file `{}` does not exist (finish the NpyWriter before committing)",
                    row.raw_file
                ),
            });
        }
        let (line, crc) = row.encode()?;
        let r = self.trials.append_line(&line);
        self.poison(r)?;
        #[cfg(test)]
        if self.fail_completion_record {
            let r = Err(ExportError::Trial {
                key,
                message: "injected failure before trial_completed".into(),
            });
            return self.poison(r);
        }
        let r = self.journal.append(Record::TrialCompleted {
            trial: key,
            row_crc32: checksum::crc32_hex(crc),
            adopted: false,
        });
        self.poison(r)?;
        self.completed.insert(key, crc);
        self.open_trial = None;
        Ok(crc)
    }

    /// Abandons a begun trial: journals `trial_aborted`; the trial stays
    /// pending and is run again later with the same seeds.
    ///
    /// # Errors
    /// I/O errors.
    pub fn abort_trial(&mut self, ticket: TrialTicket, reason: &str) -> Result<()> {
        let key = ticket.key();
        self.check_usable(key)?;
        let r = self.journal.append(Record::TrialAborted {
            trial: key,
            reason: reason.to_owned(),
        });
        self.poison(r)?;
        self.open_trial = None;
        Ok(())
    }

    /// Aborts the open trial without its ticket (e.g. after
    /// [`StudyStore::commit_trial`] refused a row, which leaves the trial
    /// open). Returns the trial aborted, if one was open.
    ///
    /// # Errors
    /// I/O errors.
    pub fn abort_open_trial(&mut self, reason: &str) -> Result<Option<TrialKey>> {
        let Some(key) = self.open_trial else {
            return Ok(None);
        };
        self.check_usable(key)?;
        let r = self.journal.append(Record::TrialAborted {
            trial: key,
            reason: reason.to_owned(),
        });
        self.poison(r)?;
        self.open_trial = None;
        Ok(Some(key))
    }

    /// The trial begun and not yet committed or aborted.
    pub fn open_trial(&self) -> Option<TrialKey> {
        self.open_trial
    }

    /// Journals a free-text note.
    ///
    /// # Errors
    /// I/O errors.
    pub fn note(&mut self, text: &str) -> Result<()> {
        self.journal
            .append(Record::Note {
                text: text.to_owned(),
            })
            .map(|_| ())
    }

    /// Journals a pause.
    ///
    /// # Errors
    /// I/O errors.
    pub fn pause(&mut self, reason: &str) -> Result<()> {
        self.journal
            .append(Record::Paused {
                reason: reason.to_owned(),
            })
            .map(|_| ())
    }

    /// Journals the end of a pause.
    ///
    /// # Errors
    /// I/O errors.
    pub fn resume(&mut self) -> Result<()> {
        self.journal.append(Record::Resumed).map(|_| ())
    }

    /// Regenerates `cells_long.csv`, `cells_wide.csv` (from `trials.csv`)
    /// and `session.json` (sittings and progress from the journal).
    ///
    /// # Errors
    /// Those of [`regenerate_summaries`]; I/O errors.
    pub fn regenerate_summaries(&mut self) -> Result<SummaryFiles> {
        let files = regenerate_summaries(&self.dir)?;
        self.write_session_info()?;
        Ok(files)
    }

    /// Closes the sitting: regenerates the summaries and journals
    /// `session_done`. (Dropping the store without `close` is equivalent to
    /// a crash between trials: nothing is lost; the next open reports an
    /// unclosed sitting.)
    ///
    /// # Errors
    /// [`ExportError::Trial`] when a trial is still open; those of
    /// [`StudyStore::regenerate_summaries`].
    pub fn close(mut self) -> Result<SummaryFiles> {
        if let Some(key) = self.open_trial {
            return Err(ExportError::Trial {
                key,
                message: "still open: commit or abort it before closing".into(),
            });
        }
        let files = regenerate_summaries(&self.dir)?;
        self.journal.append(Record::SessionDone {
            completed: self.completed.len() as u64,
            planned: self.plan.len() as u64,
        })?;
        self.write_session_info()?;
        Ok(files)
    }
}

fn write_session(path: &Path, info: &SessionInfo) -> Result<()> {
    let mut json = serde_json::to_vec_pretty(info).map_err(|source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    json.push(b'\n');
    write_atomic(path, &json)
}

/// Creates `trials.csv` with its header, durably.
fn create_trials_file(path: &Path) -> Result<fs::File> {
    let mut f = fs::OpenOptions::new()
        .create_new(true)
        .append(true)
        .open(path)
        .map_err(io_err(path, "create"))?;
    append_durable(&mut f, path, trials::header_line().as_bytes())?;
    f.sync_all().map_err(io_err(path, "fsync"))?;
    sync_dir(&parent_of(path))?;
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seeds::Phase;

    fn protocol() -> Protocol {
        Protocol::from_toml_str(
            "name = \"order\"\nparticipants = 1\nconditions = [\"V\", \"D\"]\n\
             trials_per_session = 2\n[training]\npractice_trials = 0\n[task.circling]\n",
            "<test>",
        )
        .unwrap()
    }

    fn commit(store: &mut StudyStore, key: TrialKey) -> Result<u32> {
        let ticket = store.begin_trial(key, UtcTime::from_unix_millis(0))?;
        let mut row = ticket.row();
        row.success = true;
        row.time_s = Some(1.5);
        store.commit_trial(ticket, &row)
    }

    /// The row is on disk before its journal record: a failure (crash) after
    /// the row leaves a row without record, which the next open adopts —
    /// never a record without row.
    #[test]
    fn commit_writes_the_row_before_the_journal_record() {
        let dir = std::env::temp_dir().join(format!(
            "kilotouch-commit-order-{}-{}",
            std::process::id(),
            UtcTime::now().unix_millis()
        ));
        let p = protocol();
        let meta = StudyMeta::new("test");
        let mut store = StudyStore::open(&dir, &p, &meta).unwrap();
        let k1 = TrialKey::new(0, store.plan()[0].key.condition, Phase::Test, 1);
        commit(&mut store, k1).unwrap();
        let k2 = store.next_pending().unwrap().key;
        store.fail_completion_record = true;
        assert!(commit(&mut store, k2).is_err());
        // Poisoned: no further writes until reopened.
        store.fail_completion_record = false;
        let k3 = store.plan()[2].key;
        let e = store
            .begin_trial(k3, UtcTime::from_unix_millis(0))
            .unwrap_err();
        assert!(e.to_string().contains("reopen"), "{e}");
        let rows = read_trials(&dir.join(TRIALS_FILE)).unwrap().rows;
        assert_eq!(rows.len(), 2, "the row reached trials.csv");
        let j = journal::read_journal(&dir.join(JOURNAL_FILE)).unwrap();
        let completed = j
            .entries
            .iter()
            .filter(|e| matches!(e.record, Record::TrialCompleted { .. }))
            .count();
        assert_eq!(completed, 1, "its record did not");
        drop(store);
        let store = StudyStore::open(&dir, &p, &meta).unwrap();
        assert_eq!(store.recovery().adopted, vec![k2]);
        assert_eq!(store.completed_count(), 2);
        drop(store);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
