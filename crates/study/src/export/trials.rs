//! `trials.csv`: one row per trial, long format, append-only, one CRC-32 per
//! row.
//!
//! Layout ([`TRIALS_COLUMNS`]): comma-separated, `\n` line ends, UTF-8, a
//! header line, RFC 4180 quoting where needed (text cells cannot contain
//! line breaks, so one row is exactly one line). Missing values (a metric
//! not defined for the task or the trial) are **empty cells** (NA);
//! booleans are `1` / `0`; numbers are written in the shortest form that
//! reads back to the same `f64` (Rust `Display`, never exponent notation).
//! The last column `row_crc32` is the CRC-32 of the line up to, not
//! including, its last comma.

use std::collections::HashMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::checksum::{crc32, crc32_hex, parse_crc32_hex};
use crate::protocol::{Condition, Task};
use crate::seeds::{Phase, TrialKey, format_seed, parse_seed};
use crate::storage::error::{ExportError, Position, Result, io_err};
use crate::storage::fsutil::{
    Checked, Line, TornTail, append_durable, no_follow, open_append, parent_of, split_lines,
    sync_dir, valid_prefix,
};
use crate::storage::utc::UtcTime;

/// File name of the trial table.
pub const TRIALS_FILE: &str = "trials.csv";

/// Columns of `trials.csv`, in order.
pub const TRIALS_COLUMNS: [&str; 22] = [
    "participant",
    "session_index",
    "session_order",
    "condition",
    "phase",
    "trial",
    "task",
    "success",
    "reject_reason",
    "time_s",
    "force_mean_pn",
    "force_mean_n",
    "disp_err_mean_um",
    "contact_fraction",
    "seed",
    "started_utc",
    "escaped",
    "time_to_collision_s",
    "peak_force_pn",
    "retreat_angle_err_deg",
    "raw_file",
    "row_crc32",
];

/// The columns a trial's ticket fills when the trial begins (the row's
/// identity, as opposed to its results), in [`TRIALS_COLUMNS`] order.
pub(crate) const IDENTITY_COLUMNS: [&str; 10] = [
    "participant",
    "session_index",
    "session_order",
    "condition",
    "phase",
    "trial",
    "task",
    "seed",
    "started_utc",
    "raw_file",
];

/// The first of `columns` (names of [`TRIALS_COLUMNS`]) whose cell differs
/// between two rows, as `(column, expected cell, found cell)` with the cells
/// as `trials.csv` writes them ([`TrialRow::cells`]).
pub(crate) fn first_difference<'c>(
    expected: &TrialRow,
    found: &TrialRow,
    columns: &[&'c str],
) -> Option<(&'c str, String, String)> {
    let (e, f) = (expected.cells(), found.cells());
    columns.iter().find_map(|&column| {
        let i = TRIALS_COLUMNS.iter().position(|&c| c == column)?;
        (e[i] != f[i]).then(|| (column, e[i].clone(), f[i].clone()))
    })
}

/// The header line (with `\n`).
pub fn header_line() -> String {
    let mut s = TRIALS_COLUMNS.join(",");
    s.push('\n');
    s
}

/// Task of a trial (`task` column).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskKind {
    /// Circling (§4.3).
    Circling,
    /// Blind navigation (§4.2).
    BlindNavigation,
}

impl TaskKind {
    /// `circling` or `blind_navigation`.
    pub fn as_str(self) -> &'static str {
        match self {
            TaskKind::Circling => "circling",
            TaskKind::BlindNavigation => "blind_navigation",
        }
    }

    /// The kind of a protocol task.
    pub fn of(task: &Task) -> Self {
        match task {
            Task::Circling(_) => TaskKind::Circling,
            Task::BlindNavigation(_) => TaskKind::BlindNavigation,
        }
    }
}

impl FromStr for TaskKind {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "circling" => Ok(TaskKind::Circling),
            "blind_navigation" => Ok(TaskKind::BlindNavigation),
            o => Err(format!(
                "unknown task `{o}` (expected `circling` or `blind_navigation`)"
            )),
        }
    }
}

