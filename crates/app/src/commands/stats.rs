//! `kilotouch stats`: one-way ANOVA, repeated-measures ANOVA, Friedman test,
//! pairwise post-hoc tests or descriptives on a long-format CSV (one row per
//! observation; repeats are averaged into participant × condition cell
//! means, as pingouin and R's ez do).
//!
//! Rows are chosen by the study crate's row rule
//! ([`kilotouch_study::stats::rows`]): when the file has `phase` / `success`
//! columns (a study's `trials.csv`), only successful test trials are used
//! unless `--include-practice` / `--include-rejected` say otherwise. A row
//! whose dependent variable is empty (NA) is left out and counted. The
//! within-subject tests drop participants lacking a condition (listwise
//! deletion) and name them. The output reports `rows_used`,
//! `rows_excluded` (by reason) and `participants_dropped`.

use crate::output::emit;
use kilotouch_study::csvio::{CsvError, CsvReader, Limits};
use kilotouch_study::seeds::Phase;
use kilotouch_study::stats::rows::{parse_phase, parse_success};
use kilotouch_study::stats::{
    Design, LongRow, RowCounts, RowRule, Test, TestReport, analyse, select_rows,
};
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `kilotouch stats`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Long-format CSV with a header row (e.g. `trials.csv` or `cells_long.csv`).
    pub file: PathBuf,
    /// Dependent variable column (numeric; empty cells are NA).
    #[arg(long)]
    pub dv: String,
    /// Within-subject factor column (condition labels).
    #[arg(long)]
    pub within: String,
    /// Subject column (participant labels).
    #[arg(long)]
    pub subject: String,
    /// Test to run: `oneway`, `rm` (repeated-measures ANOVA), `friedman`,
    /// `pairwise` (paired t + Wilcoxon per pair, Holm), `describe`.
    #[arg(long, value_parser = ["oneway", "rm", "friedman", "pairwise", "describe"])]
    pub test: String,
    /// Also use practice trials (rows with `phase = practice`).
    #[arg(long)]
    pub include_practice: bool,
    /// Also use rejected trials (rows with `success = 0`).
    #[arg(long)]
    pub include_rejected: bool,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// What `kilotouch stats --json` prints: the test's fields, then the rows
/// and participants the test used.
#[derive(Debug, Serialize)]
struct Output {
    #[serde(flatten)]
    report: TestReport,
    /// Rows used and excluded by reason.
    #[serde(flatten)]
    rows: RowCounts,
    /// Participants left out of a within-subject test (a condition without
    /// any used row), in data order.
    participants_dropped: Vec<String>,
    /// Participants in the test.
    participants_used: usize,
    /// The row rule applied.
    row_rule: RowRule,
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let test: Test = a.test.parse()?;
    let path = a.file.display().to_string();
    let rows = read_long(a)?;
    let long = rows.iter().map(|r| LongRow {
        subject: &r.subject,
        condition: &r.condition,
        value: r.value,
        phase: r.phase,
        success: r.success,
    });
    let rule = RowRule {
        include_practice: a.include_practice,
        include_rejected: a.include_rejected,
    };
    let (triples, rows) = select_rows(rule, long);
    if triples.is_empty() {
        anyhow::bail!(
            "{path}: no row to analyse: {} (rule: {}; see --include-practice, \
             --include-rejected)",
            rows.sentence(),
            rule.describe()
        );
    }
    let design = Design::from_long(triples).map_err(|e| anyhow::anyhow!("{path}: {e}"))?;
    let (report, dropped) = analyse(&design, test).map_err(|e| {
        anyhow::anyhow!(
            "{path}: {e} ({}; rule: {})",
            rows.sentence(),
            rule.describe()
        )
    })?;
    let out = Output {
        participants_used: design.subjects().len() - dropped.len(),
        report,
        rows,
        participants_dropped: dropped,
        row_rule: rule,
    };
    emit(a.json, &out, || human(&out, a))
}

/// One row of the long table, as the row rule reads it.
struct Owned {
    subject: String,
    condition: String,
    value: Option<f64>,
    phase: Option<Phase>,
    success: Option<bool>,
}

