//! Maximum-length sequences (m-sequences) of order 2–32 from a Fibonacci
//! linear feedback shift register, bit-compatible with
//! `scipy.signal.max_len_seq` (same tap table, same register convention, same
//! all-ones seed): the lazy, allocation-free generator [`Mls`] for real-time
//! loops, and the [`mls_bits`] / [`mls_signal`] builders.

use super::buffer::alloc_len;
use crate::error::check_positive;
use crate::{DspError, Result};

/// Smallest supported MLS order (register length in bits).
pub const MLS_MIN_ORDER: u32 = 2;
/// Largest supported MLS order (register length in bits).
pub const MLS_MAX_ORDER: u32 = 32;

/// Feedback taps for orders 2..=32, index `order − 2`.
///
/// Source: `scipy.signal.max_len_seq` (`scipy/signal/_max_len_seq.py`,
/// `_mls_taps`, E. Larson 2014), which lists one primitive trinomial or
/// pentanomial per order. For order n and taps {t}, the register obeys the
/// recurrence a\[i+n\] = a\[i\] ⊕ ⨁ₜ a\[i+t\], whose characteristic polynomial
/// c(x) = xⁿ + Σₜ xᵗ + 1 is primitive over GF(2), so the period is 2ⁿ − 1
/// (Golomb, *Shift Register Sequences*, 1967; MacWilliams & Sloane, Proc.
/// IEEE 64(12), 1976). The unit tests re-prove primitivity of every entry.
const MLS_TAPS: [&[u32]; 31] = [
    &[1],          // 2
    &[2],          // 3
    &[3],          // 4
    &[3],          // 5
    &[5],          // 6
    &[6],          // 7
    &[7, 6, 1],    // 8
    &[5],          // 9
    &[7],          // 10
    &[9],          // 11
    &[11, 10, 4],  // 12
    &[12, 11, 8],  // 13
    &[13, 12, 2],  // 14
    &[14],         // 15
    &[15, 13, 4],  // 16
    &[14],         // 17
    &[11],         // 18
    &[18, 17, 14], // 19
    &[17],         // 20
    &[19],         // 21
    &[21],         // 22
    &[18],         // 23
    &[23, 22, 17], // 24
    &[22],         // 25
    &[25, 24, 20], // 26
    &[26, 25, 22], // 27
    &[25],         // 28
    &[27],         // 29
    &[29, 28, 7],  // 30
    &[28],         // 31
    &[31, 30, 10], // 32
];

fn check_order(order: u32) -> Result<()> {
    if (MLS_MIN_ORDER..=MLS_MAX_ORDER).contains(&order) {
        Ok(())
    } else {
        Err(DspError::InvalidParameter {
            name: "order",
            value: f64::from(order),
            reason: format!("MLS order must be in {MLS_MIN_ORDER}..={MLS_MAX_ORDER}"),
        })
    }
}

/// Feedback taps (scipy convention) of the built-in primitive polynomial of
/// the given order (table taken from `scipy.signal.max_len_seq`).
pub fn mls_taps(order: u32) -> Result<&'static [u32]> {
    check_order(order)?;
    Ok(MLS_TAPS[(order - MLS_MIN_ORDER) as usize])
}

/// Period 2ⁿ − 1 (in chips) of a maximum-length sequence of order n.
pub fn mls_period(order: u32) -> Result<u64> {
    check_order(order)?;
    Ok((1u64 << order) - 1)
}

/// Lazy maximum-length-sequence generator.
///
/// Fibonacci LFSR of `order` bits; bit j of the register holds a\[i+j\]. One
/// step outputs a\[i\] (bit 0) and shifts in a\[i+n\] = a\[i\] ⊕ ⨁ₜ a\[i+t\]. With the
/// default all-ones seed and the built-in taps the bit stream is identical to
/// `scipy.signal.max_len_seq(order)[0]`.
///
/// Bits are mapped to samples as 1 → +amplitude, 0 → −amplitude, and each
/// chip is held for `hold` samples (zero-order hold, e.g. to limit the
/// bandwidth of a PRBS to fs/hold). [`Mls::next_sample`] does no allocation,
/// no locking and cannot panic, so it can run in a real-time loop at any order.
#[derive(Debug, Clone, PartialEq)]
pub struct Mls {
    order: u32,
    feedback_mask: u64,
    seed: u64,
    state: u64,
    amplitude: f64,
    hold: u32,
    hold_left: u32,
    current: f64,
}

