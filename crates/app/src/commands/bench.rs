//! `kilotouch bench`: quick speed figures of the hot paths.
//!
//! These are the numbers a user can reproduce in seconds on their machine;
//! the criterion benches (`cargo bench -p kilotouch-dsp`) give distributions.
//! Each figure is the best of several repetitions (the least disturbed run).

use crate::output::emit;
use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use kilotouch_dsp::spectral::{WelchConfig, welch};
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::plant::PlantInput;
use kilotouch_rig::realtime::{load_average, thread_cpu_ns};
use kilotouch_rig::tweezer::{SimTweezer, Tweezer, TweezerParams};
use kilotouch_rig::{DualStagePlant, Integrator, RigConfig};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;
use std::hint::black_box;
use std::time::Instant;

/// Arguments of `kilotouch bench`.
#[derive(Debug, clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct Args {
    /// A benchmark of its own instead of the speed figures.
    #[command(subcommand)]
    pub command: Option<BenchCommand>,
    /// Repetitions per figure (the best is reported).
    #[arg(long, default_value_t = 7)]
    pub reps: usize,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Instead of the speed figures: run the paced engine on the simulated
    /// rig for this many seconds with a busy GUI thread and report its
    /// deadline misses next to those of an idle thread on the same schedule
    /// (does this machine keep the engine on time? 60 is a good choice).
    #[arg(long, value_name = "SECONDS")]
    pub paced: Option<f64>,
    /// Rig file for `--paced` (default: the built-in rig).
    #[arg(long, value_name = "FILE", requires = "paced")]
    pub rig_config: Option<std::path::PathBuf>,
    /// `--paced`: run it twice in one go, without and then with the Lab
    /// Streaming Layer outlets on (1 kHz signal stream), and report both.
    #[cfg(feature = "lsl")]
    #[arg(long, requires = "paced")]
    pub lsl: bool,
    /// Instead of the speed figures: hardware in the loop against the
    /// simulation. The paper's protocol runs through `study simulate` and,
    /// sitting by sitting, through `study run` on the DAQ emulator hosting
    /// the same simulated participants; each condition's success rate,
    /// time, force, displacement error and contact fraction are compared
    /// (within 2.5 pooled SE). Takes about 10 min per participant of real
    /// time divided by `--speed`.
    #[arg(long, conflicts_with = "paced")]
    pub hil: bool,
    /// `--hil`: participants (10 test trials per condition each).
    #[arg(long, default_value_t = 6, requires = "hil")]
    pub participants: usize,
    /// `--hil`: the study seed.
    #[arg(long, default_value_t = 1, requires = "hil")]
    pub seed: u64,
    /// `--hil`: the emulator's clock speed (1 = real time; the loop delay
    /// in samples is the same at any speed).
    #[arg(long, default_value_t = 4.0, requires = "hil")]
    pub speed: f64,
    /// `--hil`: folder for both studies (default: a new temporary folder,
    /// kept and named in the report).
    #[arg(long, requires = "hil")]
    pub out: Option<std::path::PathBuf>,
    /// `--hil`: the tweezer live too — the tweezer emulator serving the
    /// paper's micro-world (`emulate tweezer --protocol paper`) beside the
    /// DAQ emulator, block-synchronous (no command lead), in every sitting.
    #[arg(long, requires = "hil")]
    pub live_tweezer: bool,
}

