//! Excitation signals for system identification (paper §3.2: "pseudo-random
//! binary sequence input … PSD analysis (Welch method)").
//!
//! * [`Mls`] — maximum-length sequences (m-sequences) of order 2–32 from a
//!   Fibonacci linear feedback shift register, bit-compatible with
//!   `scipy.signal.max_len_seq` (same tap table, same register convention,
//!   same all-ones seed). Lazy, allocation-free generator for real-time loops
//!   plus [`mls_bits`] / [`mls_signal`] builders.
//! * [`LogSweep`] — Farina's exponential (logarithmic) swept sine
//!   (Farina 2000, AES 108th Convention, preprint 5093).
//! * [`SteppedSineConfig`] / [`stepped_sine`] — stepped sines with settle and
//!   measurement windows of whole cycles, and the per-step schedule.
//! * [`sine_fit`] — three-parameter least-squares sine fit (IEEE Std 1057
//!   "three-parameter" fit, known frequency) solved by Householder QR;
//!   [`sine_dft`] — the single-bin DFT estimate of the same quantities.
//!
//! Units: frequencies in Hz, times in s, sample rates `fs` in Hz, phases in
//! rad, amplitudes in the caller's signal unit.

use crate::{DspError, Result};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::ops::Range;

// ---------------------------------------------------------------------------
// Maximum-length sequences
// ---------------------------------------------------------------------------

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
        if !(amplitude.is_finite() && amplitude > 0.0) {
            return Err(DspError::InvalidParameter {
                name: "amplitude",
                value: amplitude,
                reason: "must be finite and > 0".into(),
            });
        }
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

fn alloc_len(len: u128, what: &'static str) -> Result<Vec<f64>> {
    let too_long = || DspError::InvalidParameter {
        name: what,
        value: len as f64,
        reason: "requested signal is too long to allocate".into(),
    };
    let n = usize::try_from(len).map_err(|_| too_long())?;
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| too_long())?;
    Ok(v)
}

/// One period of the built-in m-sequence of `order` as 0/1 values; equals
/// `scipy.signal.max_len_seq(order)[0]`.
pub fn mls_bits(order: u32) -> Result<Vec<u8>> {
    let period = mls_period(order)?;
    let n = usize::try_from(period).map_err(|_| DspError::InvalidParameter {
        name: "order",
        value: f64::from(order),
        reason: "period does not fit in memory".into(),
    })?;
    let mut bits = Vec::new();
    bits.try_reserve_exact(n)
        .map_err(|_| DspError::InvalidParameter {
            name: "order",
            value: f64::from(order),
            reason: "period does not fit in memory".into(),
        })?;
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

// ---------------------------------------------------------------------------
// Exponential sweep (Farina 2000)
// ---------------------------------------------------------------------------

/// Exponential ("logarithmic") swept sine, Farina (2000):
///
/// x(t) = A sin( 2π f₁ T / ln(f₂/f₁) · (e^{t ln(f₂/f₁)/T} − 1) ),  0 ≤ t < T,
///
/// whose instantaneous frequency f(t) = f₁ e^{t ln(f₂/f₁)/T} rises by the same
/// number of octaves per second. Optional raised-cosine fades (half Hann) of
/// `fade_in`/`fade_out` seconds taper the start and the end.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LogSweep {
    /// Start frequency f₁ (Hz), > 0.
    pub f1: f64,
    /// End frequency f₂ (Hz), f₁ < f₂ ≤ fs/2.
    pub f2: f64,
    /// Sweep duration T (s).
    pub duration: f64,
    /// Peak amplitude A (signal units).
    pub amplitude: f64,
    /// Raised-cosine fade-in length (s), 0 for none.
    pub fade_in: f64,
    /// Raised-cosine fade-out length (s), 0 for none.
    pub fade_out: f64,
}

impl LogSweep {
    /// Sweep without fades.
    pub fn new(f1: f64, f2: f64, duration: f64, amplitude: f64) -> Self {
        Self {
            f1,
            f2,
            duration,
            amplitude,
            fade_in: 0.0,
            fade_out: 0.0,
        }
    }

