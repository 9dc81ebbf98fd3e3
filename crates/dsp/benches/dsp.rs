//! Criterion benchmarks of kilotouch-dsp.
//!
//! Signal-chain benchmarks: `cargo bench -p kilotouch-dsp --bench dsp -- chain`.
//! Each iteration streams 1e6 samples of the paper's chain (LR4 at 200 Hz,
//! C_L, C_H with Ĝ_H of eq. 2 and F at 1 kHz, fs = 10 kHz); the reported
//! time divided by 1e6 is the cost per sample (criterion's throughput line
//! gives samples/s).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use kilotouch_dsp::filter::Sos;
use std::hint::black_box;

const N: usize = 1_000_000;

/// Deterministic broadband input in [−1, 1) (xorshift64*), never silent, so
/// the denormal flush never triggers.
/// The paper's chain coefficients, the input and two output buffers.
fn chain_setup() -> (ChainCoefficients, Vec<f64>, Vec<f64>, Vec<f64>) {
    let coeffs = ChainCoefficients::paper().expect("paper chain");
    (coeffs, chain_input(), vec![0.0; N], vec![0.0; N])
}

fn chain_input() -> Vec<f64> {
    let mut s: u64 = 0x9E37_79B9_7F4A_7C15;
    (0..N)
        .map(|_| {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            let r = s.wrapping_mul(0x2545_F491_4F6C_DD1D);
            (r >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        })
        .collect()
}

/// Per-sample APIs: `Chain::stream` (samples pulled one by one from an
/// iterator, each output pair pushed to a closure) and `Chain::process`
/// called once per sample in a loop.
fn bench_chain_per_sample(c: &mut Criterion) {
    let (coeffs, input, mut low, mut high) = chain_setup();
    let mut chain = Chain::new(&coeffs);
    let mut g = c.benchmark_group("chain");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(30);
    g.bench_function("paper_stream_per_sample_1e6", |b| {
        b.iter(|| {
            let mut i = 0;
            chain.stream(input.iter().copied(), |l, h| {
                low[i] = l;
                high[i] = h;
                i += 1;
            });
            black_box((&low, &high));
        })
    });
    g.bench_function("paper_process_per_sample_1e6", |b| {
        b.iter(|| {
            for ((&x, l), h) in input.iter().zip(low.iter_mut()).zip(high.iter_mut()) {
                (*l, *h) = chain.process(x);
            }
            black_box((&low, &high));
        })
    });
    g.finish();
}

/// Block API: one 1e6-sample block, and 64-sample blocks (a typical
/// real-time buffer).
fn bench_chain_block(c: &mut Criterion) {
    let (coeffs, input, mut low, mut high) = chain_setup();
    let mut chain = Chain::new(&coeffs);
    let mut g = c.benchmark_group("chain");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(30);
    g.bench_function("paper_block_1e6", |b| {
        b.iter(|| {
            chain.process_block(&input, &mut low, &mut high);
            black_box((&low, &high));
        })
    });
    g.bench_function("paper_block64_1e6", |b| {
        b.iter(|| {
            for ((x, l), h) in input
                .chunks(64)
                .zip(low.chunks_mut(64))
                .zip(high.chunks_mut(64))
            {
                chain.process_block(x, l, h);
            }
            black_box((&low, &high));
        })
    });
    g.finish();
}

/// Scalar reference: the same six sections as two TDF-II `Sos` cascades run
/// one after the other (the structure of scipy's `sosfilt`, ~7.3 ns/sample
/// there).
fn bench_chain_scalar_reference(c: &mut Criterion) {
    let (coeffs, input, mut low, mut high) = chain_setup();
    let mut lo = Sos::new(coeffs.low().to_vec()).expect("low");
    let mut hi = Sos::new(coeffs.high().to_vec()).expect("high");
    let mut g = c.benchmark_group("chain");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(20);
    g.bench_function("scalar_sos_reference_1e6", |b| {
        b.iter(|| {
            lo.process_block(&input, &mut low);
            hi.process_block(&input, &mut high);
            black_box((&low, &high));
        })
    });
    g.finish();
}

criterion_group!(
    chain_benches,
    bench_chain_per_sample,
    bench_chain_block,
    bench_chain_scalar_reference
);
criterion_main!(chain_benches);
