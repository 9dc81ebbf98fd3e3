//! `kilotouch psd`: Welch power spectral density of one CSV column.

use crate::output::{WelchArgs, emit};
use kilotouch_dsp::spectral::welch;
use kilotouch_study::csvio::read_columns;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `kilotouch psd`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// CSV file with a header row.
    pub file: PathBuf,
    /// Column to analyse.
    #[arg(long)]
    pub column: String,
    /// Sample rate and segmenting.
    #[command(flatten)]
    pub welch: WelchArgs,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// JSON document: one-sided density in unit²/Hz.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Frequencies, Hz.
    pub f: Vec<f64>,
    /// One-sided PSD, unit²/Hz.
    pub psd: Vec<f64>,
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let cols = read_columns(&a.file, &[a.column.as_str()], &[])?;
    let x = &cols.data[0];
    let cfg = a.welch.config();
    let s = welch(x, a.welch.fs, &cfg)?;
    let report = Report { f: s.f, psd: s.p };
    emit(a.json, &report, || {
        let mut t = format!(
            "Welch PSD of `{}` ({} samples, {} segments, nperseg {})\n{:>12} {:>14}\n",
            a.column,
            x.len(),
            s.n_segments,
            a.welch.nperseg,
            "f [Hz]",
            "PSD [u²/Hz]"
        );
        for (f, p) in report.f.iter().zip(&report.psd) {
            t += &format!("{f:>12.4} {p:>14.6e}\n");
        }
        t
    })
}