/// Numeric per-trial metrics (the averaged columns of the summaries).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Metric {
    /// `time_s`: manipulation time of the trial, s.
    TimeS,
    /// `force_mean_pn`: mean magnitude of the optical force on the bead, pN.
    ForceMeanPn,
    /// `force_mean_n`: mean magnitude of the force rendered at the hand, N.
    ForceMeanN,
    /// `disp_err_mean_um`: mean displacement error from the task's
    /// reference trajectory (defined by the task), µm.
    DispErrMeanUm,
    /// `contact_fraction`: fraction of the trajectory in contact, 0–1.
    ContactFraction,
    /// `time_to_collision_s` (blind): time from start to first contact, s.
    TimeToCollisionS,
    /// `peak_force_pn` (blind): peak optical force at the collision, pN.
    PeakForcePn,
    /// `retreat_angle_err_deg` (blind): angle between retreat direction and
    /// the surface normal at contact, degrees.
    RetreatAngleErrDeg,
}

impl Metric {
    /// All metrics in column order.
    pub const ALL: [Metric; 8] = [
        Metric::TimeS,
        Metric::ForceMeanPn,
        Metric::ForceMeanN,
        Metric::DispErrMeanUm,
        Metric::ContactFraction,
        Metric::TimeToCollisionS,
        Metric::PeakForcePn,
        Metric::RetreatAngleErrDeg,
    ];

    /// Column name.
    pub fn column(self) -> &'static str {
        match self {
            Metric::TimeS => "time_s",
            Metric::ForceMeanPn => "force_mean_pn",
            Metric::ForceMeanN => "force_mean_n",
            Metric::DispErrMeanUm => "disp_err_mean_um",
            Metric::ContactFraction => "contact_fraction",
            Metric::TimeToCollisionS => "time_to_collision_s",
            Metric::PeakForcePn => "peak_force_pn",
            Metric::RetreatAngleErrDeg => "retreat_angle_err_deg",
        }
    }

    /// Unit.
    pub fn unit(self) -> &'static str {
        match self {
            Metric::TimeS | Metric::TimeToCollisionS => "s",
            Metric::ForceMeanPn | Metric::PeakForcePn => "pN",
            Metric::ForceMeanN => "N",
            Metric::DispErrMeanUm => "µm",
            Metric::ContactFraction => "1",
            Metric::RetreatAngleErrDeg => "deg",
        }
    }

    /// Value of this metric in `row`.
    pub fn get(self, row: &TrialRow) -> Option<f64> {
        match self {
            Metric::TimeS => row.time_s,
            Metric::ForceMeanPn => row.force_mean_pn,
            Metric::ForceMeanN => row.force_mean_n,
            Metric::DispErrMeanUm => row.disp_err_mean_um,
            Metric::ContactFraction => row.contact_fraction,
            Metric::TimeToCollisionS => row.time_to_collision_s,
            Metric::PeakForcePn => row.peak_force_pn,
            Metric::RetreatAngleErrDeg => row.retreat_angle_err_deg,
        }
    }

    /// Metric by column name.
    pub fn from_column(name: &str) -> Option<Metric> {
        Metric::ALL.into_iter().find(|m| m.column() == name)
    }
}

