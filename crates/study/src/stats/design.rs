//! Long-format data → participant × condition cell means.
//!
//! Every statistic of this module works on *cell means*: when a participant
//! has several rows (trials) in one condition, they are averaged first, as
//! pingouin (`rm_anova`, `friedman`) and R's `ez` (`ezANOVA`, which warns and
//! aggregates) do. The trial-level data never enter the tests directly, so
//! the repeated-measures error term is participant × condition, not trial.

use std::collections::HashMap;

use serde::Serialize;

use super::error::{MissingCell, Result, StatsError};

/// Neumaier-compensated mean of a non-empty slice (Neumaier 1974): the
/// cell means of every table the study crate writes or analyses.
pub fn compensated_mean(values: &[f64]) -> f64 {
    let mut sum = 0.0_f64;
    let mut comp = 0.0_f64;
    for &v in values {
        let t = sum + v;
        if sum.abs() >= v.abs() {
            comp += (sum - t) + v;
        } else {
            comp += (v - t) + sum;
        }
        sum = t;
    }
    (sum + comp) / values.len() as f64
}

/// Cell means of long-format data, possibly incomplete.
///
/// Subjects and conditions keep the order of their first appearance in the
/// data (use [`Design::with_condition_order`] to impose another).
#[derive(Debug, Clone, PartialEq)]
pub struct Design {
    subjects: Vec<String>,
    conditions: Vec<String>,
    /// Row-major `subjects × conditions`: raw values of each cell.
    cells: Vec<Vec<f64>>,
}

impl Design {
    /// Builds a design from long-format rows `(subject, condition, value)`.
    ///
    /// Repeated rows of one (subject, condition) cell are averaged. Missing
    /// cells are allowed here (a between-groups analysis needs none of them);
    /// [`Design::cell_matrix`] reports them.
    ///
    /// # Errors
    /// [`StatsError::Empty`] without rows, [`StatsError::NonFinite`] for a NaN
    /// or infinite value (naming the row, subject and condition).
    pub fn from_long<I, S, C>(rows: I) -> Result<Self>
    where
        I: IntoIterator<Item = (S, C, f64)>,
        S: AsRef<str>,
        C: AsRef<str>,
    {
        let mut subjects: Vec<String> = Vec::new();
        let mut conditions: Vec<String> = Vec::new();
        let mut subject_index: HashMap<String, usize> = HashMap::new();
        let mut condition_index: HashMap<String, usize> = HashMap::new();
        let mut raw: Vec<(usize, usize, f64)> = Vec::new();
        for (row, (s, c, value)) in rows.into_iter().enumerate() {
            let (s, c) = (s.as_ref(), c.as_ref());
            if !value.is_finite() {
                return Err(StatsError::NonFinite {
                    row,
                    subject: s.to_owned(),
                    condition: c.to_owned(),
                    value,
                });
            }
            let si = *subject_index.entry(s.to_owned()).or_insert_with(|| {
                subjects.push(s.to_owned());
                subjects.len() - 1
            });
            let ci = *condition_index.entry(c.to_owned()).or_insert_with(|| {
                conditions.push(c.to_owned());
                conditions.len() - 1
            });
            raw.push((si, ci, value));
        }
        if raw.is_empty() {
            return Err(StatsError::Empty);
        }
        let k = conditions.len();
        let mut cells = vec![Vec::new(); subjects.len() * k];
        for (si, ci, v) in raw {
            cells[si * k + ci].push(v);
        }
        Ok(Self {
            subjects,
            conditions,
            cells,
        })
    }

    /// Subject labels in order of first appearance.
    pub fn subjects(&self) -> &[String] {
        &self.subjects
    }

    /// Condition labels in order of first appearance (or as reordered).
    pub fn conditions(&self) -> &[String] {
        &self.conditions
    }

