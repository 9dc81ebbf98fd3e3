//! IIR filtering in second-order sections, transposed direct form II.
//!
//! A [`Biquad`] realises
//!
//! ```text
//!         b0 + b1 z⁻¹ + b2 z⁻²
//! H(z) = ----------------------        (a0 normalised to 1)
//!          1 + a1 z⁻¹ + a2 z⁻²
//! ```
//!
//! in transposed direct form II (Oppenheim & Schafer, *Discrete-Time Signal
//! Processing*, 3rd ed., §6.5, Fig. 6.26):
//!
//! ```text
//! y[n]    = b0 x[n] + s1[n]
//! s1[n+1] = (b1 x[n] + s2[n]) − a1 y[n]
//! s2[n+1] = b2 x[n] − a2 y[n]
//! ```
//!
//! The operations are evaluated in exactly this order (the parenthesised sum
//! first, which keeps the feedback path y → s1 two operations long). The
//! reference kernel of the signal chain in [`crate::chain`] uses the same
//! order per lane, so it is bit-identical to an [`Sos`] built from the same
//! sections (up to the sign of a zero output); the chain's fast kernel
//! normalises each section to b0 = 1 and agrees with it to rounding.
//!
//! An [`Sos`] is a cascade of biquads. All coefficients and state are `f64`.
//!
//! # Real-time guarantees
//! `process`, `process_block` and `process_in_place` allocate nothing, lock
//! nothing and never panic.
//!
//! * **Non-finite input** (NaN, ±∞): the output for that sample is 0, the
//!   state is reset to zero and the event is counted
//!   ([`Sos::nonfinite_events`]).
//! * **Non-finite state** (overflow from absurdly large but finite input): if
//!   the output of a sample is non-finite, it is replaced by 0, the state is
//!   reset and the event counted. Every [`FLUSH_INTERVAL`] samples the whole
//!   state is also checked, so a non-finite value hidden in `s2` is caught.
//! * **Denormals**: every [`FLUSH_INTERVAL`] samples each state variable with
//!   magnitude below [`FLUSH_THRESHOLD`] is set to exactly 0. After the input
//!   falls silent the state therefore reaches exact zero instead of decaying
//!   through the subnormal range (where x86 arithmetic can be ~100× slower and
//!   floating-point limit cycles can persist). The absolute error introduced
//!   is below 1e-200 per flush, irrelevant for any physical signal. The check
//!   runs off the per-sample hot path (a counter and a predictable branch).

use crate::{C64, DspError, Result};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// State magnitudes below this are flushed to exactly zero (see module docs).
pub const FLUSH_THRESHOLD: f64 = 1e-200;

/// Number of samples between two state maintenance passes (denormal flush and
/// non-finite check).
pub const FLUSH_INTERVAL: u32 = 64;

/// Coefficients of one second-order section, a0 normalised to 1.
///
/// A first-order section has `b2 = a2 = 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BiquadCoeffs {
    /// Numerator coefficient of z⁰.
    pub b0: f64,
    /// Numerator coefficient of z⁻¹.
    pub b1: f64,
    /// Numerator coefficient of z⁻².
    pub b2: f64,
    /// Denominator coefficient of z⁻¹ (a0 = 1).
    pub a1: f64,
    /// Denominator coefficient of z⁻² (a0 = 1).
    pub a2: f64,
}

impl BiquadCoeffs {
    /// The identity section H(z) = 1.
    pub const IDENTITY: Self = Self {
        b0: 1.0,
        b1: 0.0,
        b2: 0.0,
        a1: 0.0,
        a2: 0.0,
    };

    /// Section from un-normalised coefficients `b = [b0, b1, b2]`,
    /// `a = [a0, a1, a2]`; everything is divided by a0.
    pub fn new(b: [f64; 3], a: [f64; 3]) -> Result<Self> {
        if b.iter().chain(a.iter()).any(|c| !c.is_finite()) {
            return Err(DspError::InvalidInput(
                "biquad coefficients must be finite".into(),
            ));
        }
        if a[0] == 0.0 {
            return Err(DspError::InvalidParameter {
                name: "a0",
                value: a[0],
                reason: "leading denominator coefficient must be non-zero".into(),
            });
        }
        let c = Self {
            b0: b[0] / a[0],
            b1: b[1] / a[0],
            b2: b[2] / a[0],
            a1: a[1] / a[0],
            a2: a[2] / a[0],
        };
        if !c.is_finite() {
            return Err(DspError::Numerical(
                "biquad coefficients overflow after normalisation by a0".into(),
            ));
        }
        Ok(c)
    }

