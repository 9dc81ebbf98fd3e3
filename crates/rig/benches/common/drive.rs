//! The test signal of the rig's speed measurements, shared by the criterion
//! benchmarks (`benches/rig.rs`) and the timing tables
//! (`examples/rig_tables.rs -- --timings`), which include this file.

/// Precomputed test signal (no `sin` inside the timed loops): 4096 samples
/// of 0.3 sin(0.0731 k).
static DRIVE: std::sync::LazyLock<Vec<f64>> = std::sync::LazyLock::new(|| {
    (0..4096)
        .map(|k| 0.3 * ((k as f64) * 0.0731).sin())
        .collect()
});

/// Sample `k` of the test signal (repeating every 4096 samples).
#[inline]
pub fn drive(k: usize) -> f64 {
    DRIVE[k & 4095]
}