/// One row of `trials.csv`. `None` metrics are written as empty cells (NA).
#[derive(Debug, Clone, PartialEq)]
pub struct TrialRow {
    /// Participant id, `P01`, ….
    pub participant: String,
    /// 1-based position of the condition's session in the participant's
    /// order; 0 for practice trials (training block).
    pub session_index: u32,
    /// The participant's condition order, e.g. `VDP`.
    pub session_order: String,
    /// Condition.
    pub condition: Condition,
    /// `practice` or `test`.
    pub phase: Phase,
    /// 1-based trial number within (participant, condition, phase).
    pub trial: u32,
    /// Task.
    pub task: TaskKind,
    /// Whether the trial was successful (not rejected), `1`/`0`.
    pub success: bool,
    /// Why the trial was rejected (empty when successful): `escaped`,
    /// `low_contact`, `timeout`, `no_collision`, `retreat_angle`, or free
    /// text.
    pub reject_reason: String,
    /// See [`Metric::TimeS`].
    pub time_s: Option<f64>,
    /// See [`Metric::ForceMeanPn`].
    pub force_mean_pn: Option<f64>,
    /// See [`Metric::ForceMeanN`].
    pub force_mean_n: Option<f64>,
    /// See [`Metric::DispErrMeanUm`].
    pub disp_err_mean_um: Option<f64>,
    /// See [`Metric::ContactFraction`].
    pub contact_fraction: Option<f64>,
    /// Trial seed ([`TrialKey::seed`]).
    pub seed: u64,
    /// Start of the trial.
    pub started_utc: UtcTime,
    /// Circling: whether the bead escaped the trap, `1`/`0`.
    pub escaped: Option<bool>,
    /// See [`Metric::TimeToCollisionS`].
    pub time_to_collision_s: Option<f64>,
    /// See [`Metric::PeakForcePn`].
    pub peak_force_pn: Option<f64>,
    /// See [`Metric::RetreatAngleErrDeg`].
    pub retreat_angle_err_deg: Option<f64>,
    /// Raw-signal file relative to the output folder (`/` separators), or
    /// empty.
    pub raw_file: String,
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

fn fmt_bool(b: bool) -> &'static str {
    if b { "1" } else { "0" }
}

impl TrialRow {
    /// Identity of the row, given the participant's 0-based index.
    pub fn key(&self, participant_index: u32) -> TrialKey {
        TrialKey::new(participant_index, self.condition, self.phase, self.trial)
    }

    /// Checks the values that cannot be written faithfully: non-finite
    /// metrics, line breaks or control characters in text cells, success
    /// with a reject reason or failure without one, practice rows with a
    /// session index.
    ///
    /// # Errors
    /// [`ExportError::InvalidRow`] naming the column.
    pub fn validate(&self, key: TrialKey) -> Result<()> {
        let bad = |column: &'static str, message: String| ExportError::InvalidRow {
            key,
            column,
            message,
        };
        for m in Metric::ALL {
            if let Some(v) = m.get(self)
                && !v.is_finite()
            {
                return Err(bad(
                    m.column(),
                    format!("non-finite value {v}; use None (NA) for a metric that is not defined"),
                ));
            }
        }
        for (column, text) in [
            ("participant", &self.participant),
            ("session_order", &self.session_order),
            ("reject_reason", &self.reject_reason),
            ("raw_file", &self.raw_file),
        ] {
            if text.chars().any(char::is_control) {
                return Err(bad(
                    column,
                    "contains a line break or control character".into(),
                ));
            }
        }
        if self.participant.is_empty() {
            return Err(bad("participant", "must not be empty".into()));
        }
        if self.success && !self.reject_reason.is_empty() {
            return Err(bad(
                "reject_reason",
                format!(
                    "a successful trial has no reject reason, got `{}`",
                    self.reject_reason
                ),
            ));
        }
        if !self.success && self.reject_reason.trim().is_empty() {
            return Err(bad(
                "reject_reason",
                "a rejected trial needs a reason (e.g. `escaped`, `low_contact`, `timeout`)".into(),
            ));
        }
        if self.trial == 0 {
            return Err(bad("trial", "trial numbers start at 1".into()));
        }
        if (self.phase == Phase::Practice) != (self.session_index == 0) {
            return Err(bad(
                "session_index",
                "must be 0 for practice trials and ≥ 1 for test trials".into(),
            ));
        }
        if self.raw_file.contains('\\') || self.raw_file.starts_with('/') {
            return Err(bad(
                "raw_file",
                "must be a relative path with `/` separators".into(),
            ));
        }
        Ok(())
    }

    /// The cells, in [`TRIALS_COLUMNS`] order without `row_crc32`.
    pub fn cells(&self) -> [String; 21] {
        [
            self.participant.clone(),
            self.session_index.to_string(),
            self.session_order.clone(),
            self.condition.code().to_owned(),
            self.phase.as_str().to_owned(),
            self.trial.to_string(),
            self.task.as_str().to_owned(),
            fmt_bool(self.success).to_owned(),
            self.reject_reason.clone(),
            fmt_opt(self.time_s),
            fmt_opt(self.force_mean_pn),
            fmt_opt(self.force_mean_n),
            fmt_opt(self.disp_err_mean_um),
            fmt_opt(self.contact_fraction),
            format_seed(self.seed),
            self.started_utc.to_string(),
            self.escaped
                .map(|b| fmt_bool(b).to_owned())
                .unwrap_or_default(),
            fmt_opt(self.time_to_collision_s),
            fmt_opt(self.peak_force_pn),
            fmt_opt(self.retreat_angle_err_deg),
            self.raw_file.clone(),
        ]
    }

    /// The complete line (with `row_crc32` and `\n`) and its CRC. Does not
    /// validate (see [`TrialRow::validate`]).
    ///
    /// # Errors
    /// Cannot fail for validated rows (CSV writer errors are reported as
    /// [`ExportError::Format`]).
    pub fn encode(&self) -> Result<(String, u32)> {
        let mut w = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .has_headers(false)
            .from_writer(Vec::new());
        let fmt_err = |message: String| ExportError::Format {
            path: PathBuf::from(TRIALS_FILE),
            at: Position {
                line: 0,
                column: None,
            },
            message,
        };
        w.write_record(self.cells())
            .map_err(|e| fmt_err(e.to_string()))?;
        let bytes = w.into_inner().map_err(|e| fmt_err(e.to_string()))?;
        let mut line = String::from_utf8(bytes).map_err(|e| fmt_err(e.to_string()))?;
        if line.ends_with('\n') {
            line.pop();
        }
        let crc = crc32(line.as_bytes());
        line.push(',');
        line.push_str(&crc32_hex(crc));
        line.push('\n');
        Ok((line, crc))
    }
}

