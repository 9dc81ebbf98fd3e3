//! The per-sample signal chain of the paper's Fig. 6:
//!
//! ```text
//!            ┌─ L(z) ─ C_L ───────────► low output  (Pantograph)
//! input ─────┤
//!            └─ H(z) ─ C_H(z) ────────► high output (Haptuator)
//! ```
//!
//! L, H: Linkwitz–Riley crossover ([`crate::crossover`]); C_L = K_sys/G0_L
//! (folded into the numerator of the first low section); C_H(z): bilinear
//! image of C_H(s) = K_sys·F(s)/Ĝ_H(s) ([`crate::compensator`]).
//!
//! # Kernels
//! The arithmetic lives in `kernel.rs` (private module `kernel`): the fast
//! kernel packs the low and high paths as the two SIMD lanes of `[f64; 2]`
//! and runs each section normalised to b0 = 1 (4 multiplies per section),
//! monomorphised per stage count; the reference kernel next to it is plain
//! TDF-II per lane, the same operations as [`Sos`](crate::filter::Sos). The
//! fast kernel runs every chain whose sections can be normalised (all
//! designed chains); its outputs agree with the reference to rounding
//! (`tests/equivalence.rs` checks every stage count).
//!
//! # Entry points
//! The recursive state must stay in registers to be fast: an f64 value
//! stored and reloaded through memory on every sample adds the
//! store-to-load forwarding latency (5–9 cycles on current x86 cores) to
//! every section's feedback loop, as much as the whole per-sample budget.
//! Hence three entry points:
//! * [`Chain::process_block`]: whole blocks, state in registers between
//!   maintenance points, checks done per chunk. Fastest.
//! * [`Chain::stream`]: per-sample streaming — each input sample is pulled
//!   from an iterator and each output pair handed to a closure at once;
//!   kernel dispatched once, state in registers for the whole stream.
//! * [`Chain::process`]: one call per sample. The state necessarily lives in
//!   `self` between calls, so each call pays the memory round trip (about
//!   1.5× the cost of `stream` when called through a `&mut` from a loop).
//!
//! All three give identical outputs sample for sample.
//!
//! # Coefficient swap without clicks
//! [`Chain::set_coefficients`] switches the running coefficients to the new
//! design (same section counts) at once, converting the running state to the
//! new design's scaling (TDF-II state is kept), and keeps the old design
//! running as a "ghost" from a copy of the state; the output cross-fades
//! linearly from the ghost to the new design over `fade_len` samples:
//! out = y_old + α (y_new − y_old), α = i/fade_len, i = 1…fade_len. Nothing
//! is copied when the fade ends. Consequences (tested):
//! * swapping to identical coefficients is bit-identical to not swapping
//!   (y_new − y_old = 0 exactly);
//! * during the fade, the sample-to-sample change of the output is bounded by
//!   the larger change of the two designs' outputs plus
//!   max|y_new − y_old|/fade_len: no step ("click") larger than what the
//!   signal itself does.
//!
//! # Real-time guarantees
//! `process`, `stream`, `process_block` and `set_coefficients` (success
//! path) never allocate, lock or panic. Non-finite input → (0, 0) output,
//! state reset, event counted; non-finite output (state overflow) → (0, 0),
//! reset, counted; every [`FLUSH_INTERVAL`]-th sample tiny state is flushed
//! to zero and the state checked for non-finite values (reset and counted,
//! output (0, 0) for that sample) — the denormal policy of
//! [`crate::filter`].

mod kernel;

pub use self::kernel::MAX_STAGES;

use self::kernel::{
    Coefs, Kernel, State, ZERO_STATE, cold, guarded, nan_if_nonfinite, run_full, run_general,
    run_norm, with_kernel, zero_state,
};
use crate::compensator::{self, HighCompensatorConfig};
use crate::crossover::LinkwitzRiley;
use crate::design::{self, Prewarp};
use crate::filter::{BiquadCoeffs, FLUSH_INTERVAL, sections_response};
use crate::{C64, DspError, Result, Tf};

/// Default cross-fade length of a coefficient swap, in samples (6.4 ms at
/// 10 kHz: longer than the LR4 time constant at 200 Hz, short enough to
/// feel immediate).
pub const DEFAULT_FADE_SAMPLES: u32 = 64;

/// Everything needed to design the chain.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainDesign {
    /// Sample rate in hertz.
    pub fs: f64,
    /// Linkwitz–Riley order: 2, 4 or 8.
    pub crossover_order: usize,
    /// Crossover frequency in hertz.
    pub crossover_hz: f64,
    /// Desired overall gain K_sys.
    pub k_sys: f64,
    /// Static gain of the low channel G0_L.
    pub g0_l: f64,
    /// Identified high channel Ĝ_H(s).
    pub g_h: Tf,
    /// Band-limiting filter F of C_H.
    pub high: HighCompensatorConfig,
    /// Prewarping of the bilinear transform of C_H. `AtCutoff` means the
    /// crossover frequency, so the whole chain is the bilinear image of the
    /// analog chain under one frequency map.
    pub c_h_prewarp: Prewarp,
}

impl ChainDesign {
    /// The paper's chain: LR4 at 200 Hz, fs = 10 kHz, K_sys = 1, G0_L = 1,
    /// Ĝ_H of eq. 2, F at 1 kHz with ζ = 1/√2, C_H prewarped at 200 Hz.
    pub fn paper() -> Self {
        Self {
            fs: 10_000.0,
            crossover_order: 4,
            crossover_hz: 200.0,
            k_sys: 1.0,
            g0_l: 1.0,
            g_h: compensator::paper_g_h(),
            high: HighCompensatorConfig::default(),
            c_h_prewarp: Prewarp::AtCutoff,
        }
    }
}

