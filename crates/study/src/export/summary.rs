//! Participant × condition summaries of `trials.csv`: `cells_long.csv`
//! (one row per participant × condition, for pingouin / R `ez` /
//! statsmodels) and `cells_wide.csv` (one row per participant, one column
//! per metric × condition, for JASP).
//!
//! Only **test** trials enter the summaries (practice rows are ignored).
//! Per cell:
//!
//! * `session_index` — position of the condition's session for the
//!   participant;
//! * `n_trials` — test trials; `n_success` — successful ones;
//!   `success_rate` = `n_success / n_trials`;
//! * `n_escaped` — trials with `escaped = 1` (only when some row defines
//!   `escaped`; NA when no trial of the cell does);
//! * one column per metric ([`Metric`]): the mean over the cell's
//!   **successful** trials with a value (rejected trials are excluded, as in
//!   the paper §4.3); empty (NA) when there is none. A metric column is
//!   written only when at least one cell has a value.
//!
//! Means use Neumaier-compensated summation over the rows in file order —
//! the same algorithm and order as [`crate::stats::Design`], so statistics
//! computed from `cells_long.csv` equal those computed from the trials.
//! Numbers are written in the shortest form that reads back to the same
//! `f64`. [`regenerate_summaries`] writes both files of a study folder from
//! its `trials.csv`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::trials::{Metric, TRIALS_FILE, TrialRow, read_trials};
use crate::protocol::Condition;
use crate::seeds::Phase;
use crate::stats::rows::{LongRow, RowCounts, RowRule, select_rows};
use crate::storage::error::{ExportError, Position, Result};
use crate::storage::fsutil::{TornTail, write_atomic};

/// File name of the long summary.
pub const CELLS_LONG_FILE: &str = "cells_long.csv";
/// File name of the wide summary.
pub const CELLS_WIDE_FILE: &str = "cells_wide.csv";

pub use crate::stats::compensated_mean;

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
/// reported), and `datapackage.json` describing the three tables
/// ([`super::datapackage`]). The files are replaced atomically.
///
/// # Errors
/// Those of [`read_trials`] and [`summarize`]; I/O errors.
pub fn regenerate_summaries(dir: &Path) -> Result<SummaryFiles> {
    let read = read_trials(&dir.join(TRIALS_FILE))?;
    let summary = summarize(&read.rows)?;
    let long = csv_text(&summary.long_header(), &summary.long_records())?;
    let wide = csv_text(&summary.wide_header(), &summary.wide_records())?;
    let cells_long = dir.join(CELLS_LONG_FILE);
    let cells_wide = dir.join(CELLS_WIDE_FILE);
    write_atomic(&cells_long, long.as_bytes())?;
    write_atomic(&cells_wide, wide.as_bytes())?;
    let value_columns = summary.value_columns();
    super::datapackage::write_datapackage(
        dir,
        super::datapackage::SummaryLayout {
            long_file: CELLS_LONG_FILE,
            wide_file: CELLS_WIDE_FILE,
            value_columns: &value_columns,
            conditions: &summary.conditions,
        },
        "kilotouch study",
    )?;
    Ok(SummaryFiles {
        cells_long,
        cells_wide,
        summary,
        ignored_tail: read.torn,
    })
}

/// One participant × condition cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// Participant id.
    pub participant: String,
    /// Condition.
    pub condition: Condition,
    /// Session index of the condition for the participant.
    pub session_index: u32,
    /// Test trials.
    pub n_trials: u32,
    /// Successful test trials.
    pub n_success: u32,
    /// `n_escaped`, when any trial of the cell defines `escaped`.
    pub n_escaped: Option<u32>,
    /// Mean of each metric of [`Summary::metrics`] over successful trials.
    pub means: Vec<Option<f64>>,
}

impl Cell {
    /// `n_success / n_trials`.
    pub fn success_rate(&self) -> f64 {
        f64::from(self.n_success) / f64::from(self.n_trials)
    }
}

/// Cells of a set of trial rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Metrics with at least one value, in column order.
    pub metrics: Vec<Metric>,
    /// Whether any test row defines `escaped`.
    pub has_escaped: bool,
    /// Conditions present, in V, P, D order.
    pub conditions: Vec<Condition>,
    /// Participants present (test rows), sorted.
    pub participants: Vec<String>,
    /// Cells sorted by participant, then condition.
    pub cells: Vec<Cell>,
}