impl Mls {
    /// Generator with the built-in taps of `order`, amplitude `amplitude`
    /// (> 0, finite) and `hold` ≥ 1 samples per chip, seeded with all ones.
    pub fn new(order: u32, amplitude: f64, hold: u32) -> Result<Self> {
        Self::with_taps(order, mls_taps(order)?, amplitude, hold)
    }

    /// Generator with caller-supplied taps (scipy convention: each tap t in
    /// 1..order adds a\[i+t\] to the feedback). The period is 2ⁿ − 1 only if
    /// xⁿ + Σ xᵗ + 1 is primitive; this is not checked here.
    pub fn with_taps(order: u32, taps: &[u32], amplitude: f64, hold: u32) -> Result<Self> {
        check_order(order)?;
        if taps.is_empty() {
            return Err(DspError::InvalidParameter {
                name: "taps",
                value: 0.0,
                reason: "at least one feedback tap is required".into(),
            });
        }
        let mut feedback_mask = 1u64;
        for &t in taps {
            if t == 0 || t >= order {
                return Err(DspError::InvalidParameter {
                    name: "taps",
                    value: f64::from(t),
                    reason: format!("each tap must be in 1..{order}"),
                });
            }
            feedback_mask ^= 1u64 << t;
        }
        check_positive("amplitude", amplitude)?;
        if hold == 0 {
            return Err(DspError::InvalidParameter {
                name: "hold",
                value: 0.0,
                reason: "must hold each chip for at least 1 sample".into(),
            });
        }
        let seed = (1u64 << order) - 1;
        Ok(Self {
            order,
            feedback_mask,
            seed,
            state: seed,
            amplitude,
            hold,
            hold_left: 0,
            current: 0.0,
        })
    }

    /// Replace the seed (and restart). Bit j of `state` is the j-th register
    /// cell, i.e. scipy's `state[j]`. Must be non-zero and fit in `order` bits.
    pub fn with_state(mut self, state: u64) -> Result<Self> {
        if state == 0 || state >> self.order != 0 {
            return Err(DspError::InvalidParameter {
                name: "state",
                value: state as f64,
                reason: format!("must be non-zero and fit in {} bits", self.order),
            });
        }
        self.seed = state;
        self.reset();
        Ok(self)
    }

    /// Register length n.
    pub fn order(&self) -> u32 {
        self.order
    }

    /// Chips per period, 2ⁿ − 1.
    pub fn period_chips(&self) -> u64 {
        (1u64 << self.order) - 1
    }

    /// Samples per period, (2ⁿ − 1)·hold (cannot overflow: both factors < 2³²).
    pub fn period_samples(&self) -> u64 {
        self.period_chips() * u64::from(self.hold)
    }

    /// Samples per chip.
    pub fn hold(&self) -> u32 {
        self.hold
    }

    /// Output amplitude (signal units).
    pub fn amplitude(&self) -> f64 {
        self.amplitude
    }

    /// Current register contents (bit j = cell j).
    pub fn state(&self) -> u64 {
        self.state
    }

    /// Restart from the seed.
    pub fn reset(&mut self) {
        self.state = self.seed;
        self.hold_left = 0;
        self.current = 0.0;
    }

    /// Advance the register by one chip and return the output bit (true = 1).
    /// Ignores `hold`; mixing with [`Mls::next_sample`] desynchronises the hold.
    #[inline]
    pub fn next_bit(&mut self) -> bool {
        let out = self.state & 1;
        let fb = u64::from((self.state & self.feedback_mask).count_ones() & 1);
        self.state = (self.state >> 1) | (fb << (self.order - 1));
        out == 1
    }

    /// Next output sample: ±amplitude, each chip repeated `hold` times.
    #[inline]
    pub fn next_sample(&mut self) -> f64 {
        if self.hold_left == 0 {
            self.current = if self.next_bit() {
                self.amplitude
            } else {
                -self.amplitude
            };
            self.hold_left = self.hold;
        }
        self.hold_left -= 1;
        self.current
    }

    /// Fill `out` with the next samples (no allocation).
    pub fn fill(&mut self, out: &mut [f64]) {
        for v in out {
            *v = self.next_sample();
        }
    }
}

/// Endless stream of samples (see [`Mls::next_sample`]).
impl Iterator for Mls {
    type Item = f64;

    #[inline]
    fn next(&mut self) -> Option<f64> {
        Some(self.next_sample())
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (usize::MAX, None)
    }
}