/// Digital coefficients of the chain: low path (crossover low-pass with C_L
/// folded into the first numerator) and high path (crossover high-pass, then
/// C_H), as second-order sections.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainCoefficients {
    fs: f64,
    low: Vec<BiquadCoeffs>,
    high: Vec<BiquadCoeffs>,
}

impl ChainCoefficients {
    /// From explicit sections. Each path needs 1..=[`MAX_STAGES`] finite,
    /// stable sections; `fs` in hertz.
    pub fn new(fs: f64, low: Vec<BiquadCoeffs>, high: Vec<BiquadCoeffs>) -> Result<Self> {
        if !(fs.is_finite() && fs > 0.0) {
            return Err(DspError::InvalidParameter {
                name: "fs",
                value: fs,
                reason: "sample rate must be finite and > 0 Hz".into(),
            });
        }
        for (name, path) in [("low", &low), ("high", &high)] {
            if path.is_empty() || path.len() > MAX_STAGES {
                return Err(DspError::InvalidInput(format!(
                    "{name} path has {} sections; 1..={MAX_STAGES} supported",
                    path.len()
                )));
            }
            if let Some(c) = path.iter().find(|c| !c.is_stable()) {
                return Err(DspError::Unstable(format!(
                    "{name} path section {c:?} is not finite and stable"
                )));
            }
        }
        Ok(Self { fs, low, high })
    }

    /// Design from a [`ChainDesign`] (paper §3.1 and §3.3).
    pub fn design(d: &ChainDesign) -> Result<Self> {
        let xo = LinkwitzRiley::new(d.crossover_order, d.crossover_hz, d.fs)?;
        let c_l = compensator::low_gain(d.k_sys, d.g0_l)?;
        let mut low = xo.low_sections().to_vec();
        low[0] = low[0].scaled(c_l);
        let c_h = compensator::high_zpk(d.k_sys, &d.g_h, d.high.f_corner_hz, d.high.zeta)?;
        let prewarp = match d.c_h_prewarp {
            Prewarp::None => None,
            Prewarp::AtCutoff => Some(d.crossover_hz),
            Prewarp::AtHz(f) => Some(f),
        };
        let mut high = xo.high_sections().to_vec();
        let mut c_h_sos = design::analog_zpk_to_sos(&c_h, d.fs, prewarp)?;
        // A first-order section goes last, where the chain's kernel can skip
        // its s2 update (the cascade's response does not depend on the order).
        c_h_sos.sort_by_key(BiquadCoeffs::is_first_order);
        high.extend(c_h_sos);
        Self::new(d.fs, low, high)
    }

    /// The paper's chain ([`ChainDesign::paper`]).
    pub fn paper() -> Result<Self> {
        Self::design(&ChainDesign::paper())
    }

    /// Sample rate in hertz.
    pub fn fs(&self) -> f64 {
        self.fs
    }

    /// Low-path sections (C_L included).
    pub fn low(&self) -> &[BiquadCoeffs] {
        &self.low
    }

    /// High-path sections (crossover high-pass then C_H).
    pub fn high(&self) -> &[BiquadCoeffs] {
        &self.high
    }

    /// Number of packed stages: max of the two section counts.
    pub fn stages(&self) -> usize {
        self.low.len().max(self.high.len())
    }

    /// Digital response (low, high) at `f` hertz.
    pub fn response(&self, f: f64) -> (C64, C64) {
        (
            sections_response(&self.low, f, self.fs),
            sections_response(&self.high, f, self.fs),
        )
    }

    /// Digital response of low + high at `f` hertz.
    pub fn sum_response(&self, f: f64) -> C64 {
        let (l, h) = self.response(f);
        l + h
    }
}

/// The running signal chain (Fig. 6). See the module docs.
///
/// Layout for speed: the running coefficients and state sit at fixed places
/// (`c`, `s`). A swap switches `c` to the new design at once (state
/// converted) and moves the old design into `gc`/`gs`, which runs only
/// during the cross-fade; nothing is copied when the fade ends. Every path
/// of [`Chain::process`] is inlined, call-free and indexes the state with
/// constants only, so that in a caller's sample loop the compiler can keep
/// the state in registers: an f64 store-to-load round trip through memory
/// costs ≈ 9 cycles on current x86 cores, as much as the whole per-sample
/// budget.
#[derive(Debug, Clone)]
pub struct Chain {
    c: Coefs,
    s: State,
    gc: Coefs,
    gs: State,
    fading: bool,
    fade_len: u32,
    fade_pos: u32,
    tick: u32,
    nonfinite: u64,
    stages: usize,
    /// Set by [`Chain::new_reference`]: never run the fast kernel.
    reference: bool,
    n_low: usize,
    n_high: usize,
    fs: f64,
}

impl Chain {
    /// Chain with the [`DEFAULT_FADE_SAMPLES`] cross-fade for coefficient swaps.
    pub fn new(coeffs: &ChainCoefficients) -> Self {
        Self::with_fade(coeffs, DEFAULT_FADE_SAMPLES)
    }

    /// Chain with a cross-fade of `fade_len` samples for coefficient swaps
    /// (0 = switch at once, keeping the state).
    pub fn with_fade(coeffs: &ChainCoefficients, fade_len: u32) -> Self {
        Self::build(coeffs, fade_len, false)
    }

    /// Chain that runs the reference kernel (plain TDF-II per lane, the same
    /// operations as an [`Sos`](crate::filter::Sos) of each path) for every
    /// coefficient set, including later swaps; otherwise identical to
    /// [`Chain::new`]. For the equivalence harness
    /// (`tests/equivalence.rs`), which checks the fast kernel against
    /// it; not meant for production use.
    #[doc(hidden)]
    pub fn new_reference(coeffs: &ChainCoefficients) -> Self {
        Self::build(coeffs, DEFAULT_FADE_SAMPLES, true)
    }