fn fmt_num(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

/// Summarises the test rows of `rows` (see the module documentation).
///
/// # Errors
/// [`ExportError::Inconsistent`] when the rows of one cell disagree on
/// `session_index`.
pub fn summarize(rows: &[TrialRow]) -> Result<Summary> {
    let test: Vec<&TrialRow> = rows.iter().filter(|r| r.phase == Phase::Test).collect();
    let mut groups: BTreeMap<(String, Condition), Vec<&TrialRow>> = BTreeMap::new();
    for r in &test {
        groups
            .entry((r.participant.clone(), r.condition))
            .or_default()
            .push(r);
    }
    let has_escaped = test.iter().any(|r| r.escaped.is_some());
    let metrics: Vec<Metric> = Metric::ALL
        .into_iter()
        .filter(|m| test.iter().any(|r| r.success && m.get(r).is_some()))
        .collect();
    let conditions: Vec<Condition> = Condition::ALL
        .into_iter()
        .filter(|c| test.iter().any(|r| r.condition == *c))
        .collect();
    let mut participants: Vec<String> = test.iter().map(|r| r.participant.clone()).collect();
    participants.sort();
    participants.dedup();
    let mut cells = Vec::with_capacity(groups.len());
    for ((participant, condition), rs) in groups {
        let session_index = rs[0].session_index;
        if let Some(other) = rs.iter().find(|r| r.session_index != session_index) {
            return Err(ExportError::Inconsistent {
                path: PathBuf::from(super::trials::TRIALS_FILE),
                message: format!(
                    "participant {participant}, condition {condition}: trials disagree on \
                     session_index ({session_index} and {})",
                    other.session_index
                ),
            });
        }
        let n_trials = u32::try_from(rs.len()).unwrap_or(u32::MAX);
        let n_success = u32::try_from(rs.iter().filter(|r| r.success).count()).unwrap_or(u32::MAX);
        let n_escaped = rs.iter().any(|r| r.escaped.is_some()).then(|| {
            u32::try_from(rs.iter().filter(|r| r.escaped == Some(true)).count()).unwrap_or(u32::MAX)
        });
        let means = metrics
            .iter()
            .map(|m| {
                let v: Vec<f64> = rs
                    .iter()
                    .filter(|r| {
                        RowRule::default()
                            .exclusion(Some(r.phase), Some(r.success), true)
                            .is_none()
                    })
                    .filter_map(|r| m.get(r))
                    .collect();
                (!v.is_empty()).then(|| compensated_mean(&v))
            })
            .collect();
        cells.push(Cell {
            participant,
            condition,
            session_index,
            n_trials,
            n_success,
            n_escaped,
            means,
        });
    }
    Ok(Summary {
        metrics,
        has_escaped,
        conditions,
        participants,
        cells,
    })
}

impl Summary {
    /// Names of the numeric per-cell columns, in order.
    pub fn value_columns(&self) -> Vec<String> {
        let mut cols: Vec<String> = ["session_index", "n_trials", "n_success", "success_rate"]
            .iter()
            .map(|s| (*s).to_owned())
            .collect();
        if self.has_escaped {
            cols.push("n_escaped".into());
        }
        cols.extend(self.metrics.iter().map(|m| m.column().to_owned()));
        cols
    }

    /// Numeric values of `cell` in [`Summary::value_columns`] order.
    pub fn values(&self, cell: &Cell) -> Vec<Option<f64>> {
        let mut v = vec![
            Some(f64::from(cell.session_index)),
            Some(f64::from(cell.n_trials)),
            Some(f64::from(cell.n_success)),
            Some(cell.success_rate()),
        ];
        if self.has_escaped {
            v.push(cell.n_escaped.map(f64::from));
        }
        v.extend(cell.means.iter().copied());
        v
    }

    /// Header of `cells_long.csv`.
    pub fn long_header(&self) -> Vec<String> {
        let mut h = vec!["participant".to_owned(), "condition".to_owned()];
        h.extend(self.value_columns());
        h
    }

    /// Records of `cells_long.csv`.
    pub fn long_records(&self) -> Vec<Vec<String>> {
        self.cells
            .iter()
            .map(|c| {
                let mut r = vec![c.participant.clone(), c.condition.code().to_owned()];
                // Counts as integers, not "3" vs "3.0" ambiguity: f64
                // Display of an integral value has no decimal point.
                r.extend(self.values(c).into_iter().map(fmt_num));
                r
            })
            .collect()
    }

    /// Header of `cells_wide.csv`: `participant`, then `{column}_{condition}`
    /// for every value column and condition (conditions adjacent).
    pub fn wide_header(&self) -> Vec<String> {
        let mut h = vec!["participant".to_owned()];
        for col in self.value_columns() {
            for c in &self.conditions {
                h.push(format!("{col}_{c}"));
            }
        }
        h
    }

    /// Records of `cells_wide.csv` (NA for a missing cell).
    pub fn wide_records(&self) -> Vec<Vec<String>> {
        let ncols = self.value_columns().len();
        self.participants
            .iter()
            .map(|p| {
                let mut r = vec![p.clone()];
                let per_condition: Vec<Option<Vec<Option<f64>>>> = self
                    .conditions
                    .iter()
                    .map(|c| {
                        self.cells
                            .iter()
                            .find(|cell| &cell.participant == p && cell.condition == *c)
                            .map(|cell| self.values(cell))
                    })
                    .collect();
                for j in 0..ncols {
                    for vals in &per_condition {
                        r.push(fmt_num(vals.as_ref().and_then(|v| v[j])));
                    }
                }
                r
            })
            .collect()
    }
}

/// CSV text of a header and records (`\n` line ends).
///
/// # Errors
/// CSV writer failure (not expected for in-memory output).
pub fn csv_text(header: &[String], records: &[Vec<String>]) -> Result<String> {
    let err = |e: &dyn std::fmt::Display| ExportError::Format {
        path: PathBuf::new(),
        at: Position {
            line: 0,
            column: None,
        },
        message: e.to_string(),
    };
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    w.write_record(header).map_err(|e| err(&e))?;
    for r in records {
        w.write_record(r).map_err(|e| err(&e))?;
    }
    let bytes = w.into_inner().map_err(|e| err(&e))?;
    String::from_utf8(bytes).map_err(|e| err(&e))
}

/// A CSV table read back as text cells.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Table {
    /// Header.
    pub header: Vec<String>,
    /// Records.
    pub records: Vec<Vec<String>>,
}

