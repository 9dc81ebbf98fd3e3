//! Reading a pilot: a study folder's `trials.csv` or any long-format CSV
//! with a header row, and the rows a power analysis models.
//!
//! Bounds: at most [`MAX_PILOT_ROWS`] data rows are read; a larger file is
//! refused with a clear error rather than truncated.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::error::PowerError;
use crate::export::TRIALS_FILE;
use crate::seeds::Phase;
use crate::stats::Design;
use crate::stats::rows::RowRule;

/// Largest number of data rows read from a pilot file (a pilot has tens of
/// participants × hundreds of trials; 10⁷ rows is ~1 GB of CSV).
pub const MAX_PILOT_ROWS: usize = 10_000_000;

/// Column of the trial phase (`practice` / `test`), optional.
pub const PHASE_COLUMN: &str = "phase";
/// Column of the trial outcome (`1` success, `0` rejected), optional.
pub const SUCCESS_COLUMN: &str = "success";

/// One row of a pilot file, as far as a power analysis needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct PilotRow {
    /// 1-based line number in the file (the header is line 1).
    pub line: u64,
    /// Participant label.
    pub subject: String,
    /// Condition label.
    pub condition: String,
    /// `false` only for a row whose phase is `practice` (no phase column:
    /// every row is a test row).
    pub test: bool,
    /// Trial outcome (`None`: no success column, or an empty cell).
    pub success: Option<bool>,
    /// The dependent variable (`None`: empty cell, NA).
    pub value: Option<f64>,
}

/// A pilot file read into memory.
#[derive(Debug, Clone, PartialEq)]
pub struct PilotTable {
    /// The file read.
    pub path: PathBuf,
    /// Name of the dependent-variable column.
    pub dv: String,
    /// Its rows, in file order.
    pub rows: Vec<PilotRow>,
}

impl PilotTable {
    /// Whether the dependent variable is the `success` column itself (then
    /// the analysed value of a trial is its outcome, 1 or 0).
    pub fn dv_is_success(&self) -> bool {
        self.dv == SUCCESS_COLUMN
    }
}

/// The file a `--pilot` argument names: a folder means its `trials.csv`.
pub fn pilot_file(path: &Path) -> PathBuf {
    if path.is_dir() {
        path.join(TRIALS_FILE)
    } else {
        path.to_path_buf()
    }
}

/// A `success` cell: empty (no outcome recorded) or the flag read by the
/// row rule's [`crate::stats::rows::parse_success`]; `None` when malformed.
fn parse_success(cell: &str) -> Option<Option<bool>> {
    if cell.trim().is_empty() {
        Some(None)
    } else {
        crate::stats::rows::parse_success(cell).ok().map(Some)
    }
}

/// Reads a pilot (folder or CSV file) with columns `subject`, `within` and
/// `dv` (required) and `phase`, `success` (used when present).
///
/// # Errors
/// [`PowerError::Read`] for an unreadable file or a malformed cell (naming
/// the line and column), [`PowerError::MissingColumn`] naming the columns
/// the file has.
pub fn read_pilot(
    path: &Path,
    dv: &str,
    within: &str,
    subject: &str,
) -> Result<PilotTable, PowerError> {
    let file = pilot_file(path);
    let read_err = |line: Option<u64>, detail: String| PowerError::Read {
        path: file.clone(),
        line,
        detail,
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(false)
        .from_path(&file)
        .map_err(|e| read_err(None, e.to_string()))?;
    let headers = reader
        .headers()
        .map_err(|e| read_err(Some(1), e.to_string()))?
        .clone();
    let find = |name: &str| headers.iter().position(|h| h.trim() == name);
    let need = |name: &str, what: &'static str| {
        find(name).ok_or_else(|| PowerError::MissingColumn {
            path: file.clone(),
            what,
            column: name.to_owned(),
            available: headers.iter().map(str::to_owned).collect(),
        })
    };
    let i_subject = need(subject, "participant (--subject)")?;
    let i_within = need(within, "condition (--within)")?;
    let i_dv = need(dv, "dependent variable (--dv)")?;
    let i_phase = find(PHASE_COLUMN);
    let i_success = find(SUCCESS_COLUMN);
    let mut rows = Vec::new();
    for (k, rec) in reader.records().enumerate() {
        let line = k as u64 + 2;
        let rec = rec.map_err(|e| read_err(Some(line), e.to_string()))?;
        if rows.len() >= MAX_PILOT_ROWS {
            return Err(read_err(
                Some(line),
                format!("more than {MAX_PILOT_ROWS} rows; a pilot this large is not supported"),
            ));
        }
        let cell = |i: usize| rec.get(i).unwrap_or("");
        let test = match i_phase.map(cell).map(str::trim) {
            None | Some("test") => true,
            Some("practice") => false,
            Some(other) => {
                return Err(read_err(
                    Some(line),
                    format!("column `{PHASE_COLUMN}`: `{other}` is neither `test` nor `practice`"),
                ));
            }
        };
        let success = match i_success {
            None => None,
            Some(i) => parse_success(cell(i)).ok_or_else(|| {
                read_err(
                    Some(line),
                    format!(
                        "column `{SUCCESS_COLUMN}`: `{}` is not 1, 0 or empty",
                        cell(i)
                    ),
                )
            })?,
        };
        let raw = cell(i_dv).trim();
        let value = if raw.is_empty() || raw.eq_ignore_ascii_case("na") {
            None
        } else {
            let v: f64 = raw.parse().map_err(|_| {
                read_err(
                    Some(line),
                    format!("column `{dv}`: `{raw}` is not a number"),
                )
            })?;
            if !v.is_finite() {
                return Err(read_err(
                    Some(line),
                    format!("column `{dv}`: `{raw}` is not a finite number"),
                ));
            }
            Some(v)
        };
        let subject = cell(i_subject).trim();
        let condition = cell(i_within).trim();
        if subject.is_empty() || condition.is_empty() {
            return Err(read_err(
                Some(line),
                format!(
                    "empty `{}` or `{}` cell",
                    headers[i_subject].trim(),
                    headers[i_within].trim()
                ),
            ));
        }
        rows.push(PilotRow {
            line,
            subject: subject.to_owned(),
            condition: condition.to_owned(),
            test,
            success,
            value,
        });
    }
    if rows.is_empty() {
        return Err(read_err(None, "no data rows".into()));
    }
    Ok(PilotTable {
        path: file,
        dv: dv.to_owned(),
        rows,
    })
}