    fn build(coeffs: &ChainCoefficients, fade_len: u32, reference: bool) -> Self {
        let c = Coefs::new(&coeffs.low, &coeffs.high, !reference);
        Self {
            c,
            s: ZERO_STATE,
            gc: c,
            gs: ZERO_STATE,
            fading: false,
            fade_len,
            fade_pos: 0,
            tick: 0,
            nonfinite: 0,
            stages: coeffs.stages(),
            reference,
            n_low: coeffs.low.len(),
            n_high: coeffs.high.len(),
            fs: coeffs.fs,
        }
    }

    /// Sample rate in hertz.
    pub fn fs(&self) -> f64 {
        self.fs
    }

    /// Number of packed stages.
    pub fn stages(&self) -> usize {
        self.stages
    }

    /// True when the running coefficients use the fast normalised kernel
    /// (always the case for designed chains; hand-made sections with b0 = 0
    /// fall back to the reference kernel, which [`Chain::new_reference`]
    /// always uses).
    pub fn uses_fast_kernel(&self) -> bool {
        matches!(self.c.kernel, Kernel::Norm { .. })
    }

    /// `Some((stage count, first-order tail))` of the fast kernel running the
    /// current coefficients, `None` when the reference kernel runs them. For
    /// the equivalence harness (`tests/equivalence.rs`), which checks
    /// that every fast kernel was exercised.
    #[doc(hidden)]
    pub fn fast_kernel_shape(&self) -> Option<(usize, bool)> {
        match self.c.kernel {
            Kernel::Norm { stages, tail1 } => Some((stages, tail1)),
            Kernel::General => None,
        }
    }

    /// True while a coefficient cross-fade is in progress.
    pub fn is_fading(&self) -> bool {
        self.fading
    }

    /// Number of non-finite events (input or state) since construction.
    pub fn nonfinite_events(&self) -> u64 {
        self.nonfinite
    }

    /// Zero the state (a running cross-fade continues).
    #[inline(always)]
    pub fn reset(&mut self) {
        zero_state(&mut self.s);
        zero_state(&mut self.gs);
        self.tick = 0;
    }

    /// Swap in new coefficients without allocating: they must have the same
    /// sample rate and the same numbers of low and high sections as the
    /// running ones. The new design takes over the running state (converted
    /// to its scaling) and the output cross-fades from the old design over
    /// `fade_len` samples (see module docs). Refused while a previous
    /// cross-fade is still running.
    pub fn set_coefficients(&mut self, coeffs: &ChainCoefficients) -> Result<()> {
        if coeffs.low.len() != self.n_low || coeffs.high.len() != self.n_high {
            return Err(DspError::InvalidInput(format!(
                "coefficient swap needs {} low and {} high sections, got {} and {}",
                self.n_low,
                self.n_high,
                coeffs.low.len(),
                coeffs.high.len()
            )));
        }
        if coeffs.fs != self.fs {
            return Err(DspError::InvalidParameter {
                name: "fs",
                value: coeffs.fs,
                reason: format!("chain runs at {} Hz", self.fs),
            });
        }
        if self.fading {
            return Err(DspError::InvalidInput(
                "a coefficient cross-fade is still in progress".into(),
            ));
        }
        let new = Coefs::new(&coeffs.low, &coeffs.high, !self.reference);
        let s = new.convert_state(&self.c, &self.s);
        if self.fade_len > 0 {
            self.gc = self.c;
            self.gs = self.s;
            self.fading = true;
            self.fade_pos = 0;
        }
        self.c = new;
        self.s = s;
        Ok(())
    }

    /// Digital responses (low, high) of the running coefficients at `f` hertz.
    pub fn response(&self, f: f64) -> (C64, C64) {
        let w = 2.0 * std::f64::consts::PI * f / self.fs;
        let mut r = [C64::new(1.0, 0.0); 2];
        for (lane, n) in [(0, self.n_low), (1, self.n_high)] {
            for stage in &self.c.st[..n] {
                r[lane] *= stage.orig[lane].response_at(w);
            }
        }
        (r[0], r[1])
    }

    /// Digital response of low + high at `f` hertz.
    pub fn sum_response(&self, f: f64) -> C64 {
        let (l, h) = self.response(f);
        l + h
    }

    /// One input sample → (low output, high output). Never allocates or
    /// panics; see the module docs for non-finite handling.
    ///
    /// Between calls the recursive state lives in `self`, so every call pays
    /// a store-to-load round trip through memory in each section's feedback
    /// loop; for long runs prefer [`Chain::stream`] (per-sample, state in
    /// registers) or [`Chain::process_block`], which give identical output.
    #[inline]
    pub fn process(&mut self, x: f64) -> (f64, f64) {
        with_kernel!(self.c.kernel, N, T => self.step::<N, T>(x))
    }

    /// Block processing: `input` → `low`, `high`; processes
    /// `min(input.len(), low.len(), high.len())` samples and returns that
    /// count. Output is identical, sample for sample, to [`Chain::process`].
    pub fn process_block(&mut self, input: &[f64], low: &mut [f64], high: &mut [f64]) -> usize {
        let n = input.len().min(low.len()).min(high.len());
        let (input, low, high) = (&input[..n], &mut low[..n], &mut high[..n]);
        // The kernel cannot change inside this call (only `set_coefficients`
        // changes it), so dispatch once and run a monomorphised loop.
        with_kernel!(self.c.kernel, N, T => self.block::<N, T>(input, low, high));
        n
    }

