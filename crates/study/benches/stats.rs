//! Statistics speed: Friedman's test (ranks per subject block and the
//! 2 000-resample bootstrap interval of Kendall's W) from 100 to 10 000
//! subjects × 3 conditions, on the cell matrix and from long-format rows
//! (what `kilotouch stats --test friedman` runs after reading the CSV), and
//! the repeated-measures ANOVA beside it.
//!
//! Run: `cargo bench -p kilotouch-study --bench stats`. Figures in
//! `docs/PERFORMANCE.md`.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use kilotouch_study::stats::{CellMatrix, Design, Test, analyse, friedman, rm_anova};

/// n subjects × 3 conditions of tied, shifted integer-valued data (a
/// deterministic generator: the benchmark needs no RNG crate).
fn long_rows(n: usize, reps: usize) -> Vec<(String, &'static str, f64)> {
    let mut s = 0x9E37_79B9_7F4A_7C15_u64;
    let mut rows = Vec::with_capacity(n * 3 * reps);
    for i in 0..n {
        for (j, c) in ["V", "P", "D"].into_iter().enumerate() {
            for _ in 0..reps {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                rows.push((format!("P{i:05}"), c, (s % 50) as f64 + 0.5 * j as f64));
            }
        }
    }
    rows
}

fn matrix(n: usize) -> CellMatrix {
    Design::from_long(long_rows(n, 1))
        .and_then(|d| d.cell_matrix())
        .expect("complete design")
}

fn bench_friedman(c: &mut Criterion) {
    let mut g = c.benchmark_group("friedman");
    g.sample_size(10);
    for n in [100, 1_000, 5_000, 10_000] {
        let m = matrix(n);
        g.bench_with_input(BenchmarkId::new("cell matrix, k = 3", n), &m, |b, m| {
            b.iter(|| friedman(black_box(m)).expect("friedman"));
        });
    }
    let rows = long_rows(10_000, 2);
    g.bench_function("long rows → design → test, 10000 × 3 × 2 rows", |b| {
        b.iter(|| {
            let d = Design::from_long(black_box(rows.iter().map(|(s, c, v)| (s, *c, *v))))
                .expect("design");
            analyse(&d, Test::Friedman).expect("friedman")
        });
    });
    let m = matrix(10_000);
    g.bench_function("rm_anova beside it, 10000 × 3", |b| {
        b.iter(|| rm_anova(black_box(&m)).expect("rm anova"));
    });
    g.finish();
}

criterion_group!(benches, bench_friedman);
criterion_main!(benches);
