//! `kilotouch crossover`: response of the digital Linkwitz–Riley crossover.

use crate::output::{db, emit, parse_freqs, wrap_deg};
use kilotouch_dsp::crossover::LinkwitzRiley;
use serde::Serialize;

/// Arguments of `kilotouch crossover`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Sample rate in Hz.
    #[arg(long)]
    pub fs: f64,
    /// Crossover frequency in Hz (0 < fc < fs/2).
    #[arg(long)]
    pub fc: f64,
    /// Linkwitz–Riley order.
    #[arg(long, default_value_t = 4, value_parser = parse_order)]
    pub order: u32,
    /// Comma-separated evaluation frequencies in Hz.
    #[arg(long)]
    pub freqs: String,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Accept only the implemented Linkwitz–Riley orders.
fn parse_order(s: &str) -> Result<u32, String> {
    match s.trim() {
        "2" => Ok(2),
        "4" => Ok(4),
        "8" => Ok(8),
        other => Err(format!(
            "`{other}` is not a supported order (use 2, 4 or 8)"
        )),
    }
}

/// One evaluation point.
#[derive(Debug, Serialize)]
pub struct Point {
    /// Frequency, Hz.
    pub f: f64,
    /// Low-pass magnitude, dB.
    pub low_db: f64,
    /// Low-pass phase, degrees in (−180, 180].
    pub low_deg: f64,
    /// High-pass magnitude, dB.
    pub high_db: f64,
    /// High-pass phase, degrees.
    pub high_deg: f64,
    /// Sum magnitude, dB.
    pub sum_db: f64,
    /// Sum phase, degrees.
    pub sum_deg: f64,
}

/// JSON document.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Points in the order given.
    pub points: Vec<Point>,
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let freqs = parse_freqs(&a.freqs)?;
    let xo = LinkwitzRiley::new(a.order as usize, a.fc, a.fs)?;
    let points: Vec<Point> = freqs
        .iter()
        .map(|&f| {
            let (l, h) = xo.response(f);
            let s = l + h;
            Point {
                f,
                low_db: db(l.norm()),
                low_deg: wrap_deg(l.arg().to_degrees()),
                high_db: db(h.norm()),
                high_deg: wrap_deg(h.arg().to_degrees()),
                sum_db: db(s.norm()),
                sum_deg: wrap_deg(s.arg().to_degrees()),
            }
        })
        .collect();
    let report = Report { points };
    emit(a.json, &report, || {
        let mut t = format!(
            "LR{} crossover, fc = {} Hz, fs = {} Hz\n{:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}\n",
            a.order,
            a.fc,
            a.fs,
            "f [Hz]",
            "low dB",
            "low °",
            "high dB",
            "high °",
            "sum dB",
            "sum °"
        );
        for p in &report.points {
            t += &format!(
                "{:>10.3} {:>9.3} {:>9.2} {:>9.3} {:>9.2} {:>9.4} {:>9.2}\n",
                p.f, p.low_db, p.low_deg, p.high_db, p.high_deg, p.sum_db, p.sum_deg
            );
        }
        t
    })
}