    /// Block loop of kernel (N, T), equivalent sample for sample to
    /// [`Chain::process`]. The samples up to the next maintenance sample run
    /// as one chunk through the fast kernel with the state in a local (kept
    /// in registers) and without per-sample branches: the only per-sample
    /// check is an accumulator `acc += y − y`, which stays 0 while every
    /// output is finite and becomes NaN otherwise (a non-finite input always
    /// yields a non-finite output at the same sample). If it is not finite
    /// after the chunk, the first non-finite output j is located, output j
    /// zeroed, the state reset, the event counted, and processing resumes at
    /// j + 1 — exactly what the per-sample path does. The last sample of a
    /// chunk flushes and checks the state in registers. The reference kernel
    /// and cross-fades go through the per-sample step.
    fn block<const N: usize, const T: bool>(
        &mut self,
        input: &[f64],
        low: &mut [f64],
        high: &mut [f64],
    ) {
        let n = input.len().min(low.len()).min(high.len());
        let (input, low, high) = (&input[..n], &mut low[..n], &mut high[..n]);
        let mut i = 0;
        while i < n {
            if N == 0 || self.fading {
                (low[i], high[i]) = self.step::<N, T>(input[i]);
                i += 1;
                continue;
            }
            // After `room` more samples `tick` reaches FLUSH_INTERVAL: that
            // sample flushes and checks the state.
            let room = FLUSH_INTERVAL.saturating_sub(self.tick).max(1) as usize;
            let end = n.min(i + room);
            let maintain = end - i == room;
            let mut s = ZERO_STATE;
            s[..N].copy_from_slice(&self.s[..N]);
            let mut acc = [0.0f64; 2];
            let mut state_ok = true;
            let body_end = if maintain { end - 1 } else { end };
            for ((&x, l), h) in input[i..body_end]
                .iter()
                .zip(&mut low[i..body_end])
                .zip(&mut high[i..body_end])
            {
                let (y, _) = run_norm::<N, T>(&self.c, &mut s, x, false);
                acc = [
                    acc[0] + nan_if_nonfinite(y[0]),
                    acc[1] + nan_if_nonfinite(y[1]),
                ];
                *l = y[0];
                *h = y[1];
            }
            if maintain {
                let (y, ok) = run_norm::<N, T>(&self.c, &mut s, input[end - 1], true);
                acc = [
                    acc[0] + nan_if_nonfinite(y[0]),
                    acc[1] + nan_if_nonfinite(y[1]),
                ];
                low[end - 1] = y[0];
                high[end - 1] = y[1];
                state_ok = ok;
            }
            if acc[0] == 0.0 && acc[1] == 0.0 && state_ok {
                self.s[..N].copy_from_slice(&s[..N]);
                self.tick = if maintain {
                    0
                } else {
                    self.tick + (end - i) as u32
                };
                i = end;
            } else {
                cold();
                let j = low[i..end]
                    .iter()
                    .zip(&high[i..end])
                    .position(|(l, h)| !(l.is_finite() && h.is_finite()))
                    .map_or(end - 1, |p| i + p);
                self.on_nonfinite();
                low[j] = 0.0;
                high[j] = 0.0;
                i = j + 1;
            }
        }
    }

    /// Per-sample streaming: pulls the input samples one at a time from
    /// `input` and hands each output pair `(low, high)` to `sink` at once.
    /// Identical, sample for sample, to calling [`Chain::process`] in a loop,
    /// but the kernel is dispatched once and the state is held in a local
    /// (registers) for the whole stream, instead of going through memory on
    /// every call. Returns the number of samples processed. Allocates nothing.
    pub fn stream<I, S>(&mut self, input: I, mut sink: S) -> usize
    where
        I: IntoIterator<Item = f64>,
        S: FnMut(f64, f64),
    {
        let mut it = input.into_iter();
        let mut count = 0;
        while self.fading {
            let Some(x) = it.next() else {
                return count;
            };
            let (l, h) = self.process(x);
            sink(l, h);
            count += 1;
        }
        count + with_kernel!(self.c.kernel, N, T => self.stream_fast::<N, T, _, _>(it, &mut sink))
    }

    /// The monomorphised streaming loop (not fading: a fade cannot start
    /// while `self` is borrowed here).
    fn stream_fast<const N: usize, const T: bool, I, S>(&mut self, it: I, sink: &mut S) -> usize
    where
        I: Iterator<Item = f64>,
        S: FnMut(f64, f64),
    {
        let mut s = self.s;
        let mut tick = self.tick;
        let mut events = 0u64;
        let mut count = 0;
        for x in it {
            let (l, h) = guarded::<N, T>(&self.c, &mut s, &mut tick, &mut events, x);
            sink(l, h);
            count += 1;
        }
        self.s = s;
        self.tick = tick;
        self.nonfinite += events;
        count
    }

    /// The guarded per-sample step with kernel (N, T) on the running state;
    /// N = 0 means the reference kernel.
    #[inline(always)]
    fn step<const N: usize, const T: bool>(&mut self, x: f64) -> (f64, f64) {
        if self.fading {
            cold();
            return self.fade_step::<N, T>(x);
        }
        guarded::<N, T>(&self.c, &mut self.s, &mut self.tick, &mut self.nonfinite, x)
    }

