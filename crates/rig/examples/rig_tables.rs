//! Accuracy and stability tables for `docs/PERFORMANCE.md`.
//!
//! `cargo run --release -p kilotouch-rig --example rig_tables`
//! (`-- --timings`: thread-CPU cost per step; criterion: `cargo bench -p
//! kilotouch-rig`; `-- --hankel`: Hankel singular values of the plant's
//! paths).

use kilotouch_rig::Condition;
use kilotouch_rig::accel::Accelerometer;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::lti::{self, Integrator};
use kilotouch_rig::plant::{Axis, AxisModel, Channel, IN_DRIVE, IN_FORCE, OUT_ACCEL, OUT_MOTOR};
use kilotouch_rig::plant::{AxisSim, DualStagePlant, NU, NX, PlantInput};
use kilotouch_rig::realtime::thread_cpu_ns;
use kilotouch_rig::tweezer::{Obstacle, SimTweezer, Tweezer};
use kilotouch_rig::tweezer::{TweezerIntegrator, TweezerParams};
use nalgebra::SVector;
use std::hint::black_box;

#[path = "../benches/common/drive.rs"]
mod common_drive;
use common_drive::drive;

fn grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// Best of 5 runs of `n` calls: CPU ns per call.
fn ns_per_call(n: usize, mut f: impl FnMut(usize) -> f64) -> f64 {
    let mut best = f64::INFINITY;
    let mut sink = 0.0;
    for _ in 0..6 {
        let t0 = thread_cpu_ns().unwrap_or(0);
        for k in 0..n {
            sink += f(k);
        }
        let t1 = thread_cpu_ns().unwrap_or(0);
        best = best.min((t1 - t0) as f64 / n as f64);
    }
    black_box(sink);
    best
}

