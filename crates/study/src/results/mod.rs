//! The study-results model behind the app's Results page and
//! `kilotouch paper`: reading an output folder, the per-participant and
//! per-condition values of a metric, the statistics table and its export
//! ([`table`]), bead trajectories from raw files ([`trajectory`]).
//!
//! * Data: `trials.csv` read with [`read_trials`] (file:line errors, CRC
//!   checks, a torn last line reported, not fatal); only **test** trials
//!   count, and the metric values of **successful** ones (rejected trials
//!   are excluded, as in the paper §4.3 and as `cells_long.csv` does).
//! * Per participant (Fig. 11): for each participant × condition, the mean
//!   and sample SD over that cell's trials. The pseudo-metric "successful
//!   trials" is the count of successful test trials (no SD).
//! * Per condition (Fig. 12): mean and sample SD over the participants'
//!   cell means.
//! * Statistics on the participant × condition cell means
//!   ([`crate::stats::Design::from_long`] on
//!   [`StudyResults::triples`], conditions in V, P, D order): repeated-measures
//!   ANOVA (Greenhouse–Geisser, Huynh–Feldt), Friedman (Kendall's W),
//!   one-way ANOVA (the paper's test, conditions as independent groups of
//!   cell means) and post-hoc paired t and Wilcoxon tests with Holm's
//!   correction (a pair where a test is undefined, e.g. zero variance of
//!   the differences, keeps its row with the reason; the others are
//!   shown). The rows come from the study crate's row rule
//!   ([`crate::stats::rows`], the one `kilotouch stats` uses) and
//!   the table says how many were used and excluded. Within-subject tests
//!   drop participants missing a condition (listwise deletion, reported); each test's failure (too few
//!   participants, zero variance…) is shown in its row, the others still
//!   run.
//! * Export: `stats.csv` (one row per test or comparison, every metric)
//!   and `stats.json` (the full results) written atomically into the
//!   folder; the summaries through
//!   [`crate::export::regenerate_summaries`].

use crate::export::summary::trial_selection;
use crate::export::{
    ExportError, Metric, Summary, TRIALS_FILE, TornTail, TrialRow, read_trials, summarize,
};
use crate::protocol::Condition;
use crate::seeds::Phase;
use crate::stats::{Design, RowCounts, RowRule};
use std::path::{Path, PathBuf};
use thiserror::Error;

mod table;
mod trajectory;

pub use table::{STATS_CSV, STATS_JSON, StatsRow, StatsTable};
pub use trajectory::{Trajectory, decimate_indices, read_trajectory};

/// Errors reading a study folder's results or writing its statistics.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ResultsError {
    /// The folder has no `trials.csv`.
    #[error("{}: no {TRIALS_FILE} here — is this a study output folder?", dir.display())]
    NotAStudyFolder {
        /// The folder.
        dir: PathBuf,
    },
    /// Reading `trials.csv` or a raw file, or writing an export, failed
    /// (the message names the file and line).
    #[error("{0}")]
    Export(#[from] ExportError),
    /// The raw file's sidecar does not name a channel the trajectory needs.
    #[error("{}: no `{name}` channel in the sidecar", path.display())]
    MissingChannel {
        /// The raw file.
        path: PathBuf,
        /// The channel.
        name: String,
    },
    /// The raw file has fewer columns than its sidecar names.
    #[error("{}: the array has {cols} columns, the sidecar names more", path.display())]
    TooFewColumns {
        /// The raw file.
        path: PathBuf,
        /// Columns in the array.
        cols: usize,
    },
    /// The raw file has more rows than this machine can address.
    #[error("file too large")]
    TooLarge,
    /// Writing the statistics table failed.
    #[error("{0}")]
    Csv(#[from] csv::Error),
    /// Serialising the statistics failed.
    #[error("{0}")]
    Json(#[from] serde_json::Error),
}

/// What the charts and tests are about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ResultMetric {
    /// Number of successful test trials per participant × condition
    /// (Figs. 11a, 12a).
    SuccessCount,
    /// A numeric column of `trials.csv`.
    Column(Metric),
}

impl ResultMetric {
    /// Short name (the column name, or `n_success`).
    pub fn name(self) -> &'static str {
        match self {
            ResultMetric::SuccessCount => "n_success",
            ResultMetric::Column(m) => m.column(),
        }
    }

    /// Label with unit for the charts.
    pub fn label(self) -> String {
        match self {
            ResultMetric::SuccessCount => "successful trials".into(),
            ResultMetric::Column(m) => {
                let what = match m {
                    Metric::TimeS => "manipulation time",
                    Metric::ForceMeanPn => "mean optical force",
                    Metric::ForceMeanN => "mean hand force",
                    Metric::DispErrMeanUm => "mean displacement error",
                    Metric::ContactFraction => "contact fraction",
                    Metric::TimeToCollisionS => "time to collision",
                    Metric::PeakForcePn => "peak force",
                    Metric::RetreatAngleErrDeg => "retreat angle error",
                };
                format!("{what} ({})", m.unit())
            }
        }
    }
}