    /// A pure gain section H(z) = g.
    pub fn gain(g: f64) -> Result<Self> {
        Self::new([g, 0.0, 0.0], [1.0, 0.0, 0.0])
    }

    /// True when all five coefficients are finite.
    pub fn is_finite(&self) -> bool {
        [self.b0, self.b1, self.b2, self.a1, self.a2]
            .iter()
            .all(|c| c.is_finite())
    }

    /// True when both poles are strictly inside the unit circle (stability
    /// triangle: |a2| < 1 and |a1| < 1 + a2; Oppenheim & Schafer, Prob. 5.x /
    /// Jury criterion for second-order polynomials).
    pub fn is_stable(&self) -> bool {
        self.is_finite() && self.a2.abs() < 1.0 && self.a1.abs() < 1.0 + self.a2
    }

    /// True for a first-order section (b2 = a2 = 0).
    pub fn is_first_order(&self) -> bool {
        self.b2 == 0.0 && self.a2 == 0.0
    }

    /// The same section with its numerator multiplied by `g`.
    pub fn scaled(&self, g: f64) -> Self {
        Self {
            b0: self.b0 * g,
            b1: self.b1 * g,
            b2: self.b2 * g,
            ..*self
        }
    }

    /// Frequency response at `f` hertz for sample rate `fs` hertz.
    pub fn response(&self, f: f64, fs: f64) -> C64 {
        self.response_at(2.0 * PI * f / fs)
    }

    /// Frequency response at the normalised angular frequency `w` (rad/sample).
    pub fn response_at(&self, w: f64) -> C64 {
        let e = Expansion::new(w);
        e.eval([self.b0, self.b1, self.b2]) / e.eval([1.0, self.a1, self.a2])
    }

    /// Response H and its derivative dH/dw (w in rad/sample), used for the
    /// analytic group delay τ = −Im(H'/H).
    pub fn response_and_derivative(&self, w: f64) -> (C64, C64) {
        let e = Expansion::new(w);
        let (b, db) = e.eval_with_derivative([self.b0, self.b1, self.b2]);
        let (a, da) = e.eval_with_derivative([1.0, self.a1, self.a2]);
        (b / a, (db * a - b * da) / (a * a))
    }
}

/// Evaluation of p0 + p1 q + p2 q² at q = z⁻¹ = e^{−jw}, expanded around
/// c = ±1 (the nearer of DC or Nyquist): q = c + u.
///
/// For poles close to z = 1 (low fc/fs) the naive sum 1 + a1 q + a2 q²
/// cancels catastrophically. In the expanded form the constant term
/// (p0 + c p1) + p2 and the linear term p1 + 2c p2 are computed exactly by
/// Sterbenz's lemma in that case, and u = −2 sin²(w/2) − j sin w (for c = 1)
/// carries no cancellation, so the response of the *stored* coefficients is
/// evaluated to near machine precision even at fc/fs = 1e-4.
struct Expansion {
    c: f64,
    u: C64,
    /// dq/dw = −j q.
    dq: C64,
}

impl Expansion {
    fn new(w: f64) -> Self {
        let (s, co) = w.sin_cos();
        let half = (0.5 * w).sin_cos();
        let q = C64::new(co, -s);
        if co >= 0.0 {
            // u = q − 1 = (cos w − 1) − j sin w = −2 sin²(w/2) − j sin w
            Self {
                c: 1.0,
                u: C64::new(-2.0 * half.0 * half.0, -s),
                dq: C64::new(0.0, -1.0) * q,
            }
        } else {
            // u = q + 1 = (1 + cos w) − j sin w = 2 cos²(w/2) − j sin w
            Self {
                c: -1.0,
                u: C64::new(2.0 * half.1 * half.1, -s),
                dq: C64::new(0.0, -1.0) * q,
            }
        }
    }

    fn coefficients(&self, p: [f64; 3]) -> [f64; 3] {
        let g0 = (p[0] + self.c * p[1]) + p[2];
        let g1 = p[1] + 2.0 * self.c * p[2];
        [g0, g1, p[2]]
    }

    fn eval(&self, p: [f64; 3]) -> C64 {
        let g = self.coefficients(p);
        (self.u * g[2] + g[1]) * self.u + g[0]
    }