fn timings(cfg: &RigConfig) -> Result<(), Box<dyn std::error::Error>> {
    let n = 1_000_000;
    println!("## Cost per step (thread CPU time, best of 6 × 1e6 calls)\n");
    println!("| what | ns |");
    println!("|---|---|");
    let mut p = DualStagePlant::new(cfg, Integrator::Zoh)?;
    let t = ns_per_call(n, |k| {
        p.step(&PlantInput {
            force_n: [drive(k), -drive(k)],
            drive_v: drive(k + 3),
            ..Default::default()
        })
        .accel_m_s2[0]
    });
    println!("| plant, both axes, ZOH (`plant_ns_per_step`) | {t:.1} |");
    let m = AxisModel::new(cfg, Axis::X)?;
    // Force and drive from the test signal, hand still, end-stop input 1.
    let x_step = |s: &mut AxisSim<NX>, k: usize| {
        s.step(&SVector::<f64, NU>::from([
            drive(k),
            drive(k + 3),
            0.0,
            0.0,
            1.0,
        ]))
        .accel
    };
    for integ in Integrator::ALL {
        let mut s = AxisSim::<NX>::new(&m, integ, 1e-4)?;
        let t = ns_per_call(n, |k| x_step(&mut s, k));
        println!("| plant x axis only, {} | {t:.1} |", integ.name());
    }
    let mut s = AxisSim::<NX>::new(&m, Integrator::Zoh, 1e-4)?;
    s.force_dense();
    let t = ns_per_call(n, |k| x_step(&mut s, k));
    println!("| plant x axis only, zoh, dense update (no modal form) | {t:.1} |");
    for (name, params) in [
        (
            "tweezer, free space, exact (`tweezer_ns_per_step`)",
            TweezerParams::paper_default(),
        ),
        (
            "tweezer, free space, Euler–Maruyama",
            TweezerParams {
                integrator: TweezerIntegrator::Euler,
                ..TweezerParams::paper_default()
            },
        ),
        (
            "tweezer, default scene (2 obstacles, drag corrections)",
            TweezerParams::from_config(&cfg.tweezer),
        ),
    ] {
        let mut tw = SimTweezer::new(params, 1e4)?;
        let t = ns_per_call(n, |k| tw.step([1e-9 * drive(k), 0.0]).force_n[0]);
        println!("| {name} | {t:.1} |");
    }
    let mut tw = SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), 1e4)?;
    tw.set_drag_table(false);
    let t = ns_per_call(n, |k| tw.step([1e-9 * drive(k), 0.0]).force_n[0]);
    println!("| tweezer, default scene, exact coefficients (table bypassed) | {t:.1} |");
    {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
        let t = ns_per_call(20 * n, |_| rng.sample::<f64, _>(rand_distr::StandardNormal));
        println!("| N(0,1) variate, rand_distr ziggurat on xoshiro256++ | {t:.1} |");
        let mut ns = kilotouch_rig::normal::NormalStream::new(1);
        let t = ns_per_call(20 * n, |_| ns.sample());
        println!("| N(0,1) variate, `NormalStream` (256-layer ziggurat, blocks of 64) | {t:.1} |");
    }
    let pressed = TweezerParams {
        obstacles: vec![Obstacle {
            centre_m: [10e-6, 0.0],
            radius_m: 5e-6,
        }],
        ..TweezerParams::paper_default()
    };
    let mut tw = SimTweezer::new(pressed, 1e4)?;
    let trap = [4.0e-6, 0.0];
    tw.reset(trap);
    let t = ns_per_call(n / 10, |_| tw.step(trap).force_n[0]);
    println!("| tweezer, pressed on an obstacle (sub-steps) | {t:.1} |");
    let mut a = Accelerometer::new(&cfg.accelerometer, 1e4)?;
    let t = ns_per_call(n, |k| a.sample([drive(k), 0.0, 0.0]).m_s2[0]);
    println!("| accelerometer (3 axes) | {t:.1} |");
    let coeffs = kilotouch_dsp::chain::ChainCoefficients::design(
        &kilotouch_rig::coupling::model_chain_design(cfg)?,
    )?;
    let mut chain = kilotouch_dsp::chain::Chain::new(&coeffs);
    let t = ns_per_call(n, |k| chain.process(drive(k)).1);
    println!("| dsp chain `process` (one call per sample) | {t:.1} |");
    for (name, condition) in [
        ("closed loop, D (`closed_loop_ns_per_sample`)", Condition::D),
        ("closed loop, P", Condition::P),
    ] {
        let mut c = cfg.clone();
        c.coupling.mode = condition;
        let chain = LoopChain::as_designed(&c)?;
        let clearance = Clearance::check(&c, &chain)?;
        let mut cl = SimLoop::simulated(&c, &chain, clearance)?;
        let t = ns_per_call(n, |_| {
            cl.step().map(|s| s.command.force_n[0]).unwrap_or(0.0)
        });
        println!("| {name} | {t:.1} |");
    }
    println!();
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let cfg0 = RigConfig::default();
    if std::env::args().any(|a| a == "--timings") {
        return timings(&cfg0);
    }
    if std::env::args().any(|a| a == "--hankel") {
        return hankel(&cfg0);
    }
    plant_accuracy(&cfg0)?;
    plant_stability(&cfg0)?;
    tweezer_variance()
}

/// The x axis's free model, its in-contact model and its number of position states.
fn x_models(
    cfg: &RigConfig,
) -> Result<(AxisModel, lti::StateSpace, lti::StateSpace, usize), Box<dyn std::error::Error>> {
    let m = AxisModel::new(cfg, Axis::X)?;
    let ss = m.active_free();
    let contact = m.plus.restrict(&m.active);
    let n_pos = m.active.iter().filter(|&&i| i < m.dofs.n_dof).count();
    Ok((m, ss, contact, n_pos))
}