/// A study folder read for the Results page.
#[derive(Debug, Clone)]
pub struct StudyResults {
    /// The folder.
    pub dir: PathBuf,
    /// Rows of `trials.csv` in file order.
    pub rows: Vec<TrialRow>,
    /// A torn last line that was ignored (crash during a write), if any.
    pub torn: Option<TornTail>,
    /// Participant × condition summary of the test rows.
    pub summary: Summary,
    /// The sittings' timing verdicts from `session.json` (start time, rig,
    /// verdict), in order; empty for a batch simulation.
    pub timing: Vec<(String, crate::export::SittingTiming)>,
}

/// Mean and SD of one bar.
pub type MeanSd = Option<(f64, Option<f64>)>;

/// Values of a metric per participant and condition (Fig. 11).
#[derive(Debug, Clone, PartialEq)]
pub struct ParticipantBars {
    /// Participants (x groups), sorted.
    pub participants: Vec<String>,
    /// Conditions (series), V, P, D order.
    pub conditions: Vec<String>,
    /// `values[c][p]`: mean and SD of condition c for participant p.
    pub values: Vec<Vec<MeanSd>>,
}

/// Values of a metric per condition (Fig. 12).
#[derive(Debug, Clone, PartialEq)]
pub struct ConditionBars {
    /// Conditions, V, P, D order.
    pub conditions: Vec<String>,
    /// Mean and SD over the participants' cell means.
    pub values: Vec<MeanSd>,
    /// Participants contributing to each condition.
    pub n: Vec<usize>,
}

/// Conditions present in `design`, in V, P, D order (others after, as
/// found).
fn vpd_order(design: &Design) -> Vec<String> {
    let present = design.conditions();
    let mut order: Vec<String> = Condition::ALL
        .iter()
        .map(|c| c.code().to_owned())
        .filter(|c| present.contains(c))
        .collect();
    for c in present {
        if !order.contains(c) {
            order.push(c.clone());
        }
    }
    order
}

impl StudyResults {
    /// Read `dir/trials.csv` and summarise it. Errors name the file and
    /// line (study crate) and are never panics.
    pub fn load(dir: &Path) -> Result<Self, ResultsError> {
        let path = dir.join(TRIALS_FILE);
        if !path.is_file() {
            return Err(ResultsError::NotAStudyFolder {
                dir: dir.to_path_buf(),
            });
        }
        let read = read_trials(&path)?;
        let summary = summarize(&read.rows)?;
        let timing = crate::export::read_session(&dir.join(crate::export::SESSION_FILE))
            .map(|s| {
                s.sittings
                    .into_iter()
                    .filter_map(|x| {
                        x.timing
                            .map(|t| (format!("sitting of {} on {}", x.started_utc, x.rig), t))
                    })
                    .collect()
            })
            .unwrap_or_default();
        Ok(Self {
            dir: dir.to_path_buf(),
            rows: read.rows,
            torn: read.torn,
            summary,
            timing,
        })
    }

    /// Metrics with data: the success count, then the numeric columns.
    pub fn metrics(&self) -> Vec<ResultMetric> {
        let mut v = vec![ResultMetric::SuccessCount];
        v.extend(
            self.summary
                .metrics
                .iter()
                .map(|&m| ResultMetric::Column(m)),
        );
        v
    }

    /// Number of test trials.
    pub fn n_test_trials(&self) -> usize {
        self.rows.iter().filter(|r| r.phase == Phase::Test).count()
    }

    /// Long-format (participant, condition, value) triples of `metric`:
    /// the successful test trials' values, or one count per cell.
    pub fn triples(&self, metric: ResultMetric) -> Vec<(String, String, f64)> {
        self.selection(metric).0
    }