    /// Number of rows averaged into cell (`subject`, `condition`) (indices).
    pub fn cell_count(&self, subject: usize, condition: usize) -> usize {
        if subject >= self.subjects.len() || condition >= self.conditions.len() {
            return 0;
        }
        self.cells[subject * self.conditions.len() + condition].len()
    }

    /// Mean of cell (`subject`, `condition`) (indices), `None` when empty.
    pub fn cell_mean(&self, subject: usize, condition: usize) -> Option<f64> {
        if subject >= self.subjects.len() || condition >= self.conditions.len() {
            return None;
        }
        let cell = &self.cells[subject * self.conditions.len() + condition];
        (!cell.is_empty()).then(|| compensated_mean(cell))
    }

    /// Every (subject, condition) pair without data, subjects in data order.
    pub fn missing_cells(&self) -> Vec<MissingCell> {
        let k = self.conditions.len();
        let mut out = Vec::new();
        for (si, s) in self.subjects.iter().enumerate() {
            for (ci, c) in self.conditions.iter().enumerate() {
                if self.cells[si * k + ci].is_empty() {
                    out.push(MissingCell {
                        subject: s.clone(),
                        condition: c.clone(),
                    });
                }
            }
        }
        out
    }

    /// True when every subject has every condition.
    pub fn is_complete(&self) -> bool {
        self.cells.iter().all(|c| !c.is_empty())
    }

    /// Refuses a cell whose mean is not finite (finite values whose sum
    /// overflows `f64`): no test ranks or averages such a cell.
    ///
    /// # Errors
    /// [`StatsError::NonFiniteCell`] naming the first such cell.
    pub fn check_cell_means(&self) -> Result<()> {
        let k = self.conditions.len();
        for (i, cell) in self.cells.iter().enumerate() {
            if cell.is_empty() {
                continue;
            }
            let value = compensated_mean(cell);
            if !value.is_finite() {
                return Err(StatsError::NonFiniteCell {
                    subject: self.subjects[i / k].clone(),
                    condition: self.conditions[i % k].clone(),
                    rows: cell.len(),
                    value,
                });
            }
        }
        Ok(())
    }

    /// The cell-mean matrix of a complete within-subject design.
    ///
    /// # Errors
    /// [`StatsError::IncompleteDesign`] naming each subject and the
    /// conditions it lacks; [`StatsError::NonFiniteCell`].
    pub fn cell_matrix(&self) -> Result<CellMatrix> {
        let missing = self.missing_cells();
        if !missing.is_empty() {
            return Err(StatsError::IncompleteDesign { missing });
        }
        self.check_cell_means()?;
        let values = self.cells.iter().map(|c| compensated_mean(c)).collect();
        Ok(CellMatrix {
            subjects: self.subjects.clone(),
            conditions: self.conditions.clone(),
            values,
        })
    }

    /// Listwise deletion: the design restricted to subjects with every
    /// condition, and the labels of the subjects dropped.
    ///
    /// # Errors
    /// [`StatsError::Empty`] when no subject is complete.
    pub fn complete_subjects_only(&self) -> Result<(Design, Vec<String>)> {
        let k = self.conditions.len();
        let mut subjects = Vec::new();
        let mut cells = Vec::new();
        let mut dropped = Vec::new();
        for (si, s) in self.subjects.iter().enumerate() {
            let row = &self.cells[si * k..(si + 1) * k];
            if row.iter().all(|c| !c.is_empty()) {
                subjects.push(s.clone());
                cells.extend_from_slice(row);
            } else {
                dropped.push(s.clone());
            }
        }
        if subjects.is_empty() {
            return Err(StatsError::Empty);
        }
        Ok((
            Design {
                subjects,
                conditions: self.conditions.clone(),
                cells,
            },
            dropped,
        ))
    }