    /// The guarded step during a cross-fade: new design (running state) and
    /// old design (ghost), blended linearly in fade_pos/fade_len.
    #[inline(always)]
    fn fade_step<const N: usize, const T: bool>(&mut self, x: f64) -> (f64, f64) {
        if !x.is_finite() {
            self.on_nonfinite();
            return (0.0, 0.0);
        }
        self.tick += 1;
        let flush = self.tick >= FLUSH_INTERVAL;
        if flush {
            self.tick = 0;
        }
        let (yn, ok_n) = if N == 0 {
            run_general(&self.c, &mut self.s, x, flush)
        } else {
            run_norm::<N, T>(&self.c, &mut self.s, x, flush)
        };
        let (yo, ok_o) = run_full(&self.gc, &mut self.gs, x, flush);
        self.fade_pos += 1;
        let alpha = f64::from(self.fade_pos) / f64::from(self.fade_len);
        let y = [
            yo[0] + alpha * (yn[0] - yo[0]),
            yo[1] + alpha * (yn[1] - yo[1]),
        ];
        if self.fade_pos >= self.fade_len {
            self.fading = false;
        }
        if !(ok_n && ok_o && y[0].is_finite() && y[1].is_finite()) {
            self.on_nonfinite();
            return (0.0, 0.0);
        }
        (y[0], y[1])
    }

