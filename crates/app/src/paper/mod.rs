//! The paper, regenerated (`kilotouch paper`): Figs. 4, 5, 7, 9, 10, 11
//! and 12 of the dual-stage paper redrawn from the code as it stands, each
//! with its data (CSV) and the paper's statements checked against what was
//! measured ([`Claim`]).
//!
//! | figure | from | module |
//! |---|---|---|
//! | 4 | the as-designed chain's crossover | [`fig4`] |
//! | 5 | `calibrate` on the simulated rig (identification) and `sim frf` | [`fig5`] |
//! | 7 | the same calibration's verification, plus each channel alone | [`fig7`] |
//! | 9 | `sim press` with a free-space hold before the approach | [`fig9`] |
//! | 10 | `study simulate` of the blind-navigation protocol | [`fig10`] |
//! | 11, 12 | `study simulate` of the paper's circling protocol, the Results page's statistics | [`study_figs`] |
//!
//! Nothing is computed twice: each figure calls the procedure the rest of
//! the program uses. What differs from the paper and why:
//! `docs/PAPER.md`.

pub mod fig10;
pub mod fig4;
pub mod fig5;
pub mod fig7;
pub mod fig9;
pub mod study_figs;
pub mod style;

use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

use kilotouch_rig::config::RigConfig;

/// Errors of the paper run.
#[derive(Debug, thiserror::Error)]
pub enum PaperError {
    /// Signal processing.
    #[error(transparent)]
    Dsp(#[from] kilotouch_dsp::DspError),
    /// Rig models and loop.
    #[error(transparent)]
    Rig(#[from] kilotouch_rig::error::RigError),
    /// Calibration procedure.
    #[error(transparent)]
    Calibration(#[from] kilotouch_rig::calibration::CalibrationError),
    /// Study simulation.
    #[error(transparent)]
    Study(#[from] kilotouch_study::runner::RunError),
    /// Study files.
    #[error("{0}")]
    Results(String),
    /// Drawing.
    #[error("{0}")]
    Draw(String),
    /// Files.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: std::io::Error,
    },
}

/// One statement of the paper beside what the simulator measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Claim {
    /// Figure number ("4", "5", …).
    pub figure: String,
    /// What is checked, in words.
    pub claim: String,
    /// What the paper says (quoted or paraphrased, with its section).
    pub paper: String,
    /// The measured value.
    pub measured: f64,
    /// Its unit.
    pub unit: String,
    /// The criterion the value must meet.
    pub criterion: String,
    /// True when it does.
    pub holds: bool,
    /// A documented disagreement of the simulation with the paper: why
    /// the claim may not hold (`docs/PAPER.md`). Such a claim is checked
    /// and reported, but when it does not hold the run does not fail.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub known_disagreement: Option<String>,
}

impl Claim {
    /// A checked claim.
    pub fn new(
        figure: &str,
        claim: &str,
        paper: &str,
        measured: f64,
        unit: &str,
        criterion: &str,
        holds: bool,
    ) -> Self {
        Self {
            figure: figure.into(),
            claim: claim.into(),
            paper: paper.into(),
            measured,
            unit: unit.into(),
            criterion: criterion.into(),
            holds: holds && measured.is_finite(),
            known_disagreement: None,
        }
    }

    /// Marks a documented disagreement with the paper (`why`).
    pub fn known_disagreement(self, why: &str) -> Self {
        Self {
            known_disagreement: Some(why.into()),
            ..self
        }
    }

    /// Whether the claim fails the run: it does not hold and is not a
    /// documented disagreement.
    pub fn fails(&self) -> bool {
        !self.holds && self.known_disagreement.is_none()
    }
}

/// The files of one figure (names relative to the output folder).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FigureFiles {
    /// Figure number.
    pub id: String,
    /// PNG.
    pub png: String,
    /// SVG.
    pub svg: String,
    /// Data (CSV).
    pub data: String,
    /// Title (report).
    pub title: String,
}

impl FigureFiles {
    fn new(id: &str, title: &str) -> Self {
        Self {
            id: id.into(),
            png: format!("fig{id}.png"),
            svg: format!("fig{id}.svg"),
            data: format!("fig{id}.csv"),
            title: title.into(),
        }
    }
}

/// What `kilotouch paper` produced (`--json`).
#[derive(Debug, Clone, Serialize)]
pub struct PaperReport {
    /// The figures, in paper order.
    pub figures: Vec<FigureFiles>,
    /// Every claim checked.
    pub claims: Vec<Claim>,
    /// Output folder.
    pub out: PathBuf,
    /// Quick mode.
    pub quick: bool,
    /// Seed.
    pub seed: u64,
    /// Claims that do not hold and are not documented disagreements
    /// ([`Claim::fails`]).
    pub failed: usize,
    /// Wall time, s.
    pub wall_s: f64,
}

/// Options of [`run`].
#[derive(Debug, Clone)]
pub struct PaperOptions {
    /// Output folder (created).
    pub out: PathBuf,
    /// Quick mode: shorter records, smaller studies (`docs/PAPER.md`).
    pub quick: bool,
    /// Seed of every random generator (rig noise, operators, studies).
    pub seed: u64,
    /// Rig file (the built-in rig by default).
    pub rig: RigConfig,
    /// Worker threads of the study simulations.
    pub threads: usize,
}

/// Observer of the run: `fraction` of the whole run done, what runs now.
pub trait PaperProgress {
    /// Report.
    fn report(&mut self, fraction: f64, message: &str);
}

impl<F: FnMut(f64, &str)> PaperProgress for F {
    fn report(&mut self, fraction: f64, message: &str) {
        self(fraction, message);
    }
}

/// Relative cost of each stage (quick mode, measured), for the progress
/// fraction.
const STAGES: [(&str, f64); 6] = [
    ("Fig. 4: crossover", 0.01),
    ("Figs. 5, 7: calibrating the simulated rig", 0.2),
    ("Fig. 7: each channel alone", 0.05),
    ("Fig. 9: free space, collision, pressing", 0.09),
    ("Fig. 10: blind-navigation study", 0.25),
    ("Figs. 11, 12: circling study", 0.4),
];

/// Progress across the stages.
struct Stages<'a> {
    p: &'a mut dyn PaperProgress,
    done: f64,
}