impl Table {
    /// Reads a CSV file with a header (every row must have the header's
    /// width).
    ///
    /// # Errors
    /// I/O, malformed CSV or ragged rows, naming the line.
    pub fn read(path: &Path) -> Result<Self> {
        let bytes = crate::storage::fsutil::read_no_follow(path)?;
        let mut reader = csv::ReaderBuilder::new().from_reader(bytes.as_slice());
        let fmt = |line: u64, message: String| ExportError::Format {
            path: path.to_path_buf(),
            at: Position { line, column: None },
            message,
        };
        let header: Vec<String> = reader
            .headers()
            .map_err(|e| fmt(1, e.to_string()))?
            .iter()
            .map(str::to_owned)
            .collect();
        let mut records = Vec::new();
        for rec in reader.records() {
            let rec = rec.map_err(|e| {
                let line = e.position().map_or(0, csv::Position::line);
                fmt(line, e.to_string())
            })?;
            records.push(rec.iter().map(str::to_owned).collect());
        }
        Ok(Self { header, records })
    }

    /// Index of a column.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// Numeric value of `column` in record `i` (`None` for an empty cell).
    ///
    /// # Errors
    /// Unknown column or a cell that is not a number (line and column
    /// named; the header is line 1).
    pub fn number(&self, path: &Path, i: usize, column: &str) -> Result<Option<f64>> {
        let at = Position {
            line: i as u64 + 2,
            column: Some(column.to_owned()),
        };
        let j = self.column(column).ok_or_else(|| ExportError::Format {
            path: path.to_path_buf(),
            at: at.clone(),
            message: "no such column".into(),
        })?;
        let text = self.records[i].get(j).map_or("", String::as_str);
        if text.is_empty() {
            return Ok(None);
        }
        text.parse::<f64>()
            .map(Some)
            .map_err(|_| ExportError::Format {
                path: path.to_path_buf(),
                at,
                message: format!("`{text}` is not a number"),
            })
    }

    /// Long-format triples `(participant, condition, value)` of a column of
    /// `cells_long.csv`, skipping NA cells — the input of
    /// [`crate::stats::Design::from_long`].
    ///
    /// # Errors
    /// Missing `participant` / `condition` column, or a non-numeric cell.
    pub fn long_triples(&self, path: &Path, column: &str) -> Result<Vec<(String, String, f64)>> {
        let missing = |name: &str| ExportError::Format {
            path: path.to_path_buf(),
            at: Position {
                line: 1,
                column: Some(name.to_owned()),
            },
            message: "column missing".into(),
        };
        let pi = self
            .column("participant")
            .ok_or_else(|| missing("participant"))?;
        let ci = self
            .column("condition")
            .ok_or_else(|| missing("condition"))?;
        let mut out = Vec::new();
        for i in 0..self.records.len() {
            if let Some(v) = self.number(path, i, column)? {
                out.push((self.records[i][pi].clone(), self.records[i][ci].clone(), v));
            }
        }
        Ok(out)
    }
}

/// Long-format triples `(participant, condition, value)` of one metric over
/// the successful test trials — the trial-level input that
/// [`crate::stats::Design::from_long`] averages into the same cells as
/// `cells_long.csv` ([`trial_selection`] with the default rule).
pub fn trial_triples(rows: &[TrialRow], metric: Metric) -> Vec<(String, String, f64)> {
    trial_selection(rows, metric, RowRule::default()).0
}

/// The triples of `metric` over the trials `rule` admits
/// ([`crate::stats::rows`], the one row rule) and the counts of used and
/// excluded rows.
pub fn trial_selection(
    rows: &[TrialRow],
    metric: Metric,
    rule: RowRule,
) -> (Vec<(String, String, f64)>, RowCounts) {
    let codes: Vec<&'static str> = rows.iter().map(|r| r.condition.code()).collect();
    select_rows(
        rule,
        rows.iter().zip(&codes).map(|(r, c)| LongRow {
            subject: &r.participant,
            condition: c,
            value: metric.get(r),
            phase: Some(r.phase),
            success: Some(r.success),
        }),
    )
}