/// Worst FRF error of each integrator against the analytic response and
/// exact ZOH, at three sample rates.
fn plant_accuracy(cfg: &RigConfig) -> Result<(), Box<dyn std::error::Error>> {
    let (m, ss, contact, n_pos) = x_models(cfg)?;
    let freqs = grid(10.0, 1000.0, 800);

    println!("## Plant: worst FRF error over 10–1000 Hz (dB)\n");
    println!(
        "| fs (kHz) | integrator | low vs analytic | high vs analytic | high vs analytic, 100–1000 Hz | low vs exact ZOH | high vs exact ZOH | stable free / in contact |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for fs in [10e3, 20e3, 50e3] {
        let (pz, gz) = lti::zoh(&ss.a, &ss.b, 1.0 / fs)?;
        for integ in Integrator::ALL {
            let (p, g) = lti::one_step_map(integ, &ss.a, &ss.b, 1.0 / fs, n_pos)?;
            let (pc, _) = lti::one_step_map(integ, &contact.a, &contact.b, 1.0 / fs, n_pos)?;
            let mut e = [0.0_f64; 4];
            let mut e_hi_band = 0.0_f64;
            for &f in &freqs {
                for (k, (ch, inp)) in [(Channel::Low, IN_FORCE), (Channel::High, IN_DRIVE)]
                    .into_iter()
                    .enumerate()
                {
                    let hd = lti::discrete_response(&p, &g, (&ss.c, &ss.d), OUT_ACCEL, inp, f, fs)?;
                    let hz =
                        lti::discrete_response(&pz, &gz, (&ss.c, &ss.d), OUT_ACCEL, inp, f, fs)?;
                    let hc = m.channel_response(ch, f)?;
                    e[k] = e[k].max((20.0 * (hd.norm() / hc.norm()).log10()).abs());
                    if k == 1 && f >= 100.0 {
                        e_hi_band = e_hi_band.max((20.0 * (hd.norm() / hc.norm()).log10()).abs());
                    }
                    e[k + 2] = e[k + 2].max((20.0 * (hd.norm() / hz.norm()).log10()).abs());
                }
            }
            let yn = |b: bool| if b { "yes" } else { "NO" };
            println!(
                "| {:.0} | {} | {:.3} | {:.3} | {:.3} | {:.2e} | {:.2e} | {} / {} |",
                fs / 1e3,
                integ.name(),
                e[0],
                e[1],
                e_hi_band,
                e[2],
                e[3],
                yn(lti::spectral_radius(&p) < 1.0),
                yn(lti::spectral_radius(&pc) < 1.0)
            );
        }
    }

    Ok(())
}

/// Lowest stable sample rate of each integrator, free, on the default end
/// stop and on a ten times stiffer one; the free regime's poles.
fn plant_stability(cfg: &RigConfig) -> Result<(), Box<dyn std::error::Error>> {
    let (m, ss, contact, n_pos) = x_models(cfg)?;
    println!("\n## Plant: stability limits (lowest stable sample rate, Hz)\n");
    println!("| integrator | free | end stop k_s = 1e6 N/m (default) | end stop k_s = 1e7 N/m |");
    println!("|---|---|---|---|");
    let mut stiff = cfg.clone();
    stiff.haptuator.stop_stiffness_n_per_m = 1e7;
    let ms = AxisModel::new(&stiff, Axis::X)?;
    let cs = ms.plus.restrict(&ms.active);
    for integ in Integrator::ALL {
        let lim = |s: &lti::StateSpace| -> Result<String, Box<dyn std::error::Error>> {
            Ok(
                match lti::stability_limit(
                    |dt| Ok(lti::one_step_map(integ, &s.a, &s.b, dt, n_pos)?.0),
                    1e-7,
                    1e-1,
                )? {
                    None => "any (A-stable)".to_string(),
                    Some(dt) => format!("{:.0}", 1.0 / dt),
                },
            )
        };
        println!(
            "| {} | {} | {} | {} |",
            integ.name(),
            lim(&ss)?,
            lim(&contact)?,
            lim(&cs)?
        );
    }
    let mut poles: Vec<_> = m.poles().into_iter().filter(|p| p.im >= 0.0).collect();
    poles.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
    println!("\nPoles (free regime): ");
    for p in poles {
        println!(
            "- {:.1} Hz, ζ = {:.4}",
            p.norm() / (2.0 * std::f64::consts::PI),
            -p.re / p.norm()
        );
    }

    Ok(())
}