    /// Cell means grouped by condition (for the between-groups one-way
    /// ANOVA): for each condition, the means of the subjects that have it,
    /// in subject order.
    pub fn condition_groups(&self) -> Vec<(String, Vec<f64>)> {
        let k = self.conditions.len();
        self.conditions
            .iter()
            .enumerate()
            .map(|(ci, c)| {
                let values = (0..self.subjects.len())
                    .filter_map(|si| {
                        let cell = &self.cells[si * k + ci];
                        (!cell.is_empty()).then(|| compensated_mean(cell))
                    })
                    .collect();
                (c.clone(), values)
            })
            .collect()
    }

    /// The same design with the conditions in the given order (a
    /// permutation of [`Design::conditions`]).
    ///
    /// # Errors
    /// [`StatsError::UnknownCondition`], [`StatsError::DuplicateLabel`] or
    /// [`StatsError::BadConditionOrder`] if `order` is not a permutation.
    pub fn with_condition_order<L: AsRef<str>>(&self, order: &[L]) -> Result<Design> {
        let k = self.conditions.len();
        if order.len() != k {
            return Err(StatsError::BadConditionOrder {
                expected: k,
                got: order.len(),
            });
        }
        let mut perm = Vec::with_capacity(k);
        for label in order {
            let label = label.as_ref();
            let ci = self
                .conditions
                .iter()
                .position(|c| c == label)
                .ok_or_else(|| StatsError::UnknownCondition(label.to_owned()))?;
            if perm.contains(&ci) {
                return Err(StatsError::DuplicateLabel {
                    what: "condition",
                    label: label.to_owned(),
                });
            }
            perm.push(ci);
        }
        let mut cells = Vec::with_capacity(self.cells.len());
        for si in 0..self.subjects.len() {
            for &ci in &perm {
                cells.push(self.cells[si * k + ci].clone());
            }
        }
        Ok(Design {
            subjects: self.subjects.clone(),
            conditions: perm.iter().map(|&ci| self.conditions[ci].clone()).collect(),
            cells,
        })
    }
}

/// Complete participant × condition matrix of cell means (row-major).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CellMatrix {
    subjects: Vec<String>,
    conditions: Vec<String>,
    values: Vec<f64>,
}

impl CellMatrix {
    /// `(subjects, conditions)`, or the error `test` reports when there are
    /// fewer than 2 of either (no within-subject comparison is possible).
    pub fn require_at_least_2x2(&self, test: &'static str) -> Result<(usize, usize)> {
        let (n, k) = (self.n_subjects(), self.n_conditions());
        if k < 2 {
            return Err(StatsError::TooFewConditions {
                test,
                needed: 2,
                got: k,
            });
        }
        if n < 2 {
            return Err(StatsError::TooFewSubjects {
                test,
                needed: 2,
                got: n,
            });
        }
        Ok((n, k))
    }

