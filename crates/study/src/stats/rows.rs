//! Which rows of a trial table enter an analysis — the one row rule of
//! `kilotouch stats`, the Results page, the summaries (`cells_long.csv`)
//! and any later analysis of a study folder.
//!
//! By default only **test** trials (`phase = test`) that **succeeded**
//! (`success = 1`) are analysed, as in the paper (§4.3: rejected trials are
//! excluded) and as `cells_long.csv` averages them. [`RowRule`] can admit
//! practice and/or rejected trials instead. A table without a `phase` or
//! `success` column is not filtered on it.
//!
//! Each excluded row is counted under one reason, the first that applies in
//! this order: [`Exclusion::Practice`], [`Exclusion::Rejected`],
//! [`Exclusion::MissingValue`] (an admitted row whose dependent variable is
//! empty — NA, e.g. a metric undefined for that trial).

use std::collections::BTreeMap;

use serde::Serialize;

use crate::seeds::Phase;

/// Why a row was left out of an analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Exclusion {
    /// A practice trial (`phase = practice`).
    Practice,
    /// A rejected (unsuccessful) trial (`success = 0`).
    Rejected,
    /// The dependent variable is empty (NA) on this row.
    MissingValue,
}

impl Exclusion {
    /// Every reason, in the order they are checked.
    pub const ALL: [Exclusion; 3] = [
        Exclusion::Practice,
        Exclusion::Rejected,
        Exclusion::MissingValue,
    ];

    /// `practice`, `rejected` or `missing_value` (the JSON key).
    pub fn key(self) -> &'static str {
        match self {
            Exclusion::Practice => "practice",
            Exclusion::Rejected => "rejected",
            Exclusion::MissingValue => "missing_value",
        }
    }

    /// Words for a researcher.
    pub fn describe(self) -> &'static str {
        match self {
            Exclusion::Practice => "practice trials",
            Exclusion::Rejected => "rejected trials",
            Exclusion::MissingValue => "rows without a value",
        }
    }
}

/// Which trials an analysis uses (module documentation). The default uses
/// successful test trials only.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct RowRule {
    /// Admit practice trials too.
    pub include_practice: bool,
    /// Admit rejected (unsuccessful) trials too.
    pub include_rejected: bool,
}

impl RowRule {
    /// Why a row with this `phase` / `success` (`None` when the table has no
    /// such column) and dependent-variable presence is excluded, or `None`
    /// when it is used.
    pub fn exclusion(
        &self,
        phase: Option<Phase>,
        success: Option<bool>,
        has_value: bool,
    ) -> Option<Exclusion> {
        if phase == Some(Phase::Practice) && !self.include_practice {
            Some(Exclusion::Practice)
        } else if success == Some(false) && !self.include_rejected {
            Some(Exclusion::Rejected)
        } else if !has_value {
            Some(Exclusion::MissingValue)
        } else {
            None
        }
    }

    /// Short description, e.g. "successful test trials".
    pub fn describe(&self) -> &'static str {
        match (self.include_practice, self.include_rejected) {
            (false, false) => "successful test trials",
            (false, true) => "test trials (successful and rejected)",
            (true, false) => "successful trials (practice and test)",
            (true, true) => "all trials (practice and test, successful and rejected)",
        }
    }
}

/// Reads a `phase` cell (`practice` / `test`, any case, surrounding blanks
/// ignored).
///
/// # Errors
/// A message naming the accepted words.
pub fn parse_phase(text: &str) -> Result<Phase, String> {
    match text.trim().to_ascii_lowercase().as_str() {
        "practice" => Ok(Phase::Practice),
        "test" => Ok(Phase::Test),
        other => Err(format!(
            "`{other}` is not a phase (expected `practice` or `test`)"
        )),
    }
}

/// Reads a `success` cell: `1` / `0`, `true` / `false` (any case).
///
/// # Errors
/// A message naming the accepted values.
pub fn parse_success(text: &str) -> Result<bool, String> {
    match text.trim().to_ascii_lowercase().as_str() {
        "1" | "true" => Ok(true),
        "0" | "false" => Ok(false),
        other => Err(format!("`{other}` is not a success flag (expected 1 or 0)")),
    }
}

/// How many rows an analysis used and why the others were left out.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RowCounts {
    /// Rows that entered the cell means.
    pub rows_used: usize,
    /// Rows left out, by reason (every reason is present, zero or not).
    pub rows_excluded: BTreeMap<&'static str, usize>,
}