/// The rows the power analysis models, after the row rule and listwise
/// deletion.
#[derive(Debug, Clone)]
pub struct PilotRows {
    /// `(participant, condition, value)` of every kept row.
    pub rows: Vec<(String, String, f64)>,
    /// Cell means of the kept rows: complete participants only, conditions
    /// in the order asked for.
    pub design: Design,
    /// Participants dropped because they lack a cell (listwise deletion).
    pub dropped: Vec<String>,
}

/// The row rule of `kilotouch stats` ([`RowRule`], default: successful test
/// trials) applied to a pilot. Keeps test-phase rows (`phase = test` when the
/// file has a phase column) that succeeded (`success = 1` when the file has
/// a success column — except when the DV *is* `success`, whose value of a
/// trial is its outcome) and have a value; restricts them to `conditions`;
/// then deletes listwise every participant lacking one of them.
///
/// # Errors
/// [`PowerError::UnknownCondition`] for a condition absent from the kept
/// rows; [`PowerError::TooFewParticipants`] with no complete participant.
pub fn pilot_rows(table: &PilotTable, conditions: &[String]) -> Result<PilotRows, PowerError> {
    // The DV `success` is a trial's outcome: as in `stats`, the success
    // column then does not filter rows.
    let dv_is_success = table.dv_is_success();
    let rule = RowRule::default();
    let rows: Vec<(String, String, f64)> = table
        .rows
        .iter()
        .filter(|r| {
            let phase = if r.test { Phase::Test } else { Phase::Practice };
            let success = if dv_is_success { None } else { r.success };
            rule.exclusion(Some(phase), success, r.value.is_some())
                .is_none()
        })
        .filter(|r| conditions.contains(&r.condition))
        .filter_map(|r| r.value.map(|v| (r.subject.clone(), r.condition.clone(), v)))
        .collect();
    for c in conditions {
        if !rows.iter().any(|r| &r.1 == c) {
            let mut available: Vec<String> = Vec::new();
            for r in &table.rows {
                if !available.contains(&r.condition) {
                    available.push(r.condition.clone());
                }
            }
            return Err(PowerError::UnknownCondition {
                label: c.clone(),
                available,
            });
        }
    }
    let design = Design::from_long(rows.iter().map(|(s, c, v)| (s, c, *v)))?
        .with_condition_order(conditions)?;
    let (design, dropped) = design
        .complete_subjects_only()
        .map_err(|_| PowerError::TooFewParticipants { got: 0 })?;
    let keep: Vec<&String> = design.subjects().iter().collect();
    let rows = rows.into_iter().filter(|r| keep.contains(&&r.0)).collect();
    Ok(PilotRows {
        rows,
        design,
        dropped,
    })
}

/// Test trials and successes of one participant in one condition.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TrialCount {
    /// Test trials run (rows with an outcome).
    pub trials: u32,
    /// Successful ones.
    pub successes: u32,
}

/// Per condition (in the order of `conditions`), each participant's test
/// trials and successes: every test row with an outcome counts, whatever
/// its DV cell (a rejected trial is a trial run). Without a success column
/// every test row is a success.
pub fn trial_counts(table: &PilotTable, conditions: &[String]) -> Vec<Vec<TrialCount>> {
    let mut per: Vec<HashMap<&str, TrialCount>> = vec![HashMap::new(); conditions.len()];
    let mut order: Vec<Vec<&str>> = vec![Vec::new(); conditions.len()];
    let has_outcomes = table.rows.iter().any(|r| r.success.is_some());
    for r in table.rows.iter().filter(|r| r.test) {
        let Some(j) = conditions.iter().position(|c| c == &r.condition) else {
            continue;
        };
        let ok = match r.success {
            Some(s) => s,
            None if !has_outcomes => true,
            None => continue,
        };
        let e = per[j].entry(r.subject.as_str()).or_insert_with(|| {
            order[j].push(r.subject.as_str());
            TrialCount::default()
        });
        e.trials += 1;
        e.successes += u32::from(ok);
    }
    order
        .iter()
        .zip(&per)
        .map(|(o, m)| o.iter().map(|s| m[s]).collect())
        .collect()
}
