//! Fast standard-normal variates for the simulation noise (accelerometer,
//! tweezer): the 256-layer ziggurat of Marsaglia & Tsang (2000, "The
//! ziggurat method for generating random variables", J. Stat. Softw. 5(8))
//! driven by xoshiro256++ (seeded with `seed_from_u64`, as before), and
//! generated in blocks.
//!
//! **Algorithm.** The density f(x) = e^{−x²/2} (unnormalised) of |x| is
//! covered by 256 layers of equal area v: 255 rectangles [0, x_i] ×
//! [f(x_i), f(x_{i+1})] plus a base strip made of the rectangle
//! [0, r] × [0, f(r)] and the tail x > r (area v as well, x_0 = v/f(r)).
//! With r = 3.654 152 885 361 009 and v = 4.928 673 233 99 × 10⁻³ the
//! layers close at the top (x_256 = 0). One 64-bit draw gives the layer i
//! (low 8 bits) and a signed uniform u ∈ [−1, 1) (top 53 bits); x = u x_i
//! is accepted at once when |x| < x_{i+1} (≈ 99 % of draws: the part of
//! the layer under the curve for certain). Otherwise the base layer samples
//! the tail by Marsaglia's (1964) exponential method and the other layers
//! accept x when f(x_{i+1}) + U (f(x_i) − f(x_{i+1})) < f(x); a rejected
//! draw starts over. The result is exactly N(0, 1) up to the resolution of
//! the 53-bit uniforms and of the tables (computed once in f64).
//!
//! **Blocks.** [`NormalStream`] fills a buffer of [`NormalStream::BLOCK`]
//! variates in a tight loop and hands them out one by one, so the
//! generator's branches and table look-ups stay out of the simulation's
//! per-sample code. The sequence of variates does not depend on how they are
//! consumed (one by one or in slices).
//!
//! The tests check the moments, the Kolmogorov–Smirnov distance to Φ, the
//! tail probabilities beyond r and the independence of consecutive draws.

use rand::{Rng, SeedableRng};
use rand_xoshiro::SplitMix64;
use std::sync::LazyLock;

/// Right edge of the base rectangle (start of the tail), Marsaglia & Tsang.
pub const ZIG_R: f64 = 3.654_152_885_361_009;
/// Area of each of the 256 layers (with f(x) = e^{−x²/2}).
pub const ZIG_V: f64 = 4.928_673_233_99e-3;

/// Layer edges x_0 … x_256 and f(x_i).
#[derive(Debug)]
struct Tables {
    x: [f64; 257],
    f: [f64; 257],
}

fn pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp()
}

static TABLES: LazyLock<Tables> = LazyLock::new(|| {
    let mut x = [0.0; 257];
    let mut f = [0.0; 257];
    x[0] = ZIG_V / pdf(ZIG_R);
    x[1] = ZIG_R;
    for i in 2..256 {
        // Layer i−1 has area v: x_{i−1} (f(x_i) − f(x_{i−1})) = v.
        let fi = ZIG_V / x[i - 1] + pdf(x[i - 1]);
        x[i] = (-2.0 * fi.ln()).sqrt();
    }
    x[256] = 0.0;
    for i in 0..257 {
        f[i] = pdf(x[i]);
    }
    f[256] = 1.0;
    Tables { x, f }
});

/// 2⁻⁵³: a u64 shifted right by 11 times this is uniform in [0, 1).
const INV_2_53: f64 = 1.0 / 9_007_199_254_740_992.0;
/// 2⁻⁵²: an i64 shifted right by 11 times this is uniform in [−1, 1).
const INV_2_52: f64 = 1.0 / 4_503_599_627_370_496.0;

/// xoshiro256++ (Blackman & Vigna 2019), the same generator, seeding and
/// sequence as `rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64` (tested),
/// written out so that the refill loop keeps the four state words in
/// registers (the state is passed by value to the rare paths instead of
/// by reference).
#[derive(Debug, Clone, Copy)]
struct Xoshiro([u64; 4]);