/// Parses one cell.
fn cell<T, F>(path: &Path, line: u64, column: &str, text: &str, parse: F) -> Result<T>
where
    F: FnOnce(&str) -> std::result::Result<T, String>,
{
    parse(text).map_err(|message| ExportError::Format {
        path: path.to_path_buf(),
        at: Position {
            line,
            column: Some(column.to_owned()),
        },
        message: format!("`{text}`: {message}"),
    })
}

fn parse_u32(s: &str) -> std::result::Result<u32, String> {
    s.parse()
        .map_err(|_| "expected a non-negative integer".into())
}

fn parse_opt_f64(s: &str) -> std::result::Result<Option<f64>, String> {
    if s.is_empty() {
        return Ok(None);
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(Some(v)),
        Ok(_) => Err("non-finite number (NA must be an empty cell)".into()),
        Err(_) => Err("expected a number or an empty cell (NA)".into()),
    }
}

fn parse_bool(s: &str) -> std::result::Result<bool, String> {
    match s {
        "1" => Ok(true),
        "0" => Ok(false),
        _ => Err("expected 1 or 0".into()),
    }
}

fn parse_condition(s: &str) -> std::result::Result<Condition, String> {
    Condition::ALL
        .into_iter()
        .find(|c| c.code() == s)
        .ok_or_else(|| "expected V, P or D".into())
}