impl Stages<'_> {
    fn total() -> f64 {
        STAGES.iter().map(|s| s.1).sum()
    }
    /// Report `f` of stage `i`.
    fn at(&mut self, i: usize, f: f64, msg: &str) {
        let before: f64 = STAGES[..i].iter().map(|s| s.1).sum();
        let x = (before + STAGES[i].1 * f.clamp(0.0, 1.0)) / Self::total();
        self.done = x;
        self.p.report(x, &format!("{}: {msg}", STAGES[i].0));
    }
}

/// Write columns of equal length as CSV with a header.
///
/// # Errors
/// File errors.
pub fn write_csv(path: &Path, header: &[&str], cols: &[&[f64]]) -> Result<(), PaperError> {
    let io = |e: csv::Error| PaperError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e.to_string()),
    };
    let mut w = csv::Writer::from_path(path).map_err(io)?;
    w.write_record(header).map_err(io)?;
    let n = cols.iter().map(|c| c.len()).min().unwrap_or(0);
    for i in 0..n {
        w.write_record(cols.iter().map(|c| fmt_num(c[i])))
            .map_err(io)?;
    }
    w.flush().map_err(|e| PaperError::Io {
        path: path.to_path_buf(),
        source: e,
    })
}

/// A number for CSV: shortest round-trip form, empty for non-finite.
pub fn fmt_num(v: f64) -> String {
    if v.is_finite() {
        v.to_string()
    } else {
        String::new()
    }
}

/// Draw `fig` to `out/figN.png` and `.svg`.
fn save<F: style::Figure>(fig: &F, out: &Path, files: &FigureFiles) -> Result<(), PaperError> {
    style::save(fig, &out.join(&files.png), &out.join(&files.svg)).map_err(PaperError::Draw)
}

/// What [`run`] has made so far: the figures' files in `out` and their
/// claims.
struct Made<'a> {
    out: &'a Path,
    figures: Vec<FigureFiles>,
    claims: Vec<Claim>,
}

