//! `kilotouch bench`: quick speed figures of the hot paths.
//!
//! These are the numbers a user can reproduce in seconds on their machine;
//! the criterion benches (`cargo bench -p kilotouch-dsp`) give distributions.
//! Each figure is the best of several repetitions (the least disturbed run).

use crate::output::emit;
use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use kilotouch_dsp::spectral::{WelchConfig, welch};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;
use std::hint::black_box;
use std::time::Instant;

/// Arguments of `kilotouch bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Repetitions per figure (the best is reported).
    #[arg(long, default_value_t = 7)]
    pub reps: usize,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// JSON document.
#[derive(Debug, Serialize)]
pub struct Report {
    /// The paper's chain (LR4 at 200 Hz + C_L + C_H with the paper's G_H),
    /// streamed sample by sample over 1e6 samples (`Chain::stream`: one input
    /// sample in, one output pair out, state kept in registers): ns per sample.
    pub chain_ns_per_sample: f64,
    /// The same chain, one `Chain::process` call per sample (state reloaded
    /// from memory on every call): ns per sample.
    pub chain_process_ns_per_sample: f64,
    /// The same chain through the block API (blocks of 64, as the real-time
    /// engine runs it): ns per sample.
    pub chain_block_ns_per_sample: f64,
    /// Welch PSD of 1e6 samples, nperseg 4096, 50 % overlap: ms.
    pub welch_1e6_ms: f64,
    /// Samples used.
    pub n_samples: usize,
    /// Repetitions per figure.
    pub reps: usize,
}

fn best_of<F: FnMut()>(reps: usize, mut f: F) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        f();
        best = best.min(t.elapsed().as_secs_f64());
    }
    best
}

/// Gaussian white noise, seeded.
pub fn white_noise(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
}

/// Run the command.
pub fn run(a: &Args) -> anyhow::Result<()> {
    const N: usize = 1_000_000;
    let x = white_noise(N, 1);
    let coeffs = ChainCoefficients::paper()?;

    let mut chain = Chain::new(&coeffs);
    let streamed = best_of(a.reps, || {
        chain.reset();
        let mut acc = 0.0;
        chain.stream(x.iter().map(|&v| black_box(v)), |l, h| acc += l + h);
        black_box(acc);
    });
    let per_call = best_of(a.reps, || {
        chain.reset();
        let mut acc = 0.0;
        for &v in &x {
            let (l, h) = chain.process(black_box(v));
            acc += l + h;
        }
        black_box(acc);
    });

    let mut low = vec![0.0; 64];
    let mut high = vec![0.0; 64];
    let block = best_of(a.reps, || {
        chain.reset();
        for blk in x.chunks(64) {
            let n = blk.len();
            chain.process_block(black_box(blk), &mut low[..n], &mut high[..n]);
            black_box((&low, &high));
        }
    });

    let cfg = WelchConfig::new(4096);
    let mut err = None;
    let w = best_of(a.reps, || {
        if let Err(e) = welch(black_box(&x), 10_000.0, &cfg) {
            err = Some(e);
        }
    });
    if let Some(e) = err {
        return Err(e.into());
    }

    let report = Report {
        chain_ns_per_sample: streamed / N as f64 * 1e9,
        chain_process_ns_per_sample: per_call / N as f64 * 1e9,
        chain_block_ns_per_sample: block / N as f64 * 1e9,
        welch_1e6_ms: w * 1e3,
        n_samples: N,
        reps: a.reps,
    };
    emit(a.json, &report, || {
        format!(
            "paper chain, streamed    : {:8.3} ns/sample\n\
             paper chain, process()   : {:8.3} ns/sample\n\
             paper chain, blocks of 64: {:8.3} ns/sample\n\
             Welch 1e6 samples, 4096  : {:8.3} ms\n\
             (best of {} repetitions; build with --release for meaningful figures)\n",
            report.chain_ns_per_sample,
            report.chain_process_ns_per_sample,
            report.chain_block_ns_per_sample,
            report.welch_1e6_ms,
            report.reps
        )
    })
}