    /// [`StudyResults::triples`] and the rows used / excluded: the study
    /// crate's row rule ([`RowRule::default`]: successful test trials) for a
    /// column; for the success count, every test trial counts (practice
    /// excluded).
    pub fn selection(&self, metric: ResultMetric) -> (Vec<(String, String, f64)>, RowCounts) {
        match metric {
            ResultMetric::Column(m) => trial_selection(&self.rows, m, RowRule::default()),
            ResultMetric::SuccessCount => {
                let mut counts = RowCounts::default();
                for r in &self.rows {
                    counts.record(RowRule::default().exclusion(Some(r.phase), None, true));
                }
                (self.success_counts(), counts)
            }
        }
    }

    fn success_counts(&self) -> Vec<(String, String, f64)> {
        self.summary
            .cells
            .iter()
            .map(|c| {
                (
                    c.participant.clone(),
                    c.condition.code().to_owned(),
                    f64::from(c.n_success),
                )
            })
            .collect()
    }

    fn design(&self, metric: ResultMetric) -> Result<Design, String> {
        let d = Design::from_long(self.triples(metric)).map_err(|e| e.to_string())?;
        let order = vpd_order(&d);
        d.with_condition_order(&order).map_err(|e| e.to_string())
    }

    /// Fig. 11: per participant and condition.
    pub fn per_participant(&self, metric: ResultMetric) -> ParticipantBars {
        let participants = self.summary.participants.clone();
        let conditions: Vec<String> = self
            .summary
            .conditions
            .iter()
            .map(|c| c.code().to_owned())
            .collect();
        let triples = self.triples(metric);
        let values = conditions
            .iter()
            .map(|c| {
                participants
                    .iter()
                    .map(|p| {
                        let v: Vec<f64> = triples
                            .iter()
                            .filter(|(tp, tc, _)| tp == p && tc == c)
                            .map(|t| t.2)
                            .collect();
                        mean_sd(&v)
                    })
                    .collect()
            })
            .collect();
        ParticipantBars {
            participants,
            conditions,
            values,
        }
    }

    /// Fig. 12: per condition, over the participants' cell means.
    pub fn per_condition(&self, metric: ResultMetric) -> ConditionBars {
        let Ok(design) = self.design(metric) else {
            return ConditionBars {
                conditions: Vec::new(),
                values: Vec::new(),
                n: Vec::new(),
            };
        };
        let groups = design.condition_groups();
        ConditionBars {
            conditions: groups.iter().map(|g| g.0.clone()).collect(),
            values: groups.iter().map(|g| mean_sd(&g.1)).collect(),
            n: groups.iter().map(|g| g.1.len()).collect(),
        }
    }

    /// Test trials of `participant` in `condition` that reference a raw
    /// file: (trial number, success, path).
    pub fn raw_trials(&self, participant: &str, condition: &str) -> Vec<(u32, bool, PathBuf)> {
        self.rows
            .iter()
            .filter(|r| {
                r.phase == Phase::Test
                    && r.participant == participant
                    && r.condition.code() == condition
                    && r.has_trusted_raw()
            })
            .map(|r| (r.trial, r.success, self.dir.join(&r.raw_file)))
            .collect()
    }
}

/// Mean (Neumaier-compensated, as the study crate's cell means) and sample
/// standard deviation (n − 1 denominator; `None` for a single value) of the
/// finite values; `None` when there is no finite value.
pub fn mean_sd(values: &[f64]) -> Option<(f64, Option<f64>)> {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let mean = crate::stats::compensated_mean(&v);
    let sd = (v.len() > 1).then(|| {
        let dev: Vec<f64> = v.iter().map(|x| (x - mean) * (x - mean)).collect();
        (crate::stats::compensated_mean(&dev) * v.len() as f64 / (v.len() - 1) as f64).sqrt()
    });
    Some((mean, sd))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_sample_sd_match_the_textbook_example() {
        // 2, 4, 4, 4, 5, 5, 7, 9: mean 5, Σ(x − x̄)² = 32, sample SD √(32/7).
        let (m, sd) = mean_sd(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).unwrap();
        assert!((m - 5.0).abs() < 1e-15);
        assert!((sd.unwrap() - (32.0f64 / 7.0).sqrt()).abs() < 1e-14);
        assert_eq!(mean_sd(&[3.0]), Some((3.0, None)));
        assert_eq!(mean_sd(&[]), None);
        assert_eq!(mean_sd(&[f64::NAN]), None);
        // Non-finite values are ignored, not propagated.
        let (m, sd) = mean_sd(&[1.0, f64::INFINITY, 3.0]).unwrap();
        assert_eq!(m, 2.0);
        assert!((sd.unwrap() - 2f64.sqrt()).abs() < 1e-15);
    }
}