    /// Set the fade lengths (s).
    pub fn with_fades(mut self, fade_in: f64, fade_out: f64) -> Self {
        self.fade_in = fade_in;
        self.fade_out = fade_out;
        self
    }

    fn rate(&self) -> f64 {
        (self.f2 / self.f1).ln()
    }

    /// Instantaneous phase φ(t) (rad) of Farina's sweep.
    pub fn phase(&self, t: f64) -> f64 {
        let l = self.rate();
        2.0 * PI * self.f1 * self.duration / l * (t * l / self.duration).exp_m1()
    }

    /// Instantaneous frequency f(t) = φ'(t)/2π = f₁ e^{t ln(f₂/f₁)/T} (Hz).
    pub fn instantaneous_frequency(&self, t: f64) -> f64 {
        self.f1 * (t * self.rate() / self.duration).exp()
    }

    /// Time (s) at which the sweep passes frequency `f`: T ln(f/f₁)/ln(f₂/f₁).
    pub fn time_at_frequency(&self, f: f64) -> f64 {
        self.duration * (f / self.f1).ln() / self.rate()
    }

    /// Check the parameters against the sample rate `fs` (Hz).
    pub fn validate(&self, fs: f64) -> Result<()> {
        check_fs(fs)?;
        if !(self.f1.is_finite() && self.f1 > 0.0) {
            return Err(invalid("f1", self.f1, "must be finite and > 0"));
        }
        if !(self.f2.is_finite() && self.f2 > self.f1 && self.f2 <= fs / 2.0) {
            return Err(invalid("f2", self.f2, "must satisfy f1 < f2 ≤ fs/2"));
        }
        if !(self.duration.is_finite() && self.duration * fs >= 2.0) {
            return Err(invalid(
                "duration",
                self.duration,
                "must be finite and last at least 2 samples",
            ));
        }
        if !(self.amplitude.is_finite() && self.amplitude > 0.0) {
            return Err(invalid(
                "amplitude",
                self.amplitude,
                "must be finite and > 0",
            ));
        }
        if !(self.fade_in.is_finite() && self.fade_in >= 0.0) {
            return Err(invalid("fade_in", self.fade_in, "must be finite and ≥ 0"));
        }
        if !(self.fade_out.is_finite() && self.fade_out >= 0.0) {
            return Err(invalid("fade_out", self.fade_out, "must be finite and ≥ 0"));
        }
        if self.fade_in + self.fade_out > self.duration {
            return Err(invalid(
                "fade_out",
                self.fade_out,
                "fade_in + fade_out must not exceed the duration",
            ));
        }
        Ok(())
    }

    /// Number of samples round(T·fs).
    pub fn num_samples(&self, fs: f64) -> Result<usize> {
        self.validate(fs)?;
        let n = (self.duration * fs).round();
        if n > (isize::MAX as f64) / 8.0 {
            return Err(invalid("duration", self.duration, "sweep too long"));
        }
        Ok(n as usize)
    }

    /// Sampled sweep x\[n\] = A·g\[n\]·sin φ(n/fs), n = 0 … round(T fs) − 1, with
    /// fade gain g\[n\] = ½(1 − cos(π t/τ_in)) for t < τ_in and
    /// ½(1 − cos(π t_rem/τ_out)) for t_rem = (N−1−n)/fs < τ_out (1 elsewhere).
    pub fn generate(&self, fs: f64) -> Result<Vec<f64>> {
        let n = self.num_samples(fs)?;
        let mut v = alloc_len(n as u128, "duration")?;
        let t_last = (n - 1) as f64 / fs;
        for i in 0..n {
            let t = i as f64 / fs;
            let mut g = 1.0;
            if t < self.fade_in {
                g *= 0.5 * (1.0 - (PI * t / self.fade_in).cos());
            }
            let t_rem = t_last - t;
            if t_rem < self.fade_out {
                g *= 0.5 * (1.0 - (PI * t_rem / self.fade_out).cos());
            }
            v.push(self.amplitude * g * self.phase(t).sin());
        }
        Ok(v)
    }
}

// ---------------------------------------------------------------------------
// Stepped sines
// ---------------------------------------------------------------------------