    /// Builds a matrix from labels and row-major values
    /// (`values[i * conditions.len() + j]` = subject i, condition j).
    ///
    /// # Errors
    /// Length mismatch, duplicated labels, non-finite values, no subject or
    /// no condition.
    pub fn new(subjects: Vec<String>, conditions: Vec<String>, values: Vec<f64>) -> Result<Self> {
        if subjects.is_empty() || conditions.is_empty() {
            return Err(StatsError::Empty);
        }
        let expected = subjects.len() * conditions.len();
        if values.len() != expected {
            return Err(StatsError::LengthMismatch {
                what: "values vs subjects × conditions",
                left: values.len(),
                right: expected,
            });
        }
        for (what, labels) in [("subject", &subjects), ("condition", &conditions)] {
            let mut seen = std::collections::HashSet::with_capacity(labels.len());
            if let Some(l) = labels.iter().find(|l| !seen.insert(l.as_str())) {
                return Err(StatsError::DuplicateLabel {
                    what,
                    label: l.clone(),
                });
            }
        }
        let k = conditions.len();
        if let Some((i, &v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(StatsError::NonFinite {
                row: i,
                subject: subjects[i / k].clone(),
                condition: conditions[i % k].clone(),
                value: v,
            });
        }
        Ok(Self {
            subjects,
            conditions,
            values,
        })
    }

    /// Builds a matrix from one column of values per condition; subjects are
    /// labelled `1`, `2`, … in row order.
    ///
    /// # Errors
    /// Columns of unequal length, plus the errors of [`CellMatrix::new`].
    pub fn from_columns<L: AsRef<str>, V: AsRef<[f64]>>(columns: &[(L, V)]) -> Result<Self> {
        let Some((_, first)) = columns.first() else {
            return Err(StatsError::Empty);
        };
        let n = first.as_ref().len();
        for (_, col) in columns {
            if col.as_ref().len() != n {
                return Err(StatsError::LengthMismatch {
                    what: "condition columns",
                    left: n,
                    right: col.as_ref().len(),
                });
            }
        }
        let k = columns.len();
        let mut values = vec![0.0; n * k];
        for (j, (_, col)) in columns.iter().enumerate() {
            for (i, &v) in col.as_ref().iter().enumerate() {
                values[i * k + j] = v;
            }
        }
        let subjects = (1..=n).map(|i| i.to_string()).collect();
        let conditions = columns.iter().map(|(l, _)| l.as_ref().to_owned()).collect();
        Self::new(subjects, conditions, values)
    }

    /// Subject labels (rows).
    pub fn subjects(&self) -> &[String] {
        &self.subjects
    }

    /// Condition labels (columns).
    pub fn conditions(&self) -> &[String] {
        &self.conditions
    }

    /// Number of subjects n.
    pub fn n_subjects(&self) -> usize {
        self.subjects.len()
    }

    /// Number of conditions k.
    pub fn n_conditions(&self) -> usize {
        self.conditions.len()
    }

    /// Row-major values.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Row of subject `i` (one value per condition).
    pub fn row(&self, i: usize) -> &[f64] {
        let k = self.conditions.len();
        &self.values[i * k..(i + 1) * k]
    }

    /// Column of condition `j` (one value per subject).
    pub fn column(&self, j: usize) -> Vec<f64> {
        let k = self.conditions.len();
        self.values.iter().skip(j).step_by(k).copied().collect()
    }

    /// The same matrix with the columns permuted: column `j` of the result is
    /// column `perm[j]` of `self`.
    ///
    /// # Errors
    /// [`StatsError::BadConditionOrder`] if `perm` is not a permutation.
    pub fn permute_conditions(&self, perm: &[usize]) -> Result<Self> {
        let k = self.conditions.len();
        let mut seen = vec![false; k];
        for &p in perm {
            if p >= k || seen[p] {
                return Err(StatsError::BadConditionOrder {
                    expected: k,
                    got: perm.len(),
                });
            }
            seen[p] = true;
        }
        if perm.len() != k {
            return Err(StatsError::BadConditionOrder {
                expected: k,
                got: perm.len(),
            });
        }
        let mut values = Vec::with_capacity(self.values.len());
        for i in 0..self.subjects.len() {
            let row = self.row(i);
            values.extend(perm.iter().map(|&p| row[p]));
        }
        Ok(Self {
            subjects: self.subjects.clone(),
            conditions: perm.iter().map(|&p| self.conditions[p].clone()).collect(),
            values,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeats_are_averaged_and_order_is_first_appearance() {
        let rows = vec![
            ("s2", "P", 1.0),
            ("s1", "V", 4.0),
            ("s2", "P", 3.0),
            ("s1", "P", 5.0),
            ("s2", "V", 7.0),
            ("s1", "V", 6.0),
            ("s1", "V", 8.0),
        ];
        let d = Design::from_long(rows).unwrap();
        assert_eq!(d.subjects(), ["s2", "s1"]);
        assert_eq!(d.conditions(), ["P", "V"]);
        assert!(d.is_complete());
        assert_eq!(d.cell_count(1, 1), 3);
        let m = d.cell_matrix().unwrap();
        assert_eq!(m.values(), &[2.0, 7.0, 5.0, 6.0]);
        assert_eq!(m.column(1), vec![7.0, 6.0]);
        let r = d
            .with_condition_order(&["V", "P"])
            .unwrap()
            .cell_matrix()
            .unwrap();
        assert_eq!(r.values(), &[7.0, 2.0, 6.0, 5.0]);
        assert_eq!(r, m.permute_conditions(&[1, 0]).unwrap());
    }

    #[test]
    fn incomplete_design_names_subjects_and_conditions() {
        let rows = vec![
            ("a", "V", 1.0),
            ("a", "P", 1.0),
            ("a", "D", 1.0),
            ("b", "V", 2.0),
            ("c", "D", 3.0),
        ];
        let d = Design::from_long(rows).unwrap();
        assert!(!d.is_complete());
        let err = d.cell_matrix().unwrap_err();
        let StatsError::IncompleteDesign { missing } = &err else {
            panic!("wrong error {err:?}")
        };
        assert_eq!(missing.len(), 4);
        assert_eq!(
            err.to_string(),
            "incomplete design: subject `b` lacks `P`, `D`; subject `c` lacks `V`, `P`"
        );
        let (complete, dropped) = d.complete_subjects_only().unwrap();
        assert_eq!(complete.subjects(), ["a"]);
        assert_eq!(dropped, vec!["b".to_string(), "c".to_string()]);
        let groups = d.condition_groups();
        assert_eq!(groups[0], ("V".to_string(), vec![1.0, 2.0]));
        assert_eq!(groups[1], ("P".to_string(), vec![1.0]));
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let empty: Vec<(&str, &str, f64)> = vec![];
        assert_eq!(Design::from_long(empty), Err(StatsError::Empty));
        // Finite values whose cell mean overflows: refused, naming the cell,
        // by the matrix of the within tests and by the one-way ANOVA.
        let huge = Design::from_long(vec![
            ("a", "V", 1.0),
            ("a", "P", 1e308),
            ("a", "P", 1e308),
            ("b", "V", 2.0),
            ("b", "P", 3.0),
        ])
        .unwrap();
        let err = huge.cell_matrix().unwrap_err();
        assert!(
            matches!(err, StatsError::NonFiniteCell { rows: 2, .. }),
            "{err:?}"
        );
        assert!(
            err.to_string()
                .contains("cell (subject `a`, condition `P`) over 2 row(s)"),
            "{err}"
        );
        assert_eq!(
            crate::stats::oneway(&huge).unwrap_err().to_string(),
            err.to_string()
        );
        let err = Design::from_long(vec![("a", "V", 1.0), ("a", "P", f64::NAN)]).unwrap_err();
        assert!(
            matches!(err, StatsError::NonFinite { row: 1, .. }),
            "{err:?}"
        );
        assert!(err.to_string().contains("subject `a`, condition `P`"));
        let d = Design::from_long(vec![("a", "V", 1.0), ("a", "P", 2.0)]).unwrap();
        assert!(matches!(
            d.with_condition_order(&["V", "X"]),
            Err(StatsError::UnknownCondition(_))
        ));
        assert!(matches!(
            d.with_condition_order(&["V", "V"]),
            Err(StatsError::DuplicateLabel { .. })
        ));
        assert!(matches!(
            d.with_condition_order(&["V"]),
            Err(StatsError::BadConditionOrder { .. })
        ));
        assert!(CellMatrix::from_columns(&[("A", vec![1.0, 2.0]), ("B", vec![1.0])]).is_err());
        assert!(
            CellMatrix::new(
                vec!["x".into(), "x".into()],
                vec!["A".into()],
                vec![1.0, 2.0]
            )
            .is_err()
        );
        assert!(CellMatrix::from_columns(&[("A", vec![1.0, f64::INFINITY])]).is_err());
    }

    #[test]
    fn compensated_mean_survives_large_offsets() {
        let big = 1e16;
        let m = compensated_mean(&[big, 1.0, -big, 1.0]);
        assert_eq!(m, 0.5);
    }
}
