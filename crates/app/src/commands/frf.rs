//! `kilotouch frf`: H1 frequency-response estimate with coherence.

use crate::csvio::read_columns;
use crate::output::{WelchArgs, db, emit};
use kilotouch_dsp::spectral::frf;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `kilotouch frf`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// CSV file with a header row.
    pub file: PathBuf,
    /// Input (excitation) column.
    #[arg(long)]
    pub input: String,
    /// Output (response) column.
    #[arg(long)]
    pub output: String,
    /// Sample rate and segmenting.
    #[command(flatten)]
    pub welch: WelchArgs,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// JSON document: H1 = Pxy/Pxx and γ² = |Pxy|²/(Pxx·Pyy).
#[derive(Debug, Serialize)]
pub struct Report {
    /// Frequencies, Hz.
    pub f: Vec<f64>,
    /// Real part of H1.
    pub re: Vec<f64>,
    /// Imaginary part of H1.
    pub im: Vec<f64>,
    /// Magnitude-squared coherence in [0, 1].
    pub coherence: Vec<f64>,
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let cols = read_columns(&a.file, &[a.input.as_str(), a.output.as_str()], &[])?;
    let cfg = a.welch.config();
    let e = frf(&cols.data[0], &cols.data[1], a.welch.fs, &cfg)?;
    let report = Report {
        re: e.h1.iter().map(|h| h.re).collect(),
        im: e.h1.iter().map(|h| h.im).collect(),
        f: e.f,
        coherence: e.coherence,
    };
    emit(a.json, &report, || {
        let mut t = format!(
            "H1 estimate `{}` → `{}`\n{:>12} {:>10} {:>9} {:>10}\n",
            a.input, a.output, "f [Hz]", "|H1| dB", "∠H1 °", "coherence"
        );
        for i in 0..report.f.len() {
            let h = kilotouch_dsp::C64::new(report.re[i], report.im[i]);
            t += &format!(
                "{:>12.4} {:>10.3} {:>9.2} {:>10.4}\n",
                report.f[i],
                db(h.norm()),
                h.arg().to_degrees(),
                report.coherence[i]
            );
        }
        t
    })
}
