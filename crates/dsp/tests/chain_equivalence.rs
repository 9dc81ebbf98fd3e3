//! Equivalence harness of the signal chain's kernels
//! (`kilotouch_dsp::chain`, private module `kernel`).
//!
//! The chain has a fast kernel (two paths packed as SIMD lanes, sections
//! normalised to b0 = 1, one monomorphised kernel per stage count and
//! first-order tail) and a reference kernel (plain TDF-II per lane, the same
//! operations as `filter::Sos`). [`Chain::new_reference`] builds a chain
//! that always runs the reference kernel; it is `#[doc(hidden)]` and exists
//! for this harness, as does [`Chain::fast_kernel_shape`].

use kilotouch_dsp::chain::{Chain, ChainCoefficients, MAX_STAGES};
use kilotouch_dsp::filter::{BiquadCoeffs, Sos};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use std::collections::BTreeSet;
use std::f64::consts::PI;

/// Largest pole radius of the random sections (stable: < 1).
const R_POLE: f64 = 0.95;
/// Largest zero radius of the random sections (zeros may lie outside the
/// unit circle).
const R_ZERO: f64 = 1.5;
/// Samples per run.
const LEN: usize = 4096;
/// Input scales: every run is repeated at each, from tiny to huge.
const SCALES: [f64; 5] = [1e-150, 1e-5, 1.0, 1e5, 1e150];
/// Largest |fast − reference| allowed, relative to the reference's peak
/// |output| in the same lane and run (see [`fast_kernel_matches_reference_at_every_size`]).
const TOL: f64 = 1e-10;

/// Two roots as (sum, product), either a complex pair of radius < `r` or
/// two real roots in (−r, r): the polynomial is 1 − sum z⁻¹ + product z⁻².
fn root_pair(rng: &mut StdRng, r: f64) -> (f64, f64) {
    if rng.random_bool(0.5) {
        let rho = r * rng.random::<f64>().sqrt();
        let theta = PI * rng.random::<f64>();
        (2.0 * rho * theta.cos(), rho * rho)
    } else {
        let p1 = rng.random_range(-r..r);
        let p2 = rng.random_range(-r..r);
        (p1 + p2, p1 * p2)
    }
}

/// A random stable section (poles of radius < [`R_POLE`]), first order
/// (b2 = a2 = 0) when `first`; |b0| log-uniform in [0.1, 3.2], either sign.
fn random_section(rng: &mut StdRng, first: bool) -> BiquadCoeffs {
    let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let g = sign * 10f64.powf(rng.random_range(-1.0..0.5));
    let c = if first {
        let p = rng.random_range(-R_POLE..R_POLE);
        let z = rng.random_range(-R_ZERO..R_ZERO);
        BiquadCoeffs::new([g, -g * z, 0.0], [1.0, -p, 0.0])
    } else {
        let (ps, pp) = root_pair(rng, R_POLE);
        let (zs, zp) = root_pair(rng, R_ZERO);
        BiquadCoeffs::new([g, -g * zs, g * zp], [1.0, -ps, pp])
    };
    let c = c.expect("finite section");
    assert!(c.is_stable(), "{c:?}");
    c
}

/// `n` random sections; each first order with probability 1/3, the last
/// one first order whenever `tail_first_order`.
fn random_path(rng: &mut StdRng, n: usize, tail_first_order: bool) -> Vec<BiquadCoeffs> {
    (0..n)
        .map(|k| {
            let first = (tail_first_order && k + 1 == n) || rng.random_bool(1.0 / 3.0);
            random_section(rng, first)
        })
        .collect()
}

/// `LEN` samples of `scale`·u, u uniform in [−1, 1), with 2 % spikes (×1e3),
/// 2 % dips (×1e-12), 1 % exact zeros and a stretch of silence.
fn random_input(rng: &mut StdRng, scale: f64) -> Vec<f64> {
    (0..LEN)
        .map(|i| {
            if (LEN / 2..LEN / 2 + 200).contains(&i) {
                return 0.0;
            }
            let u: f64 = rng.random_range(-1.0..1.0);
            let kind: f64 = rng.random();
            let v = if kind < 0.02 {
                u * 1e3
            } else if kind < 0.04 {
                u * 1e-12
            } else if kind < 0.05 {
                0.0
            } else {
                u
            };
            scale * v
        })
        .collect()
}

/// Outputs of `chain` through `process`, `stream` and `process_block`
/// (irregular block sizes), each from a fresh clone; asserts the three are
/// bit-identical (the module docs of `chain` promise it) and returns them.
fn run_all_apis(chain: &Chain, x: &[f64]) -> Vec<(f64, f64)> {
    let mut a = chain.clone();
    let per: Vec<(f64, f64)> = x.iter().map(|&v| a.process(v)).collect();
    let mut b = chain.clone();
    let mut st = Vec::with_capacity(x.len());
    b.stream(x.iter().copied(), |l, h| st.push((l, h)));
    let mut c = chain.clone();
    let (mut bl, mut bh) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    let mut start = 0;
    for size in [1, 5, 63, 64, 65, 200, 1000].iter().cycle() {
        if start >= x.len() {
            break;
        }
        let end = (start + size).min(x.len());
        c.process_block(&x[start..end], &mut bl[start..end], &mut bh[start..end]);
        start = end;
    }
    let bits = |(l, h): (f64, f64)| (l.to_bits(), h.to_bits());
    for i in 0..x.len() {
        assert_eq!(bits(per[i]), bits(st[i]), "stream differs at {i}");
        assert_eq!(bits(per[i]), bits((bl[i], bh[i])), "block differs at {i}");
    }
    for ch in [&a, &b, &c] {
        assert_eq!(ch.nonfinite_events(), 0, "no event expected");
    }
    per
}