/// Benchmarks of `kilotouch bench` with arguments of their own.
#[derive(Debug, clap::Subcommand)]
pub enum BenchCommand {
    /// Speed against error of the simulation's fidelity levels (full,
    /// scene, draft): the same cohort at each level; CPU time per trial and
    /// participant, speed-up over full, each metric's difference from full
    /// in pooled SE, the power analysis's n per level; a frontier plot and
    /// JSON under --out.
    Fidelity(super::bench_fidelity::FidelityArgs),
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
    /// Two-axis dual-stage plant, exact zero-order hold: ns per step (best of
    /// many 20 000-step runs, like the closed loop).
    pub plant_ns_per_step: f64,
    /// Optical tweezer in free space (exact Ornstein–Uhlenbeck step): ns per
    /// step (best of many 20 000-step runs).
    pub tweezer_ns_per_step: f64,
    /// Closed loop, D mode (chain + plant + sensor + tweezer + coupling), default
    /// scene: ns per sample, wall clock, best of many 20 000-sample runs (short
    /// enough to fit between two preemptions on a loaded machine).
    pub closed_loop_ns_per_sample: f64,
    /// The same closed loop in thread CPU time (Linux `schedstat`; time spent
    /// descheduled does not count): ns per sample, mean over all the runs.
    /// Close to the wall figure on an idle machine; `null` where unavailable.
    pub closed_loop_cpu_ns_per_sample: Option<f64>,
    /// 1-minute load average while benchmarking (Linux; `null` elsewhere).
    pub load_average: Option<f64>,
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
    if let Some(BenchCommand::Fidelity(f)) = &a.command {
        return super::bench_fidelity::run(f);
    }
    if let Some(seconds) = a.paced {
        return run_paced(a, seconds);
    }
    if a.hil {
        let out = match &a.out {
            Some(p) => p.clone(),
            None => std::env::temp_dir().join(format!(
                "kilotouch-bench-hil-{}-{}",
                std::process::id(),
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_secs())
            )),
        };
        let report = super::bench_hil::run(&super::bench_hil::HilBench {
            participants: a.participants,
            seed: a.seed,
            speed: a.speed,
            live_tweezer: a.live_tweezer,
            out,
            threads: std::thread::available_parallelism().map_or(1, usize::from),
        })?;
        emit(a.json, &report, || report.describe())?;
        if !report.all_agree {
            anyhow::bail!("hardware in the loop and the simulation differ (see the table)");
        }
        return Ok(());
    }
    let x = white_noise(N, 1);
    let chain = chain_figures(&x, a.reps)?;
    let welch_1e6_ms = welch_figure(&x, a.reps)? * 1e3;
    let rig = rig_figures(10 * a.reps.max(1))?;
    let report = Report {
        chain_ns_per_sample: chain.streamed / N as f64 * 1e9,
        chain_process_ns_per_sample: chain.per_call / N as f64 * 1e9,
        chain_block_ns_per_sample: chain.block / N as f64 * 1e9,
        welch_1e6_ms,
        plant_ns_per_step: rig.plant / N_RIG as f64 * 1e9,
        tweezer_ns_per_step: rig.tweezer / N_RIG as f64 * 1e9,
        closed_loop_ns_per_sample: rig.closed_loop / N_RIG as f64 * 1e9,
        closed_loop_cpu_ns_per_sample: rig.closed_loop_cpu,
        load_average: load_average(),
        n_samples: N,
        reps: a.reps,
    };
    emit(a.json, &report, || report.describe())
}

/// Samples of the chain and Welch figures.
const N: usize = 1_000_000;

/// Steps per rig run: many short runs (≈ 1–2 ms each), the best one
/// reported — the least disturbed by other processes on a shared machine.
const N_RIG: usize = 20_000;

/// Best wall times of the paper's chain over `x`, s.
struct ChainTimes {
    streamed: f64,
    per_call: f64,
    block: f64,
}