/// The file's rows: subject, condition and DV (empty, NA or NaN: missing),
/// and `phase` / `success` when the file has them (and they are not one of
/// those three).
fn read_long(a: &Args) -> Result<Vec<Owned>, CsvError> {
    let mut reader = CsvReader::open(&a.file, Limits::default())?;
    let header = reader.header();
    let i_subject = header.require(&a.subject)?;
    let i_within = header.require(&a.within)?;
    let i_dv = header.require(&a.dv)?;
    let named = [&a.subject, &a.within, &a.dv];
    let optional = |name: &str| {
        header
            .position(name)
            .filter(|_| !named.iter().any(|n| n.as_str() == name))
    };
    let i_phase = optional("phase");
    let i_success = optional("success");
    let mut rows = Vec::new();
    while let Some(row) = reader.next_row()? {
        let phase = i_phase
            .map(|i| parse_phase(row.text(i)).map_err(|e| row.error(i, e)))
            .transpose()?;
        let success = i_success
            .map(|i| parse_success(row.text(i)).map_err(|e| row.error(i, e)))
            .transpose()?;
        rows.push(Owned {
            subject: row.text(i_subject).to_owned(),
            condition: row.text(i_within).to_owned(),
            value: row.value(i_dv)?,
            phase,
            success,
        });
    }
    Ok(rows)
}

fn ci(c: Option<[f64; 2]>) -> String {
    c.map_or("n/a".into(), |[lo, hi]| format!("[{lo:.4}, {hi:.4}]"))
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("undefined".into(), |x| format!("{x:.digits$}"))
}

fn human(o: &Output, a: &Args) -> String {
    let mut s = format!(
        "{} ~ {} | {}\nrows: {} ({})\nparticipants: {}",
        a.dv,
        a.within,
        a.subject,
        o.rows.sentence(),
        o.row_rule.describe(),
        o.participants_used
    );
    if o.participants_dropped.is_empty() {
        s.push('\n');
    } else {
        s += &format!(
            "; dropped (a condition without data): {}\n",
            o.participants_dropped.join(", ")
        );
    }
    s + &match &o.report {
        TestReport::Oneway(o) => format!(
            "one-way ANOVA: F({}, {}) = {:.4}, p = {:.6}; η² = {:.4}, 95% CI {}\n",
            o.df1,
            o.df2,
            o.f,
            o.p,
            o.eta2,
            ci(o.eta2_ci)
        ),
        TestReport::Rm(o) => format!(
            "repeated-measures ANOVA: F({}, {}) = {:.4}, p = {:.6}\n\
             Greenhouse–Geisser ε = {:.4} (p = {:.6}); Huynh–Feldt ε = {:.4} (p = {:.6})\n\
             Mauchly W = {}, p = {}; partial η² = {:.4}, 95% CI {}; generalised η² = {:.4}\n",
            o.df1,
            o.df2,
            o.f,
            o.p,
            o.eps_gg,
            o.p_gg,
            o.eps_hf,
            o.p_hf,
            o.mauchly_w.map_or("n/a".into(), |w| format!("{w:.4}")),
            o.mauchly_p.map_or("n/a".into(), |p| format!("{p:.4}")),
            o.np2,
            ci(o.np2_ci),
            o.ng2
        ),
        TestReport::Friedman(o) => format!(
            "Friedman: χ²({}) = {:.4}, p = {:.6}; Kendall's W = {:.4}, 95% CI {}\n",
            o.df,
            o.chi2,
            o.p,
            o.kendall_w,
            ci(o.kendall_w_ci)
        ),
        TestReport::Pairwise(p) => {
            let mut t = String::from(
                "pair      mean diff [95% CI]              t        df   p        p_holm   \
                 W        p_W      p_W,holm d_z [95% CI]\n",
            );
            for r in &p.pairs {
                t += &format!(
                    "{:<9} {:>9.4} {:<22} {:>8} {:>4} {:>8} {:>8} {:>8} {:>8} {:>8} {} {}\n",
                    format!("{}–{}", r.a, r.b),
                    r.mean_diff,
                    ci(r.mean_diff_ci),
                    opt(r.t, 3),
                    r.df.map_or("-".into(), |d| format!("{d}")),
                    opt(r.p, 5),
                    opt(r.p_holm, 5),
                    opt(r.wilcoxon_w, 1),
                    opt(r.wilcoxon_p, 5),
                    opt(r.wilcoxon_p_holm, 5),
                    opt(r.dz, 3),
                    ci(r.dz_ci)
                );
                for u in &r.undefined {
                    t += &format!("  {}–{} undefined: {u}\n", r.a, r.b);
                }
            }
            t + "Holm's correction within each family over the pairs where the test is defined\n"
        }
        TestReport::Describe(d) => {
            let mut t = String::from("condition  n     mean        SD          median      IQR\n");
            for c in &d.conditions {
                t += &format!(
                    "{:<10} {:<5} {:<11.5} {:<11} {:<11.5} {:.5} ({:.5}–{:.5})\n",
                    c.condition,
                    c.n,
                    c.mean,
                    opt(c.sd, 5),
                    c.median,
                    c.iqr,
                    c.q1,
                    c.q3
                );
            }
            t + "over the participants' cell means\n"
        }
    }
}
