//! The statistics table of one metric ([`StatsTable`]): the tests of the
//! results model (module [`super`]) as rows, and their export to
//! `stats.csv` and `stats.json`.

use super::{ResultMetric, ResultsError, StudyResults};
use crate::export::fsutil::write_atomic;
use crate::stats::{
    self, Friedman, OneWayAnova, PairwiseTests, RmAnova, RowCounts, RowRule, WilcoxonOptions,
};
use serde::Serialize;
use std::path::PathBuf;

/// File name of the exported statistics table (CSV).
pub const STATS_CSV: &str = "stats.csv";
/// File name of the exported statistics (JSON).
pub const STATS_JSON: &str = "stats.json";

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

impl StudyResults {
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
    pub fn export_stats(&self) -> Result<(PathBuf, PathBuf), ResultsError> {
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
        ])?;
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
                ])?;
            }
        }
        let csv_bytes = w
            .into_inner()
            .map_err(|e| csv::Error::from(e.into_error()))?;
        let json = serde_json::to_vec_pretty(&tables)?;
        let csv_path = self.dir.join(STATS_CSV);
        let json_path = self.dir.join(STATS_JSON);
        write_atomic(&csv_path, &csv_bytes)?;
        write_atomic(&json_path, &json)?;
        Ok((csv_path, json_path))
    }
}