/// The paper's chain streamed, called per sample and run in blocks of 64.
fn chain_figures(x: &[f64], reps: usize) -> anyhow::Result<ChainTimes> {
    let coeffs = ChainCoefficients::paper()?;
    let mut chain = Chain::new(&coeffs);
    let streamed = best_of(reps, || {
        chain.reset();
        let mut acc = 0.0;
        chain.stream(x.iter().map(|&v| black_box(v)), |l, h| acc += l + h);
        black_box(acc);
    });
    let per_call = best_of(reps, || {
        chain.reset();
        let mut acc = 0.0;
        for &v in x {
            let (l, h) = chain.process(black_box(v));
            acc += l + h;
        }
        black_box(acc);
    });
    let mut low = vec![0.0; 64];
    let mut high = vec![0.0; 64];
    let block = best_of(reps, || {
        chain.reset();
        for blk in x.chunks(64) {
            let n = blk.len();
            chain.process_block(black_box(blk), &mut low[..n], &mut high[..n]);
            black_box((&low, &high));
        }
    });
    Ok(ChainTimes {
        streamed,
        per_call,
        block,
    })
}

/// Best wall time of a Welch PSD of `x` (nperseg 4096, 50 % overlap), s.
fn welch_figure(x: &[f64], reps: usize) -> anyhow::Result<f64> {
    let cfg = WelchConfig::new(4096);
    let mut err = None;
    let w = best_of(reps, || {
        if let Err(e) = welch(black_box(x), 10_000.0, &cfg) {
            err = Some(e);
        }
    });
    match err {
        Some(e) => Err(e.into()),
        None => Ok(w),
    }
}

/// Best wall times of [`N_RIG`] steps of the plant, the tweezer and the
/// closed loop, s; the loop's thread CPU time, ns per sample.
struct RigTimes {
    plant: f64,
    tweezer: f64,
    closed_loop: f64,
    closed_loop_cpu: Option<f64>,
}

/// The default rig's plant, tweezer and D-mode closed loop, each the best of
/// `reps` runs of [`N_RIG`] steps; the drive signal is precomputed (no libm
/// call in the timed loops).
fn rig_figures(reps: usize) -> anyhow::Result<RigTimes> {
    let cfg = RigConfig::default();
    let table: Vec<f64> = (0..4096).map(|k| 0.3 * (k as f64 * 0.0731).sin()).collect();
    let drive = |k: usize| table[k & 4095];
    let mut plant = DualStagePlant::new(&cfg, Integrator::Zoh)?;
    let mut k0 = 0;
    let plant_t = best_of(reps, || {
        let mut acc = 0.0;
        for k in k0..k0 + N_RIG {
            let out = plant.step(&PlantInput {
                force_n: [drive(k), -drive(k)],
                drive_v: drive(k + 3),
                ..Default::default()
            });
            acc += out.accel_m_s2[0];
        }
        k0 += N_RIG;
        black_box(acc);
    });

    let mut tweezer = SimTweezer::new(TweezerParams::paper_default(), cfg.rig.sample_rate_hz)?;
    let mut k0 = 0;
    let tweezer_t = best_of(reps, || {
        let mut acc = 0.0;
        for k in k0..k0 + N_RIG {
            acc += tweezer.step([1e-9 * drive(k), 0.0]).force_n[0];
        }
        k0 += N_RIG;
        black_box(acc);
    });

    let (loop_t, loop_cpu) = closed_loop_figure(&cfg, reps)?;
    Ok(RigTimes {
        plant: plant_t,
        tweezer: tweezer_t,
        closed_loop: loop_t,
        closed_loop_cpu: loop_cpu,
    })
}

/// Best wall time of [`N_RIG`] closed-loop samples (D mode, default scene),
/// s, and the thread CPU time over all runs, ns per sample. Out of line, so
/// that the loop's code does not depend on the figures timed around it.
#[inline(never)]
fn closed_loop_figure(cfg: &RigConfig, reps: usize) -> anyhow::Result<(f64, Option<f64>)> {
    let chain = LoopChain::as_designed(cfg)?;
    let clearance = Clearance::check(cfg, &chain)?;
    let mut closed = SimLoop::simulated(cfg, &chain, clearance)?;
    let mut loop_err = None;
    let cpu0 = thread_cpu_ns();
    let loop_t = best_of(reps, || {
        let mut acc = 0.0;
        for _ in 0..N_RIG {
            match closed.step() {
                Ok(s) => acc += s.command.force_n[0],
                Err(e) => {
                    loop_err = Some(e);
                    break;
                }
            }
        }
        black_box(acc);
    });
    // Thread CPU time over all runs (the kernel updates it at scheduler
    // ticks: only the total over ≈ 0.1 s is meaningful).
    let loop_cpu = match (cpu0, thread_cpu_ns()) {
        (Some(a0), Some(a1)) if a1 > a0 => Some((a1 - a0) as f64 / (reps * N_RIG) as f64),
        _ => None,
    };
    if let Some(e) = loop_err {
        return Err(e.into());
    }
    Ok((loop_t, loop_cpu))
}