/// Parses the fields of a data line (without `row_crc32` check) into a row.
///
/// # Errors
/// [`ExportError::Format`] naming line and column.
pub fn parse_row(path: &Path, line: u64, fields: &csv::StringRecord) -> Result<TrialRow> {
    if fields.len() != TRIALS_COLUMNS.len() {
        return Err(ExportError::Format {
            path: path.to_path_buf(),
            at: Position { line, column: None },
            message: format!(
                "{} field(s), the header has {}",
                fields.len(),
                TRIALS_COLUMNS.len()
            ),
        });
    }
    let f = |i: usize| fields.get(i).unwrap_or("");
    let c = TRIALS_COLUMNS;
    Ok(TrialRow {
        participant: cell(path, line, c[0], f(0), |s| {
            if s.is_empty() {
                Err("participant id must not be empty".into())
            } else {
                Ok(s.to_owned())
            }
        })?,
        session_index: cell(path, line, c[1], f(1), parse_u32)?,
        session_order: f(2).to_owned(),
        condition: cell(path, line, c[3], f(3), parse_condition)?,
        phase: cell(path, line, c[4], f(4), Phase::from_str)?,
        trial: cell(path, line, c[5], f(5), parse_u32)?,
        task: cell(path, line, c[6], f(6), TaskKind::from_str)?,
        success: cell(path, line, c[7], f(7), parse_bool)?,
        reject_reason: f(8).to_owned(),
        time_s: cell(path, line, c[9], f(9), parse_opt_f64)?,
        force_mean_pn: cell(path, line, c[10], f(10), parse_opt_f64)?,
        force_mean_n: cell(path, line, c[11], f(11), parse_opt_f64)?,
        disp_err_mean_um: cell(path, line, c[12], f(12), parse_opt_f64)?,
        contact_fraction: cell(path, line, c[13], f(13), parse_opt_f64)?,
        seed: cell(path, line, c[14], f(14), |s| {
            parse_seed(s).ok_or_else(|| "expected 0x followed by 16 hex digits".into())
        })?,
        started_utc: cell(path, line, c[15], f(15), UtcTime::parse)?,
        escaped: cell(path, line, c[16], f(16), |s| {
            if s.is_empty() {
                Ok(None)
            } else {
                parse_bool(s).map(Some)
            }
        })?,
        time_to_collision_s: cell(path, line, c[17], f(17), parse_opt_f64)?,
        peak_force_pn: cell(path, line, c[18], f(18), parse_opt_f64)?,
        retreat_angle_err_deg: cell(path, line, c[19], f(19), parse_opt_f64)?,
        raw_file: f(20).to_owned(),
    })
}

/// First difference between a found header and [`TRIALS_COLUMNS`].
fn header_difference(found: &str) -> String {
    let cols: Vec<&str> = found.split(',').collect();
    for (i, expected) in TRIALS_COLUMNS.iter().enumerate() {
        match cols.get(i) {
            Some(c) if c == expected => {}
            Some(c) => return format!("column {} is `{c}`, expected `{expected}`", i + 1),
            None => {
                return format!(
                    "{} column(s), expected {}; first missing `{expected}`",
                    cols.len(),
                    TRIALS_COLUMNS.len()
                );
            }
        }
    }
    format!(
        "{} column(s), expected {}; extra column `{}`",
        cols.len(),
        TRIALS_COLUMNS.len(),
        cols.get(TRIALS_COLUMNS.len()).unwrap_or(&"")
    )
}

/// Options of [`read_trials_with`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReadOptions {
    /// Verify `row_crc32` (default true). Turn off only to read a file that
    /// was edited by hand on purpose.
    pub verify_checksums: bool,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            verify_checksums: true,
        }
    }
}

/// Valid rows of a `trials.csv` and its torn tail.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialsRead {
    /// Rows in file order.
    pub rows: Vec<TrialRow>,
    /// `row_crc32` of each row.
    pub crcs: Vec<u32>,
    /// 1-based line of each row.
    pub lines: Vec<u64>,
    /// Discarded tail (crash mid-append), if any.
    pub torn: Option<TornTail>,
    /// Length in bytes of the valid part (header + rows).
    pub valid_len: u64,
}