    #[inline(always)]
    fn on_nonfinite(&mut self) {
        self.nonfinite += 1;
        self.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::Sos;
    use crate::filter::tests::Noise;
    use std::f64::consts::{PI, SQRT_2};

    #[test]
    fn paper_chain_structure() {
        let c = ChainCoefficients::paper().unwrap();
        assert_eq!(c.low().len(), 2);
        // LR4 high (2) + C_H (order 3 → 2 sections).
        assert_eq!(c.high().len(), 4);
        assert_eq!(c.stages(), 4);
        assert_eq!(c.fs(), 10_000.0);
    }

    /// Run `x` through `process`, `stream` and `process_block` (irregular
    /// block sizes) of fresh chains; assert the three are identical and
    /// return the outputs.
    fn run_all_apis(coeffs: &ChainCoefficients, x: &[f64]) -> Vec<(f64, f64)> {
        let mut a = Chain::new(coeffs);
        let per: Vec<(f64, f64)> = x.iter().map(|&v| a.process(v)).collect();
        let mut b = Chain::new(coeffs);
        let mut st = Vec::with_capacity(x.len());
        assert_eq!(b.stream(x.iter().copied(), |l, h| st.push((l, h))), x.len());
        let mut c = Chain::new(coeffs);
        let mut bl = vec![0.0; x.len()];
        let mut bh = vec![0.0; x.len()];
        let mut start = 0;
        for size in [1, 7, 63, 64, 65, 1000, 5000].iter().cycle() {
            if start >= x.len() {
                break;
            }
            let end = (start + size).min(x.len());
            assert_eq!(
                c.process_block(&x[start..end], &mut bl[start..end], &mut bh[start..end]),
                end - start
            );
            start = end;
        }
        for i in 0..x.len() {
            assert_eq!(per[i], st[i], "stream differs at {i}");
            assert_eq!(per[i], (bl[i], bh[i]), "block differs at {i}");
        }
        assert_eq!(a.nonfinite_events(), b.nonfinite_events());
        assert_eq!(a.nonfinite_events(), c.nonfinite_events());
        per
    }

    /// The two-lane chain equals two scalar TDF-II `Sos` cascades of the same
    /// sections to 1e-12 of the output amplitude, for the paper's chain,
    /// LR8, LR2 (inverted high path), a low crossover (fc/fs = 1e-3, large
    /// internal gain after b0 normalisation) and hand-made sections with
    /// b0 = 0 (general kernel).
    #[test]
    fn simd_lanes_equal_scalar_sos() {
        let delay = BiquadCoeffs::new([0.0, 0.5, 0.25], [1.0, -0.5, 0.1]).unwrap();
        let hand = ChainCoefficients::new(
            10_000.0,
            vec![
                delay,
                BiquadCoeffs::new([0.2, 0.1, 0.0], [1.0, -0.3, 0.0]).unwrap(),
            ],
            vec![BiquadCoeffs::new([1.0, -1.0, 0.3], [1.0, -1.2, 0.5]).unwrap()],
        )
        .unwrap();
        let designs = [
            ChainDesign::paper(),
            ChainDesign {
                crossover_order: 8,
                crossover_hz: 150.0,
                k_sys: 3.0,
                g0_l: 0.7,
                ..ChainDesign::paper()
            },
            ChainDesign {
                crossover_order: 2,
                ..ChainDesign::paper()
            },
            ChainDesign {
                crossover_hz: 10.0,
                ..ChainDesign::paper()
            },
        ];
        let mut all: Vec<ChainCoefficients> = designs
            .iter()
            .map(|d| ChainCoefficients::design(d).unwrap())
            .collect();
        all.push(hand);
        for (idx, coeffs) in all.iter().enumerate() {
            assert_eq!(Chain::new(coeffs).uses_fast_kernel(), idx < 4);
            let mut n = Noise(5 + idx as u64);
            let x: Vec<f64> = (0..20_000).map(|_| n.next()).collect();
            let out = run_all_apis(coeffs, &x);
            let mut lo = Sos::new(coeffs.low().to_vec()).unwrap();
            let mut hi = Sos::new(coeffs.high().to_vec()).unwrap();
            let (mut el, mut eh, mut rl, mut rh) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for (&v, &(l, h)) in x.iter().zip(&out) {
                let (sl, sh) = (lo.process(v), hi.process(v));
                el = el.max((l - sl).abs());
                eh = eh.max((h - sh).abs());
                rl = rl.max(sl.abs());
                rh = rh.max(sh.abs());
            }
            assert!(rl > 0.0 && rh > 0.0);
            assert!(
                el <= 1e-12 * rl && eh <= 1e-12 * rh,
                "design {idx}: {el:e} {eh:e}"
            );
        }
    }

    #[test]
    fn paper_chain_puts_first_order_section_last() {
        let c = ChainCoefficients::paper().unwrap();
        let last = c.high().last().unwrap();
        assert!(last.is_first_order());
        assert!(c.high()[..3].iter().all(|s| !s.is_first_order()));
        let chain = Chain::new(&c);
        assert!(chain.uses_fast_kernel());
        assert_eq!(chain.stages(), 4);
        // The response of the sections equals the product of the pieces:
        // LR4 (with C_L) · 1 for low; LR4 high · C_H(z) for high.
        let xo = LinkwitzRiley::new(4, 200.0, 10_000.0).unwrap();
        let ch = design::tf_to_sos(
            &compensator::high(
                1.0,
                &compensator::paper_g_h(),
                1000.0,
                std::f64::consts::FRAC_1_SQRT_2,
            )
            .unwrap(),
            10_000.0,
            Some(200.0),
        )
        .unwrap();
        for f in [10.0, 200.0, 500.0, 1000.0, 3000.0] {
            let (l, h) = chain.response(f);
            let (xl, xh) = xo.response(f);
            let want_h = xh * sections_response(&ch, f, 10_000.0);
            assert!((l - xl).norm() < 1e-12 * xl.norm());
            assert!((h - want_h).norm() < 1e-9 * want_h.norm(), "f={f}");
        }
    }

    /// With a plant whose responses are exactly G0_L (low) and Ĝ_H (high),
    /// C_L·L·G0_L + C_H·H·Ĝ_H = K_sys·(L + F·H): compared (i) tightly against
    /// the analog formulas through the bilinear frequency map and (ii) against
    /// the paper's flat target K_sys·(allpass·F) over 10 Hz–1 kHz.
    #[test]
    fn compensated_sum_is_flat() {
        for (k_sys, g0_l) in [(1.0, 1.0), (2.0, 0.35)] {
            let d = ChainDesign {
                k_sys,
                g0_l,
                ..ChainDesign::paper()
            };
            let coeffs = ChainCoefficients::design(&d).unwrap();
            let chain = Chain::new(&coeffs);
            let (fs, fc) = (d.fs, d.crossover_hz);
            let wc = 2.0 * PI * fc;
            let wf = 2.0 * PI * d.high.f_corner_hz;
            let kw = design::bilinear_constant(fs, Some(fc)).unwrap();
            let g = &d.g_h;
            let dpoly = |s: C64| {
                s.powi(4)
                    + 2.0 * SQRT_2 * wc * s.powi(3)
                    + 4.0 * wc * wc * s * s
                    + 2.0 * SQRT_2 * wc.powi(3) * s
                    + wc.powi(4)
            };
            let lr = |s: C64| (wc.powi(4) / dpoly(s), s.powi(4) / dpoly(s));
            let ff = |s: C64| wf * wf / (s * s + 2.0 * d.high.zeta * wf * s + wf * wf);
            let allpass =
                |s: C64| (s * s - SQRT_2 * wc * s + wc * wc) / (s * s + SQRT_2 * wc * s + wc * wc);
            let mut worst_db: f64 = 0.0;
            let mut f = 10.0;
            while f <= 1000.0 {
                let s = C64::new(0.0, 2.0 * PI * f);
                let sw = C64::new(0.0, kw * (PI * f / fs).tan()); // bilinear map
                let (l, h) = chain.response(f);
                let (l2, h2) = coeffs.response(f);
                assert_eq!((l, h), (l2, h2));
                let sum = l * g0_l + h * g.eval(s);
                // (i) exact prediction: C_L L(sw) G0_L + H(sw) C_H(sw) Ĝ_H(s).
                let (la, ha) = lr(sw);
                let pred =
                    (k_sys / g0_l) * la * g0_l + ha * k_sys * ff(sw) / g.eval(sw) * g.eval(s);
                assert!(
                    (sum - pred).norm() < 1e-9 * pred.norm(),
                    "f={f}: {sum} vs {pred}"
                );
                // (ii) flatness against K_sys·|A·F|.
                let target = k_sys * (allpass(s) * ff(s)).norm();
                let dev = 20.0 * (sum.norm() / target).log10();
                worst_db = worst_db.max(dev.abs());
                f *= 1.02;
            }
            // L + F·H differs from (L + H)·F by < 0.12 dB around fc (F's phase
            // at 200 Hz is −16°), and the bilinear warp of C_H against the
            // analog plant adds < 0.14 dB near 1 kHz; together < 0.2 dB, far
            // inside the paper's "flat within a few dB".
            assert!(worst_db < 0.2, "worst deviation {worst_db} dB");
        }
    }

    #[test]
    fn nonfinite_input_never_reaches_outputs() {
        let coeffs = ChainCoefficients::paper().unwrap();
        let mut c = Chain::new(&coeffs);
        let mut fresh = Chain::new(&coeffs);
        for i in 0..500 {
            c.process((i as f64 * 0.05).sin());
        }
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(c.process(bad), (0.0, 0.0));
        }
        assert_eq!(c.nonfinite_events(), 3);
        for i in 0..300 {
            let v = (i as f64 * 0.2).cos();
            assert_eq!(c.process(v), fresh.process(v));
        }
        // Block path: NaNs inside a block.
        let mut b = Chain::new(&coeffs);
        let mut r = Chain::new(&coeffs);
        let mut x: Vec<f64> = (0..200).map(|i| (i as f64 * 0.1).sin()).collect();
        x[50] = f64::NAN;
        x[51] = f64::INFINITY;
        x[150] = f64::NAN;
        let mut lo = vec![0.0; 200];
        let mut hi = vec![0.0; 200];
        b.process_block(&x, &mut lo, &mut hi);
        for (i, &v) in x.iter().enumerate() {
            let (l, h) = r.process(v);
            assert_eq!((l, h), (lo[i], hi[i]), "i={i}");
            assert!(lo[i].is_finite() && hi[i].is_finite());
        }
        assert_eq!(lo[50], 0.0);
        assert_eq!(b.nonfinite_events(), 3);
        // Overflowing input (the TDF-II state reaches ≈ |a1|·1e308): outputs
        // stay finite.
        let mut o = Chain::new(&coeffs);
        for _ in 0..100 {
            let (l, h) = o.process(1e308);
            assert!(l.is_finite() && h.is_finite());
        }
        assert!(o.nonfinite_events() > 0);
    }