/// The fast kernel against the reference kernel, over every supported stage
/// count: every (low, high) pair of section counts in 1..=[`MAX_STAGES`],
/// each drawn twice (first-order sections at random, and with the last
/// section of both paths first order, so that all 2·[`MAX_STAGES`] fast
/// kernels, with and without the first-order tail, run), with random stable
/// sections and random inputs at scales from 1e-150 to 1e150.
///
/// Bit-identical, because the code promises it:
/// * `process`, `stream` and `process_block` of one chain, for both kernels;
/// * the reference kernel and two `Sos` cascades of the same sections (same
///   TDF-II operations in the same order, same flush schedule), up to the
///   sign of zero: the reference kernel also runs the identity sections that
///   pad both paths to [`MAX_STAGES`], and 1·(−0) + 0 = +0, so an output
///   that `Sos` gives as −0 comes out as +0 (IEEE 754 equal, so `==`).
///
/// Within [`TOL`] = 1e-10 of the reference's peak |output| per lane and run:
/// the fast kernel. Both evaluate the same linear recursion, but the fast
/// one rounds differently: it divides each section by b0
/// (c1 = b1/b0 − a1, c2 = b2/b0 − a2), carries the state divided by the
/// product of the b0 and applies that product once at the output. Each
/// difference starts as a relative rounding error of at most
/// u = 2⁻⁵³ ≈ 1.1e-16 of one coefficient or one intermediate value, and
/// reaches the output through stable recursions whose gain from an
/// internal node to the output is bounded by the ℓ1 norm of the impulse
/// response from that node; with poles of radius < 0.95 and up to 8
/// sections the worst deviation over these draws is 1.1e-13 of the peak
/// (printed by the test). 1e-10 leaves a factor of ~1000 for other draws
/// and platforms, and is still tight: one feedback coefficient of a
/// first-order tail off by 1e-9 relative already exceeds it (checked by
/// hand while writing this test); a skipped stage or a mis-scaled state
/// errs by far more. The flush to zero of state below 1e-200 acts on
/// differently scaled states in the two kernels; its effect (of the order
/// of 1e-200 absolute) is far below this tolerance at every scale used here.
#[test]
fn fast_kernel_matches_reference_at_every_size() {
    let mut rng = StdRng::seed_from_u64(0x6b69_6c6f);
    let mut shapes = BTreeSet::new();
    let mut worst: f64 = 0.0;
    for n_low in 1..=MAX_STAGES {
        for n_high in 1..=MAX_STAGES {
            for tail_first_order in [false, true] {
                let low = random_path(&mut rng, n_low, tail_first_order);
                let high = random_path(&mut rng, n_high, tail_first_order);
                let coeffs = ChainCoefficients::new(10_000.0, low.clone(), high.clone())
                    .expect("stable sections");
                let fast = Chain::new(&coeffs);
                let reference = Chain::new_reference(&coeffs);
                assert!(fast.uses_fast_kernel());
                assert!(!reference.uses_fast_kernel());
                assert_eq!(reference.fast_kernel_shape(), None);
                let shape = fast.fast_kernel_shape().expect("fast kernel");
                assert_eq!(shape.0, n_low.max(n_high));
                if tail_first_order {
                    assert!(shape.1, "first-order tail not detected");
                }
                shapes.insert(shape);
                for scale in SCALES {
                    let x = random_input(&mut rng, scale);
                    let yf = run_all_apis(&fast, &x);
                    let yr = run_all_apis(&reference, &x);
                    let mut lo = Sos::new(low.clone()).expect("low");
                    let mut hi = Sos::new(high.clone()).expect("high");
                    let (mut peak, mut err) = ([0.0f64; 2], [0.0f64; 2]);
                    for (i, (&v, (&f, &r))) in x.iter().zip(yf.iter().zip(&yr)).enumerate() {
                        let s = (lo.process(v), hi.process(v));
                        // `==` on finite values: bit equality, except that
                        // +0 and −0 compare equal (see the doc comment).
                        assert!(
                            r == s,
                            "reference vs Sos, {n_low}/{n_high} sections, scale {scale:e}, \
                             i={i}: {r:?} vs {s:?}"
                        );
                        peak = [peak[0].max(r.0.abs()), peak[1].max(r.1.abs())];
                        err = [err[0].max((f.0 - r.0).abs()), err[1].max((f.1 - r.1).abs())];
                    }
                    for lane in 0..2 {
                        assert!(peak[lane] > 0.0 && peak[lane].is_finite());
                        let rel = err[lane] / peak[lane];
                        worst = worst.max(rel);
                        assert!(
                            rel <= TOL,
                            "{n_low}/{n_high} sections (tail {tail_first_order}), scale \
                             {scale:e}, lane {lane}: |fast − reference| = {rel:e} of the peak"
                        );
                    }
                }
            }
        }
    }
    // Every fast kernel ran: stage counts 1..=MAX_STAGES, with and without
    // the first-order tail.
    let all: BTreeSet<(usize, bool)> = (1..=MAX_STAGES)
        .flat_map(|n| [(n, false), (n, true)])
        .collect();
    assert_eq!(shapes, all);
    eprintln!("worst |fast − reference| / peak: {worst:e}");
}
