//! Welch PSD speed target: 1e6 samples, nperseg 4096, noverlap 2048, Hann,
//! density scaling, constant detrend — ≤ 8.5 ms single-threaded on the
//! project's 2-core AMD EPYC (scipy.signal.welch: ~17 ms).
//!
//! Run: `cargo bench -p kilotouch-dsp --bench welch`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use kilotouch_dsp::spectral::{StreamingFrf, StreamingWelch, WelchConfig, frf, welch};
use std::hint::black_box;

/// Deterministic broadband test signal (xorshift64* uniform in [−1, 1)).
fn signal(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed | 1;
    (0..n)
        .map(|_| {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            let u = s.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11;
            u as f64 / (1u64 << 52) as f64 - 1.0
        })
        .collect()
}

fn bench_welch(c: &mut Criterion) {
    let n = 1_000_000;
    let x = signal(n, 0x5eed);
    let y = signal(n, 0xbeef);
    let cfg = WelchConfig::new(4096).with_noverlap(2048);
    let fs = 10_000.0;

    let mut g = c.benchmark_group("welch_1e6");
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function("welch nperseg4096 hann density", |b| {
        b.iter(|| welch(black_box(&x), fs, black_box(&cfg)))
    });
    g.bench_function("streaming welch, 1000-sample blocks", |b| {
        let mut s = StreamingWelch::new(fs, &cfg).expect("valid Welch configuration");
        b.iter(|| {
            s.reset();
            for blk in x.chunks(1000) {
                s.feed(black_box(blk)).expect("finite input");
            }
            s.n_segments()
        })
    });
    g.bench_function("frf (H1, H2, coherence) nperseg4096", |b| {
        b.iter(|| frf(black_box(&x), black_box(&y), fs, black_box(&cfg)))
    });
    g.bench_function("streaming frf, 1000-sample blocks", |b| {
        let mut s = StreamingFrf::new(fs, &cfg).expect("valid Welch configuration");
        b.iter(|| {
            s.reset();
            for (bx, by) in x.chunks(1000).zip(y.chunks(1000)) {
                s.feed(black_box(bx), black_box(by)).expect("finite input");
            }
            s.n_segments()
        })
    });
    g.finish();
}

criterion_group!(benches, bench_welch);
criterion_main!(benches);
