//! Cost of one simulated trial sample: station (rig + tweezer + coupling),
//! simulated operator, metrics, camera, with and without the raw NPY sink.
//!
//! Run: `cargo bench -p kilotouch-study --bench tasks`.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use kilotouch_rig::config::RigConfig;
use kilotouch_study::operator::SimCohort;
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::rawsig::{Dtype, NpyWriter};
use kilotouch_study::runner::{NoRaw, RunnerConfig, TrialEngine, raw_layout};
use kilotouch_study::seeds::{Phase, TrialKey};
use kilotouch_study::task::sim_station::SimStation;

fn bench_trial(c: &mut Criterion) {
    let p = Protocol::paper().expect("built-in protocol");
    let cfg = RunnerConfig {
        raw: None,
        ..Default::default()
    };
    let station = SimStation::new(&RigConfig::default()).expect("default rig");
    let mut e = TrialEngine::new(station, cfg).expect("engine");
    let dir = tempfile::tempdir().expect("temporary directory");
    // One second (10 000 samples) of a circling trial, from its start.
    let n = 10_000;
    let mut g = c.benchmark_group("trial_1s_10kHz");
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(20);
    for cond in [Condition::V, Condition::D] {
        let key = TrialKey::new(0, cond, Phase::Test, 1);
        let setup = e.setup(&p, key);
        g.bench_function(format!("{cond}_no_raw"), |b| {
            b.iter(|| {
                let mut who = SimCohort::new(p.seeds.study, 1000.0, 10_000.0);
                e.start(&setup, &mut who).expect("start");
                black_box(e.run(&mut who, &mut NoRaw, n).expect("run"))
            })
        });
        g.bench_function(format!("{cond}_raw_f32"), |b| {
            b.iter(|| {
                let mut who = SimCohort::new(p.seeds.study, 1000.0, 10_000.0);
                e.start(&setup, &mut who).expect("start");
                let mut w = NpyWriter::create(
                    &dir.path().join("bench.npy"),
                    raw_layout(10_000.0, Dtype::F32),
                )
                .expect("raw file");
                let r = e.run(&mut who, &mut w, n).expect("run");
                w.finish().expect("finish");
                black_box(r)
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench_trial);
criterion_main!(benches);
