//! `kilotouch stats`: one-way ANOVA, repeated-measures ANOVA or Friedman test
//! on a long-format CSV (one row per observation; repeats are averaged into
//! participant × condition cell means, as pingouin and R's ez do).

use crate::csvio::read_table;
use crate::output::emit;
use kilotouch_study::stats::{Test, TestReport, run_test_long};
use std::path::PathBuf;

/// Arguments of `kilotouch stats`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Long-format CSV with a header row (e.g. `trials.csv` or `cells_long.csv`).
    pub file: PathBuf,
    /// Dependent variable column (numeric).
    #[arg(long)]
    pub dv: String,
    /// Within-subject factor column (condition labels).
    #[arg(long)]
    pub within: String,
    /// Subject column (participant labels).
    #[arg(long)]
    pub subject: String,
    /// Test to run.
    #[arg(long, value_parser = ["oneway", "rm", "friedman"])]
    pub test: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let test: Test = a.test.parse()?;
    let t = read_table(
        &a.file,
        &[a.subject.as_str(), a.within.as_str()],
        &[a.dv.as_str()],
        &[],
    )?;
    let rows = t.text[0]
        .iter()
        .zip(&t.text[1])
        .zip(&t.data[0])
        .map(|((s, c), &v)| (s.as_str(), c.as_str(), v));
    let report =
        run_test_long(rows, test).map_err(|e| anyhow::anyhow!("{}: {e}", a.file.display()))?;
    emit(a.json, &report, || human(&report, a))
}

fn human(r: &TestReport, a: &Args) -> String {
    let head = format!("{} ~ {} | {}\n", a.dv, a.within, a.subject);
    head + &match r {
        TestReport::Oneway(o) => format!(
            "one-way ANOVA: F({}, {}) = {:.4}, p = {:.6}\n",
            o.df1, o.df2, o.f, o.p
        ),
        TestReport::Rm(o) => format!(
            "repeated-measures ANOVA: F({}, {}) = {:.4}, p = {:.6}\n\
             Greenhouse–Geisser ε = {:.4} (p = {:.6}); Huynh–Feldt ε = {:.4} (p = {:.6})\n\
             Mauchly W = {}, p = {}; partial η² = {:.4}; generalised η² = {:.4}\n",
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
            o.ng2
        ),
        TestReport::Friedman(o) => format!(
            "Friedman: χ²({}) = {:.4}, p = {:.6}; Kendall's W = {:.4}\n",
            o.df, o.chi2, o.p, o.kendall_w
        ),
    }
}