impl Default for RowCounts {
    fn default() -> Self {
        Self {
            rows_used: 0,
            rows_excluded: Exclusion::ALL.iter().map(|e| (e.key(), 0)).collect(),
        }
    }
}

impl RowCounts {
    /// Count one row (`None`: used).
    pub fn record(&mut self, exclusion: Option<Exclusion>) {
        match exclusion {
            None => self.rows_used += 1,
            Some(e) => *self.rows_excluded.entry(e.key()).or_insert(0) += 1,
        }
    }

    /// Rows excluded for `reason`.
    pub fn excluded(&self, reason: Exclusion) -> usize {
        self.rows_excluded.get(reason.key()).copied().unwrap_or(0)
    }

    /// Rows excluded for any reason.
    pub fn total_excluded(&self) -> usize {
        self.rows_excluded.values().sum()
    }

    /// "used 120 of 150 rows; excluded 20 practice trials, 10 rejected
    /// trials" (reasons with zero rows are omitted).
    pub fn sentence(&self) -> String {
        let parts: Vec<String> = Exclusion::ALL
            .iter()
            .filter(|e| self.excluded(**e) > 0)
            .map(|e| format!("{} {}", self.excluded(*e), e.describe()))
            .collect();
        let total = self.rows_used + self.total_excluded();
        if parts.is_empty() {
            format!("used all {total} rows")
        } else {
            format!(
                "used {} of {total} rows; excluded {}",
                self.rows_used,
                parts.join(", ")
            )
        }
    }
}

/// One row of a long-format table as the row rule sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LongRow<'a> {
    /// Participant label.
    pub subject: &'a str,
    /// Condition label.
    pub condition: &'a str,
    /// Dependent variable (`None`: empty / NA).
    pub value: Option<f64>,
    /// `phase` of the row, when the table has that column.
    pub phase: Option<Phase>,
    /// `success` of the row, when the table has that column.
    pub success: Option<bool>,
}

/// Applies `rule` to `rows`: the `(subject, condition, value)` triples that
/// enter [`super::Design::from_long`], and the counts.
pub fn select_rows<'a, I>(rule: RowRule, rows: I) -> (Vec<(String, String, f64)>, RowCounts)
where
    I: IntoIterator<Item = LongRow<'a>>,
{
    let mut counts = RowCounts::default();
    let mut out = Vec::new();
    for r in rows {
        let why = rule.exclusion(r.phase, r.success, r.value.is_some());
        counts.record(why);
        if why.is_none()
            && let Some(v) = r.value
        {
            out.push((r.subject.to_owned(), r.condition.to_owned(), v));
        }
    }
    (out, counts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_rule_keeps_successful_test_trials() {
        let rows = [
            ("a", "V", Some(1.0), Some(Phase::Practice), Some(true)),
            ("a", "V", Some(2.0), Some(Phase::Test), Some(true)),
            ("a", "V", Some(3.0), Some(Phase::Test), Some(false)),
            ("a", "V", None, Some(Phase::Test), Some(true)),
            ("a", "V", Some(5.0), Some(Phase::Practice), Some(false)),
        ];
        let long = rows.iter().map(|r| LongRow {
            subject: r.0,
            condition: r.1,
            value: r.2,
            phase: r.3,
            success: r.4,
        });
        let (t, c) = select_rows(RowRule::default(), long.clone());
        assert_eq!(t, vec![("a".into(), "V".into(), 2.0)]);
        assert_eq!(c.rows_used, 1);
        assert_eq!(c.excluded(Exclusion::Practice), 2);
        assert_eq!(c.excluded(Exclusion::Rejected), 1);
        assert_eq!(c.excluded(Exclusion::MissingValue), 1);
        assert_eq!(
            c.sentence(),
            "used 1 of 5 rows; excluded 2 practice trials, 1 rejected trials, 1 rows without a value"
        );
        let all = RowRule {
            include_practice: true,
            include_rejected: true,
        };
        let (t, c) = select_rows(all, long);
        assert_eq!(t.len(), 4);
        assert_eq!(c.total_excluded(), 1);
    }

    #[test]
    fn cells_parse_in_researcher_words() {
        assert_eq!(parse_phase(" Test "), Ok(Phase::Test));
        assert!(parse_phase("train").unwrap_err().contains("practice"));
        assert_eq!(parse_success("1"), Ok(true));
        assert_eq!(parse_success("FALSE"), Ok(false));
        assert!(parse_success("yes").is_err());
    }
}
