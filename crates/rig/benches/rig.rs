//! Criterion benchmarks of kilotouch-rig (`cargo bench -p kilotouch-rig`).
//!
//! Each iteration runs `N` steps; criterion's throughput line gives steps/s
//! and time/N is the cost per step. Keys of `kilotouch bench --json`:
//! * `plant_ns_per_step`          ← `plant/dual_stage_zoh` (both axes, ZOH)
//! * `tweezer_ns_per_step`        ← `tweezer/free_exact`
//! * `closed_loop_ns_per_sample`  ← `closed_loop/dual` (chain + plant +
//!   accelerometer + tweezer + coupling + safety layer, one sample per
//!   `process_block`)
//! * `safety/apply` (enabled, slew and limits active) and
//!   `safety/apply_disabled`: the safety layer alone, per sample.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use kilotouch_rig::Condition;
use kilotouch_rig::accel::Accelerometer;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::LoopChain;
use kilotouch_rig::device::{ActuatorFrame, SensorFrame};
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::lti::Integrator;
use kilotouch_rig::plant::{Axis, AxisModel, AxisSim, DualStagePlant, NU, NX, PlantInput};
use kilotouch_rig::safety::{SafetyLayer, SafetyState};
use kilotouch_rig::tweezer::{Obstacle, SimTweezer, Tweezer, TweezerIntegrator, TweezerParams};
use nalgebra::SVector;
use std::hint::black_box;

#[path = "common/drive.rs"]
mod common_drive;
use common_drive::drive;

const N: usize = 10_000;

fn bench_plant(c: &mut Criterion) {
    let cfg = RigConfig::default();
    let mut g = c.benchmark_group("plant");
    g.throughput(Throughput::Elements(N as u64));
    let mut p = DualStagePlant::new(&cfg, Integrator::Zoh).expect("plant");
    g.bench_function("dual_stage_zoh", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..N {
                let o = p.step(&PlantInput {
                    force_n: [drive(k), -drive(k)],
                    drive_v: drive(k + 3),
                    ..Default::default()
                });
                acc += o.accel_m_s2[0];
            }
            black_box(acc)
        })
    });
    let m = AxisModel::new(&cfg, Axis::X).expect("model");
    for integ in Integrator::ALL {
        let mut s = AxisSim::<NX>::new(&m, integ, 1e-4).expect("sim");
        g.bench_function(format!("x_axis_{}", integ.name()), |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for k in 0..N {
                    let o = s.step(&SVector::<f64, NU>::from([
                        drive(k),
                        drive(k + 3),
                        0.0,
                        0.0,
                        1.0,
                    ]));
                    acc += o.accel;
                }
                black_box(acc)
            })
        });
    }
    g.finish();
}

fn bench_tweezer(c: &mut Criterion) {
    let mut g = c.benchmark_group("tweezer");
    g.throughput(Throughput::Elements(N as u64));
    for (name, integ) in [
        ("free_exact", TweezerIntegrator::Exact),
        ("free_euler", TweezerIntegrator::Euler),
    ] {
        let mut t = SimTweezer::new(
            TweezerParams {
                integrator: integ,
                ..TweezerParams::paper_default()
            },
            1e4,
        )
        .expect("tweezer");
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for k in 0..N {
                    acc += t.step([1e-9 * drive(k), 0.0]).force_n[0];
                }
                black_box(acc)
            })
        });
    }
    // Pressed against an obstacle (drag tensor, contact, sub-steps).
    let p = TweezerParams {
        obstacles: vec![Obstacle {
            centre_m: [10e-6, 0.0],
            radius_m: 5e-6,
        }],
        ..TweezerParams::paper_default()
    };
    let mut t = SimTweezer::new(p, 1e4).expect("tweezer");
    let trap = [10e-6 - 5e-6 - 1.5e-6 + 0.5e-6, 0.0];
    t.reset(trap);
    g.bench_function("pressed_on_obstacle", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for _ in 0..N {
                acc += t.step(trap).force_n[0];
            }
            black_box(acc)
        })
    });
    // The default scene: two obstacles several µm away (drag corrections on).
    let cfg = RigConfig::default();
    let mut t = SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), 1e4).expect("tweezer");
    g.bench_function("default_scene_free", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..N {
                acc += t.step([1e-9 * drive(k), 0.0]).force_n[0];
            }
            black_box(acc)
        })
    });
    // The same with the exact near-obstacle coefficients (table bypassed).
    let mut t = SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), 1e4).expect("tweezer");
    t.set_drag_table(false);
    g.bench_function("default_scene_exact_coefficients", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..N {
                acc += t.step([1e-9 * drive(k), 0.0]).force_n[0];
            }
            black_box(acc)
        })
    });
    g.finish();
}