    fn eval_with_derivative(&self, p: [f64; 3]) -> (C64, C64) {
        let g = self.coefficients(p);
        let v = (self.u * g[2] + g[1]) * self.u + g[0];
        let dv_du = self.u * (2.0 * g[2]) + g[1];
        (v, dv_du * self.dq)
    }
}

/// One transposed-direct-form-II step (see module docs for the equations and
/// the operation order). `s = [s1, s2]`.
#[inline(always)]
pub(crate) fn tdf2_step(c: &BiquadCoeffs, s: &mut [f64; 2], x: f64) -> f64 {
    let y = c.b0 * x + s[0];
    s[0] = (c.b1 * x + s[1]) - c.a1 * y;
    s[1] = c.b2 * x - c.a2 * y;
    y
}

/// Flush tiny state values to zero; returns false if any value is non-finite.
#[inline]
pub(crate) fn flush_state(s: &mut [f64; 2]) -> bool {
    let mut finite = true;
    for v in s.iter_mut() {
        if !v.is_finite() {
            finite = false;
        } else if v.abs() < FLUSH_THRESHOLD {
            *v = 0.0;
        }
    }
    finite
}

fn check_coeffs(c: &BiquadCoeffs) -> Result<()> {
    if c.is_finite() {
        Ok(())
    } else {
        Err(DspError::InvalidInput(format!(
            "biquad coefficients must be finite: {c:?}"
        )))
    }
}

/// The guard of [`Biquad`] and [`Sos`] (module docs): non-finite events
/// counted and the state reset, the state flushed every [`FLUSH_INTERVAL`]
/// samples. Works on a cascade of TDF-II sections (one for a [`Biquad`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Guard {
    /// Non-finite events (input, output or state) since construction.
    nonfinite: u64,
    /// Samples since the last flush.
    tick: u32,
}

impl Guard {
    /// Filter one sample through the sections `coeffs` with their states
    /// `state`, first section first: the output, or 0 (state reset, event
    /// counted) when the input or the output is non-finite.
    #[inline(always)]
    fn process(&mut self, coeffs: &[BiquadCoeffs], state: &mut [[f64; 2]], x: f64) -> f64 {
        if !x.is_finite() {
            self.on_nonfinite(state);
            return 0.0;
        }
        let mut v = x;
        for (c, s) in coeffs.iter().zip(state.iter_mut()) {
            v = tdf2_step(c, s, v);
        }
        if !v.is_finite() {
            self.on_nonfinite(state);
            return 0.0;
        }
        self.tick += 1;
        if self.tick >= FLUSH_INTERVAL {
            self.maintain(state);
        }
        v
    }

    /// Zero the state and restart the flush interval (events are kept).
    #[inline]
    fn reset(&mut self, state: &mut [[f64; 2]]) {
        state.fill([0.0; 2]);
        self.tick = 0;
    }

    #[cold]
    #[inline(never)]
    fn on_nonfinite(&mut self, state: &mut [[f64; 2]]) {
        self.nonfinite += 1;
        self.reset(state);
    }

    /// Flush every section's tiny state values to zero; a non-finite one
    /// counts as an event and resets the state.
    #[cold]
    #[inline(never)]
    fn maintain(&mut self, state: &mut [[f64; 2]]) {
        self.tick = 0;
        let mut finite = true;
        for s in state.iter_mut() {
            finite &= flush_state(s);
        }
        if !finite {
            self.on_nonfinite(state);
        }
    }
}

/// Pass `min(input.len(), output.len())` samples of `input` through
/// `process` into `output`; returns that count.
#[inline]
fn process_block_with(
    input: &[f64],
    output: &mut [f64],
    mut process: impl FnMut(f64) -> f64,
) -> usize {
    let n = input.len().min(output.len());
    for (o, &x) in output[..n].iter_mut().zip(&input[..n]) {
        *o = process(x);
    }
    n
}

/// A single second-order section with its state (transposed direct form II).
#[derive(Debug, Clone, PartialEq)]
pub struct Biquad {
    c: BiquadCoeffs,
    s: [f64; 2],
    guard: Guard,
}

impl Biquad {
    /// New section with zero state. Errors on non-finite coefficients.
    pub fn new(c: BiquadCoeffs) -> Result<Self> {
        check_coeffs(&c)?;
        Ok(Self {
            c,
            s: [0.0; 2],
            guard: Guard::default(),
        })
    }

    /// The coefficients.
    pub fn coefficients(&self) -> BiquadCoeffs {
        self.c
    }