    fn test_signal(i: usize, fs: f64) -> f64 {
        let t = i as f64 / fs;
        (2.0 * PI * 80.0 * t).sin()
            + 0.5 * (2.0 * PI * 410.0 * t).sin()
            + 0.2 * (2.0 * PI * 900.0 * t).sin()
    }

    #[test]
    fn swapping_to_identical_coefficients_is_bit_identical() {
        let coeffs = ChainCoefficients::paper().unwrap();
        for fade in [0, 1, 64] {
            let mut a = Chain::with_fade(&coeffs, fade);
            let mut b = Chain::with_fade(&coeffs, fade);
            for i in 0..3000 {
                let x = test_signal(i, 10_000.0);
                if i == 1234 {
                    b.set_coefficients(&coeffs).unwrap();
                }
                assert_eq!(a.process(x), b.process(x), "fade={fade} i={i}");
            }
        }
    }

    /// "No click": during and after a swap to a slightly different design
    /// (crossover 200 → 210 Hz, F corner 1000 → 950 Hz), the output's
    /// sample-to-sample change never exceeds the larger steady-state change of
    /// the old and new designs by more than max|y_new − y_old|/fade_len.
    /// A hard swap that resets the state violates this bound.
    #[test]
    fn coefficient_swap_without_click() {
        let fs = 10_000.0;
        let a = ChainCoefficients::paper().unwrap();
        let b = ChainCoefficients::design(&ChainDesign {
            crossover_hz: 210.0,
            high: HighCompensatorConfig {
                f_corner_hz: 950.0,
                ..HighCompensatorConfig::default()
            },
            ..ChainDesign::paper()
        })
        .unwrap();
        let n = 6000;
        let swap = 3000;
        let run = |coeffs: &ChainCoefficients| -> Vec<(f64, f64)> {
            let mut c = Chain::new(coeffs);
            (0..n).map(|i| c.process(test_signal(i, fs))).collect()
        };
        let ya = run(&a);
        let yb = run(&b);
        let max_step = |y: &[(f64, f64)], r: std::ops::Range<usize>| -> (f64, f64) {
            r.fold((0.0f64, 0.0f64), |m, i| {
                (
                    m.0.max((y[i].0 - y[i - 1].0).abs()),
                    m.1.max((y[i].1 - y[i - 1].1).abs()),
                )
            })
        };
        let sa = max_step(&ya, 1000..swap);
        let sb = max_step(&yb, 1000..n);
        let diff = (swap..n).fold((0.0f64, 0.0f64), |m, i| {
            (
                m.0.max((ya[i].0 - yb[i].0).abs()),
                m.1.max((ya[i].1 - yb[i].1).abs()),
            )
        });
        let fade = DEFAULT_FADE_SAMPLES as f64;
        let bound = (
            sa.0.max(sb.0) + diff.0 / fade,
            sa.1.max(sb.1) + diff.1 / fade,
        );
        let mut c = Chain::new(&a);
        let mut y = Vec::with_capacity(n);
        for i in 0..n {
            if i == swap {
                c.set_coefficients(&b).unwrap();
                assert!(c.is_fading());
                assert!(c.set_coefficients(&a).is_err(), "second swap during fade");
            }
            y.push(c.process(test_signal(i, fs)));
        }
        assert!(!c.is_fading());
        let s = max_step(&y, swap - 10..n);
        assert!(s.0 <= bound.0 * 1.05, "low step {} > {}", s.0, bound.0);
        assert!(s.1 <= bound.1 * 1.05, "high step {} > {}", s.1, bound.1);
        // After the fade the chain is the new design: converges to y_b.
        for i in n - 100..n {
            assert!((y[i].0 - yb[i].0).abs() < 1e-9 && (y[i].1 - yb[i].1).abs() < 1e-9);
        }
        // The bound is not vacuous: restarting the new design from zero state
        // at the swap (what a naive re-instantiation does) is a click.
        let mut naive_a = Chain::new(&a);
        let mut naive_b = Chain::new(&b);
        let mut z = Vec::with_capacity(n);
        for i in 0..n {
            let x = test_signal(i, fs);
            let ya_i = naive_a.process(x);
            z.push(if i < swap {
                ya_i
            } else {
                naive_b_after(&mut naive_b, i, swap, x)
            });
        }
        let sz = max_step(&z, swap - 10..n);
        assert!(
            sz.0 > bound.0 * 1.05 || sz.1 > bound.1 * 1.05,
            "naive swap should click"
        );
        // Mismatched shapes are refused.
        let lr8 = ChainCoefficients::design(&ChainDesign {
            crossover_order: 8,
            ..ChainDesign::paper()
        })
        .unwrap();
        assert!(Chain::new(&a).set_coefficients(&lr8).is_err());
    }

    fn naive_b_after(c: &mut Chain, i: usize, swap: usize, x: f64) -> (f64, f64) {
        if i == swap {
            c.reset();
        }
        c.process(x)
    }

