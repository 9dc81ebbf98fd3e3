//! Reading a pilot: a study folder's `trials.csv` or any long-format CSV
//! with a header row, and the rows a power analysis models.
//!
//! Bounds: at most [`MAX_PILOT_ROWS`] data rows and [`crate::csvio::MAX_BYTES`]
//! bytes are read; a larger file is refused with a clear error rather than
//! truncated.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::error::PowerError;
use crate::csvio::{CsvReader, Limits};
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
    if cell.is_empty() {
        Some(None)
    } else {
        crate::stats::rows::parse_success(cell).ok().map(Some)
    }
}

/// Reads a pilot (folder or CSV file) with columns `subject`, `within` and
/// `dv` (required) and `phase`, `success` (used when present), with the
/// bounded reader of [`crate::csvio`] (at most [`MAX_PILOT_ROWS`] rows).
/// A DV cell that is empty, `NA` or `NaN` is a missing value.
///
/// # Errors
/// [`PowerError::Csv`] for an unreadable file or a malformed cell (naming
/// the line and column), [`PowerError::MissingColumn`] naming the columns
/// the file has.
pub fn read_pilot(
    path: &Path,
    dv: &str,
    within: &str,
    subject: &str,
) -> Result<PilotTable, PowerError> {
    let file = pilot_file(path);
    let limits = Limits {
        rows: MAX_PILOT_ROWS,
        ..Limits::default()
    };
    let mut reader = CsvReader::open(&file, limits)?;
    let header = reader.header();
    let need = |name: &str, what: &'static str| {
        header
            .position(name)
            .ok_or_else(|| PowerError::MissingColumn {
                path: file.clone(),
                what,
                column: name.to_owned(),
                available: header.names().to_vec(),
            })
    };
    let i_subject = need(subject, "participant (--subject)")?;
    let i_within = need(within, "condition (--within)")?;
    let i_dv = need(dv, "dependent variable (--dv)")?;
    let i_phase = header.position(PHASE_COLUMN);
    let i_success = header.position(SUCCESS_COLUMN);
    let mut rows = Vec::new();
    while let Some(row) = reader.next_row()? {
        let test = match i_phase.map(|i| (i, row.text(i))) {
            None | Some((_, "test")) => true,
            Some((_, "practice")) => false,
            Some((i, other)) => {
                return Err(row
                    .error(i, format!("`{other}` is neither `test` nor `practice`"))
                    .into());
            }
        };
        let success = match i_success {
            None => None,
            Some(i) => parse_success(row.text(i))
                .ok_or_else(|| row.error(i, format!("`{}` is not 1, 0 or empty", row.text(i))))?,
        };
        let value = row.value(i_dv)?;
        for i in [i_subject, i_within] {
            if row.text(i).is_empty() {
                return Err(row
                    .error(
                        i,
                        "empty cell (every row needs a participant and a condition)",
                    )
                    .into());
            }
        }
        rows.push(PilotRow {
            line: row.line(),
            subject: row.text(i_subject).to_owned(),
            condition: row.text(i_within).to_owned(),
            test,
            success,
            value,
        });
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