impl Xoshiro {
    /// The state `Xoshiro256PlusPlus::seed_from_u64(seed)` starts from:
    /// 32 bytes of SplitMix64(seed), little-endian words (an all-zero seed
    /// is replaced by SplitMix64(0)'s output, as in rand_xoshiro).
    fn seed_from_u64(seed: u64) -> Self {
        let words = |seed: u64| {
            let mut sm = SplitMix64::seed_from_u64(seed);
            let mut bytes = [0u8; 32];
            sm.fill_bytes(&mut bytes);
            std::array::from_fn(|j| {
                let mut w = [0u8; 8];
                w.copy_from_slice(&bytes[8 * j..8 * j + 8]);
                u64::from_le_bytes(w)
            })
        };
        let s: [u64; 4] = words(seed);
        Self(if s == [0; 4] { words(0) } else { s })
    }

    /// Next 64-bit output (xoshiro256++: rotl(s0 + s3, 23) + s0).
    #[inline(always)]
    fn next_u64(&mut self) -> u64 {
        let [s0, s1, s2, s3] = self.0;
        let out = s0.wrapping_add(s3).rotate_left(23).wrapping_add(s0);
        let t = s1 << 17;
        let s2 = s2 ^ s0;
        let s3 = s3 ^ s1;
        let s1 = s1 ^ s2;
        let s0 = s0 ^ s3;
        let s2 = s2 ^ t;
        let s3 = s3.rotate_left(45);
        self.0 = [s0, s1, s2, s3];
        out
    }
}

/// Buffered N(0, 1) generator (module docs). Allocation-free after
/// construction; deterministic for a seed.
#[derive(Debug, Clone)]
pub struct NormalStream {
    rng: Xoshiro,
    buf: [f64; Self::BLOCK],
    pos: usize,
    tab: &'static Tables,
}

impl NormalStream {
    /// Variates generated per refill.
    pub const BLOCK: usize = 64;

    /// A stream seeded like `Xoshiro256PlusPlus::seed_from_u64(seed)`.
    pub fn new(seed: u64) -> Self {
        Self {
            rng: Xoshiro::seed_from_u64(seed),
            buf: [0.0; Self::BLOCK],
            pos: Self::BLOCK,
            tab: &TABLES,
        }
    }

    /// Next variate.
    #[inline(always)]
    pub fn sample(&mut self) -> f64 {
        if self.pos >= Self::BLOCK {
            self.refill();
        }
        let v = self.buf.get(self.pos).copied().unwrap_or(0.0);
        self.pos += 1;
        v
    }

    /// Next two variates (the same values, in the same order, as two calls
    /// of [`Self::sample`]), with one buffer test for both.
    #[inline(always)]
    pub fn sample2(&mut self) -> [f64; 2] {
        let p = self.pos;
        if let Some(&[a, b]) = self.buf.get(p..p + 2) {
            self.pos = p + 2;
            [a, b]
        } else {
            [self.sample(), self.sample()]
        }
    }

    /// Fill `out` with the next `out.len()` variates (the same values
    /// `sample` would return).
    pub fn fill(&mut self, out: &mut [f64]) {
        for o in out.iter_mut() {
            *o = self.sample();
        }
    }

    #[cold]
    #[inline(never)]
    fn refill(&mut self) {
        let tab = self.tab;
        // The state lives in a local (registers) for the whole block.
        let mut rng = self.rng;
        for v in self.buf.iter_mut() {
            *v = loop {
                let b = rng.next_u64();
                let i = (b & 0xff) as usize;
                let u = ((b as i64) >> 11) as f64 * INV_2_52;
                let x = u * tab.x[i];
                if x.abs() < tab.x[i + 1] {
                    break x;
                }
                // A separate copy for the rare path, so that `rng` itself is
                // never borrowed (and stays in registers).
                let mut state = rng;
                let v = Self::edge(&mut state, tab, i, x);
                rng = state;
                if let Some(v) = v {
                    break v;
                }
            };
        }
        self.rng = rng;
        self.pos = 0;
    }