    #[test]
    fn coefficient_validation() {
        let ok = vec![BiquadCoeffs::IDENTITY];
        assert!(ChainCoefficients::new(10_000.0, ok.clone(), ok.clone()).is_ok());
        assert!(ChainCoefficients::new(0.0, ok.clone(), ok.clone()).is_err());
        assert!(ChainCoefficients::new(10_000.0, vec![], ok.clone()).is_err());
        assert!(
            ChainCoefficients::new(10_000.0, ok.clone(), vec![BiquadCoeffs::IDENTITY; 9]).is_err()
        );
        let unstable = BiquadCoeffs::new([1.0, 0.0, 0.0], [1.0, 0.0, 1.5]).unwrap();
        assert!(ChainCoefficients::new(10_000.0, vec![unstable], ok).is_err());
        // Design errors propagate (RHP zero in Ĝ_H).
        let d = ChainDesign {
            g_h: Tf::new(vec![-250.0, 6.4e5], vec![1.0, 2135.0, 4.56e6]).unwrap(),
            ..ChainDesign::paper()
        };
        assert!(matches!(
            ChainCoefficients::design(&d),
            Err(DspError::RightHalfPlaneZeros { .. })
        ));
    }

    #[test]
    fn silence_after_signal_reaches_exact_zero() {
        let coeffs = ChainCoefficients::paper().unwrap();
        let mut c = Chain::new(&coeffs);
        let mut n = Noise(9);
        for _ in 0..10_000 {
            c.process(n.next());
        }
        let mut lo = vec![0.0; 20_000];
        let mut hi = vec![0.0; 20_000];
        let zeros = vec![0.0; 20_000];
        c.process_block(&zeros, &mut lo, &mut hi);
        assert!(lo.iter().chain(&hi).all(|v| *v == 0.0 || v.is_normal()));
        assert_eq!((lo[19_999], hi[19_999]), (0.0, 0.0));
        assert!(c.s.iter().flatten().flatten().all(|v| *v == 0.0));
    }
    /// A swap at the same sample gives the same output through `process`,
    /// `stream` and `process_block`, also while fading, and also between the
    /// fast and the general kernel (state converted between scalings).
    #[test]
    fn swaps_are_identical_across_apis() {
        let a = ChainCoefficients::paper().unwrap();
        let b = ChainCoefficients::design(&ChainDesign {
            crossover_hz: 230.0,
            ..ChainDesign::paper()
        })
        .unwrap();
        // Same shape as `a` (2 low, 4 high sections) but with a b0 = 0
        // section: runs on the general kernel.
        let g_low = a.low().to_vec();
        let mut g_high = a.high().to_vec();
        g_high[3] = BiquadCoeffs::new([0.0, 0.3, 0.0], [1.0, -0.7, 0.0]).unwrap();
        let g = ChainCoefficients::new(10_000.0, g_low, g_high).unwrap();
        assert!(!Chain::new(&g).uses_fast_kernel());
        let x: Vec<f64> = (0..3000).map(|i| test_signal(i, 10_000.0)).collect();
        let swaps = [(500usize, &b), (900, &g), (1500, &a), (1510, &b)];
        // Per-sample reference.
        let mut r = Chain::new(&a);
        let mut want = Vec::new();
        for (i, &v) in x.iter().enumerate() {
            for (at, c) in swaps {
                if at == i {
                    let res = r.set_coefficients(c);
                    assert_eq!(res.is_ok(), at != 1510, "swap at {at}");
                }
            }
            want.push(r.process(v));
        }
        // Block and stream, cut at the swap points.
        let mut blk = Chain::new(&a);
        let mut stm = Chain::new(&a);
        let mut got_b = vec![(0.0, 0.0); x.len()];
        let mut got_s = Vec::new();
        let mut start = 0;
        for (at, c) in swaps.iter().map(|(at, c)| (*at, *c)).chain([(x.len(), &a)]) {
            let mut lo = vec![0.0; at - start];
            let mut hi = vec![0.0; at - start];
            blk.process_block(&x[start..at], &mut lo, &mut hi);
            for (k, (l, h)) in lo.iter().zip(&hi).enumerate() {
                got_b[start + k] = (*l, *h);
            }
            stm.stream(x[start..at].iter().copied(), |l, h| got_s.push((l, h)));
            if at < x.len() {
                assert_eq!(blk.set_coefficients(c).is_ok(), at != 1510);
                assert_eq!(stm.set_coefficients(c).is_ok(), at != 1510);
            }
            start = at;
        }
        for i in 0..x.len() {
            assert_eq!(want[i], got_b[i], "block at {i}");
            assert_eq!(want[i], got_s[i], "stream at {i}");
        }
        // After the last swap the chain runs `a`'s design again (up to the
        // memory of the transient): compare with a chain that always ran `a`.
        let mut plain = Chain::new(&a);
        let ya: Vec<(f64, f64)> = x.iter().map(|&v| plain.process(v)).collect();
        for i in 2900..3000 {
            assert!((want[i].0 - ya[i].0).abs() < 1e-9 && (want[i].1 - ya[i].1).abs() < 1e-9);
        }
    }

    #[test]
    fn stream_handles_nonfinite_and_overflow() {
        let coeffs = ChainCoefficients::paper().unwrap();
        let mut x: Vec<f64> = (0..400).map(|i| (i as f64 * 0.05).sin()).collect();
        x[10] = f64::NAN;
        x[200] = f64::NEG_INFINITY;
        for v in &mut x[300..310] {
            *v = 1e308;
        }
        let out = run_all_apis(&coeffs, &x);
        assert!(out.iter().all(|(l, h)| l.is_finite() && h.is_finite()));
        assert_eq!(out[10], (0.0, 0.0));
        assert_eq!(out[200], (0.0, 0.0));
        let mut c = Chain::new(&coeffs);
        c.stream(x.iter().copied(), |_, _| {});
        assert!(c.nonfinite_events() >= 3);
    }
}