    /// Replace the coefficients, keeping the state.
    pub fn set_coefficients(&mut self, c: BiquadCoeffs) -> Result<()> {
        check_coeffs(&c)?;
        self.c = c;
        Ok(())
    }

    /// Current state `[s1, s2]`.
    pub fn state(&self) -> [f64; 2] {
        self.s
    }

    /// Filter one sample (guarded: see module docs).
    #[inline]
    pub fn process(&mut self, x: f64) -> f64 {
        self.guard.process(
            std::slice::from_ref(&self.c),
            std::slice::from_mut(&mut self.s),
            x,
        )
    }

    /// Filter `input` into `output`; processes `min(input.len(), output.len())`
    /// samples and returns that count.
    pub fn process_block(&mut self, input: &[f64], output: &mut [f64]) -> usize {
        process_block_with(input, output, |x| self.process(x))
    }

    /// Filter a buffer in place.
    pub fn process_in_place(&mut self, buf: &mut [f64]) {
        for v in buf.iter_mut() {
            *v = self.process(*v);
        }
    }

    /// Zero the state (the event counter is kept).
    pub fn reset(&mut self) {
        self.guard.reset(std::slice::from_mut(&mut self.s));
    }

    /// Number of non-finite events (input or state) since construction.
    pub fn nonfinite_events(&self) -> u64 {
        self.guard.nonfinite
    }

    /// Frequency response at `f` hertz for sample rate `fs` hertz.
    pub fn response(&self, f: f64, fs: f64) -> C64 {
        self.c.response(f, fs)
    }
}

/// A cascade of second-order sections (transposed direct form II each).
///
/// Sections are stored at construction; processing never allocates.
#[derive(Debug, Clone, PartialEq)]
pub struct Sos {
    coeffs: Vec<BiquadCoeffs>,
    state: Vec<[f64; 2]>,
    guard: Guard,
}

impl Sos {
    /// Cascade of the given sections, first section applied first. Errors on
    /// an empty list or non-finite coefficients.
    pub fn new(sections: Vec<BiquadCoeffs>) -> Result<Self> {
        if sections.is_empty() {
            return Err(DspError::InvalidInput(
                "a second-order-section cascade needs at least one section".into(),
            ));
        }
        for c in &sections {
            check_coeffs(c)?;
        }
        let n = sections.len();
        Ok(Self {
            coeffs: sections,
            state: vec![[0.0; 2]; n],
            guard: Guard::default(),
        })
    }

    /// Number of sections.
    pub fn len(&self) -> usize {
        self.coeffs.len()
    }

    /// Always false (an `Sos` has at least one section); provided for API symmetry.
    pub fn is_empty(&self) -> bool {
        self.coeffs.is_empty()
    }

    /// The sections, first applied first.
    pub fn sections(&self) -> &[BiquadCoeffs] {
        &self.coeffs
    }

    /// Current state of every section, `[s1, s2]` each.
    pub fn state(&self) -> &[[f64; 2]] {
        &self.state
    }

    /// True when every section is stable (see [`BiquadCoeffs::is_stable`]).
    pub fn is_stable(&self) -> bool {
        self.coeffs.iter().all(BiquadCoeffs::is_stable)
    }

    /// Replace the coefficients (same number of sections), keeping the state.
    /// Does not allocate.
    pub fn set_sections(&mut self, sections: &[BiquadCoeffs]) -> Result<()> {
        if sections.len() != self.coeffs.len() {
            return Err(DspError::InvalidInput(format!(
                "expected {} sections, got {}",
                self.coeffs.len(),
                sections.len()
            )));
        }
        for c in sections {
            check_coeffs(c)?;
        }
        self.coeffs.copy_from_slice(sections);
        Ok(())
    }

    /// Filter one sample through the cascade (guarded: see module docs).
    #[inline]
    pub fn process(&mut self, x: f64) -> f64 {
        self.guard.process(&self.coeffs, &mut self.state, x)
    }

    /// Filter `input` into `output`; processes `min(input.len(), output.len())`
    /// samples and returns that count. Identical, sample for sample, to
    /// calling [`Sos::process`] in a loop.
    pub fn process_block(&mut self, input: &[f64], output: &mut [f64]) -> usize {
        process_block_with(input, output, |x| self.process(x))
    }

    /// Filter a buffer in place.
    pub fn process_in_place(&mut self, buf: &mut [f64]) {
        for v in buf.iter_mut() {
            *v = self.process(*v);
        }
    }