impl Report {
    /// The figures as text, one per line.
    pub fn describe(&self) -> String {
        let or_na = |v: Option<f64>, digits: usize| {
            v.map_or("n/a".to_string(), |v| format!("{v:.digits$}"))
        };
        format!(
            "paper chain, streamed    : {:8.3} ns/sample\n\
             paper chain, process()   : {:8.3} ns/sample\n\
             paper chain, blocks of 64: {:8.3} ns/sample\n\
             Welch 1e6 samples, 4096  : {:8.3} ms\n\
             plant (2 axes, ZOH)      : {:8.3} ns/step\n\
             tweezer (exact OU)       : {:8.3} ns/step\n\
             closed loop (D mode)     : {:8.3} ns/sample ({} ns/sample CPU)\n\
             (best of {} repetitions; load average {}; build with --release for meaningful figures)\n",
            self.chain_ns_per_sample,
            self.chain_process_ns_per_sample,
            self.chain_block_ns_per_sample,
            self.welch_1e6_ms,
            self.plant_ns_per_step,
            self.tweezer_ns_per_step,
            self.closed_loop_ns_per_sample,
            or_na(self.closed_loop_cpu_ns_per_sample, 3),
            self.reps,
            or_na(self.load_average, 2),
        )
    }
}

/// `kilotouch bench --paced S` ([`crate::engine::soak`]).
fn run_paced(a: &Args, seconds: f64) -> anyhow::Result<()> {
    use crate::engine::EngineOptions;
    use crate::engine::soak::run_soak;
    if !(seconds.is_finite() && seconds >= 1.0) {
        anyhow::bail!("--paced: give at least 1 second (got {seconds})");
    }
    let cfg = RigConfig::load_or_default(a.rig_config.as_ref())?;
    let mut bar = super::progress::Progress::new("s of the paced run");
    let total = seconds.ceil() as usize;
    let report = run_soak(&cfg, EngineOptions::default(), seconds, &mut |f| {
        bar.count(((f * seconds).floor() as usize).min(total), total);
    })?;
    drop(bar);
    #[cfg(feature = "lsl")]
    if a.lsl {
        use crate::engine::EngineError;
        let mut bar = super::progress::Progress::new("s of the paced run with LSL");
        let mut attach = |h: &crate::engine::EngineHandle| {
            let id = crate::lsl::LslIdentity {
                study: "bench".to_owned(),
                participant: String::new(),
                id_width: 2,
            };
            h.start_lsl(1000.0, id)
                .map(|p| Box::new(p) as Box<dyn std::fmt::Debug>)
                .map_err(|e| EngineError::Rig(kilotouch_rig::RigError::Device(e.to_string())))
        };
        let with = crate::engine::soak::run_soak_with(
            &cfg,
            EngineOptions::default(),
            seconds,
            &mut |f| bar.count(((f * seconds).floor() as usize).min(total), total),
            &mut attach,
        )?;
        drop(bar);
        let both = serde_json::json!({ "without_lsl": report, "with_lsl": with });
        return emit(a.json, &both, || {
            format!(
                "without LSL:\n{}\nwith LSL (1 kHz signal stream):\n{}",
                report.describe(),
                with.describe()
            )
        });
    }
    emit(a.json, &report, || report.describe())
}
