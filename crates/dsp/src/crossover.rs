//! Two-way Linkwitz–Riley crossover (paper §3.1, Fig. 3–4).
//!
//! An LR crossover of order 2k is a k-th order Butterworth filter squared, in
//! each branch (Linkwitz 1976/1978):
//!
//! ```text
//! L(s) = 1/B_k(s/ωc)²,   H(s) = (s/ωc)^{2k}/B_k(s/ωc)²
//! ```
//!
//! For LR4 (k = 2) this is the paper's L(s) = ωc⁴/D(s), H(s) = s⁴/D(s) with
//! D(s) = s⁴ + 2√2 ωc s³ + 4 ωc² s² + 2√2 ωc³ s + ωc⁴. Because
//! B_k(s)B_k(−s) = 1 + (−s²)^k, the sum L + (−1)^k H = B_k(−s)/B_k(s) is an
//! allpass. Hence the **polarity rule**: when k = order/2 is odd (LR2) the
//! high output is inverted, so that low + high is always the allpass
//! B_k(−s)/B_k(s) (flat magnitude).
//!
//! Digital realisation: the analog Butterworth zpk at ωc is mapped with the
//! bilinear transform prewarped at fc (so |L(fc)| = |H(fc)| = ½ exactly),
//! squared in zpk form and paired into second-order sections with
//! [`crate::design::zpk2sos`]. The polarity sign is folded into the first
//! high-pass section's numerator.

use crate::design::{self, FilterKind, Prewarp};
use crate::filter::{
    BiquadCoeffs, Sos, sections_group_delay, sections_response, sections_response_and_derivative,
};
use crate::{C64, DspError, Result, Zpk};
use std::f64::consts::PI;

/// A two-way Linkwitz–Riley crossover of order 2, 4 or 8.
#[derive(Debug, Clone)]
pub struct LinkwitzRiley {
    order: usize,
    fc: f64,
    fs: f64,
    invert_high: bool,
    low: Sos,
    high: Sos,
    low_zpk: Zpk,
    high_zpk: Zpk,
    nonfinite: u64,
}

fn square(z: &Zpk) -> Zpk {
    Zpk {
        zeros: z.zeros.iter().chain(&z.zeros).copied().collect(),
        poles: z.poles.iter().chain(&z.poles).copied().collect(),
        gain: z.gain * z.gain,
    }
}

impl LinkwitzRiley {
    /// Design an LR crossover of `order` ∈ {2, 4, 8} at `fc` hertz for sample
    /// rate `fs` hertz, fc ∈ (0, fs/2). The bilinear transform is prewarped at
    /// fc.
    pub fn new(order: usize, fc: f64, fs: f64) -> Result<Self> {
        if !matches!(order, 2 | 4 | 8) {
            return Err(DspError::InvalidParameter {
                name: "order",
                value: order as f64,
                reason: "Linkwitz–Riley order must be 2, 4 or 8".into(),
            });
        }
        if !(fs.is_finite() && fs > 0.0) {
            return Err(DspError::InvalidParameter {
                name: "fs",
                value: fs,
                reason: "sample rate must be finite and > 0 Hz".into(),
            });
        }
        if !(fc.is_finite() && fc > 0.0 && fc < fs / 2.0) {
            return Err(DspError::InvalidParameter {
                name: "fc",
                value: fc,
                reason: format!(
                    "crossover frequency must be in (0, fs/2) = (0, {}) Hz",
                    fs / 2.0
                ),
            });
        }
        let k = order / 2;
        let invert_high = k % 2 == 1;
        let bl = design::butter_zpk(k, fc, fs, FilterKind::Lowpass, Prewarp::AtCutoff)?;
        let bh = design::butter_zpk(k, fc, fs, FilterKind::Highpass, Prewarp::AtCutoff)?;
        let low_zpk = square(&bl);
        let mut high_zpk = square(&bh);
        if invert_high {
            high_zpk.gain = -high_zpk.gain;
        }
        let low = Sos::new(design::zpk2sos(&low_zpk)?)?;
        let high = Sos::new(design::zpk2sos(&high_zpk)?)?;
        if !(low.is_stable() && high.is_stable()) {
            return Err(DspError::Unstable(
                "crossover sections are unstable after rounding".into(),
            ));
        }
        Ok(Self {
            order,
            fc,
            fs,
            invert_high,
            low,
            high,
            low_zpk,
            high_zpk,
            nonfinite: 0,
        })
    }

    /// Crossover order (2, 4 or 8).
    pub fn order(&self) -> usize {
        self.order
    }