impl Made<'_> {
    /// Fig. `id` (`title`): its data written by `write_csv`, its drawing
    /// saved, its claims (from `claims`) collected, in that order.
    fn add<F: style::Figure>(
        &mut self,
        fig: &F,
        id: &str,
        title: &str,
        write_csv: impl FnOnce(&F, &Path) -> Result<(), PaperError>,
        claims: impl FnOnce(&F) -> Result<Vec<Claim>, PaperError>,
    ) -> Result<(), PaperError> {
        let files = FigureFiles::new(id, title);
        write_csv(fig, &self.out.join(&files.data))?;
        save(fig, self.out, &files)?;
        self.claims.extend(claims(fig)?);
        self.figures.push(files);
        Ok(())
    }
}

/// Regenerate every figure into `opts.out`, check the claims, write
/// `report.md`. A failed claim is reported, not an error.
///
/// # Errors
/// Any stage that cannot run (invalid rig file, files that cannot be
/// written).
pub fn run(
    opts: &PaperOptions,
    progress: &mut dyn PaperProgress,
) -> Result<PaperReport, PaperError> {
    let t0 = Instant::now();
    let out = &opts.out;
    std::fs::create_dir_all(out).map_err(|e| PaperError::Io {
        path: out.clone(),
        source: e,
    })?;
    let mut st = Stages {
        p: progress,
        done: 0.0,
    };
    let mut made = Made {
        out,
        figures: Vec::new(),
        claims: Vec::new(),
    };

    // Fig. 4.
    st.at(0, 0.0, "LR4 response");
    let f4 = fig4::Fig4::compute(&opts.rig)?;
    made.add(
        &f4,
        "4",
        "LR4 crossover: low, high and sum",
        fig4::Fig4::write_csv,
        |f| f.claims(),
    )?;
    st.at(0, 1.0, "done");

    // Figs. 5 and 7: one calibration of the simulated rig.
    let mut rig = kilotouch_rig::calibration::RigAdapter::sim(&opts.rig, Some(opts.seed))?;
    let outcome = fig5::calibrate_rig(&mut rig, &mut |f, msg: &str| st.at(1, f, msg))?;
    let f5 = fig5::Fig5::from_outcome(&opts.rig, &outcome)?;
    made.add(
        &f5,
        "5",
        "Channel responses: Welch H1 as identified, and the model",
        fig5::Fig5::write_csv,
        |f| Ok(f.claims()),
    )?;

    let f7 = fig7::Fig7::measure(&mut rig, &outcome, &mut |f, msg: &str| st.at(2, f, msg))?;
    made.add(
        &f7,
        "7",
        "Third-octave magnitudes: each channel and the compensated sum",
        fig7::Fig7::write_csv,
        |f| Ok(f.claims()),
    )?;

    // Fig. 9.
    st.at(3, 0.0, "closed loop");
    let f9 = fig9::Fig9::simulate(&opts.rig, opts.quick, opts.seed)?;
    made.add(
        &f9,
        "9",
        "Free space, collision and pressing, felt at the fingertip",
        fig9::Fig9::write_csv,
        |f| Ok(f.claims()),
    )?;
    st.at(3, 1.0, "done");

    // Fig. 10.
    let f10 = fig10::Fig10::simulate(opts, &mut |f, msg: &str| st.at(4, f, msg))?;
    made.add(
        &f10,
        "10",
        "Blind navigation: trajectories that collided",
        fig10::Fig10::write_csv,
        |f| Ok(f.claims()),
    )?;

    // Figs. 11 and 12.
    let study = study_figs::CirclingStudy::simulate(opts, &mut |f, msg: &str| st.at(5, f, msg))?;
    made.add(
        &study.fig11(),
        "11",
        "Circling study per participant (mean ± SD)",
        study_figs::Fig11::write_csv,
        |f| Ok(f.claims()),
    )?;
    made.add(
        &study.fig12(),
        "12",
        "Circling study per condition, with the statistics",
        study_figs::Fig12::write_csv,
        |f| Ok(f.claims()),
    )?;
    st.at(5, 1.0, "done");

    let Made {
        figures, claims, ..
    } = made;
    let failed = claims.iter().filter(|c| c.fails()).count();
    let report = PaperReport {
        figures,
        claims,
        out: out.clone(),
        quick: opts.quick,
        seed: opts.seed,
        failed,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    let md = report_markdown(&report);
    let path = out.join("report.md");
    std::fs::write(&path, md).map_err(|e| PaperError::Io { path, source: e })?;
    Ok(report)
}

impl PaperReport {
    /// "N of M claims hold", with the documented disagreements that do not.
    pub fn tally(&self) -> String {
        let holding = self.claims.iter().filter(|c| c.holds).count();
        let known = self
            .claims
            .iter()
            .filter(|c| !c.holds && c.known_disagreement.is_some())
            .count();
        let mut s = format!("{holding} of {} claims hold", self.claims.len());
        if known > 0 {
            s.push_str(&format!(
                "; {known} known disagreement(s) with the paper do not (docs/PAPER.md)"
            ));
        }
        s.push('.');
        s
    }
}

/// `report.md`: each figure with its claims in a table.
pub fn report_markdown(r: &PaperReport) -> String {
    let mut s = String::new();
    s.push_str("# The paper, regenerated\n\n");
    s.push_str(&format!(
        "kilotouch {} — {} mode, seed {}, {:.0} s. {}\n\n",
        env!("CARGO_PKG_VERSION"),
        if r.quick { "quick" } else { "full" },
        r.seed,
        r.wall_s,
        r.tally()
    ));
    s.push_str("How each figure is made and what differs from the paper: `docs/PAPER.md`.\n\n");
    for f in &r.figures {
        s.push_str(&format!("## Fig. {} — {}\n\n", f.id, f.title));
        s.push_str(&format!(
            "![Fig. {}]({})\n\nData: [`{}`]({}), vector: [`{}`]({})\n\n",
            f.id, f.png, f.data, f.data, f.svg, f.svg
        ));
        s.push_str("| claim | paper | measured | criterion | holds |\n|---|---|---|---|---|\n");
        for c in r.claims.iter().filter(|c| c.figure == f.id) {
            s.push_str(&format!(
                "| {} | {} | {} {} | {} | {} |\n",
                c.claim.replace('|', "\\|"),
                c.paper.replace('|', "\\|"),
                fmt_measured(c.measured),
                c.unit,
                c.criterion.replace('|', "\\|"),
                match (c.holds, &c.known_disagreement) {
                    (true, _) => "yes".to_owned(),
                    (false, None) => "**NO**".to_owned(),
                    (false, Some(why)) => format!("no — known disagreement: {why}"),
                }
            ));
        }
        s.push('\n');
    }
    s
}

/// A measured value with 4 significant digits.
pub fn fmt_measured(v: f64) -> String {
    if !v.is_finite() {
        return "n/a".into();
    }
    if v == v.round() && v.abs() < 1e6 {
        return format!("{v:.0}");
    }
    let mag = v.abs().log10().floor() as i32;
    let decimals = (3 - mag).clamp(0, 8) as usize;
    format!("{v:.decimals$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_disagreement_is_reported_but_does_not_fail_the_run() {
        let checked = Claim::new("12", "a", "paper", 0.02, "", "< 0.01", false);
        let known = checked.clone().known_disagreement("why it differs");
        let holding = Claim::new("12", "b", "paper", 0.001, "", "< 0.01", true);
        assert!(checked.fails());
        assert!(!known.fails() && !holding.fails());
        let report = PaperReport {
            figures: vec![FigureFiles::new("12", "title")],
            claims: vec![known, holding, checked],
            out: PathBuf::from("out"),
            quick: true,
            seed: 1,
            failed: 1,
            wall_s: 1.0,
        };
        assert_eq!(
            report.tally(),
            "1 of 3 claims hold; 1 known disagreement(s) with the paper do not (docs/PAPER.md)."
        );
        let md = report_markdown(&report);
        assert!(
            md.contains("| no — known disagreement: why it differs |"),
            "{md}"
        );
        assert!(md.contains("| **NO** |") && md.contains("| yes |"), "{md}");
    }
}
