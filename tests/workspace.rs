//! End-to-end checks across crates.

/// The dsp crate's paper model evaluates to the published value at 1 kHz
/// (docs/REFERENCE-VALUES.md: |G_H(j2π·1000)| = 0.0453443).
#[test]
fn paper_model_is_reachable_from_the_workspace() {
    let g = kilotouch_dsp::Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).expect("valid");
    assert!((g.response_hz(1000.0).norm() - 0.0453443).abs() < 1e-7);
}
