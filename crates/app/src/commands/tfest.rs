//! `kilotouch tfest`: fit a continuous-time transfer function to FRF data.

use crate::output::emit;
use kilotouch_dsp::C64;
use kilotouch_dsp::fit::{FitOptions, fit_tf};
use kilotouch_study::csvio::read_columns;
use serde::Serialize;
use std::path::PathBuf;

/// Arguments of `kilotouch tfest`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// CSV with columns `f,re,im` and optionally `weight` (f in Hz).
    pub file: PathBuf,
    /// Numerator order.
    #[arg(long)]
    pub nb: usize,
    /// Denominator order.
    #[arg(long)]
    pub na: usize,
    /// Lowest frequency used, Hz.
    #[arg(long)]
    pub fmin: Option<f64>,
    /// Highest frequency used, Hz.
    #[arg(long)]
    pub fmax: Option<f64>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// A complex number for JSON.
#[derive(Debug, Serialize)]
pub struct Complex {
    /// Real part, rad/s.
    pub re: f64,
    /// Imaginary part, rad/s.
    pub im: f64,
}

/// A complex pole pair.
#[derive(Debug, Serialize)]
pub struct ModeOut {
    /// Natural frequency, Hz.
    pub wn_hz: f64,
    /// Damping ratio.
    pub zeta: f64,
}

/// JSON document.
#[derive(Debug, Serialize)]
pub struct Report {
    /// Numerator, descending powers of s.
    pub num: Vec<f64>,
    /// Denominator, descending powers of s.
    pub den: Vec<f64>,
    /// Poles, rad/s.
    pub poles: Vec<Complex>,
    /// Zeros, rad/s.
    pub zeros: Vec<Complex>,
    /// Complex pole pairs.
    pub modes: Vec<ModeOut>,
    /// G(0).
    pub dc_gain: f64,
    /// RMS of |Ĝ−H|/|H| over the fitted points.
    pub rms_rel_error: f64,
    /// Max of |Ĝ−H|/|H|.
    pub max_rel_error: f64,
    /// 2-norm condition number of the final (scaled) least-squares matrix.
    pub condition_number: f64,
    /// Sanathanan–Koerner iterations performed.
    pub iterations: usize,
    /// Whether the iterations converged.
    pub converged: bool,
    /// Points used.
    pub n_points: usize,
}

fn cx(v: &[C64]) -> Vec<Complex> {
    v.iter().map(|z| Complex { re: z.re, im: z.im }).collect()
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    let cols = read_columns(&a.file, &["f", "re", "im"], &["weight"])?;
    let f = &cols.data[0];
    let h: Vec<C64> = cols.data[1]
        .iter()
        .zip(&cols.data[2])
        .map(|(&re, &im)| C64::new(re, im))
        .collect();
    let opts = FitOptions {
        fmin_hz: a.fmin,
        fmax_hz: a.fmax,
        ..FitOptions::default()
    };
    let r = fit_tf(f, &h, cols.get("weight"), a.nb, a.na, &opts)?;
    let report = Report {
        num: r.tf.num.clone(),
        den: r.tf.den.clone(),
        poles: cx(&r.poles),
        zeros: cx(&r.zeros),
        modes: r
            .modes
            .iter()
            .map(|m| ModeOut {
                wn_hz: m.wn_hz,
                zeta: m.zeta,
            })
            .collect(),
        dc_gain: r.dc_gain,
        rms_rel_error: r.rms_rel_error,
        max_rel_error: r.max_rel_error,
        condition_number: r.condition_number,
        iterations: r.iterations,
        converged: r.converged,
        n_points: r.n_points,
    };
    emit(a.json, &report, || {
        let mut t = format!("G(s) = {}\n", r.tf);
        for m in &report.modes {
            t += &format!("mode: f_n = {:.3} Hz, ζ = {:.5}\n", m.wn_hz, m.zeta);
        }
        t += &format!(
            "DC gain {:.6e}; rms rel. error {:.3e}, max {:.3e}; cond {:.3e}; {} iterations{}\n",
            report.dc_gain,
            report.rms_rel_error,
            report.max_rel_error,
            report.condition_number,
            report.iterations,
            if report.converged {
                ""
            } else {
                " (NOT converged)"
            }
        );
        t
    })
}
