//! The study-results model behind the Results page and `kilotouch paper`:
//! reading an output folder, the per-participant and per-condition values of a metric, the
//! statistics table and its export. No egui here.
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
//!   ([`kilotouch_study::stats::Design::from_long`] on
//!   [`trial_triples`], conditions in V, P, D order): repeated-measures
//!   ANOVA (Greenhouse–Geisser, Huynh–Feldt), Friedman (Kendall's W),
//!   one-way ANOVA (the paper's test, conditions as independent groups of
//!   cell means) and post-hoc paired t and Wilcoxon tests with Holm's
//!   correction (a pair where a test is undefined, e.g. zero variance of
//!   the differences, keeps its row with the reason; the others are
//!   shown). The rows come from the study crate's row rule
//!   ([`kilotouch_study::stats::rows`], the one `kilotouch stats` uses) and
//!   the table says how many were used and excluded. Within-subject tests drop participants missing a condition
//!   (listwise deletion, reported); each test's failure (too few
//!   participants, zero variance…) is shown in its row, the others still
//!   run.
//! * Export: `stats.csv` (one row per test or comparison, every metric)
//!   and `stats.json` (the full results) written atomically into the
//!   folder; the summaries through
//!   [`kilotouch_study::export::regenerate_summaries`].

use kilotouch_study::export::fsutil::write_atomic;
use kilotouch_study::export::summary::trial_selection;
use kilotouch_study::export::{
    Metric, Summary, TRIALS_FILE, TornTail, TrialRow, read_trials, summarize,
};
use kilotouch_study::protocol::Condition;
use kilotouch_study::rawsig::{read_npy, read_sidecar, sidecar_path};
use kilotouch_study::seeds::Phase;
use kilotouch_study::stats::{
    self, Design, Friedman, OneWayAnova, PairwiseTests, RmAnova, RowCounts, RowRule,
    WilcoxonOptions,
};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// File name of the exported statistics table (CSV).
pub const STATS_CSV: &str = "stats.csv";
/// File name of the exported statistics (JSON).
pub const STATS_JSON: &str = "stats.json";

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
    pub timing: Vec<(String, kilotouch_study::export::SittingTiming)>,
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

/// The statistics of one metric (module documentation). `None` results
/// come with their error in `errors` (test name → message).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StatsTable {
    /// Metric name.
    pub metric: String,
    /// Conditions in column order.
    pub conditions: Vec<String>,
    /// Participants with at least one value.
    pub participants: Vec<String>,
    /// Participants dropped from the within-subject tests (missing a
    /// condition).
    pub dropped_participants: Vec<String>,
    /// Rows of `trials.csv` used and excluded (by reason) for this metric.
    pub rows: RowCounts,
    /// The row rule applied.
    pub row_rule: RowRule,
    /// Repeated-measures ANOVA.
    pub rm_anova: Option<RmAnova>,
    /// Friedman's test.
    pub friedman: Option<Friedman>,
    /// One-way ANOVA on the cell means.
    pub oneway: Option<OneWayAnova>,
    /// Paired t and Wilcoxon signed-rank tests per pair, Holm-corrected.
    pub pairwise: Option<PairwiseTests>,
    /// Why a test has no result.
    pub errors: Vec<(String, String)>,
}

/// One line of the statistics table (display and CSV).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StatsRow {
    /// Metric.
    pub metric: String,
    /// Test.
    pub test: String,
    /// Pair compared (post-hoc) or empty.
    pub comparison: String,
    /// Name of the statistic (F, χ², t, W⁺…).
    pub statistic_name: String,
    /// Its value.
    pub statistic: Option<f64>,
    /// Degrees of freedom (numerator).
    pub df1: Option<f64>,
    /// Degrees of freedom (denominator).
    pub df2: Option<f64>,
    /// p-value (uncorrected).
    pub p: Option<f64>,
    /// Greenhouse–Geisser-corrected p (RM ANOVA).
    pub p_gg: Option<f64>,
    /// Huynh–Feldt-corrected p (RM ANOVA).
    pub p_hf: Option<f64>,
    /// Holm-adjusted p (post-hoc).
    pub p_holm: Option<f64>,
    /// Effect-size name.
    pub effect_name: String,
    /// Effect size.
    pub effect: Option<f64>,
    /// Remarks (ε values, errors).
    pub note: String,
}

fn fmt_ci(c: Option<[f64; 2]>) -> String {
    c.map_or("n/a".into(), |[lo, hi]| format!("[{lo:.3}, {hi:.3}]"))
}