/// Stepped-sine measurement plan: one sine per frequency, each played for a
/// settle time (transients die out) followed by a measurement window that
/// holds a whole number of cycles.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SteppedSineConfig {
    /// Requested frequencies (Hz), each in (0, fs/2). Played in this order.
    pub frequencies: Vec<f64>,
    /// Sine amplitude (signal units), > 0.
    pub amplitude: f64,
    /// Minimum settle time (s) before each measurement window, ≥ 0.
    pub settle_time: f64,
    /// Minimum measurement time (s) per step, > 0.
    pub measure_time: f64,
}

/// One step of a stepped-sine schedule (sample indices into the signal
/// returned by [`stepped_sine`]).
///
/// In the measurement window the excitation is exactly
/// x\[m\] = A sin(2π `frequency` m/fs + `measure_phase`), m = n − `measure_start`,
/// and the window spans exactly `cycles` periods: `frequency` = cycles·fs/M
/// with M = `end` − `measure_start` (coherent sampling, no DFT leakage).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SineStep {
    /// Frequency asked for (Hz).
    pub requested_frequency: f64,
    /// Frequency actually played (Hz): cycles·fs/M. Since M = round(cycles·fs/f),
    /// |Δf|/f ≤ 1/(2M) (except when M had to be raised to 2·cycles + 1 just
    /// below Nyquist).
    pub frequency: f64,
    /// Whole cycles in the measurement window.
    pub cycles: u64,
    /// First sample of the step (settling starts here, at phase 0).
    pub start: usize,
    /// First sample of the measurement window.
    pub measure_start: usize,
    /// One past the last sample of the step.
    pub end: usize,
    /// Excitation phase (rad, sine convention, in (−π, π]) at `measure_start`.
    pub measure_phase: f64,
}

impl SineStep {
    /// Settling samples `start..measure_start`.
    pub fn settle_range(&self) -> Range<usize> {
        self.start..self.measure_start
    }

    /// Measurement samples `measure_start..end`.
    pub fn measure_range(&self) -> Range<usize> {
        self.measure_start..self.end
    }
}

/// Phase 2π·(num mod den)/den wrapped into (−π, π], computed exactly in
/// integers before the single rounding to f64.
fn exact_phase(num: u128, den: u128) -> f64 {
    let r = (num % den) as f64 / den as f64; // in [0, 1)
    let r = if r > 0.5 { r - 1.0 } else { r };
    2.0 * PI * r
}

/// Build the stepped-sine schedule for sample rate `fs` (Hz).
///
/// For each requested f: cycles k = max(1, ⌈f·measure_time⌉), window length
/// M = round(k·fs/f) samples (made ≥ 2k + 1 so the played frequency stays
/// below Nyquist), played frequency k·fs/M; settle length ⌈settle_time·fs⌉.
pub fn stepped_sine_schedule(cfg: &SteppedSineConfig, fs: f64) -> Result<Vec<SineStep>> {
    check_fs(fs)?;
    if cfg.frequencies.is_empty() {
        return Err(DspError::InvalidInput("no stepped-sine frequencies".into()));
    }
    if !(cfg.amplitude.is_finite() && cfg.amplitude > 0.0) {
        return Err(invalid(
            "amplitude",
            cfg.amplitude,
            "must be finite and > 0",
        ));
    }
    if !(cfg.settle_time.is_finite() && cfg.settle_time >= 0.0) {
        return Err(invalid(
            "settle_time",
            cfg.settle_time,
            "must be finite and ≥ 0",
        ));
    }
    if !(cfg.measure_time.is_finite() && cfg.measure_time > 0.0) {
        return Err(invalid(
            "measure_time",
            cfg.measure_time,
            "must be finite and > 0",
        ));
    }
    let limit = 1e15; // samples; keeps all integer arithmetic exact in f64
    let settle = (cfg.settle_time * fs).ceil();
    if settle > limit {
        return Err(invalid("settle_time", cfg.settle_time, "too long"));
    }
    let settle = settle as u64;
    let mut steps = Vec::with_capacity(cfg.frequencies.len());
    let mut pos: u64 = 0;
    for &f in &cfg.frequencies {
        if !(f.is_finite() && f > 0.0 && f < fs / 2.0) {
            return Err(invalid("frequencies", f, "each must be in (0, fs/2)"));
        }
        let k = (f * cfg.measure_time).ceil().max(1.0);
        let m = (k * fs / f).round();
        if m > limit || k > limit {
            return Err(invalid("measure_time", cfg.measure_time, "too long"));
        }
        let k = k as u64;
        let m = (m as u64).max(2 * k + 1);
        let start = pos;
        let measure_start = start + settle;
        let end = measure_start + m;
        let to_usize = |v: u64| {
            usize::try_from(v).map_err(|_| invalid("measure_time", cfg.measure_time, "too long"))
        };
        steps.push(SineStep {
            requested_frequency: f,
            frequency: k as f64 * fs / m as f64,
            cycles: k,
            start: to_usize(start)?,
            measure_start: to_usize(measure_start)?,
            end: to_usize(end)?,
            measure_phase: exact_phase(u128::from(k) * u128::from(settle), u128::from(m)),
        });
        pos = end;
        if pos as f64 > limit {
            return Err(invalid(
                "measure_time",
                cfg.measure_time,
                "schedule too long",
            ));
        }
    }
    Ok(steps)
}

