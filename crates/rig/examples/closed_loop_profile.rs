//! Profile driver of the closed loop (`docs/PERFORMANCE.md`, closed loop).
//!
//! `cargo run --release -p kilotouch-rig --example closed_loop_profile -- [N] [part]`
//! runs `N` samples (default 1e6) of the default scene's closed loop in D
//! (or only one part: `plant`, `tweezer`, `accel`, `loop`) and prints the
//! thread CPU time per sample. Under
//! `valgrind --tool=callgrind` the instruction count per sample is
//! (Ir of the run with N − Ir of the run with 0) / N: repeatable on a
//! loaded machine, unlike wall or CPU time.

use kilotouch_rig::accel::Accelerometer;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::plant::{DualStagePlant, PlantInput};
use kilotouch_rig::realtime::thread_cpu_ns;
use kilotouch_rig::tweezer::{SimTweezer, Tweezer, TweezerParams};
use kilotouch_rig::{Integrator, Rig};
use std::hint::black_box;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).map_or(Ok(1_000_000), |s| s.parse())?;
    let part = args.get(2).map_or("loop", String::as_str);
    let cfg = RigConfig::default();
    let fs = cfg.rig.sample_rate_hz;
    let table: Vec<f64> = (0..4096).map(|k| 0.3 * (k as f64 * 0.0731).sin()).collect();
    let drive = |k: usize| table[k & 4095];
    let t0 = thread_cpu_ns().unwrap_or(0);
    let mut acc = 0.0;
    match part {
        "plant" => {
            let mut p = DualStagePlant::new(&cfg, Integrator::Zoh)?;
            let t0 = thread_cpu_ns().unwrap_or(0);
            for k in 0..n {
                acc += p
                    .step(&PlantInput {
                        force_n: [drive(k), -drive(k)],
                        drive_v: drive(k + 3),
                        ..Default::default()
                    })
                    .accel_m_s2[0];
            }
            report(part, n, t0);
        }
        "tweezer" => {
            let mut t = SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), fs)?;
            if args.get(3).is_some_and(|a| a == "exact") {
                t.set_drag_table(false);
            }
            eprintln!("drag table error: {:?}", t.drag_table_error());
            let t0 = thread_cpu_ns().unwrap_or(0);
            for k in 0..n {
                acc += t.step([1e-9 * drive(k), 0.0]).force_n[0];
            }
            report(part, n, t0);
        }
        "accel" => {
            let mut a = Accelerometer::new(&cfg.accelerometer, fs)?;
            let t0 = thread_cpu_ns().unwrap_or(0);
            for k in 0..n {
                acc += a.sample([drive(k), 0.0, 0.0]).m_s2[0];
            }
            report(part, n, t0);
        }
        _ => acc += run_loop(&cfg, n)?,
    }
    black_box(acc);
    let _ = t0;
    Ok(())
}

/// The `loop` part in a function of its own, so that the other parts of
/// `main` do not change how it is compiled (inlining budgets).
#[inline(never)]
fn run_loop(cfg: &RigConfig, n: usize) -> Result<f64, Box<dyn std::error::Error>> {
    let chain = LoopChain::as_designed(cfg)?;
    let clearance = Clearance::check(cfg, &chain)?;
    let mut cl = SimLoop::simulated(cfg, &chain, clearance)?;
    let mut acc = 0.0;
    let t0 = thread_cpu_ns().unwrap_or(0);
    for _ in 0..n {
        acc += cl.step()?.command.force_n[0];
    }
    report("loop", n, t0);
    black_box(cl.rig.status());
    Ok(acc)
}

fn report(part: &str, n: usize, t0: u64) {
    let t = thread_cpu_ns().unwrap_or(0) - t0;
    if n > 0 {
        println!("{part}: {:.2} ns/sample (thread CPU)", t as f64 / n as f64);
    }
}