fn bench_normal(c: &mut Criterion) {
    use rand::{RngExt, SeedableRng};
    let mut g = c.benchmark_group("normal");
    g.throughput(Throughput::Elements(N as u64));
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
    g.bench_function("rand_distr_ziggurat", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for _ in 0..N {
                acc += rng.sample::<f64, _>(rand_distr::StandardNormal);
            }
            black_box(acc)
        })
    });
    let mut s = kilotouch_rig::normal::NormalStream::new(1);
    g.bench_function("normal_stream", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for _ in 0..N {
                acc += s.sample();
            }
            black_box(acc)
        })
    });
    g.finish();
}

fn bench_accel(c: &mut Criterion) {
    let cfg = RigConfig::default();
    let mut a = Accelerometer::new(&cfg.accelerometer, 1e4).expect("accel");
    let mut g = c.benchmark_group("accelerometer");
    g.throughput(Throughput::Elements(N as u64));
    g.bench_function("sample", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for k in 0..N {
                acc += a.sample([drive(k), 0.0, 0.0]).m_s2[0];
            }
            black_box(acc)
        })
    });
    g.finish();
}

fn bench_closed_loop(c: &mut Criterion) {
    let cfg = RigConfig::default();
    let mut g = c.benchmark_group("closed_loop");
    g.throughput(Throughput::Elements(N as u64));
    for (name, condition) in [("dual", Condition::D), ("pantograph", Condition::P)] {
        let mut c = cfg.clone();
        c.coupling.mode = condition;
        let chain = LoopChain::as_designed(&c).expect("chain");
        let clearance = Clearance::check(&c, &chain).expect("clearance");
        let mut cl = SimLoop::simulated(&c, &chain, clearance).expect("loop");
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for _ in 0..N {
                    acc += cl.step().expect("step").command.force_n[0];
                }
                black_box(acc)
            })
        });
    }
    g.finish();
}

fn bench_safety(c: &mut Criterion) {
    let cfg = RigConfig::default();
    let mut g = c.benchmark_group("safety");
    g.throughput(Throughput::Elements(N as u64));
    let mut on = SafetyLayer::from_config(&cfg).expect("safety");
    on.arm().expect("arm");
    while on.state() != SafetyState::Enabled {
        on.apply(ActuatorFrame::default(), &SensorFrame::default(), false);
    }
    let mut off = SafetyLayer::from_config(&cfg).expect("safety");
    for (name, layer) in [("apply", &mut on), ("apply_disabled", &mut off)] {
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for k in 0..N {
                    // ±12 N commands: the axis, norm and slew limits bind.
                    let o = layer.apply(
                        ActuatorFrame {
                            force_n: [40.0 * drive(k), -30.0 * drive(k + 7)],
                            haptuator_v: 10.0 * drive(k + 3),
                        },
                        &SensorFrame {
                            handle_m: [1e-6 * drive(k), 0.0],
                            ..Default::default()
                        },
                        false,
                    );
                    acc += o.force_n[0] + o.haptuator_v;
                }
                black_box(acc)
            })
        });
    }
    g.finish();
}

criterion_group!(
    benches,
    bench_plant,
    bench_tweezer,
    bench_normal,
    bench_accel,
    bench_closed_loop,
    bench_safety
);
criterion_main!(benches);