/// Stepped-sine signal and its schedule. Step i is
/// x\[n\] = A sin(2π k (n − start)/M) for n in `start..end` (each step starts at
/// phase 0, so the signal is continuous in value at step boundaries). The
/// phase is reduced exactly in integers, so long steps carry no phase drift.
pub fn stepped_sine(cfg: &SteppedSineConfig, fs: f64) -> Result<(Vec<f64>, Vec<SineStep>)> {
    let steps = stepped_sine_schedule(cfg, fs)?;
    let total = steps.last().map_or(0, |s| s.end);
    let mut x = alloc_len(total as u128, "measure_time")?;
    for s in &steps {
        let m = (s.end - s.measure_start) as u128;
        for i in 0..(s.end - s.start) {
            let ph = exact_phase(u128::from(s.cycles) * i as u128, m);
            x.push(cfg.amplitude * ph.sin());
        }
    }
    Ok((x, steps))
}

// ---------------------------------------------------------------------------
// Sine estimation
// ---------------------------------------------------------------------------

fn check_sine_args(x: &[f64], f: f64, fs: f64) -> Result<()> {
    check_fs(fs)?;
    if !(f.is_finite() && f > 0.0 && f < fs / 2.0) {
        return Err(invalid("f", f, "must be in (0, fs/2)"));
    }
    if x.len() < 3 {
        return Err(DspError::InvalidInput(format!(
            "sine fit needs at least 3 samples, got {}",
            x.len()
        )));
    }
    if x.iter().any(|v| !v.is_finite()) {
        return Err(DspError::InvalidInput("non-finite sample in x".into()));
    }
    Ok(())
}

/// Phase ω n = 2π (f/fs) n reduced to one turn before scaling by 2π.
#[inline]
fn angle(cycles_per_sample: f64, n: usize) -> f64 {
    2.0 * PI * (cycles_per_sample * n as f64).fract()
}

