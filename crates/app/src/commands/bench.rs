//! `kilotouch bench`: quick speed figures of the hot paths.
//!
//! These are the numbers a user can reproduce in seconds on their machine;
//! the criterion benches (`cargo bench -p kilotouch-dsp`) give distributions.
//! Each figure is the best of several repetitions (the least disturbed run).

use crate::output::emit;
use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use kilotouch_dsp::spectral::{WelchConfig, welch};
use kilotouch_rig::coupling::{ClosedLoop, Coupling};
use kilotouch_rig::plant::PlantInput;
use kilotouch_rig::tweezer::{SimTweezer, Tweezer, TweezerParams};
use kilotouch_rig::{DualStagePlant, Integrator, RigConfig, SimRig};
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
    /// Two-axis dual-stage plant, exact zero-order hold: ns per step.
    pub plant_ns_per_step: f64,
    /// Optical tweezer in free space (exact Ornstein–Uhlenbeck step): ns per step.
    pub tweezer_ns_per_step: f64,
    /// Closed loop, D mode (chain + plant + sensor + tweezer + coupling): ns per sample.
    pub closed_loop_ns_per_sample: f64,
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

    let cfg = RigConfig::default();
    let drive = |k: usize| 0.3 * (k as f64 * 0.0731).sin();
    let mut plant = DualStagePlant::new(&cfg, Integrator::Zoh)?;
    let plant_t = best_of(a.reps, || {
        plant.reset();
        let mut acc = 0.0;
        for k in 0..N {
            let out = plant.step(&PlantInput {
                force_n: [drive(k), -drive(k)],
                drive_v: drive(k + 3),
                ..Default::default()
            });
            acc += out.accel_m_s2[0];
        }
        black_box(acc);
    });

    let mut tweezer = SimTweezer::new(TweezerParams::paper_default(), cfg.rig.sample_rate_hz)?;
    let tweezer_t = best_of(a.reps, || {
        tweezer.reset([0.0, 0.0]);
        let mut acc = 0.0;
        for k in 0..N {
            acc += tweezer.step([1e-9 * drive(k), 0.0]).force_n[0];
        }
        black_box(acc);
    });

    const N_LOOP: usize = 200_000;
    let mut closed = ClosedLoop::new(
        SimRig::new(&cfg)?,
        SimTweezer::new(
            TweezerParams::from_config(&cfg.tweezer),
            cfg.rig.sample_rate_hz,
        )?,
        Coupling::from_config(&cfg)?,
    )?;
    let mut loop_err = None;
    let loop_t = best_of(a.reps, || {
        let mut acc = 0.0;
        for _ in 0..N_LOOP {
            match closed.step() {
                Ok((act, _)) => acc += act.force_n[0],
                Err(e) => {
                    loop_err = Some(e);
                    break;
                }
            }
        }
        black_box(acc);
    });
    if let Some(e) = loop_err {
        return Err(e.into());
    }

    let report = Report {
        chain_ns_per_sample: streamed / N as f64 * 1e9,
        chain_process_ns_per_sample: per_call / N as f64 * 1e9,
        chain_block_ns_per_sample: block / N as f64 * 1e9,
        welch_1e6_ms: w * 1e3,
        plant_ns_per_step: plant_t / N as f64 * 1e9,
        tweezer_ns_per_step: tweezer_t / N as f64 * 1e9,
        closed_loop_ns_per_sample: loop_t / N_LOOP as f64 * 1e9,
        n_samples: N,
        reps: a.reps,
    };
    emit(a.json, &report, || {
        format!(
            "paper chain, streamed    : {:8.3} ns/sample\n\
             paper chain, process()   : {:8.3} ns/sample\n\
             paper chain, blocks of 64: {:8.3} ns/sample\n\
             Welch 1e6 samples, 4096  : {:8.3} ms\n\
             plant (2 axes, ZOH)      : {:8.3} ns/step\n\
             tweezer (exact OU)       : {:8.3} ns/step\n\
             closed loop (D mode)     : {:8.3} ns/sample\n\
             (best of {} repetitions; build with --release for meaningful figures)\n",
            report.chain_ns_per_sample,
            report.chain_process_ns_per_sample,
            report.chain_block_ns_per_sample,
            report.welch_1e6_ms,
            report.plant_ns_per_step,
            report.tweezer_ns_per_step,
            report.closed_loop_ns_per_sample,
            report.reps
        )
    })
}