/// Parses `trials.csv` bytes.
///
/// Rules: the header must equal [`TRIALS_COLUMNS`]; every data line must
/// end with `\n`, carry a valid `row_crc32` and parse. Invalid trailing
/// lines are the torn tail (reported, not an error); an invalid line
/// followed by a valid one is an error naming line and column. Two rows of
/// the same (participant, condition, phase, trial) are an error.
///
/// # Errors
/// [`ExportError::HeaderMismatch`], [`ExportError::Format`],
/// [`ExportError::Checksum`], [`ExportError::Inconsistent`] (duplicates).
pub fn parse_trials(path: &Path, bytes: &[u8], opts: ReadOptions) -> Result<TrialsRead> {
    let expected = header_line();
    let lines = split_lines(bytes);
    let Some(first) = lines.first() else {
        return Err(ExportError::Format {
            path: path.to_path_buf(),
            at: Position {
                line: 1,
                column: None,
            },
            message: "empty file (the header line is missing)".into(),
        });
    };
    let found = String::from_utf8_lossy(first.text).into_owned();
    if !first.complete || found != expected.trim_end() {
        if !first.complete && expected.trim_end().starts_with(found.as_str()) {
            // Crash while writing the header of a new file: nothing else can
            // be in it.
            return Err(ExportError::Format {
                path: path.to_path_buf(),
                at: Position {
                    line: 1,
                    column: None,
                },
                message: "incomplete header line (the file's creation was interrupted)".into(),
            });
        }
        return Err(ExportError::HeaderMismatch {
            path: path.to_path_buf(),
            expected: expected.trim_end().to_owned(),
            detail: header_difference(&found),
            found,
        });
    }
    let data_start = lines.get(1).map_or(bytes.len(), |l| l.offset as usize);
    let checked = lines[1..]
        .iter()
        .map(|&line| (line, check_line(path, line, opts)))
        .collect();
    let (good, torn) = valid_prefix(path, bytes, checked)?;
    let valid_len = torn.as_ref().map_or(bytes.len() as u64, |t| t.offset);
    let mut out = TrialsRead {
        rows: Vec::with_capacity(good.len()),
        crcs: Vec::with_capacity(good.len()),
        lines: Vec::with_capacity(good.len()),
        torn,
        valid_len,
    };
    // The checked lines are complete as written (their checksums hold): a
    // problem from here on is never a torn tail. One CSV reader over the
    // whole valid region (a reader per line costs ~0.1 ms to build).
    let region = &bytes[data_start.min(valid_len as usize)..valid_len as usize];
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(region);
    let mut record = csv::StringRecord::new();
    let mut seen: HashMap<(String, Condition, Phase, u32), u64> = HashMap::new();
    for (line, crc) in good {
        let fmt = |message: String| ExportError::Format {
            path: path.to_path_buf(),
            at: Position { line, column: None },
            message,
        };
        match reader.read_record(&mut record) {
            Ok(true) => {}
            Ok(false) => return Err(fmt("empty line".into())),
            Err(e) => return Err(fmt(format!("malformed CSV: {e}"))),
        }
        // A quoted cell spanning lines would shift every following row.
        if record.position().map(|p| p.line() + 1) != Some(line) {
            return Err(fmt("malformed CSV: a quoted cell spans lines".into()));
        }
        let row = parse_row(path, line, &record)?;
        let id = (row.participant.clone(), row.condition, row.phase, row.trial);
        if let Some(prev) = seen.insert(id, line) {
            return Err(ExportError::Inconsistent {
                path: path.to_path_buf(),
                message: format!(
                    "line {line}: duplicate row for {} {} {} trial {} (first at line {prev})",
                    row.participant, row.condition, row.phase, row.trial
                ),
            });
        }
        out.rows.push(row);
        out.crcs.push(crc);
        out.lines.push(line);
    }
    Ok(out)
}

/// Completeness and checksum of one data line; the CRC when valid.
fn check_line(path: &Path, line: Line<'_>, opts: ReadOptions) -> Checked<u32> {
    let at = |column: Option<&str>| Position {
        line: line.number,
        column: column.map(str::to_owned),
    };
    let fmt = |message: String, column: Option<&str>| ExportError::Format {
        path: path.to_path_buf(),
        at: at(column),
        message,
    };
    if !line.complete {
        return Checked::Bad(
            fmt("incomplete row (no newline)".into(), None),
            "incomplete last row (no newline)".into(),
        );
    }
    let Ok(text) = std::str::from_utf8(line.text) else {
        return Checked::Bad(fmt("not UTF-8".into(), None), "not UTF-8".into());
    };
    let Some((content, crc_text)) = text.rsplit_once(',') else {
        return Checked::Bad(
            fmt("no row_crc32 cell".into(), None),
            "no row_crc32 cell".into(),
        );
    };
    let computed = crc32(content.as_bytes());
    let stored = parse_crc32_hex(crc_text);
    if opts.verify_checksums && stored != Some(computed) {
        return Checked::Bad(
            ExportError::Checksum {
                path: path.to_path_buf(),
                at: at(Some("row_crc32")),
                stored: crc_text.to_owned(),
                computed,
            },
            format!(
                "row checksum mismatch (stored `{}`, computed {computed:08x})",
                preview_str(crc_text)
            ),
        );
    }
    Checked::Good(stored.unwrap_or(computed))
}