/// Three-parameter least-squares sine fit at a known frequency (IEEE Std
/// 1057, known-frequency fit): minimise Σ (x\[n\] − a sin(ω n + φ) − c)² with
/// ω = 2π f/fs, n = 0 … N−1 (n = 0 is `x[0]`).
///
/// The model is linear in (s, k, c) = (a cos φ, a sin φ, c) with columns
/// sin ωn, cos ωn, 1. Columns are scaled to unit norm and the system is
/// solved by Householder QR (nalgebra), never normal equations. Returns
/// `(amplitude a ≥ 0, phase φ ∈ (−π, π] rad, offset c)`.
///
/// Errors: f outside (0, fs/2), fewer than 3 samples, non-finite data, or a
/// window so short that the columns are numerically dependent.
pub fn sine_fit(x: &[f64], f: f64, fs: f64) -> Result<(f64, f64, f64)> {
    check_sine_args(x, f, fs)?;
    let n = x.len();
    let r = f / fs;
    let mut a = DMatrix::<f64>::zeros(n, 3);
    for i in 0..n {
        let (s, c) = angle(r, i).sin_cos();
        a[(i, 0)] = s;
        a[(i, 1)] = c;
        a[(i, 2)] = 1.0;
    }
    let mut scale = [0.0; 3];
    for (j, sc) in scale.iter_mut().enumerate() {
        let norm = a.column(j).norm();
        if norm <= 0.0 {
            return Err(DspError::Numerical(
                "sine fit: a regressor column is identically zero".into(),
            ));
        }
        *sc = norm;
        a.column_mut(j).scale_mut(1.0 / norm);
    }
    let qr = a.qr();
    let rm = qr.r();
    let dmax = (0..3).map(|j| rm[(j, j)].abs()).fold(0.0, f64::max);
    if (0..3).any(|j| rm[(j, j)].abs() <= 1e-10 * dmax) {
        return Err(DspError::Numerical(
            "sine fit: window too short to separate sine, cosine and offset".into(),
        ));
    }
    let mut b = DVector::from_column_slice(x);
    qr.q_tr_mul(&mut b);
    let top = b.rows(0, 3).into_owned();
    let sol = rm
        .solve_upper_triangular(&top)
        .ok_or_else(|| DspError::Numerical("sine fit: singular triangular factor".into()))?;
    let s = sol[0] / scale[0];
    let k = sol[1] / scale[1];
    let c = sol[2] / scale[2];
    Ok((s.hypot(k), k.atan2(s), c))
}

/// Single-bin DFT estimate of a sine at a known frequency:
/// X = Σ x\[n\] e^{−jωn}, amplitude 2|X|/N, phase arg X + π/2 (sine convention,
/// wrapped to (−π, π]). Exact (no leakage, offset rejected) when the window
/// holds a whole number of cycles, as in [`stepped_sine`] windows; otherwise
/// prefer [`sine_fit`]. Returns `(amplitude, phase)`.
pub fn sine_dft(x: &[f64], f: f64, fs: f64) -> Result<(f64, f64)> {
    check_sine_args(x, f, fs)?;
    let r = f / fs;
    let (mut re, mut im) = (0.0, 0.0);
    for (i, &v) in x.iter().enumerate() {
        let (s, c) = angle(r, i).sin_cos();
        re += v * c;
        im -= v * s;
    }
    let n = x.len() as f64;
    let amp = 2.0 * re.hypot(im) / n;
    let mut ph = im.atan2(re) + PI / 2.0;
    if ph > PI {
        ph -= 2.0 * PI;
    }
    Ok((amp, ph))
}

// ---------------------------------------------------------------------------
// helpers
// ---------------------------------------------------------------------------

fn invalid(name: &'static str, value: f64, reason: &str) -> DspError {
    DspError::InvalidParameter {
        name,
        value,
        reason: reason.into(),
    }
}