/// One period of the built-in m-sequence of `order` as 0/1 values; equals
/// `scipy.signal.max_len_seq(order)[0]`.
pub fn mls_bits(order: u32) -> Result<Vec<u8>> {
    let period = mls_period(order)?;
    let too_long = || DspError::InvalidParameter {
        name: "order",
        value: f64::from(order),
        reason: "period does not fit in memory".into(),
    };
    let n = usize::try_from(period).map_err(|_| too_long())?;
    let mut bits = Vec::new();
    bits.try_reserve_exact(n).map_err(|_| too_long())?;
    let mut g = Mls::new(order, 1.0, 1)?;
    bits.extend((0..n).map(|_| u8::from(g.next_bit())));
    Ok(bits)
}

/// `periods` whole periods of the ±`amplitude` m-sequence of `order` with
/// `hold` samples per chip: (2ⁿ − 1)·hold·periods samples.
pub fn mls_signal(order: u32, amplitude: f64, hold: u32, periods: usize) -> Result<Vec<f64>> {
    let mut g = Mls::new(order, amplitude, hold)?;
    if periods == 0 {
        return Err(DspError::InvalidParameter {
            name: "periods",
            value: 0.0,
            reason: "must be ≥ 1".into(),
        });
    }
    let len = u128::from(g.period_samples()) * periods as u128;
    let mut v = alloc_len(len, "periods")?;
    // `alloc_len` succeeded, so `len` fits in usize.
    v.extend((0..len as usize).map(|_| g.next_sample()));
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use realfft::RealFftPlanner;

    // ---- GF(2) polynomial arithmetic, independent of the generator --------

    /// a·b mod p over GF(2); polynomials as bit masks, deg p = n ≤ 32.
    fn gf2_mulmod(a: u64, b: u64, p: u64, n: u32) -> u64 {
        let mut r = 0u64;
        for i in (0..n).rev() {
            r <<= 1;
            if r >> n & 1 == 1 {
                r ^= p;
            }
            if b >> i & 1 == 1 {
                r ^= a;
            }
        }
        r
    }

    fn gf2_powmod(mut base: u64, mut e: u64, p: u64, n: u32) -> u64 {
        let mut r = 1u64;
        while e > 0 {
            if e & 1 == 1 {
                r = gf2_mulmod(r, base, p, n);
            }
            base = gf2_mulmod(base, base, p, n);
            e >>= 1;
        }
        r
    }

    fn prime_factors(mut m: u64) -> Vec<u64> {
        let mut f = Vec::new();
        let mut d = 2u64;
        while d * d <= m {
            if m.is_multiple_of(d) {
                f.push(d);
                while m.is_multiple_of(d) {
                    m /= d;
                }
            }
            d += 1;
        }
        if m > 1 {
            f.push(m);
        }
        f
    }

    /// c(x) primitive ⇔ x^(2ⁿ−1) = 1 and x^((2ⁿ−1)/q) ≠ 1 for every prime q | 2ⁿ−1
    /// (Lidl & Niederreiter, *Finite Fields*, ch. 3: x has order 2ⁿ − 1).
    fn is_primitive(n: u32, p: u64) -> bool {
        let m = (1u64 << n) - 1;
        let x = 0b10;
        gf2_powmod(x, m, p, n) == 1
            && prime_factors(m)
                .into_iter()
                .all(|q| gf2_powmod(x, m / q, p, n) != 1)
    }

    fn char_poly(order: u32) -> u64 {
        let mut p = (1u64 << order) | 1;
        for &t in mls_taps(order).unwrap() {
            p ^= 1 << t;
        }
        p
    }

    #[test]
    fn tap_table_polynomials_are_primitive() {
        for order in MLS_MIN_ORDER..=MLS_MAX_ORDER {
            let taps = mls_taps(order).unwrap();
            assert!(!taps.is_empty());
            assert!(taps.iter().all(|&t| t >= 1 && t < order), "order {order}");
            assert!(is_primitive(order, char_poly(order)), "order {order}");
        }
        // The primitivity test itself must reject known non-primitive polynomials:
        // x⁴+x²+1 = (x²+x+1)² (reducible), x⁴+x³+x²+x+1 (irreducible, order 5),
        // x⁶+x³+1 (irreducible, order 9).
        assert!(!is_primitive(4, 0b10101));
        assert!(!is_primitive(4, 0b11111));
        assert!(!is_primitive(6, 0b1001001));
        assert!(is_primitive(4, 0b11001)); // x⁴+x³+1
    }

    /// Independent reference: scipy's ring-buffer loop (`_max_len_seq_inner`).
    fn scipy_reference(order: u32, taps: &[u32], len: usize) -> Vec<u8> {
        let n = order as usize;
        let mut state = vec![1u8; n];
        let mut idx = 0;
        let mut seq = Vec::with_capacity(len);
        for _ in 0..len {
            let mut fb = state[idx];
            seq.push(fb);
            for &t in taps {
                fb ^= state[(t as usize + idx) % n];
            }
            state[idx] = fb;
            idx = (idx + 1) % n;
        }
        seq
    }

    #[test]
    fn order_4_matches_scipy_exactly() {
        // scipy.signal.max_len_seq(4)[0] (REFERENCE-VALUES.md), taps {3}:
        // x⁴ + x³ + 1. scipy's table holds taps [3] for nbits = 4, not [1].
        let expected = [1u8, 1, 1, 1, 0, 1, 0, 1, 1, 0, 0, 1, 0, 0, 0];
        assert_eq!(mls_taps(4).unwrap(), &[3]);
        assert_eq!(mls_bits(4).unwrap(), expected);
        assert_eq!(scipy_reference(4, &[3], 15), expected);
    }

    #[test]
    fn all_orders_match_the_scipy_loop() {
        for order in MLS_MIN_ORDER..=MLS_MAX_ORDER {
            let taps = mls_taps(order).unwrap();
            let len = 3000;
            let mut g = Mls::new(order, 1.0, 1).unwrap();
            let ours: Vec<u8> = (0..len).map(|_| u8::from(g.next_bit())).collect();
            assert_eq!(ours, scipy_reference(order, taps, len), "order {order}");
        }
    }

    /// Number of steps until the register first returns to its seed.
    fn brute_force_period(order: u32, limit: u64) -> Option<u64> {
        let mut g = Mls::new(order, 1.0, 1).unwrap();
        let seed = g.state();
        for k in 1..=limit {
            g.next_bit();
            if g.state() == seed {
                return Some(k);
            }
        }
        None
    }

    #[test]
    fn period_is_2n_minus_1_for_orders_2_to_24_by_brute_force() {
        for order in 2..=24u32 {
            let n = mls_period(order).unwrap();
            assert_eq!(n, (1u64 << order) - 1);
            assert_eq!(brute_force_period(order, n + 1), Some(n), "order {order}");
        }
        // And the emitted sequence itself repeats with that period.
        for order in 2..=12u32 {
            let n = mls_period(order).unwrap() as usize;
            let s = mls_signal(order, 1.0, 1, 2).unwrap();
            assert_eq!(s[..n], s[n..], "order {order}");
        }
    }

    #[test]
    fn order_31_first_period_spot_check() {
        // A window of n consecutive bits (= the register state) never repeats
        // within a period: check the first 2²⁰ windows of order 31 are
        // distinct and never the all-zero lock-up state.
        let mut g = Mls::new(31, 1.0, 1).unwrap();
        let mut seen = std::collections::HashSet::with_capacity(1 << 20);
        for _ in 0..(1 << 20) {
            assert_ne!(g.state(), 0);
            assert!(seen.insert(g.state()));
            g.next_bit();
        }
        // Balance over a long stretch: the fraction of ones ≈ 1/2.
        let mut g = Mls::new(31, 1.0, 1).unwrap();
        let m = 1u64 << 22;
        let ones = (0..m).filter(|_| g.next_bit()).count() as f64;
        assert!((ones / m as f64 - 0.5).abs() < 5.0 / (m as f64).sqrt());
    }

    #[test]
    fn order_31_full_period_by_brute_force() {
        // 2³¹ − 1 register steps (≈ 4 s in the optimised test profile): the
        // seed comes back exactly after one period and not before.
        let n = mls_period(31).unwrap();
        assert_eq!(brute_force_period(31, n + 1), Some(n));
    }

    #[test]
    fn period_sum_is_plus_amplitude() {
        for order in 2..=18u32 {
            let a = 0.75;
            let s = mls_signal(order, a, 1, 1).unwrap();
            let sum: f64 = s.iter().sum();
            assert_eq!(sum, a, "order {order}"); // 2^(n−1) ones, 2^(n−1)−1 zeros
            assert!(s.iter().all(|&v| v == a || v == -a));
        }
    }

    #[test]
    fn circular_autocorrelation_is_two_valued() {
        for order in 2..=14u32 {
            let s: Vec<i32> = mls_bits(order)
                .unwrap()
                .iter()
                .map(|&b| 2 * i32::from(b) - 1)
                .collect();
            let n = s.len();
            for lag in 0..n {
                let r: i32 = (0..n).map(|i| s[i] * s[(i + lag) % n]).sum();
                let expected = if lag == 0 { n as i32 } else { -1 };
                assert_eq!(r, expected, "order {order} lag {lag}");
            }
        }
    }

    #[test]
    fn power_spectrum_is_flat() {
        let mut planner = RealFftPlanner::<f64>::new();
        for order in 2..=16u32 {
            let mut s = mls_signal(order, 1.0, 1, 1).unwrap();
            let n = s.len();
            let fft = planner.plan_fft_forward(n);
            let mut out = fft.make_output_vec();
            fft.process(&mut s, &mut out).unwrap();
            assert!((out[0].norm_sqr() - 1.0).abs() < 1e-9, "DC = sum² = 1");
            for (k, x) in out.iter().enumerate().skip(1) {
                let rel = (x.norm_sqr() - (n + 1) as f64).abs() / (n + 1) as f64;
                assert!(rel < 1e-9, "order {order} bin {k}: {}", x.norm_sqr());
            }
        }
    }

    #[test]
    fn hold_repeats_each_chip() {
        let hold = 3;
        let chips = mls_signal(7, 2.0, 1, 1).unwrap();
        let held = mls_signal(7, 2.0, hold, 2).unwrap();
        assert_eq!(held.len(), 2 * chips.len() * hold as usize);
        for (i, &v) in held.iter().enumerate() {
            assert_eq!(v, chips[(i / hold as usize) % chips.len()]);
        }
        let g = Mls::new(7, 2.0, hold).unwrap();
        assert_eq!(g.period_samples(), 127 * 3);
        // The iterator and fill() agree with the builder.
        let it: Vec<f64> = Mls::new(7, 2.0, hold).unwrap().take(held.len()).collect();
        assert_eq!(it, held);
        let mut g = Mls::new(7, 2.0, hold).unwrap();
        let mut buf = vec![0.0; 100];
        g.fill(&mut buf);
        assert_eq!(buf[..], held[..100]);
        g.reset();
        assert_eq!(g.next_sample(), held[0]);
    }

    #[test]
    fn custom_state_and_taps() {
        // Seed = the register after k steps ⇒ output is shifted by k.
        let mut g = Mls::new(10, 1.0, 1).unwrap();
        for _ in 0..37 {
            g.next_bit();
        }
        let shifted = Mls::new(10, 1.0, 1).unwrap().with_state(g.state()).unwrap();
        let a: Vec<f64> = shifted.take(500).collect();
        let b: Vec<f64> = Mls::new(10, 1.0, 1).unwrap().skip(37).take(500).collect();
        assert_eq!(a, b);
        // x⁴ + x + 1 (taps {1}) is also primitive: period 15, a different sequence.
        let mut g = Mls::with_taps(4, &[1], 1.0, 1).unwrap();
        let seq: Vec<bool> = (0..15).map(|_| g.next_bit()).collect();
        assert_eq!(g.state(), 0b1111);
        assert_eq!(seq.iter().filter(|&&b| b).count(), 8);
        assert!(Mls::new(4, 1.0, 1).unwrap().with_state(0).is_err());
        assert!(Mls::new(4, 1.0, 1).unwrap().with_state(16).is_err());
    }

    #[test]
    fn mls_parameter_errors() {
        let name = |e: DspError| match e {
            DspError::InvalidParameter { name, .. } => name,
            other => panic!("unexpected {other:?}"),
        };
        assert_eq!(name(Mls::new(1, 1.0, 1).unwrap_err()), "order");
        assert_eq!(name(Mls::new(33, 1.0, 1).unwrap_err()), "order");
        assert_eq!(name(Mls::new(5, 0.0, 1).unwrap_err()), "amplitude");
        assert_eq!(name(Mls::new(5, f64::NAN, 1).unwrap_err()), "amplitude");
        assert_eq!(name(Mls::new(5, 1.0, 0).unwrap_err()), "hold");
        assert_eq!(name(Mls::with_taps(5, &[5], 1.0, 1).unwrap_err()), "taps");
        assert_eq!(name(Mls::with_taps(5, &[], 1.0, 1).unwrap_err()), "taps");
        assert_eq!(name(mls_signal(5, 1.0, 1, 0).unwrap_err()), "periods");
        // 2³²·2³²·2⁶⁴ samples cannot be allocated: an error, not an abort.
        assert_eq!(
            name(mls_signal(32, 1.0, u32::MAX, usize::MAX).unwrap_err()),
            "periods"
        );
    }
}
