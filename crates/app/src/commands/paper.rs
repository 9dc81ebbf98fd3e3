//! `kilotouch paper`: regenerate the paper's Figs. 4, 5, 7, 9, 10, 11 and
//! 12 from the simulator, write their data and `report.md`, and check the
//! paper's claims (exit status 1 when one fails). The work is in
//! [`crate::paper`]; this file is the command line.

use std::path::PathBuf;

use super::progress::Progress;
use anyhow::Context;
use kilotouch_rig::config::RigConfig;

use crate::output::emit;
use crate::paper::{PaperOptions, PaperReport, fmt_measured, run};

/// Arguments of `kilotouch paper`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder (created; figures, CSV data, report.md and the two
    /// simulated study folders go here).
    #[arg(long)]
    pub out: PathBuf,
    /// Quick mode: smaller studies and shorter records (about 2 minutes on
    /// 2 cores, release build); the default is the paper's protocol.
    #[arg(long)]
    pub quick: bool,
    /// Seed of every random generator (rig noise, simulated operators,
    /// study plans).
    #[arg(long, default_value_t = 2016)]
    pub seed: u64,
    /// Rig file (default: the built-in rig).
    #[arg(long)]
    pub rig_config: Option<PathBuf>,
    /// Worker threads of the study simulations (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

fn human(r: &PaperReport) -> String {
    let mut s = format!(
        "{} figures in {} ({} mode, seed {}, {:.0} s)\n",
        r.figures.len(),
        r.out.display(),
        if r.quick { "quick" } else { "full" },
        r.seed,
        r.wall_s
    );
    for c in &r.claims {
        s.push_str(&format!(
            "  [{}] Fig. {:>2}: {} = {} {}\n",
            match (c.holds, c.known_disagreement.is_some()) {
                (true, _) => " ok ",
                (false, false) => "FAIL",
                (false, true) => "know",
            },
            c.figure,
            c.claim,
            fmt_measured(c.measured),
            c.unit
        ));
    }
    s.push_str(&format!(
        "{} Report: {}\n",
        r.tally(),
        r.out.join("report.md").display()
    ));
    s
}

/// Run the command.
///
/// # Errors
/// A stage that cannot run, or a claim that does not hold (after the
/// output is written).
pub fn run_cmd(a: &Args) -> anyhow::Result<()> {
    let rig = RigConfig::load_or_default(a.rig_config.as_ref())?;
    let threads = super::protocol_arg::threads(a.threads)?;
    let opts = PaperOptions {
        out: a.out.clone(),
        quick: a.quick,
        seed: a.seed,
        rig,
        threads,
    };
    let mut bar = Progress::stages();
    let mut progress = |f: f64, msg: &str| bar.fraction(f, msg);
    let report =
        run(&opts, &mut progress).with_context(|| format!("paper into {}", a.out.display()))?;
    drop(bar);
    emit(a.json, &report, || human(&report))?;
    if report.failed > 0 {
        anyhow::bail!(
            "{} of {} claims of the paper do not hold (see {})",
            report.failed,
            report.claims.len(),
            a.out.join("report.md").display()
        );
    }
    Ok(())
}
