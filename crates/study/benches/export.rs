//! Storage-layer speed: raw-signal streaming (NPY), per-trial commit
//! latency (three fsyncs: `trial_started`, row, `trial_completed`) and
//! summary regeneration.
//!
//! Run: `cargo bench -p kilotouch-study --bench export`. The commit figure is
//! dominated by the storage device's fsync latency, not by this code.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use kilotouch_study::export::{StudyMeta, StudyStore, UtcTime, regenerate_summaries};
use kilotouch_study::protocol::Protocol;
use kilotouch_study::rawsig::{Dtype, NpyWriter, RawLayout, standard_channels};
use kilotouch_study::seeds::TrialKey;

fn protocol(participants: u32) -> Protocol {
    let text = format!(
        "name = \"bench\"\nparticipants = {participants}\ntrials_per_session = 10\n\
         [training]\npractice_trials = 3\n[task.circling]\n[seeds]\nstudy = 1\n"
    );
    Protocol::from_toml_str(&text, "<bench>").expect("valid bench protocol")
}

fn bench_npy(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temporary directory");
    let channels = standard_channels().len();
    // One second at the paper's 10 kHz loop rate.
    let samples = 10_000_usize;
    let sample: Vec<f64> = (0..channels).map(|j| j as f64 * 1.25e-7).collect();
    let mut g = c.benchmark_group("npy_stream_1s_10kHz_17ch");
    g.throughput(Throughput::Elements(samples as u64));
    for dtype in [Dtype::F32, Dtype::F64] {
        let path = dir
            .path()
            .join(format!("{}.npy", dtype.descr().replace('<', "")));
        g.bench_function(format!("push per sample {}", dtype.descr()), |b| {
            b.iter_batched(
                || {
                    NpyWriter::create(&path, RawLayout::standard(10_000.0, dtype))
                        .expect("create raw file")
                },
                |mut w| {
                    for _ in 0..samples {
                        w.push(black_box(&sample)).expect("push");
                    }
                    w
                },
                BatchSize::PerIteration,
            );
        });
    }
    g.finish();
}

/// Begins trial `k` and commits it as a success in 42 s with the mean
/// displacement error `disp_err_mean_um` (µm; `None`: NA).
fn commit_success(store: &mut StudyStore, k: TrialKey, disp_err_mean_um: Option<f64>) {
    let ticket = store
        .begin_trial(k, UtcTime::from_unix_millis(0))
        .expect("begin");
    let mut row = ticket.row();
    row.success = true;
    row.time_s = Some(42.0);
    row.disp_err_mean_um = disp_err_mean_um;
    store.commit_trial(ticket, &row).expect("commit");
}

fn bench_commit(c: &mut Criterion) {
    let meta = StudyMeta::new("bench");
    let mut g = c.benchmark_group("trial_commit");
    g.sample_size(20);
    g.measurement_time(Duration::from_secs(10));
    g.bench_function("begin + commit (3 fsyncs)", |b| {
        b.iter_custom(|iters| {
            let dir = tempfile::tempdir().expect("temporary directory");
            // 39 trials per participant.
            let participants = u32::try_from(iters / 39 + 1).expect("bench size");
            let mut store =
                StudyStore::open(dir.path(), &protocol(participants), &meta).expect("open");
            let keys: Vec<_> = store.plan().iter().map(|p| p.key).collect();
            let start = Instant::now();
            for &k in keys.iter().take(iters as usize) {
                commit_success(&mut store, k, None);
            }
            start.elapsed()
        });
    });
    g.finish();

    // The paper's study size: 8 participants × 3 conditions × (3 + 10).
    let dir = tempfile::tempdir().expect("temporary directory");
    let mut store = StudyStore::open(dir.path(), &protocol(8), &meta).expect("open");
    let keys: Vec<_> = store.plan().iter().map(|p| p.key).collect();
    for k in keys {
        commit_success(&mut store, k, Some(0.5));
    }
    drop(store);
    c.bench_function("regenerate summaries, 312 trials", |b| {
        b.iter(|| regenerate_summaries(black_box(dir.path())).expect("summaries"))
    });
}

criterion_group!(benches, bench_npy, bench_commit);
criterion_main!(benches);
