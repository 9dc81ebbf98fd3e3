//! `kilotouch frf`: H1 frequency-response estimate with coherence.
//!
//! H1 = Pxy/Pxx is undefined where the input has no power: such bins are
//! reported as `null` (JSON) or `undefined` (table), never as the 0 or ∞ of
//! a 0/0, and an input without power at any frequency is an error.

use crate::output::{WelchArgs, db, emit};
use kilotouch_dsp::spectral::frf;
use kilotouch_study::csvio::read_columns;
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

/// A bin has no input power when its share of the input's power,
/// Pxx·Δf / mean(x²), is at most this (−200 dB: below it a bin holds only
/// the rounding residue of the detrending and the FFT, ≈ −300 dB in f64).
pub const NO_INPUT_POWER: f64 = 1e-20;

/// JSON document: H1 = Pxy/Pxx and γ² = |Pxy|²/(Pxx·Pyy); `null` where the
/// input has no power ([`NO_INPUT_POWER`]).
#[derive(Debug, Serialize)]
pub struct Report {
    /// Frequencies, Hz.
    pub f: Vec<f64>,
    /// Real part of H1 (`null`: undefined, no input power).
    pub re: Vec<Option<f64>>,
    /// Imaginary part of H1 (`null`: undefined).
    pub im: Vec<Option<f64>>,
    /// Magnitude-squared coherence in [0, 1] (`null`: undefined).
    pub coherence: Vec<Option<f64>>,
    /// Number of bins where H1 is undefined.
    pub undefined_bins: usize,
    /// Why those bins are undefined (`null` when none is).
    pub undefined_reason: Option<String>,
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let cols = read_columns(&a.file, &[a.input.as_str(), a.output.as_str()], &[])?;
    let cfg = a.welch.config();
    let x = &cols.data[0];
    let e = frf(x, &cols.data[1], a.welch.fs, &cfg)?;
    let mean_square = x.iter().map(|v| v * v).sum::<f64>() / x.len().max(1) as f64;
    let df = e.f.get(1).map_or(a.welch.fs, |f1| f1 - e.f[0]);
    let defined: Vec<bool> = e
        .pxx
        .iter()
        .map(|&p| p * df > NO_INPUT_POWER * mean_square)
        .collect();
    let undefined_bins = defined.iter().filter(|d| !**d).count();
    if undefined_bins == defined.len() {
        anyhow::bail!(
            "{}: input column `{}` has no power at any frequency (all zero, or constant): \
             H1 = Pxy/Pxx is undefined; check the --input column",
            a.file.display(),
            a.input
        );
    }
    let keep = |v: f64, k: usize| defined[k].then_some(v);
    let report = Report {
        re: e
            .h1
            .iter()
            .enumerate()
            .map(|(k, h)| keep(h.re, k))
            .collect(),
        im: e
            .h1
            .iter()
            .enumerate()
            .map(|(k, h)| keep(h.im, k))
            .collect(),
        coherence: e
            .coherence
            .iter()
            .enumerate()
            .map(|(k, &c)| keep(c, k))
            .collect(),
        f: e.f,
        undefined_bins,
        undefined_reason: (undefined_bins > 0).then(|| {
            format!(
                "no input power in {undefined_bins} bin(s) (Pxx·Δf ≤ {NO_INPUT_POWER:e} of the \
                 input's mean square): H1 = Pxy/Pxx is 0/0 there"
            )
        }),
    };
    emit(a.json, &report, || human(a, &report))
}

fn human(a: &Args, report: &Report) -> String {
    let mut t = format!(
        "H1 estimate `{}` → `{}`\n{:>12} {:>10} {:>9} {:>10}\n",
        a.input, a.output, "f [Hz]", "|H1| dB", "∠H1 °", "coherence"
    );
    for i in 0..report.f.len() {
        match (report.re[i], report.im[i], report.coherence[i]) {
            (Some(re), Some(im), Some(c)) => {
                let h = kilotouch_dsp::C64::new(re, im);
                t += &format!(
                    "{:>12.4} {:>10.3} {:>9.2} {:>10.4}\n",
                    report.f[i],
                    db(h.norm()),
                    h.arg().to_degrees(),
                    c
                );
            }
            _ => {
                t += &format!(
                    "{:>12.4} {:>10} {:>9} {:>10}\n",
                    report.f[i], "undefined", "", ""
                )
            }
        }
    }
    if let Some(why) = &report.undefined_reason {
        t += &format!("undefined: {why}\n");
    }
    t
}