    /// Zero the state (the event counter is kept).
    pub fn reset(&mut self) {
        self.guard.reset(&mut self.state);
    }

    /// Number of non-finite events (input or state) since construction.
    pub fn nonfinite_events(&self) -> u64 {
        self.guard.nonfinite
    }

    /// Frequency response at `f` hertz for sample rate `fs` hertz: the
    /// product of the section responses.
    pub fn response(&self, f: f64, fs: f64) -> C64 {
        sections_response(&self.coeffs, f, fs)
    }
}

/// Response of a cascade of sections at `f` hertz (sample rate `fs` hertz).
pub fn sections_response(sections: &[BiquadCoeffs], f: f64, fs: f64) -> C64 {
    let w = 2.0 * PI * f / fs;
    sections
        .iter()
        .fold(C64::new(1.0, 0.0), |h, c| h * c.response_at(w))
}

/// Response H and derivative dH/dw (w in rad/sample) of a cascade, by the
/// product rule (no division by section responses, so exact zeros are fine).
pub fn sections_response_and_derivative(sections: &[BiquadCoeffs], w: f64) -> (C64, C64) {
    let mut h = C64::new(1.0, 0.0);
    let mut dh = C64::new(0.0, 0.0);
    for c in sections {
        let (hk, dhk) = c.response_and_derivative(w);
        dh = dh * hk + h * dhk;
        h *= hk;
    }
    (h, dh)
}