fn preview_str(s: &str) -> String {
    s.chars().take(16).collect()
}

/// Reads and verifies a `trials.csv` (default options), without modifying
/// it.
///
/// # Errors
/// I/O and [`parse_trials`] errors.
pub fn read_trials(path: &Path) -> Result<TrialsRead> {
    read_trials_with(path, ReadOptions::default())
}

/// Reads a `trials.csv` with options.
///
/// # Errors
/// I/O and [`parse_trials`] errors.
pub fn read_trials_with(path: &Path, opts: ReadOptions) -> Result<TrialsRead> {
    let bytes = crate::storage::fsutil::read_no_follow(path)?;
    parse_trials(path, &bytes, opts)
}

/// Append handle on `trials.csv`.
#[derive(Debug)]
pub struct TrialsWriter {
    path: PathBuf,
    file: File,
}

impl TrialsWriter {
    /// Wraps an append-mode file whose content has been verified.
    pub(crate) fn from_file(path: PathBuf, file: File) -> Self {
        Self { path, file }
    }

    /// Appends one encoded line with a single write and fsyncs.
    ///
    /// # Errors
    /// I/O failure.
    pub fn append_line(&mut self, line: &str) -> Result<()> {
        append_durable(&mut self.file, &self.path, line.as_bytes())
    }

    /// Path of the file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Creates `trials.csv` with its header, durably.
///
/// # Errors
/// I/O errors (also when the file exists).
pub(crate) fn create_trials_file(path: &Path) -> Result<File> {
    let mut f = no_follow()
        .create_new(true)
        .append(true)
        .open(path)
        .map_err(io_err(path, "create"))?;
    append_durable(&mut f, path, header_line().as_bytes())?;
    f.sync_all().map_err(io_err(path, "fsync"))?;
    sync_dir(&parent_of(path))?;
    Ok(f)
}

/// Replaces the lines of `trials.csv` numbered in `replace` (1-based, each
/// new text with its `\n`) atomically (temporary file, rename) and opens
/// the file for appending. Every other byte is kept as it is.
///
/// # Errors
/// I/O errors.
pub(crate) fn rewrite_lines(path: &Path, replace: &HashMap<u64, String>) -> Result<File> {
    let bytes = crate::storage::fsutil::read_no_follow(path)?;
    let mut out = Vec::with_capacity(bytes.len() + 64 * replace.len());
    for line in split_lines(&bytes) {
        match replace.get(&line.number) {
            Some(text) => out.extend_from_slice(text.as_bytes()),
            None => {
                out.extend_from_slice(line.text);
                if line.complete {
                    out.push(b'\n');
                }
            }
        }
    }
    crate::storage::fsutil::write_atomic(path, &out)?;
    open_append(path)
}

/// Whether `bytes` are a strict prefix of the header: what a crash while
/// `trials.csv` was being created leaves (there cannot be any row).
pub(crate) fn is_partial_header(bytes: &[u8]) -> bool {
    let header = header_line();
    bytes.len() < header.len() && header.as_bytes().starts_with(bytes)
}

/// Writes the header of `trials.csv` again over a partial one
/// ([`is_partial_header`]), durably, and opens the file for appending.
///
/// # Errors
/// I/O errors.
pub(crate) fn rewrite_header(path: &Path) -> Result<File> {
    let mut f = no_follow()
        .write(true)
        .open(path)
        .map_err(io_err(path, "open"))?;
    f.set_len(0).map_err(io_err(path, "truncate"))?;
    f.write_all(header_line().as_bytes())
        .map_err(io_err(path, "write"))?;
    f.sync_all().map_err(io_err(path, "fsync"))?;
    drop(f);
    open_append(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_columns_are_columns_in_order() {
        let at = |c: &str| TRIALS_COLUMNS.iter().position(|&n| n == c);
        let positions: Vec<_> = IDENTITY_COLUMNS.iter().map(|c| at(c)).collect();
        assert!(positions.iter().all(Option::is_some), "{positions:?}");
        assert!(positions.is_sorted(), "{positions:?}");
    }
}