fn check_fs(fs: f64) -> Result<()> {
    if fs.is_finite() && fs > 0.0 {
        Ok(())
    } else {
        Err(invalid("fs", fs, "sample rate must be finite and > 0"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};
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

    // ---- sweep --------------------------------------------------------------

    #[test]
    fn sweep_zero_crossings_follow_farina_law() {
        let fs = 10_000.0;
        let sw = LogSweep::new(10.0, 1000.0, 2.0, 0.5);
        let x = sw.generate(fs).unwrap();
        assert_eq!(x.len(), 20_000);
        let l = (sw.f2 / sw.f1).ln();
        // Crossing k happens at φ(t_k) = kπ ⇒ t_k = (T/L) ln(1 + k L/(2 f1 T)).
        let t_k = |k: f64| sw.duration / l * (1.0 + k * l / (2.0 * sw.f1 * sw.duration)).ln();
        let mut crossings = Vec::new();
        for i in 1..x.len() {
            if x[i - 1] != 0.0 && x[i - 1].signum() != x[i].signum() {
                let frac = x[i - 1] / (x[i - 1] - x[i]);
                crossings.push((i as f64 - 1.0 + frac) / fs);
            }
        }
        // Expected count: crossings k = 1 … ⌊φ(t_last)/π⌋ (x[0] = 0 is k = 0).
        let t_last = (x.len() - 1) as f64 / fs;
        let expected = (sw.phase(t_last) / PI).floor() as usize;
        assert_eq!(crossings.len(), expected);
        for (j, &t) in crossings.iter().enumerate() {
            let k = (j + 1) as f64;
            // Linear-interpolation bound |δt| ≤ max|g''| Δt²/(8|g'|) for g = sin φ
            // near a root: |g''|/|g'| ≤ φ''/φ' + φ'² Δt with φ' = 2πf, φ''/φ' = L/T.
            let dt = 1.0 / fs;
            let w = 2.0 * PI * sw.instantaneous_frequency(t);
            let tol = (l / sw.duration + w * w * dt) * dt * dt / 8.0;
            assert!((t - t_k(k)).abs() < tol, "crossing {k}: {t} vs {}", t_k(k));
        }
        // Local frequency from the spacing of consecutive crossings (half a cycle).
        for w in crossings.windows(2).step_by(50) {
            let f_est = 0.5 / (w[1] - w[0]);
            // Mean of f1·e^{tL/T} over [t_a, t_b] = f(t_mid)·sinh(u)/u, u = (L/T)(t_b − t_a)/2.
            let u = l / sw.duration * (w[1] - w[0]) / 2.0;
            let f_law = sw.instantaneous_frequency(0.5 * (w[0] + w[1])) * u.sinh() / u;
            // Each crossing time carries the interpolation bound above.
            let dt = 1.0 / fs;
            let wl = 2.0 * PI * f_law;
            let tol_t = (l / sw.duration + wl * wl * dt) * dt * dt / 8.0;
            let tol = 2.0 * tol_t / (w[1] - w[0]);
            assert!((f_est / f_law - 1.0).abs() < tol, "{f_est} vs {f_law}");
        }
        assert!((sw.instantaneous_frequency(sw.duration) - sw.f2).abs() < 1e-9);
        assert!((sw.time_at_frequency(100.0) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn sweep_fades_and_envelope() {
        let fs = 10_000.0;
        let plain = LogSweep::new(20.0, 4000.0, 1.0, 1.0);
        let faded = plain.with_fades(0.05, 0.1);
        let a = plain.generate(fs).unwrap();
        let b = faded.generate(fs).unwrap();
        assert_eq!(a.len(), b.len());
        assert_eq!(b[0], 0.0);
        assert_eq!(*b.last().unwrap(), 0.0);
        assert!(
            b.iter()
                .zip(&a)
                .all(|(bv, av)| bv.abs() <= av.abs() + 1e-15)
        );
        // Untouched between the fades.
        assert_eq!(a[500..8999], b[500..8999]);
        // Raised-cosine gain at the middle of the fade-in is 1/2.
        let i = 250;
        let g = b[i] / a[i];
        assert!((g - 0.5).abs() < 1e-12, "{g}");
        assert!(a.iter().all(|v| v.abs() <= 1.0));
        // Errors name the parameter.
        for (sw, name) in [
            (LogSweep::new(0.0, 10.0, 1.0, 1.0), "f1"),
            (LogSweep::new(10.0, 10.0, 1.0, 1.0), "f2"),
            (LogSweep::new(10.0, 6000.0, 1.0, 1.0), "f2"),
            (LogSweep::new(10.0, 100.0, f64::NAN, 1.0), "duration"),
            (LogSweep::new(10.0, 100.0, 1.0, -1.0), "amplitude"),
            (
                LogSweep::new(10.0, 100.0, 1.0, 1.0).with_fades(0.6, 0.6),
                "fade_out",
            ),
        ] {
            match sw.generate(fs) {
                Err(DspError::InvalidParameter { name: n, .. }) => assert_eq!(n, name),
                other => panic!("{sw:?}: {other:?}"),
            }
        }
        assert!(plain.generate(0.0).is_err());
    }

    // ---- stepped sine and sine fit ------------------------------------------

    #[test]
    fn stepped_sine_schedule_has_whole_cycles() {
        let fs = 10_000.0;
        let cfg = SteppedSineConfig {
            frequencies: vec![1.3, 63.0957, 316.228, 1000.0, 4999.0],
            amplitude: 0.2,
            settle_time: 0.05,
            measure_time: 0.1,
        };
        let (x, steps) = stepped_sine(&cfg, fs).unwrap();
        assert_eq!(x.len(), steps.last().unwrap().end);
        let mut pos = 0;
        for s in &steps {
            assert_eq!(s.start, pos);
            pos = s.end;
            let m = s.end - s.measure_start;
            assert!(s.measure_start - s.start >= (cfg.settle_time * fs) as usize);
            assert!(m as f64 >= cfg.measure_time * fs - 0.5 * fs / s.requested_frequency);
            // Whole cycles: f·M/fs is the integer `cycles`.
            let cyc = s.frequency * m as f64 / fs;
            assert!((cyc - s.cycles as f64).abs() < 1e-9);
            assert!(s.frequency < fs / 2.0);
            if s.requested_frequency < 4000.0 {
                let rel = (s.frequency / s.requested_frequency - 1.0).abs();
                assert!(rel <= 0.5 / m as f64 + 1e-15, "{rel}");
            }
            // The measurement window is exactly A sin(2π f m/fs + measure_phase).
            let w = &x[s.measure_range()];
            for (i, &v) in w.iter().enumerate() {
                let e = cfg.amplitude
                    * (2.0 * PI * s.frequency * i as f64 / fs + s.measure_phase).sin();
                assert!((v - e).abs() < 1e-9, "{v} vs {e}");
            }
            let (a, ph, c) = sine_fit(w, s.frequency, fs).unwrap();
            assert!((a - cfg.amplitude).abs() < 1e-12);
            assert!(wrap(ph - s.measure_phase).abs() < 1e-9);
            assert!(c.abs() < 1e-12);
            let (a2, ph2) = sine_dft(w, s.frequency, fs).unwrap();
            assert!((a2 - cfg.amplitude).abs() < 1e-12);
            assert!(wrap(ph2 - s.measure_phase).abs() < 1e-9);
        }
    }

    fn wrap(p: f64) -> f64 {
        (p + PI).rem_euclid(2.0 * PI) - PI
    }

    #[test]
    fn stepped_sine_measures_iir_frequency_response() {
        // y[n] = b x[n] + a y[n−1]  ⇒  H(e^{jω}) = b/(1 − a e^{−jω}).
        let (a, b) = (0.95, 0.05);
        let fs = 10_000.0;
        let cfg = SteppedSineConfig {
            frequencies: vec![5.0, 50.0, 200.0, 1000.0, 3000.0, 4900.0],
            amplitude: 1.0,
            // a^S < 1e-14 ⇒ S > 630 samples.
            settle_time: 0.1,
            measure_time: 0.05,
        };
        let (x, steps) = stepped_sine(&cfg, fs).unwrap();
        let mut y = vec![0.0; x.len()];
        let mut prev = 0.0;
        for (yi, &xi) in y.iter_mut().zip(&x) {
            prev = b * xi + a * prev;
            *yi = prev;
        }
        for s in &steps {
            let w = 2.0 * PI * s.frequency / fs;
            let h = crate::C64::new(b, 0.0) / (1.0 - a * crate::C64::from_polar(1.0, -w));
            let (ax, px, _) = sine_fit(&x[s.measure_range()], s.frequency, fs).unwrap();
            let (ay, py, cy) = sine_fit(&y[s.measure_range()], s.frequency, fs).unwrap();
            // The previous step's decaying transient is the only error: a^S·|y|.
            assert!(
                (ay / ax / h.norm() - 1.0).abs() < 1e-9,
                "f = {}",
                s.frequency
            );
            assert!(wrap(py - px - h.arg()).abs() < 1e-9, "f = {}", s.frequency);
            assert!(cy.abs() < 1e-9);
        }
    }

    #[test]
    fn sine_fit_exact_for_noiseless_partial_cycles() {
        let fs = 1000.0;
        for &(f, n, a, ph, c) in &[
            (3.7, 500usize, 2.5, 0.3, -1.0), // 1.85 cycles
            (1.0, 700, 1e-3, -2.9, 5.0),     // 0.7 cycle, big offset
            (449.9, 64, 1.0, 3.0, 0.1),      // near Nyquist
            (123.456, 100_000, 0.7, -1.2, 0.0),
        ] {
            let x: Vec<f64> = (0..n)
                .map(|i| a * (2.0 * PI * f * i as f64 / fs + ph).sin() + c)
                .collect();
            let (ea, ep, ec) = sine_fit(&x, f, fs).unwrap();
            let tol = 1e-9 * (a + c.abs());
            assert!((ea - a).abs() < tol, "f={f}: {ea} vs {a}");
            assert!(wrap(ep - ph).abs() < 1e-8, "f={f}: {ep} vs {ph}");
            assert!((ec - c).abs() < tol, "f={f}: {ec} vs {c}");
        }
    }

    #[test]
    fn sine_fit_noise_matches_cramer_rao() {
        // White noise σ, N samples, whole cycles: the columns are orthogonal
        // and var(â) = 2σ²/N, var(φ̂) = 2σ²/(N a²), var(ĉ) = σ²/N.
        let (fs, f, n, a, ph, sigma) = (1000.0, 50.0, 1000usize, 1.0, 0.4, 0.5);
        let trials = 400;
        let mut rng = StdRng::seed_from_u64(11);
        let noise = Normal::new(0.0, sigma).unwrap();
        let (mut ea, mut ep, mut ec) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..trials {
            let x: Vec<f64> = (0..n)
                .map(|i| a * (2.0 * PI * f * i as f64 / fs + ph).sin() + noise.sample(&mut rng))
                .collect();
            let (aa, pp, cc) = sine_fit(&x, f, fs).unwrap();
            ea.push(aa);
            ep.push(pp);
            ec.push(cc);
        }
        let stats = |v: &[f64], truth: f64| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let s = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
            (m - truth, s)
        };
        let nn = n as f64;
        for (v, truth, sd) in [
            (&ea, a, (2.0 * sigma * sigma / nn).sqrt()),
            (&ep, ph, (2.0 * sigma * sigma / (nn * a * a)).sqrt()),
            (&ec, 0.0, (sigma * sigma / nn).sqrt()),
        ] {
            let (bias, s) = stats(v, truth);
            // Sample std of 400 draws: relative s.e. 1/√800 ≈ 3.5 %.
            assert!((s / sd - 1.0).abs() < 0.15, "std {s} vs {sd}");
            assert!(
                bias.abs() < 4.0 * sd / (trials as f64).sqrt(),
                "bias {bias}"
            );
        }
    }

    #[test]
    fn sine_fit_errors() {
        let x = vec![0.0, 1.0, 0.0, -1.0];
        assert!(matches!(
            sine_fit(&x, 0.0, 4.0),
            Err(DspError::InvalidParameter { name: "f", .. })
        ));
        assert!(matches!(
            sine_fit(&x, 2.0, 4.0),
            Err(DspError::InvalidParameter { name: "f", .. })
        ));
        assert!(matches!(
            sine_fit(&x, 1.0, -4.0),
            Err(DspError::InvalidParameter { name: "fs", .. })
        ));
        assert!(sine_fit(&x[..2], 1.0, 4.0).is_err());
        assert!(sine_fit(&[0.0, f64::NAN, 1.0], 1.0, 4.0).is_err());
        assert!(sine_dft(&[0.0, f64::INFINITY, 1.0], 1.0, 4.0).is_err());
        // 1e-6 of a cycle: sine, cosine and offset are indistinguishable.
        let short: Vec<f64> = (0..10).map(|i| i as f64).collect();
        assert!(matches!(
            sine_fit(&short, 1e-9, 1000.0),
            Err(DspError::Numerical(_))
        ));
        let cfg = SteppedSineConfig {
            frequencies: vec![10.0, 6000.0],
            amplitude: 1.0,
            settle_time: 0.0,
            measure_time: 0.1,
        };
        assert!(matches!(
            stepped_sine(&cfg, 10_000.0),
            Err(DspError::InvalidParameter {
                name: "frequencies",
                ..
            })
        ));
    }
}