/// Group delay in seconds of a cascade at `f` hertz: τ = −Im(H'/H)/fs with
/// H' = dH/dw (w in rad/sample). Analytic, not a finite difference.
pub fn sections_group_delay(sections: &[BiquadCoeffs], f: f64, fs: f64) -> f64 {
    let (h, dh) = sections_response_and_derivative(sections, 2.0 * PI * f / fs);
    -(dh / h).im / fs
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::design::{self, FilterKind, Prewarp};

    /// xorshift64* uniform noise in [−1, 1): fast and deterministic (also
    /// used by the chain's tests).
    pub(crate) struct Noise(pub(crate) u64);
    impl Noise {
        pub(crate) fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let r = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
            (r >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
    }

    fn lp2(fc: f64, fs: f64) -> BiquadCoeffs {
        design::butter(2, fc, fs, FilterKind::Lowpass, Prewarp::AtCutoff).unwrap()[0]
    }

    /// Direct-form-I reference written from the difference equation
    /// y = b0 x + b1 x1 + b2 x2 − a1 y1 − a2 y2 (a different realisation).
    fn df1(c: &BiquadCoeffs, x: &[f64]) -> Vec<f64> {
        let (mut x1, mut x2, mut y1, mut y2) = (0.0, 0.0, 0.0, 0.0);
        x.iter()
            .map(|&v| {
                let y = c.b0 * v + c.b1 * x1 + c.b2 * x2 - c.a1 * y1 - c.a2 * y2;
                x2 = x1;
                x1 = v;
                y2 = y1;
                y1 = y;
                y
            })
            .collect()
    }

    #[test]
    fn tdf2_matches_difference_equation() {
        let c = BiquadCoeffs::new([0.3, -0.2, 0.1], [2.0, -1.0, 0.5]).unwrap();
        assert_eq!(c.b0, 0.15);
        assert_eq!(c.a1, -0.5);
        let mut n = Noise(7);
        let x: Vec<f64> = (0..2000).map(|_| n.next()).collect();
        let want = df1(&c, &x);
        let mut bq = Biquad::new(c).unwrap();
        for (i, (&xi, &wi)) in x.iter().zip(&want).enumerate() {
            let y = bq.process(xi);
            assert!((y - wi).abs() <= 1e-13, "sample {i}: {y} vs {wi}");
        }
    }

    #[test]
    fn impulse_response_of_first_order_section() {
        // H(z) = 1/(1 − p z⁻¹): h[n] = pⁿ.
        let p = 0.9;
        let mut s = Sos::new(vec![
            BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, -p, 0.0]).unwrap(),
        ])
        .unwrap();
        for n in 0..50 {
            let y = s.process(if n == 0 { 1.0 } else { 0.0 });
            assert!((y - p.powi(n)).abs() < 1e-14, "n={n}");
        }
    }

    #[test]
    fn block_in_place_and_per_sample_are_identical() {
        let secs = vec![lp2(300.0, 10_000.0), lp2(1200.0, 10_000.0)];
        let mut n = Noise(3);
        let x: Vec<f64> = (0..1000).map(|_| n.next()).collect();
        let mut a = Sos::new(secs.clone()).unwrap();
        let per: Vec<f64> = x.iter().map(|&v| a.process(v)).collect();
        let mut b = Sos::new(secs.clone()).unwrap();
        let mut blk = vec![0.0; x.len()];
        assert_eq!(b.process_block(&x, &mut blk), x.len());
        let mut c = Sos::new(secs).unwrap();
        let mut inp = x.clone();
        c.process_in_place(&mut inp);
        assert_eq!(per, blk);
        assert_eq!(per, inp);
        // Mismatched lengths: the shorter one wins, no panic.
        let mut short = [0.0; 10];
        assert_eq!(b.process_block(&x, &mut short), 10);
    }

    #[test]
    fn cascade_equals_sections_applied_one_after_another() {
        let s1 = lp2(300.0, 10_000.0);
        let s2 = BiquadCoeffs::new([1.0, -0.5, 0.25], [1.0, 0.3, 0.2]).unwrap();
        let mut n = Noise(11);
        let x: Vec<f64> = (0..500).map(|_| n.next()).collect();
        let mut cas = Sos::new(vec![s1, s2]).unwrap();
        let mut b1 = Biquad::new(s1).unwrap();
        let mut b2 = Biquad::new(s2).unwrap();
        for &v in &x {
            assert_eq!(cas.process(v), b2.process(b1.process(v)));
        }
    }

    #[test]
    fn response_matches_direct_polynomial_evaluation() {
        let c = BiquadCoeffs::new([0.3, -0.2, 0.1], [1.0, -1.2, 0.5]).unwrap();
        for f in [0.0, 10.0, 1000.0, 2500.0, 3000.0, 4999.0, 5000.0] {
            let z1 = C64::from_polar(1.0, -2.0 * PI * f / 10_000.0);
            let want = (c.b0 + c.b1 * z1 + c.b2 * z1 * z1) / (1.0 + c.a1 * z1 + c.a2 * z1 * z1);
            let got = c.response(f, 10_000.0);
            assert!((got - want).norm() <= 1e-14 * want.norm(), "f={f}");
        }
        // DC gain of the cascade is the product of (Σb)/(Σa).
        let s = Sos::new(vec![c, c]).unwrap();
        let dc = (c.b0 + c.b1 + c.b2) / (1.0 + c.a1 + c.a2);
        assert!((s.response(0.0, 10_000.0).re - dc * dc).abs() < 1e-14);
    }

    #[test]
    fn response_is_accurate_for_poles_near_dc() {
        // Butterworth at fc/fs = 1e-4, poles ≈ 1 − 4.4e-4. Independent
        // reference: with δ1 = 2 + a1 and δ2 = 1 − a2 (exact by Sterbenz),
        // A(q) = (1 − q)² + δ1 q − δ2 q², q = e^{−jw}, 1 − q = 2 sin²(w/2) + j sin w:
        // no catastrophic cancellation. The naive 1 + a1 q + a2 q² loses ~7
        // digits here.
        let c = lp2(1.0, 10_000.0);
        let (d1, d2) = (2.0 + c.a1, 1.0 - c.a2);
        let mut naive_worst: f64 = 0.0;
        for f in [0.0, 0.3, 1.0, 3.0, 100.0] {
            let w = 2.0 * PI * f / 10_000.0;
            let q = C64::from_polar(1.0, -w);
            let omq = C64::new(2.0 * (0.5 * w).sin().powi(2), w.sin());
            let a = omq * omq + d1 * q - d2 * q * q;
            let b = c.b0 * (1.0 + q) * (1.0 + q);
            let want = b / a;
            let got = c.response(f, 10_000.0);
            assert!(
                (got - want).norm() <= 1e-12 * want.norm(),
                "f={f}: {got} vs {want}"
            );
            let naive = (c.b0 + c.b1 * q + c.b2 * q * q) / (1.0 + c.a1 * q + c.a2 * q * q);
            naive_worst = naive_worst.max((naive - want).norm() / want.norm());
        }
        assert!(
            naive_worst > 1e-11,
            "the naive form should be visibly worse: {naive_worst:e}"
        );
        // DC gain of a Butterworth low-pass is 1 in exact arithmetic; the
        // stored coefficients give it to within coefficient rounding.
        let dc = c.response(0.0, 10_000.0);
        assert!((dc.re - 1.0).abs() < 1e-8 && dc.im == 0.0, "{dc}");
    }

    #[test]
    fn group_delay_of_pure_delay_and_first_order_section() {
        // z⁻² has group delay 2 samples.
        let d = BiquadCoeffs::new([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]).unwrap();
        for f in [0.0, 100.0, 2000.0, 4500.0] {
            let tau = sections_group_delay(&[d], f, 1000.0 * 10.0);
            assert!((tau - 2.0 / 10_000.0).abs() < 1e-15, "f={f}: {tau}");
        }
        // 1/(1 − p z⁻¹) at DC: τ = p/(1 − p) samples.
        let p = 0.8;
        let c = BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, -p, 0.0]).unwrap();
        let tau = sections_group_delay(&[c], 0.0, 1.0);
        assert!((tau - p / (1.0 - p)).abs() < 1e-12, "{tau}");
        // Against a central difference of the phase at 1 kHz.
        let s = [lp2(300.0, 10_000.0), c];
        let f = 1000.0;
        let df = 1e-3;
        let ph = |f: f64| sections_response(&s, f, 10_000.0).arg();
        let num = -(ph(f + df) - ph(f - df)) / (2.0 * PI * 2.0 * df);
        let ana = sections_group_delay(&s, f, 10_000.0);
        assert!((num - ana).abs() < 1e-9 * ana.abs(), "{num} vs {ana}");
    }

    #[test]
    fn nonfinite_input_outputs_zero_resets_and_counts() {
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut s = Sos::new(vec![lp2(500.0, 10_000.0)]).unwrap();
            for _ in 0..10 {
                s.process(1.0);
            }
            assert_ne!(s.state()[0], [0.0, 0.0]);
            assert_eq!(s.process(bad), 0.0);
            assert_eq!(s.nonfinite_events(), 1);
            assert_eq!(s.state()[0], [0.0, 0.0]);
            // Afterwards it behaves like a fresh filter.
            let mut fresh = Sos::new(vec![lp2(500.0, 10_000.0)]).unwrap();
            for i in 0..100 {
                let x = (i as f64 * 0.1).sin();
                assert_eq!(s.process(x), fresh.process(x));
            }
            let mut b = Biquad::new(lp2(500.0, 10_000.0)).unwrap();
            b.process(1.0);
            assert_eq!(b.process(bad), 0.0);
            assert_eq!(b.nonfinite_events(), 1);
            assert_eq!(b.state(), [0.0, 0.0]);
        }
    }

    #[test]
    fn overflowing_state_is_caught_and_never_reaches_the_output() {
        // A finite but huge input overflows the state of a resonant section.
        let c = BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, -1.9, 0.95]).unwrap();
        let mut s = Sos::new(vec![c, c]).unwrap();
        let mut outs = Vec::new();
        for _ in 0..200 {
            outs.push(s.process(1e307));
        }
        assert!(outs.iter().all(|y| y.is_finite()));
        assert!(s.nonfinite_events() > 0);
        assert!(s.state().iter().flatten().all(|v| v.is_finite()));
    }

    #[test]
    fn coefficient_validation() {
        assert!(BiquadCoeffs::new([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]).is_err());
        assert!(BiquadCoeffs::new([f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0]).is_err());
        assert!(Sos::new(vec![]).is_err());
        let bad = BiquadCoeffs {
            b0: f64::INFINITY,
            ..BiquadCoeffs::IDENTITY
        };
        assert!(Sos::new(vec![bad]).is_err());
        assert!(Biquad::new(bad).is_err());
        // Stability triangle: poles at 0.5 ± 0.5j (|p|² = 0.5) stable; a2 = 1 not.
        assert!(
            BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, -1.0, 0.5])
                .unwrap()
                .is_stable()
        );
        assert!(
            !BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, 0.0, 1.0])
                .unwrap()
                .is_stable()
        );
        assert!(
            !BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, -2.1, 1.1 - 0.01])
                .unwrap()
                .is_stable()
        );
        let mut s = Sos::new(vec![BiquadCoeffs::IDENTITY]).unwrap();
        assert!(s.set_sections(&[BiquadCoeffs::IDENTITY; 2]).is_err());
        assert!(s.set_sections(&[BiquadCoeffs::gain(2.0).unwrap()]).is_ok());
        assert_eq!(s.process(1.5), 3.0);
    }

    /// 1e8 samples of white noise then silence (hard case for drift and
    /// denormals): the long-running filter must agree with a fresh filter fed
    /// only the recent past (no accumulated error), the state stays bounded,
    /// and in silence the state never enters the subnormal range and reaches
    /// exact zero.
    #[test]
    fn long_white_noise_then_silence_no_drift_no_denormals() {
        let fs = 10_000.0;
        // Band-pass: LR4 high-pass at 10 Hz (fc/fs = 1e-3, slow poles) and a
        // 3rd-order low-pass at 200 Hz (includes a first-order section).
        let mut secs =
            design::butter(2, 10.0, fs, FilterKind::Highpass, Prewarp::AtCutoff).unwrap();
        secs.extend(design::butter(2, 10.0, fs, FilterKind::Highpass, Prewarp::AtCutoff).unwrap());
        secs.extend(design::butter(3, 200.0, fs, FilterKind::Lowpass, Prewarp::AtCutoff).unwrap());
        let mut sos = Sos::new(secs.clone()).unwrap();
        let total: usize = 100_000_000;
        let keep = 40_000; // the fresh filter forgets its initial state in this many samples
        let compare = 2_000;
        let mut noise = Noise(0x9E37_79B9_7F4A_7C15);
        let mut tail_in = Vec::with_capacity(keep);
        let mut tail_out = Vec::with_capacity(compare);
        let mut max_state: f64 = 0.0;
        for n in 0..total {
            let x = noise.next();
            let y = sos.process(x);
            if n >= total - keep {
                tail_in.push(x);
            }
            if n >= total - compare {
                tail_out.push(y);
            }
            if n % 4096 == 0 {
                for s in sos.state() {
                    max_state = max_state.max(s[0].abs()).max(s[1].abs());
                }
            }
        }
        assert_eq!(sos.nonfinite_events(), 0);
        // Bounded: a generous bound from the ℓ1 norm of the state, which for
        // |x| ≤ 1 and these sections is far below 1e3.
        assert!(max_state.is_finite() && max_state < 1e3, "{max_state}");
        // No drift: the slowest pole radius r gives a memory of r^keep.
        let r_max = secs
            .iter()
            .map(|c| {
                let disc = C64::new(c.a1 * c.a1 / 4.0 - c.a2, 0.0).sqrt();
                (-c.a1 / 2.0 + disc).norm().max((-c.a1 / 2.0 - disc).norm())
            })
            .fold(0.0, f64::max);
        assert!(r_max.powi(keep as i32 / 2) < 1e-20);
        // What remains is round-off noise of the two runs, whose gain for a
        // direct-form section grows like 1/(1 − r)² (Oppenheim & Schafer
        // §6.9): allow 10·eps·Σ 1/(1 − r_k)² relative. Drift (an error growing
        // with the 1e8 samples) would be orders of magnitude larger.
        let noise_gain: f64 = secs
            .iter()
            .map(|c| {
                let disc = C64::new(c.a1 * c.a1 / 4.0 - c.a2, 0.0).sqrt();
                let r = (-c.a1 / 2.0 + disc).norm().max((-c.a1 / 2.0 - disc).norm());
                1.0 / ((1.0 - r) * (1.0 - r))
            })
            .sum();
        let tol = 10.0 * f64::EPSILON * noise_gain;
        assert!(tol < 1e-9, "{tol:e}");
        let mut fresh = Sos::new(secs).unwrap();
        let fresh_out: Vec<f64> = tail_in.iter().map(|&x| fresh.process(x)).collect();
        let rms = (tail_out.iter().map(|y| y * y).sum::<f64>() / compare as f64).sqrt();
        assert!(rms > 0.05, "{rms}");
        for (a, b) in tail_out.iter().zip(&fresh_out[keep - compare..]) {
            assert!(
                (a - b).abs() <= tol * rms,
                "drift: {a} vs {b} (tol {tol:e})"
            );
        }
        // Silence: never subnormal, exact zero eventually.
        let mut zero_at = None;
        for n in 0..400_000 {
            let y = sos.process(0.0);
            assert!(y == 0.0 || y.is_normal(), "subnormal output {y:e} at {n}");
            for s in sos.state() {
                for v in s {
                    assert!(*v == 0.0 || v.is_normal(), "subnormal state {v:e} at {n}");
                }
            }
            if zero_at.is_none() && sos.state().iter().flatten().all(|v| *v == 0.0) {
                zero_at = Some(n);
            }
        }
        assert!(zero_at.is_some(), "state did not reach exact zero");
        assert!(sos.state().iter().flatten().all(|v| *v == 0.0));
    }
}