fn row(metric: &str, test: &str) -> StatsRow {
    StatsRow {
        metric: metric.into(),
        test: test.into(),
        comparison: String::new(),
        statistic_name: String::new(),
        statistic: None,
        df1: None,
        df2: None,
        p: None,
        p_gg: None,
        p_hf: None,
        p_holm: None,
        effect_name: String::new(),
        effect: None,
        note: String::new(),
    }
}

/// A row of an omnibus test: statistic `name` = `value` with (df1, df2)
/// and p.
fn omnibus(
    metric: &str,
    test: &str,
    name: &str,
    value: f64,
    df: (f64, Option<f64>),
    p: f64,
) -> StatsRow {
    let mut r = row(metric, test);
    r.statistic_name = name.into();
    r.statistic = Some(value);
    r.df1 = Some(df.0);
    r.df2 = df.1;
    r.p = Some(p);
    r
}

impl StatsTable {
    /// The table as rows: RM ANOVA, Friedman, one-way ANOVA, then the
    /// post-hoc comparisons; a failed test gives a row with its error.
    pub fn rows(&self) -> Vec<StatsRow> {
        let m = self.metric.as_str();
        let mut out = Vec::new();
        let err = |name: &str| {
            self.errors
                .iter()
                .find(|(t, _)| t == name)
                .map(|(_, e)| e.clone())
                .unwrap_or_default()
        };
        let rm = self.rm_anova.as_ref().map(|a| {
            let mut r = omnibus(m, "rm_anova", "F", a.f, (a.df1, Some(a.df2)), a.p);
            r.p_gg = Some(a.p_gg);
            r.p_hf = Some(a.p_hf);
            r.effect_name = "partial η²".into();
            r.effect = Some(a.np2);
            r.note = format!(
                "partial η² 95% CI {}; ε_GG = {:.4}, ε_HF = {:.4}, Mauchly p = {}, \
                 generalised η² = {:.4}",
                fmt_ci(a.np2_ci),
                a.eps_gg,
                a.eps_hf,
                a.mauchly_p.map_or("n/a".into(), |p| format!("{p:.4}")),
                a.ng2
            );
            r
        });
        let fr = self.friedman.as_ref().map(|f| {
            let mut r = omnibus(m, "friedman", "χ²", f.chi2, (f.df, None), f.p);
            r.effect_name = "Kendall's W".into();
            r.effect = Some(f.kendall_w);
            r.note = format!("Kendall's W 95% CI {} (bootstrap)", fmt_ci(f.kendall_w_ci));
            r
        });
        let one = self.oneway.as_ref().map(|o| {
            let mut r = omnibus(m, "oneway_anova", "F", o.f, (o.df1, Some(o.df2)), o.p);
            r.effect_name = "η²".into();
            r.effect = Some(o.eta2);
            r.note = format!("η² 95% CI {}", fmt_ci(o.eta2_ci));
            r
        });
        for (name, r) in [("rm_anova", rm), ("friedman", fr), ("oneway_anova", one)] {
            out.push(r.unwrap_or_else(|| {
                let mut r = row(m, name);
                r.note = err(name);
                r
            }));
        }
        match &self.pairwise {
            Some(table) => {
                for name in ["paired_t", "wilcoxon"] {
                    for c in &table.pairs {
                        let mut r = row(m, name);
                        r.comparison = format!("{} vs {}", c.a, c.b);
                        if name == "paired_t" {
                            r.statistic_name = "t".into();
                            r.statistic = c.t;
                            r.df1 = c.df;
                            r.p = c.p;
                            r.p_holm = c.p_holm;
                            r.effect_name = "d_z".into();
                            r.effect = c.dz;
                            r.note = match (c.dz_ci, c.mean_diff_ci) {
                                (Some([a, b]), Some([lo, hi])) => format!(
                                    "d_z 95% CI [{a:.3}, {b:.3}]; mean difference {:.4} \
                                     [{lo:.4}, {hi:.4}]",
                                    c.mean_diff
                                ),
                                _ => undefined_note(&c.undefined, "t-test"),
                            };
                        } else {
                            r.statistic_name = "W".into();
                            r.statistic = c.wilcoxon_w;
                            r.p = c.wilcoxon_p;
                            r.p_holm = c.wilcoxon_p_holm;
                            r.effect_name = "mean difference".into();
                            r.effect = Some(c.mean_diff);
                            if c.wilcoxon_p.is_none() {
                                r.note = undefined_note(&c.undefined, "Wilcoxon");
                            }
                        }
                        out.push(r);
                    }
                }
            }
            None => {
                for name in ["paired_t", "wilcoxon"] {
                    let mut r = row(m, name);
                    r.note = err("pairwise");
                    out.push(r);
                }
            }
        }
        out
    }
}