    /// Crossover frequency in hertz.
    pub fn fc(&self) -> f64 {
        self.fc
    }

    /// Sample rate in hertz.
    pub fn fs(&self) -> f64 {
        self.fs
    }

    /// True when the high output is polarity-inverted (order/2 odd, i.e. LR2).
    pub fn high_inverted(&self) -> bool {
        self.invert_high
    }

    /// Low-pass sections (first applied first).
    pub fn low_sections(&self) -> &[BiquadCoeffs] {
        self.low.sections()
    }

    /// High-pass sections, polarity included (first applied first).
    pub fn high_sections(&self) -> &[BiquadCoeffs] {
        self.high.sections()
    }

    /// Digital zpk of the low branch.
    pub fn low_zpk(&self) -> &Zpk {
        &self.low_zpk
    }

    /// Digital zpk of the high branch (polarity included in the gain).
    pub fn high_zpk(&self) -> &Zpk {
        &self.high_zpk
    }

    /// One sample in, (low, high) out. A non-finite input gives (0, 0), resets
    /// both branches and is counted; non-finite state is handled by each
    /// branch (see [`crate::filter`]). Never allocates or panics.
    #[inline]
    pub fn process(&mut self, x: f64) -> (f64, f64) {
        if !x.is_finite() {
            self.on_nonfinite_input();
            return (0.0, 0.0);
        }
        (self.low.process(x), self.high.process(x))
    }

    /// Block version of [`LinkwitzRiley::process`]; processes
    /// `min(input.len(), low.len(), high.len())` samples and returns that
    /// count.
    pub fn process_block(&mut self, input: &[f64], low: &mut [f64], high: &mut [f64]) -> usize {
        let n = input.len().min(low.len()).min(high.len());
        for ((&x, l), h) in input[..n].iter().zip(&mut low[..n]).zip(&mut high[..n]) {
            (*l, *h) = self.process(x);
        }
        n
    }

    /// Zero the state of both branches.
    pub fn reset(&mut self) {
        self.low.reset();
        self.high.reset();
    }

    /// Non-finite events (inputs, plus state events of either branch).
    pub fn nonfinite_events(&self) -> u64 {
        self.nonfinite + self.low.nonfinite_events() + self.high.nonfinite_events()
    }

    /// Digital response (low, high) at `f` hertz, from the sections.
    pub fn response(&self, f: f64) -> (C64, C64) {
        (
            sections_response(self.low.sections(), f, self.fs),
            sections_response(self.high.sections(), f, self.fs),
        )
    }

    /// Response of low + high at `f` hertz (an allpass).
    pub fn sum_response(&self, f: f64) -> C64 {
        let (l, h) = self.response(f);
        l + h
    }

    /// Group delay of low + high at `f` hertz, in seconds, analytic:
    /// τ = −Im(S'/S)/fs with S = L + H and S' = dS/dω (ω in rad/sample).
    pub fn group_delay(&self, f: f64) -> f64 {
        let w = 2.0 * PI * f / self.fs;
        let (l, dl) = sections_response_and_derivative(self.low.sections(), w);
        let (h, dh) = sections_response_and_derivative(self.high.sections(), w);
        -((dl + dh) / (l + h)).im / self.fs
    }

    /// Group delay of the low branch alone at `f` hertz, in seconds.
    pub fn low_group_delay(&self, f: f64) -> f64 {
        sections_group_delay(self.low.sections(), f, self.fs)
    }

