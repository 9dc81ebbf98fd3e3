//! Speed of scene fidelity against the full model: one whole circling
//! test trial (start to end, ≈ 15 s simulated) per condition at each
//! fidelity, without a raw file. The ratio full/scene per condition is the
//! saving of `study simulate --fidelity scene` (docs/PERFORMANCE.md, "Scene
//! fidelity", which also has the whole-study figure).
//!
//! Run: `cargo bench -p kilotouch-study --bench fidelity`.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use kilotouch_rig::config::RigConfig;
use kilotouch_study::fidelity::Fidelity;
use kilotouch_study::operator::SimCohort;
use kilotouch_study::protocol::{Condition, Protocol};
use kilotouch_study::runner::{NoRaw, RunnerConfig, TrialEngine};
use kilotouch_study::seeds::{Phase, TrialKey};
use kilotouch_study::task::sim_station::SimStation;

fn bench_fidelity(c: &mut Criterion) {
    let p = Protocol::paper().expect("built-in protocol");
    let cfg = RunnerConfig {
        raw: None,
        ..Default::default()
    };
    let mut g = c.benchmark_group("trial_by_fidelity");
    g.sample_size(10);
    for fidelity in Fidelity::ALL {
        let mut station = SimStation::new(&RigConfig::default()).expect("default rig");
        station.set_fidelity(fidelity);
        let mut e = TrialEngine::new(station, cfg).expect("engine");
        for cond in Condition::ALL {
            let key = TrialKey::new(0, cond, Phase::Test, 1);
            let setup = e.setup(&p, key);
            g.bench_function(format!("{cond}_{fidelity}"), |b| {
                b.iter(|| {
                    let mut who = SimCohort::new(p.seeds.study, 1000.0, 10_000.0);
                    black_box(e.run_trial(&setup, &mut who, &mut NoRaw).expect("trial"))
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench_fidelity);
criterion_main!(benches);