    /// The rare cases: tail (i = 0) or the wedge of layer i; `None` rejects.
    #[cold]
    #[inline(never)]
    fn edge(rng: &mut Xoshiro, tab: &Tables, i: usize, x: f64) -> Option<f64> {
        let uniform = |rng: &mut Xoshiro| (rng.next_u64() >> 11) as f64 * INV_2_53;
        if i == 0 {
            // Tail beyond r (Marsaglia 1964): x = −ln(U₁)/r, y = −ln(U₂),
            // accept when 2y > x²; U in (0, 1] so that ln is finite.
            loop {
                let u1 = 1.0 - uniform(rng);
                let u2 = 1.0 - uniform(rng);
                let xt = -u1.ln() / ZIG_R;
                let yt = -u2.ln();
                if 2.0 * yt > xt * xt {
                    return Some((ZIG_R + xt).copysign(x));
                }
            }
        }
        let u = uniform(rng);
        if tab.f[i + 1] + u * (tab.f[i] - tab.f[i + 1]) < pdf(x) {
            Some(x)
        } else {
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use statrs::distribution::{ContinuousCDF, Normal};

    #[test]
    fn tables_close_the_ziggurat() {
        let t = &*TABLES;
        // Every layer has area v; the top one ends at x = 0 with f = 1.
        for i in 1..255 {
            let area = t.x[i] * (t.f[i + 1] - t.f[i]);
            assert!((area / ZIG_V - 1.0).abs() < 1e-9, "layer {i}: {area}");
        }
        let top = t.x[255] * (1.0 - t.f[255]);
        assert!((top / ZIG_V - 1.0).abs() < 1e-6, "top layer {top}");
        // Base strip: rectangle r·f(r) plus the tail ∫_r^∞ f = √(π/2) erfc(r/√2).
        let n = Normal::new(0.0, 1.0).unwrap();
        let tail = (2.0 * std::f64::consts::PI).sqrt() * (1.0 - n.cdf(ZIG_R));
        assert!(((ZIG_R * pdf(ZIG_R) + tail) / ZIG_V - 1.0).abs() < 1e-9);
        // 256 layers of area v cover the half-density ∫_0^∞ f = √(π/2) with
        // ≈ 0.7 % to spare (the wedges above the curve: the rejection rate).
        let eff = (0.5 * std::f64::consts::PI).sqrt() / (256.0 * ZIG_V);
        assert!(eff > 0.99 && eff < 1.0, "efficiency {eff}");
        assert!(t.x.windows(2).all(|w| w[0] > w[1]));
    }

    fn sample(seed: u64, n: usize) -> Vec<f64> {
        let mut s = NormalStream::new(seed);
        (0..n).map(|_| s.sample()).collect()
    }

    /// Mean, variance, skewness and excess kurtosis within 5 standard
    /// errors of N(0, 1) (SE: 1/√n, √(2/n), √(6/n), √(24/n)), on several seeds.
    #[test]
    fn moments_match_the_standard_normal() {
        let n = 2_000_000;
        for seed in [1, 2, 7, 12345] {
            let x = sample(seed, n);
            let nf = n as f64;
            let m = x.iter().sum::<f64>() / nf;
            let c = |p: i32| x.iter().map(|v| (v - m).powi(p)).sum::<f64>() / nf;
            let (v, m3, m4) = (c(2), c(3), c(4));
            let skew = m3 / v.powf(1.5);
            let kurt = m4 / (v * v) - 3.0;
            assert!(m.abs() < 5.0 / nf.sqrt(), "seed {seed}: mean {m}");
            assert!(
                (v - 1.0).abs() < 5.0 * (2.0 / nf).sqrt(),
                "seed {seed}: var {v}"
            );
            assert!(
                skew.abs() < 5.0 * (6.0 / nf).sqrt(),
                "seed {seed}: skew {skew}"
            );
            assert!(
                kurt.abs() < 5.0 * (24.0 / nf).sqrt(),
                "seed {seed}: kurt {kurt}"
            );
        }
    }

    /// Kolmogorov–Smirnov distance to Φ below the 0.1 % critical value
    /// 1.949/√n, and the two-sided tail beyond the base strip (|x| > r, drawn
    /// by the tail algorithm) and beyond 4.5 at their binomial frequencies.
    #[test]
    fn ks_distance_and_tails() {
        let n = 1_000_000;
        let phi = Normal::new(0.0, 1.0).unwrap();
        for seed in [3, 4] {
            let mut x = sample(seed, n);
            x.sort_by(f64::total_cmp);
            let mut d: f64 = 0.0;
            for (k, v) in x.iter().enumerate() {
                let f = phi.cdf(*v);
                d = d.max((f - k as f64 / n as f64).abs());
                d = d.max(((k + 1) as f64 / n as f64 - f).abs());
            }
            assert!(d < 1.949 / (n as f64).sqrt(), "seed {seed}: KS D = {d}");
        }
        let n = 20_000_000;
        let x = sample(5, n);
        for thr in [ZIG_R, 4.5] {
            let p = 2.0 * (1.0 - phi.cdf(thr));
            let count = x.iter().filter(|v| v.abs() > thr).count() as f64;
            let (mu, sd) = (n as f64 * p, (n as f64 * p * (1.0 - p)).sqrt());
            assert!(
                (count - mu).abs() < 5.0 * sd,
                "|x| > {thr}: {count} vs {mu} ± {sd}"
            );
        }
        // Nothing non-finite, and the largest values are plausible for 2e7 draws.
        assert!(x.iter().all(|v| v.is_finite() && v.abs() < 7.5));
    }

    /// Consecutive draws are uncorrelated (lag-1 and lag-2 correlation within
    /// 5/√n), the sequence is reproducible for a seed and `fill` gives the
    /// same values as `next`.
    #[test]
    fn independent_reproducible_and_consumption_invariant() {
        let n = 1_000_000;
        let x = sample(9, n);
        for lag in [1, 2, 64] {
            let r = x.iter().zip(&x[lag..]).map(|(a, b)| a * b).sum::<f64>() / (n - lag) as f64;
            assert!(r.abs() < 5.0 / (n as f64).sqrt(), "lag {lag}: {r}");
        }
        let mut a = NormalStream::new(9);
        let mut b = vec![0.0; 1000];
        a.fill(&mut b[..7]);
        a.fill(&mut b[7..]);
        assert_eq!(&b[..], &x[..1000]);
        assert_ne!(sample(10, 10), sample(9, 10));
        // `sample2` gives the same pairs, across block boundaries too.
        let mut c = NormalStream::new(9);
        c.sample();
        for k in 0..200 {
            assert_eq!(c.sample2(), [x[2 * k + 1], x[2 * k + 2]]);
        }
    }

    /// The written-out xoshiro256++ is rand_xoshiro's `Xoshiro256PlusPlus`
    /// (same seeding from a u64, same outputs), for edge and random seeds.
    #[test]
    fn generator_matches_rand_xoshiro() {
        use rand_xoshiro::Xoshiro256PlusPlus;
        for seed in [0, 1, 2, 7, 12345, u64::MAX, 0x9E37_79B9_7F4A_7C15] {
            let mut a = Xoshiro::seed_from_u64(seed);
            let mut b = Xoshiro256PlusPlus::seed_from_u64(seed);
            for _ in 0..10_000 {
                assert_eq!(a.next_u64(), b.next_u64(), "seed {seed}");
            }
        }
    }
}