    #[cold]
    #[inline(never)]
    fn on_nonfinite_input(&mut self) {
        self.nonfinite += 1;
        self.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::bilinear_constant;
    use realfft::RealFftPlanner;

    const SQRT2: f64 = std::f64::consts::SQRT_2;

    /// Paper §3.1, LR4: L(s) = ωc⁴/D(s), H(s) = s⁴/D(s).
    fn lr4_analog(s: C64, wc: f64) -> (C64, C64) {
        let d = s.powi(4)
            + 2.0 * SQRT2 * wc * s.powi(3)
            + 4.0 * wc * wc * s * s
            + 2.0 * SQRT2 * wc.powi(3) * s
            + wc.powi(4);
        (C64::new(wc.powi(4), 0.0) / d, s.powi(4) / d)
    }

    /// Analog LR of order 2k from the Butterworth definition
    /// |B_k(jω)|² = 1/(1 + ω^{2k}), with the polarity rule.
    fn lr_analog(order: usize, s: C64, wc: f64) -> (C64, C64) {
        let k = order / 2;
        let x = s / wc;
        // B_k from its poles (independent of the design module).
        let mut b = C64::new(1.0, 0.0);
        for m in 0..k {
            let theta = PI * (2 * m + 1) as f64 / (2 * k) as f64;
            let p = C64::new(-theta.sin(), theta.cos());
            b *= x - p;
        }
        let l = 1.0 / (b * b);
        let sign = if k % 2 == 1 { -1.0 } else { 1.0 };
        (l, sign * x.powi(2 * k as i32) * l)
    }

    fn warp(f: f64, fc: f64, fs: f64) -> C64 {
        let k = bilinear_constant(fs, Some(fc)).unwrap();
        C64::new(0.0, k * (PI * f / fs).tan())
    }

    fn db(x: f64) -> f64 {
        20.0 * x.log10()
    }

    #[test]
    fn lr4_at_fc_is_minus_6db_and_in_phase() {
        let x = LinkwitzRiley::new(4, 200.0, 10_000.0).unwrap();
        let (l, h) = x.response(200.0);
        let want = db(0.5); // −6.0206 dB
        assert!((want + 6.0206).abs() < 1e-4);
        assert!((db(l.norm()) - want).abs() < 1e-12, "{}", db(l.norm()));
        assert!((db(h.norm()) - want).abs() < 1e-12);
        // In phase: arg(L/H) = 0 (LR4 at fc: both at −180°).
        assert!((l / h).arg().abs() < 1e-12);
        assert!(!x.high_inverted());
        assert_eq!(x.low_sections().len(), 2);
        assert_eq!(x.high_sections().len(), 2);
    }

    #[test]
    fn sum_is_allpass_for_all_orders_across_frequency() {
        for (order, fc) in [(2, 200.0), (4, 200.0), (8, 200.0), (4, 1000.0), (8, 3000.0)] {
            let x = LinkwitzRiley::new(order, fc, 10_000.0).unwrap();
            assert_eq!(x.high_inverted(), order == 2);
            let mut f = 1.0;
            while f < 5000.0 {
                let m = x.sum_response(f).norm();
                assert!(
                    (m - 1.0).abs() < 1e-12,
                    "LR{order} fc={fc} f={f}: |L+H|-1 = {:e}",
                    m - 1.0
                );
                f *= 1.07;
            }
            // The sum is B_k(−s)/B_k(s) through the frequency map.
            for f in [10.0, fc, 2.0 * fc] {
                let s = warp(f, fc, 10_000.0);
                let (l, h) = lr_analog(order, s, 2.0 * PI * fc);
                let d = x.sum_response(f);
                assert!((d - (l + h)).norm() < 1e-11, "LR{order} f={f}");
            }
        }
        // Without the polarity inversion LR2 would have a notch at fc.
        let x = LinkwitzRiley::new(2, 200.0, 10_000.0).unwrap();
        let (l, h) = x.response(200.0);
        assert!(
            (l - h).norm() < 1e-12,
            "non-inverted LR2 sum must vanish at fc"
        );
    }

    #[test]
    fn lr4_slope_is_24db_per_octave_beyond_fc() {
        // Analytic: |L(jω)|² = 1/(1 + (ω/ωc)⁴)² → slope between ω and 2ω is
        // 20 log10 of the ratio; tends to −24.08 dB/oct.
        let fs = 1.0e6; // so that warping is negligible well beyond fc
        let fc = 100.0;
        let x = LinkwitzRiley::new(4, fc, fs).unwrap();
        for f in [1600.0, 3200.0] {
            let got = db(x.response(2.0 * f).0.norm()) - db(x.response(f).0.norm());
            let ana = |f: f64| lr_analog(4, warp(f, fc, fs), 2.0 * PI * fc).0.norm();
            let want = db(ana(2.0 * f)) - db(ana(f));
            assert!((got - want).abs() < 1e-9, "f={f}: {got} vs {want}");
            assert!((got + 24.08).abs() < 0.01, "f={f}: {got}");
        }
        // High branch rises at +24 dB/oct well below fc.
        let got = db(x.response(6.25).1.norm()) - db(x.response(3.125).1.norm());
        assert!((got - 24.08).abs() < 0.01, "{got}");
    }

    #[test]
    fn lr4_group_delay_at_dc() {
        // Analog: τ(0) = 2√2/ωc (allpass (s²−√2ωc s+ωc²)/(s²+√2ωc s+ωc²)).
        // Digital with prewarp at fc: τ_d(0) = τ_a(0)·(K/2fs) with
        // K = ωc/tan(ωc/2fs) (chain rule through ω_a = K tan(ω_d T/2)).
        let (fc, fs) = (200.0, 10_000.0);
        let wc = 2.0 * PI * fc;
        let x = LinkwitzRiley::new(4, fc, fs).unwrap();
        let ta = 2.0 * SQRT2 / wc;
        assert!((ta - 2.25e-3).abs() < 0.01e-3);
        let k = bilinear_constant(fs, Some(fc)).unwrap();
        let td = ta * k / (2.0 * fs);
        let got = x.group_delay(0.0);
        assert!((got - td).abs() < 1e-12 * td, "{got} vs {td}");
        // Cross-check against a numerical phase derivative at a few f.
        for f in [5.0, 150.0, 400.0] {
            let df = 1e-3;
            let num = -(x.sum_response(f + df).arg() - x.sum_response(f - df).arg())
                / (2.0 * PI * 2.0 * df);
            assert!((num - x.group_delay(f)).abs() < 1e-9, "f={f}");
        }
        // Low branch alone: analog LR4 low-pass has τ(0) = 2·(√2/ωc) too
        // (two Butterworth-2 sections, each √2/ωc).
        assert!((x.low_group_delay(0.0) - td).abs() < 1e-12 * td);
    }

    /// Digital response = analog L(s), H(s) at s = j K tan(πf/fs), for
    /// fc/fs from 1e-4 (1 Hz at 10 kHz) to 0.45 and orders 2, 4, 8.
    #[test]
    fn digital_matches_analog_through_prewarp_map() {
        let fs = 10_000.0;
        for order in [2, 4, 8] {
            for fc in [1.0, 10.0, 200.0, 1000.0, 4500.0] {
                let x = LinkwitzRiley::new(order, fc, fs).unwrap();
                let wc = 2.0 * PI * fc;
                for r in [0.01, 0.3, 1.0, 1.5, 3.0, 9.0] {
                    let f = r * fc;
                    if f >= 0.499 * fs {
                        continue;
                    }
                    let (la, ha) = lr_analog(order, warp(f, fc, fs), wc);
                    let (ld, hd) = x.response(f);
                    // zpk is exact to rounding.
                    let lz = x.low_zpk().digital_response(f, fs);
                    let hz = x.high_zpk().digital_response(f, fs);
                    assert!((lz - la).norm() <= 1e-11 * la.norm().max(1e-30) + 1e-14);
                    assert!((hz - ha).norm() <= 1e-11 * ha.norm().max(1e-30) + 1e-14);
                    // Sections carry coefficient rounding ≈ eps/|1 − p|² relative.
                    let w = wc / fs;
                    let tol = 1e-12 + 1e-14 / (w * w);
                    assert!(
                        (ld - la).norm() <= tol * la.norm() + 1e-15,
                        "LR{order} fc={fc} f={f}: low {ld} vs {la}"
                    );
                    assert!(
                        (hd - ha).norm() <= tol * ha.norm() + 1e-15,
                        "LR{order} fc={fc} f={f}: high {hd} vs {ha}"
                    );
                }
                // −6.02 dB at fc for every order and fc.
                let (l, h) = x.response(fc);
                assert!((l.norm() - 0.5).abs() < 1e-9 && (h.norm() - 0.5).abs() < 1e-9);
            }
        }
        // Paper LR4 formula agrees with the Butterworth-squared definition.
        let wc = 2.0 * PI * 200.0;
        for f in [20.0, 200.0, 700.0] {
            let s = C64::new(0.0, 2.0 * PI * f);
            let (a, b) = lr4_analog(s, wc);
            let (c, d) = lr_analog(4, s, wc);
            assert!((a - c).norm() < 1e-13 && (b - d).norm() < 1e-13);
        }
    }

    #[test]
    fn lr8_at_tiny_fc_over_fs_sums_to_allpass() {
        // fc/fs = 1e-4: the section coefficients are rounded to eps, which
        // perturbs |L + H| by ≈ eps/|1 − p|² ≈ 1e-16/(4.4e-4)² ≈ 5e-10.
        let x = LinkwitzRiley::new(8, 1.0, 10_000.0).unwrap();
        for f in [0.01, 0.5, 1.0, 2.0, 100.0, 4000.0] {
            let m = x.sum_response(f).norm();
            assert!((m - 1.0).abs() < 1e-8, "f={f}: {:e}", m - 1.0);
        }
    }

    #[test]
    fn lr4_prewarp_keeps_1khz_corner_at_10khz() {
        // REFERENCE-VALUES.md: without prewarp a 1 kHz corner at 10 kHz moves
        // by tan(π/10)/(π/10) = 1.0343.
        let fs = 10_000.0;
        let x = LinkwitzRiley::new(4, 1000.0, fs).unwrap();
        assert!((x.response(1000.0).0.norm() - 0.5).abs() < 1e-13);
        // The same analog design without prewarp (K = 2fs): the digital 1 kHz
        // shows the analog response at 1.0343·ωc (3.43 % above the corner),
        // so it is no longer −6.02 dB, and the −6.02 dB point moves down to
        // f3 with 2fs·tan(πf3/fs) = ωc.
        let wc = 2.0 * PI * 1000.0;
        let b = design::butter_analog(2, wc, FilterKind::Lowpass).unwrap();
        let analog = square(&b);
        let d = design::bilinear(&analog, fs, None).unwrap();
        let ratio = (PI / 10.0).tan() / (PI / 10.0);
        assert!((ratio - 1.0343).abs() < 5e-5);
        let seen = analog.eval(C64::new(0.0, ratio * wc));
        assert!((d.digital_response(1000.0, fs) - seen).norm() < 1e-12);
        // |L_a(j r ωc)| = 1/(1 + r⁴) for LR4.
        assert!((seen.norm() - 1.0 / (1.0 + ratio.powi(4))).abs() < 1e-12);
        assert!((d.digital_response(1000.0, fs).norm() - 0.5).abs() > 0.03);
        let f3 = fs / PI * (wc / (2.0 * fs)).atan();
        assert!((d.digital_response(f3, fs).norm() - 0.5).abs() < 1e-12);
        assert!(f3 < 1000.0 / 1.03);
    }

    /// FFT of the impulse response through process() equals response(); the
    /// impulse response of low + high is an allpass: energy 1 and flat FFT.
    #[test]
    fn time_domain_impulse_response_matches_frequency_response() {
        let n = 1 << 14;
        let fs = 10_000.0;
        for order in [2, 4, 8] {
            let mut x = LinkwitzRiley::new(order, 200.0, fs).unwrap();
            let mut low = vec![0.0; n];
            let mut high = vec![0.0; n];
            let mut input = vec![0.0; n];
            input[0] = 1.0;
            assert_eq!(x.process_block(&input, &mut low, &mut high), n);
            let mut planner = RealFftPlanner::<f64>::new();
            let fft = planner.plan_fft_forward(n);
            let mut spec_l = fft.make_output_vec();
            let mut spec_h = fft.make_output_vec();
            fft.process(&mut low.clone(), &mut spec_l).unwrap();
            fft.process(&mut high.clone(), &mut spec_h).unwrap();
            for k in (0..=n / 2).step_by(37) {
                let f = k as f64 * fs / n as f64;
                let (l, h) = x.response(f);
                assert!((spec_l[k] - l).norm() < 1e-10, "LR{order} k={k}");
                assert!((spec_h[k] - h).norm() < 1e-10, "LR{order} k={k}");
                assert!(((spec_l[k] + spec_h[k]).norm() - 1.0).abs() < 1e-10);
            }
            let energy: f64 = low.iter().zip(&high).map(|(a, b)| (a + b) * (a + b)).sum();
            assert!((energy - 1.0).abs() < 1e-10, "LR{order} energy {energy}");
        }
    }

    #[test]
    fn constructor_validation() {
        for order in [0, 1, 3, 6, 16] {
            assert!(matches!(
                LinkwitzRiley::new(order, 200.0, 10_000.0),
                Err(DspError::InvalidParameter { name: "order", .. })
            ));
        }
        for fc in [0.0, -5.0, 5000.0, 6000.0, f64::NAN] {
            assert!(matches!(
                LinkwitzRiley::new(4, fc, 10_000.0),
                Err(DspError::InvalidParameter { name: "fc", .. })
            ));
        }
        assert!(LinkwitzRiley::new(4, 200.0, 0.0).is_err());
        assert!(LinkwitzRiley::new(4, 4999.0, 10_000.0).is_ok());
    }

    #[test]
    fn nonfinite_input_is_zeroed_and_counted() {
        let mut x = LinkwitzRiley::new(4, 200.0, 10_000.0).unwrap();
        for i in 0..100 {
            x.process((i as f64).sin());
        }
        assert_eq!(x.process(f64::NAN), (0.0, 0.0));
        assert_eq!(x.nonfinite_events(), 1);
        let mut fresh = LinkwitzRiley::new(4, 200.0, 10_000.0).unwrap();
        for i in 0..100 {
            let v = (i as f64 * 0.3).cos();
            assert_eq!(x.process(v), fresh.process(v));
        }
    }
}