/// Stationary variance of the exact OU step and of Euler–Maruyama against
/// k_BT/κ over dt/τ.
fn tweezer_variance() -> Result<(), Box<dyn std::error::Error>> {
    println!("\n## Tweezer: stationary variance / (k_BT/κ), exact OU vs Euler–Maruyama\n");
    println!("| dt/τ | samples | exact | Euler–Maruyama | EM theory 1/(1 − dt/2τ) |");
    println!("|---|---|---|---|---|");
    let tau = TweezerParams::paper_default().tau();
    for r in [0.01, 0.1, 0.5, 1.0, 1.5, 1.9] {
        let fs = 1.0 / (r * tau);
        let n = if r < 0.05 { 4_000_000.0 } else { 1_000_000.0 };
        let v = |integrator| -> Result<f64, Box<dyn std::error::Error>> {
            let p = TweezerParams {
                integrator,
                escape_distance_m: f64::MAX,
                seed: 3,
                ..TweezerParams::paper_default()
            };
            let var_theory = p.variance_theory();
            let mut tw = SimTweezer::new(p, fs)?;
            tw.start_stationary();
            let (mut s, mut s2) = ([0.0; 2], [0.0; 2]);
            for _ in 0..n as usize {
                let b = tw.step([0.0, 0.0]).bead_m;
                for i in 0..2 {
                    s[i] += b[i];
                    s2[i] += b[i] * b[i];
                }
            }
            let var = |i: usize| (s2[i] - s[i] * s[i] / n) / (n - 1.0);
            Ok(0.5 * (var(0) + var(1)) / var_theory)
        };
        println!(
            "| {r} | {n:.0e} | {:.4} | {:.4} | {:.4} |",
            v(TweezerIntegrator::Exact)?,
            v(TweezerIntegrator::Euler)?,
            1.0 / (1.0 - 0.5 * r)
        );
    }
    println!("| ≥ 2 | — | stable, exact | diverges (refused) | ∞ |");
    Ok(())
}

/// Hankel singular values σᵢ/σ₁ of the default plant's paths at the rig's
/// sample rate: how many states each path needs.
fn hankel(cfg: &RigConfig) -> Result<(), Box<dyn std::error::Error>> {
    let dt = 1.0 / cfg.rig.sample_rate_hz;
    println!(
        "## Plant: Hankel singular values σᵢ/σ₁ (ZOH at {} Hz)\n",
        cfg.rig.sample_rate_hz
    );
    println!("| axis | path | σᵢ/σ₁ |");
    println!("|---|---|---|");
    let x = AxisModel::new(cfg, Axis::X)?;
    let y = AxisModel::new(cfg, Axis::Y)?;
    let rows: [(&str, &AxisModel, &str, &[usize], usize); 6] = [
        (
            "x",
            &x,
            "force, drive → ẍ_h",
            &[IN_FORCE, IN_DRIVE],
            OUT_ACCEL,
        ),
        ("x", &x, "force → ẍ_h", &[IN_FORCE], OUT_ACCEL),
        ("x", &x, "drive → ẍ_h", &[IN_DRIVE], OUT_ACCEL),
        ("x", &x, "force → x_1 (encoder)", &[IN_FORCE], OUT_MOTOR),
        ("y", &y, "force → ẍ_h", &[IN_FORCE], OUT_ACCEL),
        ("y", &y, "force → x_1 (encoder)", &[IN_FORCE], OUT_MOTOR),
    ];
    for (axis, m, path, inputs, output) in rows {
        let s = m.hankel_singular_values(inputs, output, dt)?;
        let r: Vec<String> = s.iter().map(|v| format!("{:.1e}", v / s[0])).collect();
        println!("| {axis} | {path} | {} |", r.join(" "));
    }
    println!();
    Ok(())
}