/// The reason a pair's `test` is undefined ("undefined: …").
fn undefined_note(reasons: &[String], test: &str) -> String {
    reasons
        .iter()
        .find(|r| r.starts_with(test))
        .map_or_else(|| "undefined".to_owned(), |r| format!("undefined: {r}"))
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
    pub fn load(dir: &Path) -> Result<Self, String> {
        let path = dir.join(TRIALS_FILE);
        if !path.is_file() {
            return Err(format!(
                "{}: no {TRIALS_FILE} here — is this a study output folder?",
                dir.display()
            ));
        }
        let read = read_trials(&path).map_err(|e| e.to_string())?;
        let summary = summarize(&read.rows).map_err(|e| e.to_string())?;
        let timing =
            kilotouch_study::export::read_session(&dir.join(kilotouch_study::export::SESSION_FILE))
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

    /// The statistics of `metric` (module documentation).
    pub fn stats(&self, metric: ResultMetric) -> StatsTable {
        let mut t = StatsTable {
            metric: metric.name().to_owned(),
            conditions: Vec::new(),
            participants: Vec::new(),
            dropped_participants: Vec::new(),
            rows: self.selection(metric).1,
            row_rule: RowRule::default(),
            rm_anova: None,
            friedman: None,
            oneway: None,
            pairwise: None,
            errors: Vec::new(),
        };
        let design = match self.design(metric) {
            Ok(d) => d,
            Err(e) => {
                for name in ["rm_anova", "friedman", "oneway_anova", "pairwise"] {
                    t.errors.push((name.into(), e.clone()));
                }
                return t;
            }
        };
        t.conditions = design.conditions().to_vec();
        t.participants = design.subjects().to_vec();
        match stats::oneway(&design) {
            Ok(o) => t.oneway = Some(o),
            Err(e) => t.errors.push(("oneway_anova".into(), e.to_string())),
        }
        let within = design
            .complete_subjects_only()
            .map_err(|e| e.to_string())
            .and_then(|(d, dropped)| {
                t.dropped_participants = dropped;
                d.cell_matrix().map_err(|e| e.to_string())
            });
        match within {
            Ok(m) => {
                match stats::rm_anova(&m) {
                    Ok(a) => t.rm_anova = Some(a),
                    Err(e) => t.errors.push(("rm_anova".into(), e.to_string())),
                }
                match stats::friedman(&m) {
                    Ok(f) => t.friedman = Some(f),
                    Err(e) => t.errors.push(("friedman".into(), e.to_string())),
                }
                match stats::pairwise_tests(&m, WilcoxonOptions::default()) {
                    Ok(p) => t.pairwise = Some(p),
                    Err(e) => t.errors.push(("pairwise".into(), e.to_string())),
                }
            }
            Err(e) => {
                for name in ["rm_anova", "friedman", "pairwise"] {
                    t.errors.push((name.into(), e.clone()));
                }
            }
        }
        t
    }

    /// Write `stats.csv` and `stats.json` for every metric into the folder
    /// (atomically); returns their paths.
    pub fn export_stats(&self) -> Result<(PathBuf, PathBuf), String> {
        let tables: Vec<StatsTable> = self.metrics().into_iter().map(|m| self.stats(m)).collect();
        let mut w = csv::Writer::from_writer(Vec::new());
        let num = |v: Option<f64>| v.map(|x| x.to_string()).unwrap_or_default();
        w.write_record([
            "metric",
            "test",
            "comparison",
            "statistic_name",
            "statistic",
            "df1",
            "df2",
            "p",
            "p_gg",
            "p_hf",
            "p_holm",
            "effect_name",
            "effect",
            "note",
        ])
        .map_err(|e| e.to_string())?;
        for t in &tables {
            for r in t.rows() {
                w.write_record([
                    r.metric,
                    r.test,
                    r.comparison,
                    r.statistic_name,
                    num(r.statistic),
                    num(r.df1),
                    num(r.df2),
                    num(r.p),
                    num(r.p_gg),
                    num(r.p_hf),
                    num(r.p_holm),
                    r.effect_name,
                    num(r.effect),
                    r.note,
                ])
                .map_err(|e| e.to_string())?;
            }
        }
        let csv_bytes = w.into_inner().map_err(|e| e.to_string())?;
        let json = serde_json::to_vec_pretty(&tables).map_err(|e| e.to_string())?;
        let csv_path = self.dir.join(STATS_CSV);
        let json_path = self.dir.join(STATS_JSON);
        write_atomic(&csv_path, &csv_bytes).map_err(|e| e.to_string())?;
        write_atomic(&json_path, &json).map_err(|e| e.to_string())?;
        Ok((csv_path, json_path))
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

/// A bead trajectory read from a raw file.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Trial number.
    pub trial: u32,
    /// Trial successful.
    pub success: bool,
    /// Bead (x, y), µm, decimated.
    pub bead_um: Vec<[f64; 2]>,
    /// Samples in the file.
    pub samples: u64,
}

/// Read the bead trajectory (`bead_x`, `bead_y`, m → µm) of a raw trial file
/// ([`kilotouch_study::rawsig`]: NPY + JSON sidecar naming the channels),
/// decimated to at most `max_points` points; non-finite samples are
/// skipped.
pub fn read_trajectory(
    path: &Path,
    trial: u32,
    success: bool,
    max_points: usize,
) -> Result<Trajectory, String> {
    let side = read_sidecar(&sidecar_path(path)).map_err(|e| e.to_string())?;
    let col = |name: &str| {
        side.channels
            .iter()
            .position(|c| c.name == name)
            .ok_or_else(|| format!("{}: no `{name}` channel in the sidecar", path.display()))
    };
    let (cx, cy) = (col("bead_x")?, col("bead_y")?);
    let arr = read_npy(path).map_err(|e| e.to_string())?;
    if cx >= arr.cols || cy >= arr.cols {
        return Err(format!(
            "{}: the array has {} columns, the sidecar names more",
            path.display(),
            arr.cols
        ));
    }
    let n = usize::try_from(arr.rows).map_err(|_| "file too large".to_owned())?;
    let bead_um = decimate_indices(n, max_points)
        .into_iter()
        .filter_map(|i| {
            let r = arr.row(i);
            let (x, y) = (r[cx] * 1e6, r[cy] * 1e6);
            (x.is_finite() && y.is_finite()).then_some([x, y])
        })
        .collect();
    Ok(Trajectory {
        trial,
        success,
        bead_um,
        samples: arr.rows,
    })
}

/// Mean (Neumaier-compensated, as the study crate's cell means) and sample
/// standard deviation (n − 1 denominator; `None` for a single value) of the
/// finite values; `None` when there is no finite value.
pub fn mean_sd(values: &[f64]) -> Option<(f64, Option<f64>)> {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let mean = kilotouch_study::stats::compensated_mean(&v);
    let sd = (v.len() > 1).then(|| {
        let dev: Vec<f64> = v.iter().map(|x| (x - mean) * (x - mean)).collect();
        (kilotouch_study::stats::compensated_mean(&dev) * v.len() as f64 / (v.len() - 1) as f64)
            .sqrt()
    });
    Some((mean, sd))
}

/// Indices of at most `max` samples of a record of `n`, evenly strided, the
/// last sample always included (a trajectory keeps its end point).
pub fn decimate_indices(n: usize, max: usize) -> Vec<usize> {
    if n == 0 || max == 0 {
        return Vec::new();
    }
    if n <= max {
        return (0..n).collect();
    }
    let stride = n.div_ceil(max.saturating_sub(1).max(1));
    let mut v: Vec<usize> = (0..n).step_by(stride).collect();
    if v.last() != Some(&(n - 1)) {
        v.push(n - 1);
    }
    v
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

    #[test]
    fn decimation_keeps_ends_and_bounds_the_count() {
        assert!(decimate_indices(0, 10).is_empty());
        assert_eq!(decimate_indices(5, 10), vec![0, 1, 2, 3, 4]);
        for (n, max) in [(100_000, 2000), (2001, 2000), (10, 3), (7, 2)] {
            let idx = decimate_indices(n, max);
            assert!(idx.len() <= max, "{n} {max}: {}", idx.len());
            assert_eq!(idx[0], 0);
            assert_eq!(*idx.last().unwrap(), n - 1);
            assert!(idx.windows(2).all(|w| w[0] < w[1]));
        }
    }
}
