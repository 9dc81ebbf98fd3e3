//! Welch spectral estimation (Welch 1967) with `scipy.signal` conventions,
//! cross spectra, coherence and H1/H2 frequency-response estimators
//! (Bendat & Piersol, *Random Data*, 4th ed., ch. 9), in batch form and as
//! streaming accumulators for live displays.
//!
//! Conventions (identical to `scipy.signal.welch`/`csd`/`coherence` with
//! default `return_onesided=True`, `average='mean'`, `boundary=None`,
//! `padded=False`):
//!
//! * Segments of `nperseg` samples start every `step = nperseg − noverlap`
//!   samples; K = ⌊(N − noverlap)/step⌋ segments, trailing samples unused.
//!   Default `noverlap = nperseg/2` (integer division).
//! * Each segment is detrended (default: mean removed), multiplied by a
//!   periodic ("DFT-even") window w (default Hann) and zero-padded to `nfft`.
//! * Density scaling S = 1/(fs Σw²) gives (signal unit)²/Hz; spectrum
//!   scaling S = 1/(Σw)² gives (signal unit)² (a sine of amplitude A reads
//!   A²/2). One-sided: every bin except DC and, for even `nfft`, Nyquist is
//!   doubled.
//! * Pxx = mean over segments of S·|Xₖ|²; Pxy = mean of S·conj(Xₖ)·Yₖ.
//! * Frequencies f_k = k·fs/nfft, k = 0 … ⌊nfft/2⌋ (Hz).
//!
//! One real-FFT plan (`realfft`) and one scratch buffer are created per call
//! (or per accumulator) and reused for every segment; detrending and
//! windowing are fused into the single pass that fills the FFT input.

use crate::error::check_fs;
use crate::{C64, DspError, Result};
use realfft::{RealFftPlanner, RealToComplex};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::fmt;
use std::ops::Mul;
use std::sync::Arc;

// ---------------------------------------------------------------------------
// Configuration
// ---------------------------------------------------------------------------

/// Periodic (DFT-even) data windows, as `scipy.signal.get_window(name, N)`
/// (`fftbins=True`), which `welch` uses by default.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Window {
    /// w\[n\] = ½ − ½ cos(2πn/N): Σw = N/2, Σw² = 3N/8, ENBW = 1.5 bins.
    #[default]
    Hann,
    /// w\[n\] = 0.54 − 0.46 cos(2πn/N): ENBW ≈ 1.363 bins.
    Hamming,
    /// w\[n\] = 1 (rectangular): ENBW = 1 bin.
    Boxcar,
}

impl Window {
    /// The N window coefficients (N = 1 gives `[1.0]`, as scipy).
    pub fn coefficients(self, n: usize) -> Vec<f64> {
        let a0 = match self {
            Window::Hann => 0.5,
            Window::Hamming => 0.54,
            Window::Boxcar => return vec![1.0; n],
        };
        if n == 1 {
            return vec![1.0];
        }
        (0..n)
            .map(|i| a0 - (1.0 - a0) * (2.0 * PI * i as f64 / n as f64).cos())
            .collect()
    }
}

/// (Σw, Σw²) of a window.
pub fn window_sums(w: &[f64]) -> (f64, f64) {
    (w.iter().sum(), w.iter().map(|v| v * v).sum())
}

/// Equivalent noise bandwidth in bins, N·Σw²/(Σw)² (Harris 1978).
/// Multiply by fs/N for hertz.
pub fn enbw_bins(w: &[f64]) -> f64 {
    let (s1, s2) = window_sums(w);
    w.len() as f64 * s2 / (s1 * s1)
}

/// Per-segment detrending, as scipy's `detrend=` argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Detrend {
    /// No detrending (`detrend=False`).
    None,
    /// Remove the segment mean (`'constant'`, scipy's default).
    #[default]
    Constant,
    /// Remove the least-squares straight line (`'linear'`).
    Linear,
}

/// Output scaling, as scipy's `scaling=` argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scaling {
    /// Power spectral density, unit²/Hz: S = 1/(fs Σw²).
    #[default]
    Density,
    /// Power spectrum, unit²: S = 1/(Σw)².
    Spectrum,
}

/// Welch estimator settings (scipy names and defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct WelchConfig {
    /// Segment length in samples (scipy default 256).
    pub nperseg: usize,
    /// Overlap in samples; `None` = nperseg/2.
    pub noverlap: Option<usize>,
    /// FFT length ≥ nperseg (zero padding); `None` = nperseg.
    pub nfft: Option<usize>,
    /// Data window (periodic).
    pub window: Window,
    /// Per-segment detrending.
    pub detrend: Detrend,
    /// Density or spectrum scaling.
    pub scaling: Scaling,
}

impl Default for WelchConfig {
    fn default() -> Self {
        Self::new(256)
    }
}

impl WelchConfig {
    /// scipy defaults with the given segment length: Hann, 50 % overlap,
    /// constant detrend, density scaling, nfft = nperseg.
    pub fn new(nperseg: usize) -> Self {
        Self {
            nperseg,
            noverlap: None,
            nfft: None,
            window: Window::Hann,
            detrend: Detrend::Constant,
            scaling: Scaling::Density,
        }
    }

    /// Set the overlap (samples).
    pub fn with_noverlap(mut self, noverlap: usize) -> Self {
        self.noverlap = Some(noverlap);
        self
    }

    /// Set the FFT length (samples).
    pub fn with_nfft(mut self, nfft: usize) -> Self {
        self.nfft = Some(nfft);
        self
    }

    /// Set the window.
    pub fn with_window(mut self, window: Window) -> Self {
        self.window = window;
        self
    }

    /// Set the detrending.
    pub fn with_detrend(mut self, detrend: Detrend) -> Self {
        self.detrend = detrend;
        self
    }

    /// Set the scaling.
    pub fn with_scaling(mut self, scaling: Scaling) -> Self {
        self.scaling = scaling;
        self
    }

    /// Effective overlap: `noverlap` or nperseg/2.
    pub fn overlap(&self) -> usize {
        self.noverlap.unwrap_or(self.nperseg / 2)
    }

    /// Effective FFT length: `nfft` or nperseg.
    pub fn fft_len(&self) -> usize {
        self.nfft.unwrap_or(self.nperseg)
    }

    /// Number of segments K = ⌊(len − noverlap)/(nperseg − noverlap)⌋ for a
    /// signal of `len` samples (0 if the configuration is invalid or the
    /// signal is shorter than one segment).
    pub fn num_segments(&self, len: usize) -> usize {
        let nov = self.overlap();
        if self.nperseg == 0 || nov >= self.nperseg || len < self.nperseg {
            return 0;
        }
        (len - nov) / (self.nperseg - nov)
    }
}

// ---------------------------------------------------------------------------
// Results
// ---------------------------------------------------------------------------

/// Auto spectrum estimate.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Spectrum {
    /// Frequencies (Hz), k·fs/nfft.
    pub f: Vec<f64>,
    /// One-sided PSD (unit²/Hz) or power spectrum (unit²).
    pub p: Vec<f64>,
    /// Number of averaged segments.
    pub n_segments: usize,
}

/// Cross spectrum estimate Pxy = mean S·conj(X)·Y (one-sided).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CrossSpectrum {
    /// Frequencies (Hz).
    pub f: Vec<f64>,
    /// One-sided cross spectral density (unitx·unity/Hz) or cross spectrum.
    pub pxy: Vec<C64>,
    /// Number of averaged segments.
    pub n_segments: usize,
}

/// Magnitude-squared coherence γ² = |Pxy|²/(Pxx Pyy) ∈ [0, 1].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Coherence {
    /// Frequencies (Hz).
    pub f: Vec<f64>,
    /// γ² per bin (0 where Pxx or Pyy vanishes).
    pub c: Vec<f64>,
    /// Number of averaged segments.
    pub n_segments: usize,
}

/// A single frequency-response estimate (H1 or H2).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct FrequencyResponse {
    /// Frequencies (Hz).
    pub f: Vec<f64>,
    /// Complex response (unity/unitx).
    pub h: Vec<C64>,
    /// Number of averaged segments.
    pub n_segments: usize,
}

/// Everything one pass over (x, y) yields.
///
/// H1 = Pxy/Pxx (unbiased by output noise), H2 = Pyy/Pyx = Pyy/conj(Pxy)
/// (unbiased by input noise), γ² = |Pxy|²/(Pxx Pyy) = H1/H2.
/// Bins where a denominator vanishes (no input power, e.g. DC after mean
/// removal of a constant; or no output power) report 0 for the undefined
/// quantities (H1 where Pxx = 0; H2 and γ² where Pxx, Pyy or |Pxy| = 0)
/// instead of NaN/∞, so live displays never see non-finite values; γ² = 0
/// flags such bins as unusable.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct FrfEstimate {
    /// Frequencies (Hz).
    pub f: Vec<f64>,
    /// H1 = Pxy/Pxx.
    pub h1: Vec<C64>,
    /// H2 = Pyy/Pyx.
    pub h2: Vec<C64>,
    /// γ² = |Pxy|²/(Pxx Pyy).
    pub coherence: Vec<f64>,
    /// Input auto spectrum.
    pub pxx: Vec<f64>,
    /// Output auto spectrum.
    pub pyy: Vec<f64>,
    /// Cross spectrum conj(X)·Y.
    pub pxy: Vec<C64>,
    /// Number of averaged segments.
    pub n_segments: usize,
}

// ---------------------------------------------------------------------------
// Validated parameters and the per-segment engine
// ---------------------------------------------------------------------------

#[derive(Debug, Clone, Copy)]
struct Params {
    fs: f64,
    nperseg: usize,
    noverlap: usize,
    step: usize,
    nfft: usize,
    nbins: usize,
    detrend: Detrend,
    /// S without the one-sided factor 2.
    scale: f64,
}

impl Params {
    fn new(cfg: &WelchConfig, fs: f64, len: Option<usize>) -> Result<(Self, Vec<f64>)> {
        check_fs(fs)?;
        let nperseg = cfg.nperseg;
        if nperseg == 0 {
            return Err(DspError::param("nperseg", 0.0, "must be ≥ 1"));
        }
        if let Some(len) = len {
            if len == 0 {
                return Err(DspError::InvalidInput("empty signal".into()));
            }
            if nperseg > len {
                return Err(DspError::param(
                    "nperseg",
                    nperseg as f64,
                    format!("exceeds the signal length {len}"),
                ));
            }
        }
        let noverlap = cfg.overlap();
        if noverlap >= nperseg {
            return Err(DspError::param(
                "noverlap",
                noverlap as f64,
                format!("must be < nperseg = {nperseg}"),
            ));
        }
        let nfft = cfg.fft_len();
        if nfft < nperseg {
            return Err(DspError::param(
                "nfft",
                nfft as f64,
                format!("must be ≥ nperseg = {nperseg}"),
            ));
        }
        let window = cfg.window.coefficients(nperseg);
        let (s1, s2) = window_sums(&window);
        let scale = match cfg.scaling {
            Scaling::Density => 1.0 / (fs * s2),
            Scaling::Spectrum => 1.0 / (s1 * s1),
        };
        if !(scale.is_finite() && scale > 0.0) {
            return Err(DspError::param(
                "window",
                nperseg as f64,
                "window sums vanish",
            ));
        }
        Ok((
            Self {
                fs,
                nperseg,
                noverlap,
                step: nperseg - noverlap,
                nfft,
                nbins: nfft / 2 + 1,
                detrend: cfg.detrend,
                scale,
            },
            window,
        ))
    }

    fn num_segments(&self, len: usize) -> usize {
        if len < self.nperseg {
            0
        } else {
            (len - self.noverlap) / self.step
        }
    }

    /// Scale of bin k including the one-sided doubling (not for DC, nor for
    /// the Nyquist bin of an even nfft).
    #[inline]
    fn bin_scale(&self, k: usize) -> f64 {
        if k == 0 || (self.nfft.is_multiple_of(2) && k == self.nfft / 2) {
            self.scale
        } else {
            2.0 * self.scale
        }
    }

    fn frequencies(&self) -> Vec<f64> {
        (0..self.nbins)
            .map(|k| k as f64 * self.fs / self.nfft as f64)
            .collect()
    }
}

/// Σ term(x\[i\], y\[i\]) over the common length, with eight independent
/// partial sums (vectorisable, and pairwise-like error growth), reduced in a
/// fixed order.
#[inline(always)]
fn sum8(x: &[f64], y: &[f64], term: impl Fn(f64, f64) -> f64) -> f64 {
    let mut acc = [0.0f64; 8];
    let cx = x.chunks_exact(8);
    let cy = y.chunks_exact(8);
    let (rx, ry) = (cx.remainder(), cy.remainder());
    for (a8, b8) in cx.zip(cy) {
        for ((a, &u), &v) in acc.iter_mut().zip(a8).zip(b8) {
            *a += term(u, v);
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (&u, &v) in rx.iter().zip(ry) {
        s += term(u, v);
    }
    s
}

/// Σ x\[i\] (see [`sum8`]).
#[inline]
fn fast_sum(x: &[f64]) -> f64 {
    sum8(x, x, |u, _| u)
}

/// Σ x\[i\]·y\[i\] (see [`sum8`]).
#[inline]
fn fast_dot(x: &[f64], y: &[f64]) -> f64 {
    sum8(x, y, |u, v| u * v)
}

/// Detrend + window + zero-pad + real FFT of one segment; owns the plan and
/// all buffers, so [`Engine::transform`] allocates nothing.
struct Engine {
    fft: Arc<dyn RealToComplex<f64>>,
    window: Vec<f64>,
    detrend: Detrend,
    /// Centred sample index n − (N−1)/2 (linear detrend only).
    tc: Vec<f64>,
    /// Σ tc².
    tc_ss: f64,
    input: Vec<f64>,
    scratch: Vec<C64>,
}

impl fmt::Debug for Engine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Engine")
            .field("nfft", &self.fft.len())
            .field("nperseg", &self.window.len())
            .field("detrend", &self.detrend)
            .finish_non_exhaustive()
    }
}

impl Engine {
    fn new(p: &Params, window: Vec<f64>) -> Self {
        let mut planner = RealFftPlanner::<f64>::new();
        let fft = planner.plan_fft_forward(p.nfft);
        let scratch = fft.make_scratch_vec();
        let input = fft.make_input_vec();
        let (tc, tc_ss) = if p.detrend == Detrend::Linear {
            let mid = (p.nperseg as f64 - 1.0) / 2.0;
            let tc: Vec<f64> = (0..p.nperseg).map(|i| i as f64 - mid).collect();
            let ss = tc.iter().map(|t| t * t).sum();
            (tc, ss)
        } else {
            (Vec::new(), 0.0)
        };
        Self {
            fft,
            window,
            detrend: p.detrend,
            tc,
            tc_ss,
            input,
            scratch,
        }
    }

    /// `out` ← FFT(window · detrend(seg)), zero-padded to nfft.
    ///
    /// Linear detrend uses the centred abscissa tc, for which the columns
    /// [1, tc] of the least-squares line fit are orthogonal: the QR solution
    /// is then mean = Σx/N, slope = Σ tc·x / Σ tc² exactly.
    fn transform(&mut self, seg: &[f64], out: &mut [C64]) -> Result<()> {
        let n = self.window.len();
        let (head, tail) = self.input.split_at_mut(n);
        match self.detrend {
            Detrend::None => {
                for ((d, &x), &w) in head.iter_mut().zip(seg).zip(&self.window) {
                    *d = x * w;
                }
            }
            Detrend::Constant => {
                let mean = fast_sum(seg) / n as f64;
                for ((d, &x), &w) in head.iter_mut().zip(seg).zip(&self.window) {
                    *d = (x - mean) * w;
                }
            }
            Detrend::Linear => {
                let mean = fast_sum(seg) / n as f64;
                let slope = if self.tc_ss > 0.0 {
                    fast_dot(&self.tc, seg) / self.tc_ss
                } else {
                    0.0
                };
                for (((d, &x), &w), &t) in head.iter_mut().zip(seg).zip(&self.window).zip(&self.tc)
                {
                    *d = (x - mean - slope * t) * w;
                }
            }
        }
        tail.fill(0.0);
        self.fft
            .process_with_scratch(&mut self.input, out, &mut self.scratch)
            .map_err(|e| DspError::Numerical(format!("real FFT failed: {e}")))
    }
}

#[inline]
fn accumulate_auto(acc: &mut [f64], x: &[C64]) {
    for (a, v) in acc.iter_mut().zip(x) {
        *a += v.re * v.re + v.im * v.im;
    }
}

#[inline]
fn accumulate_cross(acc: &mut [C64], x: &[C64], y: &[C64]) {
    for ((a, u), v) in acc.iter_mut().zip(x).zip(y) {
        // conj(u)·v
        a.re += u.re * v.re + u.im * v.im;
        a.im += u.re * v.im - u.im * v.re;
    }
}

/// Would adding this segment keep every accumulator finite?
fn auto_stays_finite(acc: &[f64], x: &[C64]) -> bool {
    acc.iter()
        .zip(x)
        .all(|(a, v)| (a + v.re * v.re + v.im * v.im).is_finite())
}

/// `out` = the averaged, one-sided scaled spectrum: acc\[k\]·S_k/n_seg, with
/// S_k the bin scale of [`Params::bin_scale`] (auto spectra as `f64`, cross
/// spectra as `C64`).
fn finalize<T: Copy + Mul<f64, Output = T>>(p: &Params, acc: &[T], n_seg: usize, out: &mut [T]) {
    let inv = 1.0 / n_seg as f64;
    for (k, (o, &a)) in out.iter_mut().zip(acc).enumerate() {
        *o = a * (inv * p.bin_scale(k));
    }
}

/// γ², H1, H2 from the averaged spectra (see [`FrfEstimate`]).
fn frf_from_spectra(pxx: f64, pyy: f64, pxy: C64) -> (C64, C64, f64) {
    let tiny = f64::MIN_POSITIVE;
    let m = pxy.norm();
    if pxx <= tiny || pyy <= tiny || m <= tiny {
        let h1 = if pxx > tiny {
            pxy / pxx
        } else {
            C64::new(0.0, 0.0)
        };
        return (h1, C64::new(0.0, 0.0), 0.0);
    }
    let h1 = pxy / pxx;
    let h2 = pyy / pxy.conj();
    // |Pxy|²/(Pxx Pyy) written to avoid under/overflow of the products;
    // Cauchy–Schwarz bounds it by 1 up to rounding.
    let c = ((m / pxx) * (m / pyy)).min(1.0);
    (h1, h2, c)
}

fn check_finite(x: &[f64], name: &str) -> Result<()> {
    // Branch-free scan: 0·v is NaN exactly when v is ±∞ or NaN.
    let mut acc = [0.0f64; 4];
    let chunks = x.chunks_exact(4);
    let rem = chunks.remainder();
    for c in chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            *a += 0.0 * v;
        }
    }
    let mut s = acc.iter().sum::<f64>();
    for v in rem {
        s += 0.0 * v;
    }
    if s == 0.0 {
        Ok(())
    } else {
        let i = x.iter().position(|v| !v.is_finite()).unwrap_or(0);
        Err(DspError::InvalidInput(format!(
            "non-finite value in `{name}` at index {i}"
        )))
    }
}

/// The error of an estimate that overflowed.
fn overflow_error() -> DspError {
    DspError::Numerical("spectral estimate overflowed (input magnitude too large)".into())
}

fn check_output_finite<'a>(mut values: impl Iterator<Item = &'a f64>) -> Result<()> {
    if values.all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(overflow_error())
    }
}

/// What `feed` of a streaming estimator returns: the number of segments
/// completed, or a `Numerical` error when `dropped` segments had to be
/// discarded because they would overflow the accumulators.
fn feed_result(done: usize, dropped: usize) -> Result<usize> {
    if dropped > 0 {
        return Err(DspError::Numerical(format!(
            "{dropped} segment(s) discarded: spectrum overflow"
        )));
    }
    Ok(done)
}

fn c_as_f64(v: &[C64]) -> impl Iterator<Item = &f64> {
    v.iter().flat_map(|c| [&c.re, &c.im])
}

// ---------------------------------------------------------------------------
// Batch estimators
// ---------------------------------------------------------------------------

/// Welch power spectral density (or power spectrum) of `x` sampled at `fs` Hz,
/// scipy.signal.welch conventions (module docs).
///
/// Errors (`InvalidParameter` naming the parameter): `fs` ≤ 0 or non-finite,
/// `nperseg` = 0 or > len(x), `noverlap` ≥ nperseg, `nfft` < nperseg;
/// `InvalidInput` for empty or non-finite `x`; `Numerical` if the result
/// overflows.
pub fn welch(x: &[f64], fs: f64, cfg: &WelchConfig) -> Result<Spectrum> {
    let (p, window) = Params::new(cfg, fs, Some(x.len()))?;
    check_finite(x, "x")?;
    let mut eng = Engine::new(&p, window);
    let mut spec = vec![C64::new(0.0, 0.0); p.nbins];
    let mut acc = vec![0.0; p.nbins];
    let n_seg = p.num_segments(x.len());
    for s in 0..n_seg {
        let start = s * p.step;
        eng.transform(&x[start..start + p.nperseg], &mut spec)?;
        accumulate_auto(&mut acc, &spec);
    }
    let mut out = vec![0.0; p.nbins];
    finalize(&p, &acc, n_seg, &mut out);
    check_output_finite(out.iter())?;
    Ok(Spectrum {
        f: p.frequencies(),
        p: out,
        n_segments: n_seg,
    })
}

fn check_pair(x: &[f64], y: &[f64]) -> Result<()> {
    if x.len() != y.len() {
        return Err(DspError::InvalidInput(format!(
            "`x` and `y` differ in length ({} vs {})",
            x.len(),
            y.len()
        )));
    }
    check_finite(x, "x")?;
    check_finite(y, "y")
}

/// Cross spectral density Pxy = mean S·conj(X)·Y of `x` (input) and `y`
/// (output), scipy.signal.csd conventions. Same errors as [`welch`], plus
/// `InvalidInput` if the lengths differ.
pub fn csd(x: &[f64], y: &[f64], fs: f64, cfg: &WelchConfig) -> Result<CrossSpectrum> {
    let (p, window) = Params::new(cfg, fs, Some(x.len()))?;
    check_pair(x, y)?;
    let mut eng = Engine::new(&p, window);
    let mut sx = vec![C64::new(0.0, 0.0); p.nbins];
    let mut sy = sx.clone();
    let mut acc = sx.clone();
    let n_seg = p.num_segments(x.len());
    for s in 0..n_seg {
        let r = s * p.step..s * p.step + p.nperseg;
        eng.transform(&x[r.clone()], &mut sx)?;
        eng.transform(&y[r], &mut sy)?;
        accumulate_cross(&mut acc, &sx, &sy);
    }
    let mut out = acc.clone();
    finalize(&p, &acc, n_seg, &mut out);
    check_output_finite(c_as_f64(&out))?;
    Ok(CrossSpectrum {
        f: p.frequencies(),
        pxy: out,
        n_segments: n_seg,
    })
}

/// H1, H2, γ², Pxx, Pyy and Pxy of input `x` and output `y` in one pass
/// (two FFTs per segment). Same errors as [`csd`].
pub fn frf(x: &[f64], y: &[f64], fs: f64, cfg: &WelchConfig) -> Result<FrfEstimate> {
    // Validate against the signal length like the other batch functions.
    Params::new(cfg, fs, Some(x.len()))?;
    check_pair(x, y)?;
    let mut s = StreamingFrf::new(fs, cfg)?;
    let p = s.p;
    let n_seg = p.num_segments(x.len());
    for k in 0..n_seg {
        let r = k * p.step..k * p.step + p.nperseg;
        if !s.process_segment_slices(&x[r.clone()], &y[r])? {
            return Err(overflow_error());
        }
    }
    let mut est = FrfEstimate::default();
    s.estimate_into(&mut est);
    check_output_finite(est.pxx.iter().chain(&est.pyy).chain(c_as_f64(&est.pxy)))?;
    Ok(est)
}

/// Magnitude-squared coherence γ² = |Pxy|²/(Pxx Pyy) (scipy.signal.coherence).
pub fn coherence(x: &[f64], y: &[f64], fs: f64, cfg: &WelchConfig) -> Result<Coherence> {
    let e = frf(x, y, fs, cfg)?;
    Ok(Coherence {
        f: e.f,
        c: e.coherence,
        n_segments: e.n_segments,
    })
}

/// H1 = Pxy/Pxx, the estimator that is unbiased when noise is on the output
/// only (Bendat & Piersol, ch. 9).
pub fn frf_h1(x: &[f64], y: &[f64], fs: f64, cfg: &WelchConfig) -> Result<FrequencyResponse> {
    let e = frf(x, y, fs, cfg)?;
    Ok(FrequencyResponse {
        f: e.f,
        h: e.h1,
        n_segments: e.n_segments,
    })
}

/// H2 = Pyy/Pyx, the estimator that is unbiased when noise is on the input
/// only.
pub fn frf_h2(x: &[f64], y: &[f64], fs: f64, cfg: &WelchConfig) -> Result<FrequencyResponse> {
    let e = frf(x, y, fs, cfg)?;
    Ok(FrequencyResponse {
        f: e.f,
        h: e.h2,
        n_segments: e.n_segments,
    })
}

// ---------------------------------------------------------------------------
// Streaming accumulators
// ---------------------------------------------------------------------------

/// Segment buffer: collects samples until a full segment is available, then
/// keeps the last `noverlap` samples for the next one.
#[derive(Debug, Clone)]
struct SegmentBuffer {
    buf: Vec<f64>,
    fill: usize,
}

impl SegmentBuffer {
    fn new(nperseg: usize) -> Self {
        Self {
            buf: vec![0.0; nperseg],
            fill: 0,
        }
    }

    /// Copy as much of `src` as fits; returns the number of samples taken.
    #[inline]
    fn push(&mut self, src: &[f64]) -> usize {
        let take = (self.buf.len() - self.fill).min(src.len());
        self.buf[self.fill..self.fill + take].copy_from_slice(&src[..take]);
        self.fill += take;
        take
    }

    fn is_full(&self) -> bool {
        self.fill == self.buf.len()
    }

    fn advance(&mut self, step: usize, noverlap: usize) {
        self.buf.copy_within(step.., 0);
        self.fill = noverlap;
    }
}

/// Streaming Welch PSD for live displays.
///
/// Feed blocks of any length with [`StreamingWelch::feed`]; full segments are
/// cut with the configured overlap exactly as [`welch`] cuts the
/// concatenated signal, so after feeding x in any chunking the estimate is
/// bit-for-bit `welch(x)`. All buffers and the FFT plan are allocated in
/// [`StreamingWelch::new`]; `feed`, `estimate_into` (once `out` is sized) and
/// `reset` allocate nothing and never panic.
pub struct StreamingWelch {
    p: Params,
    engine: Engine,
    seg: SegmentBuffer,
    spec: Vec<C64>,
    acc: Vec<f64>,
    n_segments: usize,
    f: Vec<f64>,
}

impl fmt::Debug for StreamingWelch {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("StreamingWelch")
            .field("params", &self.p)
            .field("engine", &self.engine)
            .field("buffered", &self.seg.fill)
            .field("n_segments", &self.n_segments)
            .finish_non_exhaustive()
    }
}

impl StreamingWelch {
    /// Accumulator for sample rate `fs` (Hz) and settings `cfg` (same
    /// validation as [`welch`], without the signal-length check).
    pub fn new(fs: f64, cfg: &WelchConfig) -> Result<Self> {
        let (p, window) = Params::new(cfg, fs, None)?;
        Ok(Self {
            engine: Engine::new(&p, window),
            seg: SegmentBuffer::new(p.nperseg),
            spec: vec![C64::new(0.0, 0.0); p.nbins],
            acc: vec![0.0; p.nbins],
            n_segments: 0,
            f: p.frequencies(),
            p,
        })
    }

    /// Consume a block of samples; returns the number of segments completed.
    ///
    /// A block containing NaN/±∞ is rejected whole (`InvalidInput`, state
    /// unchanged). A segment whose spectrum would overflow the accumulators
    /// is discarded and reported as `Numerical` after the rest of the block
    /// has been consumed.
    pub fn feed(&mut self, block: &[f64]) -> Result<usize> {
        check_finite(block, "block")?;
        let mut rest = block;
        let mut done = 0;
        let mut dropped = 0;
        while !rest.is_empty() {
            let took = self.seg.push(rest);
            rest = &rest[took..];
            if self.seg.is_full() {
                self.engine.transform(&self.seg.buf, &mut self.spec)?;
                if auto_stays_finite(&self.acc, &self.spec) {
                    accumulate_auto(&mut self.acc, &self.spec);
                    self.n_segments += 1;
                    done += 1;
                } else {
                    dropped += 1;
                }
                self.seg.advance(self.p.step, self.p.noverlap);
            }
        }
        feed_result(done, dropped)
    }

    /// Segments averaged so far.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// Bin frequencies (Hz).
    pub fn frequencies(&self) -> &[f64] {
        &self.f
    }

    /// Running estimate into `out` (resized on first use only). Returns
    /// false, with `p` zeroed, while no full segment has been seen.
    pub fn estimate_into(&self, out: &mut Spectrum) -> bool {
        if out.f != self.f {
            out.f.clone_from(&self.f);
        }
        out.p.resize(self.p.nbins, 0.0);
        out.n_segments = self.n_segments;
        if self.n_segments == 0 {
            out.p.fill(0.0);
            return false;
        }
        finalize(&self.p, &self.acc, self.n_segments, &mut out.p);
        true
    }

    /// Running estimate (allocates); `None` before the first full segment.
    pub fn estimate(&self) -> Option<Spectrum> {
        let mut s = Spectrum::default();
        self.estimate_into(&mut s).then_some(s)
    }

    /// Forget all data (keeps the plan and buffers).
    pub fn reset(&mut self) {
        self.acc.fill(0.0);
        self.n_segments = 0;
        self.seg.fill = 0;
    }
}

/// Streaming two-channel estimator (Pxx, Pyy, Pxy → H1, H2, γ²) for live
/// frequency-response displays; segmentation and guarantees as
/// [`StreamingWelch`] (feeding x, y in any chunking reproduces [`frf`]
/// bit for bit).
pub struct StreamingFrf {
    p: Params,
    engine: Engine,
    seg_x: SegmentBuffer,
    seg_y: SegmentBuffer,
    spec_x: Vec<C64>,
    spec_y: Vec<C64>,
    acc_xx: Vec<f64>,
    acc_yy: Vec<f64>,
    acc_xy: Vec<C64>,
    n_segments: usize,
    f: Vec<f64>,
}

impl fmt::Debug for StreamingFrf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("StreamingFrf")
            .field("params", &self.p)
            .field("engine", &self.engine)
            .field("buffered", &self.seg_x.fill)
            .field("n_segments", &self.n_segments)
            .finish_non_exhaustive()
    }
}

impl StreamingFrf {
    /// Accumulator for sample rate `fs` (Hz) and settings `cfg`.
    pub fn new(fs: f64, cfg: &WelchConfig) -> Result<Self> {
        let (p, window) = Params::new(cfg, fs, None)?;
        let z = vec![C64::new(0.0, 0.0); p.nbins];
        Ok(Self {
            engine: Engine::new(&p, window),
            seg_x: SegmentBuffer::new(p.nperseg),
            seg_y: SegmentBuffer::new(p.nperseg),
            spec_x: z.clone(),
            spec_y: z.clone(),
            acc_xx: vec![0.0; p.nbins],
            acc_yy: vec![0.0; p.nbins],
            acc_xy: z,
            n_segments: 0,
            f: p.frequencies(),
            p,
        })
    }

    /// Transform one (x, y) segment pair and add it to the averages unless
    /// that would overflow. Returns whether it was accumulated.
    fn process_segment_slices(&mut self, x: &[f64], y: &[f64]) -> Result<bool> {
        self.engine.transform(x, &mut self.spec_x)?;
        self.engine.transform(y, &mut self.spec_y)?;
        let cross_ok = self
            .acc_xy
            .iter()
            .zip(self.spec_x.iter().zip(&self.spec_y))
            .all(|(a, (u, v))| (a + u.conj() * v).is_finite());
        if !(cross_ok
            && auto_stays_finite(&self.acc_xx, &self.spec_x)
            && auto_stays_finite(&self.acc_yy, &self.spec_y))
        {
            return Ok(false);
        }
        accumulate_auto(&mut self.acc_xx, &self.spec_x);
        accumulate_auto(&mut self.acc_yy, &self.spec_y);
        accumulate_cross(&mut self.acc_xy, &self.spec_x, &self.spec_y);
        self.n_segments += 1;
        Ok(true)
    }

    /// Consume simultaneous blocks of input `x` and output `y` (equal
    /// lengths); returns the number of segments completed. Non-finite or
    /// mismatched blocks are rejected whole (`InvalidInput`, state unchanged).
    pub fn feed(&mut self, x: &[f64], y: &[f64]) -> Result<usize> {
        check_pair(x, y)?;
        let (mut rx, mut ry) = (x, y);
        let mut done = 0;
        let mut dropped = 0;
        while !rx.is_empty() {
            // Both buffers always hold the same fill, so both take `took`.
            let took = self.seg_x.push(rx);
            self.seg_y.push(&ry[..took]);
            rx = &rx[took..];
            ry = &ry[took..];
            if self.seg_x.is_full() {
                // Temporarily move the buffers out to satisfy the borrow checker
                // without copying.
                let sx = std::mem::take(&mut self.seg_x.buf);
                let sy = std::mem::take(&mut self.seg_y.buf);
                let r = self.process_segment_slices(&sx, &sy);
                self.seg_x.buf = sx;
                self.seg_y.buf = sy;
                if r? {
                    done += 1;
                } else {
                    dropped += 1;
                }
                self.seg_x.advance(self.p.step, self.p.noverlap);
                self.seg_y.advance(self.p.step, self.p.noverlap);
            }
        }
        feed_result(done, dropped)
    }

    /// Segments averaged so far.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// Bin frequencies (Hz).
    pub fn frequencies(&self) -> &[f64] {
        &self.f
    }

    /// Running estimate into `out` (vectors resized on first use only).
    /// Returns false, with zeroed spectra, before the first full segment.
    pub fn estimate_into(&self, out: &mut FrfEstimate) -> bool {
        let n = self.p.nbins;
        if out.f != self.f {
            out.f.clone_from(&self.f);
        }
        let z = C64::new(0.0, 0.0);
        out.h1.resize(n, z);
        out.h2.resize(n, z);
        out.coherence.resize(n, 0.0);
        out.pxx.resize(n, 0.0);
        out.pyy.resize(n, 0.0);
        out.pxy.resize(n, z);
        out.n_segments = self.n_segments;
        if self.n_segments == 0 {
            out.h1.fill(z);
            out.h2.fill(z);
            out.coherence.fill(0.0);
            out.pxx.fill(0.0);
            out.pyy.fill(0.0);
            out.pxy.fill(z);
            return false;
        }
        finalize(&self.p, &self.acc_xx, self.n_segments, &mut out.pxx);
        finalize(&self.p, &self.acc_yy, self.n_segments, &mut out.pyy);
        finalize(&self.p, &self.acc_xy, self.n_segments, &mut out.pxy);
        for k in 0..n {
            let (h1, h2, c) = frf_from_spectra(out.pxx[k], out.pyy[k], out.pxy[k]);
            out.h1[k] = h1;
            out.h2[k] = h2;
            out.coherence[k] = c;
        }
        true
    }

    /// Running estimate (allocates); `None` before the first full segment.
    pub fn estimate(&self) -> Option<FrfEstimate> {
        let mut e = FrfEstimate::default();
        self.estimate_into(&mut e).then_some(e)
    }

    /// Forget all data (keeps the plan and buffers).
    pub fn reset(&mut self) {
        self.acc_xx.fill(0.0);
        self.acc_yy.fill(0.0);
        self.acc_xy.fill(C64::new(0.0, 0.0));
        self.n_segments = 0;
        self.seg_x.fill = 0;
        self.seg_y.fill = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{RngExt, SeedableRng};
    use rand_distr::{Distribution, StandardNormal};

    fn noise(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
    }

    fn sine(n: usize, a: f64, cycles_per_sample: f64, ph: f64) -> Vec<f64> {
        (0..n)
            .map(|i| a * (2.0 * PI * cycles_per_sample * i as f64 + ph).sin())
            .collect()
    }

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    /// Direct-form FIR y = h * x (zero initial state).
    fn fir(h: &[f64], x: &[f64]) -> Vec<f64> {
        (0..x.len())
            .map(|n| {
                h.iter()
                    .enumerate()
                    .filter(|(k, _)| *k <= n)
                    .map(|(k, hk)| hk * x[n - k])
                    .sum()
            })
            .collect()
    }

    fn fir_response(h: &[f64], f: f64, fs: f64) -> C64 {
        h.iter()
            .enumerate()
            .map(|(k, &hk)| C64::from_polar(hk, -2.0 * PI * f * k as f64 / fs))
            .sum()
    }

    // ---- windows --------------------------------------------------------------

    #[test]
    fn periodic_window_sums() {
        for n in [3usize, 4, 5, 16, 255, 256, 4096] {
            let nf = n as f64;
            let w = Window::Hann.coefficients(n);
            let (s1, s2) = window_sums(&w);
            assert!(rel(s1, nf / 2.0) < 1e-13, "N={n}");
            assert!(rel(s2, 3.0 * nf / 8.0) < 1e-13, "N={n}");
            assert!(rel(enbw_bins(&w), 1.5) < 1e-13);
            assert_eq!(w[0], 0.0); // periodic: w[0] = 0, w[N−1] ≠ 0
            assert!(w[n - 1] > 0.0);
            let h = Window::Hamming.coefficients(n);
            let (h1, h2) = window_sums(&h);
            assert!(rel(h1, 0.54 * nf) < 1e-13);
            assert!(rel(h2, nf * (0.54f64.powi(2) + 0.46f64.powi(2) / 2.0)) < 1e-13);
            assert_eq!(enbw_bins(&Window::Boxcar.coefficients(n)), 1.0);
        }
        // Even N: the periodic Hann window peaks at exactly 1 at N/2.
        assert_eq!(Window::Hann.coefficients(8)[4], 1.0);
        assert_eq!(Window::Hann.coefficients(1), vec![1.0]);
    }

    // ---- deterministic signals -------------------------------------------------

    #[test]
    fn on_bin_sine_spectrum_peak_is_a2_over_2() {
        let (n, fs, a) = (1024usize, 1024.0, 3.0);
        for window in [Window::Hann, Window::Hamming, Window::Boxcar] {
            for k0 in [1usize, 100, 511] {
                let x = sine(10 * n, a, k0 as f64 / n as f64, 0.7);
                let cfg = WelchConfig::new(n)
                    .with_window(window)
                    .with_scaling(Scaling::Spectrum);
                let s = welch(&x, fs, &cfg).unwrap();
                assert_eq!(s.n_segments, 19);
                assert!(
                    rel(s.p[k0], a * a / 2.0) < 1e-12,
                    "{window:?} k0={k0}: {}",
                    s.p[k0]
                );
                assert_eq!(s.f[k0], k0 as f64);
                if window == Window::Hann && k0 > 1 && k0 < 511 {
                    // Leakage into k0 ± 1: |W[1]/W[0]|² = 1/4, doubled.
                    assert!(rel(s.p[k0 + 1], a * a / 8.0) < 1e-10);
                    assert!(rel(s.p[k0 - 1], a * a / 8.0) < 1e-10);
                }
                // Density: sum·df is the power A²/2 (Parseval), and the peak is
                // the power spread over the ENBW. (Needs the leakage of the
                // ±k0 components not to meet, i.e. 2 ≤ k0 ≤ N/2 − 2.)
                if k0 == 1 || k0 == n / 2 - 1 {
                    continue;
                }
                let d = welch(&x, fs, &cfg.with_scaling(Scaling::Density)).unwrap();
                let df = fs / n as f64;
                let total: f64 = d.p.iter().sum::<f64>() * df;
                assert!(rel(total, a * a / 2.0) < 1e-12, "{window:?}: {total}");
                let enbw = enbw_bins(&window.coefficients(n));
                assert!(rel(d.p[k0] * enbw * df, a * a / 2.0) < 1e-12);
            }
        }
    }

    #[test]
    fn dc_and_nyquist_are_not_doubled() {
        let n = 64;
        let cfg = WelchConfig::new(n)
            .with_detrend(Detrend::None)
            .with_scaling(Scaling::Spectrum);
        // Constant c: Hann DFT has W[0] = Σw, |W[±1]| = Σw/2.
        let c = 2.0;
        let s = welch(&vec![c; 4 * n], 1.0, &cfg).unwrap();
        assert!(rel(s.p[0], c * c) < 1e-14);
        assert!(rel(s.p[1], c * c / 2.0) < 1e-14);
        assert!(s.p[2..].iter().all(|&v| v < 1e-28));
        // A cos(πn) sits on the Nyquist bin with mean square A².
        let a = 0.5;
        let x: Vec<f64> = (0..4 * n)
            .map(|i| if i % 2 == 0 { a } else { -a })
            .collect();
        let s = welch(&x, 1.0, &cfg).unwrap();
        assert!(rel(s.p[n / 2], a * a) < 1e-14);
        assert!(rel(s.p[n / 2 - 1], a * a / 2.0) < 1e-14);
        // Constant detrend removes the DC component entirely.
        let s = welch(&vec![c; 4 * n], 1.0, &WelchConfig::new(n)).unwrap();
        assert!(s.p.iter().all(|&v| v < 1e-28));
    }

    #[test]
    fn parseval_single_segment() {
        for n in [1000usize, 1001] {
            let x = noise(n, 5);
            let fs = 250.0;
            let df = fs / n as f64;
            // Boxcar, no detrend: Σ P df = mean(x²) (one-sided doubling, DC and
            // even-N Nyquist undoubled).
            let cfg = WelchConfig::new(n)
                .with_window(Window::Boxcar)
                .with_detrend(Detrend::None);
            let s = welch(&x, fs, &cfg).unwrap();
            assert_eq!(s.n_segments, 1);
            assert_eq!(s.p.len(), n / 2 + 1);
            let ms = x.iter().map(|v| v * v).sum::<f64>() / n as f64;
            assert!(rel(s.p.iter().sum::<f64>() * df, ms) < 1e-12, "N={n}");
            // Hann: Σ P df = Σ(x w)²/Σw².
            let s = welch(&x, fs, &cfg.with_window(Window::Hann)).unwrap();
            let w = Window::Hann.coefficients(n);
            let (_, s2) = window_sums(&w);
            let e = x.iter().zip(&w).map(|(a, b)| (a * b).powi(2)).sum::<f64>() / s2;
            assert!(rel(s.p.iter().sum::<f64>() * df, e) < 1e-12);
        }
    }

    #[test]
    fn detrending() {
        let n = 512;
        let line: Vec<f64> = (0..8 * n).map(|i| 5.0 - 0.003 * i as f64).collect();
        let cfg = WelchConfig::new(n).with_detrend(Detrend::Linear);
        let s = welch(&line, 1.0, &cfg).unwrap();
        assert!(s.p.iter().all(|&v| v < 1e-20), "a line is removed exactly");
        let sn = sine(8 * n, 1.0, 37.0 / n as f64, 0.1);
        let mixed: Vec<f64> = sn.iter().zip(&line).map(|(a, b)| a + b).collect();
        let a = welch(&mixed, 1.0, &cfg).unwrap();
        let b = welch(&sn, 1.0, &cfg).unwrap();
        for (u, v) in a.p.iter().zip(&b.p) {
            assert!((u - v).abs() < 1e-9 * b.p[37]);
        }
        // The constant detrend leaves the ramp, which leaks into low bins.
        let c = welch(&mixed, 1.0, &WelchConfig::new(n)).unwrap();
        assert!((1..4).all(|k| c.p[k] > 100.0 * b.p[k]));
    }

    #[test]
    fn zero_padding_keeps_on_bin_power() {
        let (n, a) = (256usize, 1.5);
        let x = sine(8 * n, a, 20.0 / n as f64, 0.0);
        let cfg = WelchConfig::new(n)
            .with_nfft(2 * n)
            .with_scaling(Scaling::Spectrum);
        let s = welch(&x, 1000.0, &cfg).unwrap();
        assert_eq!(s.p.len(), n + 1);
        assert!((s.f[1] - 1000.0 / (2 * n) as f64).abs() < 1e-12);
        assert!(rel(s.p[40], a * a / 2.0) < 1e-12);
    }

    #[test]
    fn odd_segment_length_and_noverlap_zero() {
        let x = noise(5 * 301, 9);
        let cfg = WelchConfig::new(301)
            .with_noverlap(0)
            .with_window(Window::Boxcar)
            .with_detrend(Detrend::None);
        let s = welch(&x, 2.0, &cfg).unwrap();
        assert_eq!(s.n_segments, 5);
        assert_eq!(s.p.len(), 151);
        let ms = x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64;
        let df = 2.0 / 301.0;
        assert!(rel(s.p.iter().sum::<f64>() * df, ms) < 1e-12);
    }

    // ---- white noise statistics --------------------------------------------------

    #[test]
    fn white_noise_density_level_and_welch_variance() {
        let (n, fs, len, reps) = (512usize, 1000.0, 1usize << 17, 8);
        let cfg = WelchConfig::new(n);
        let w = Window::Hann.coefficients(n);
        let (_, s2) = window_sums(&w);
        // Welch (1967) eq. for Gaussian white noise: var/mean² =
        // (1/K)[1 + 2 Σ_j (1 − j/K) ρ(j)], ρ(j) = (Σ w[i] w[i+jS])²/(Σw²)².
        let k = cfg.num_segments(len) as f64;
        let step = n / 2;
        let r1 = (0..n - step).map(|i| w[i] * w[i + step]).sum::<f64>() / s2;
        let var_theory = (1.0 + 2.0 * (1.0 - 1.0 / k) * r1 * r1) / k;
        // Adjacent-bin correlation of a Hann periodogram: ρ_b(m) =
        // |Σ w² e^{−j2πmi/N}|²/(Σw²)² → effective number of independent bins.
        let rho_b = |m: usize| {
            let c: C64 = w
                .iter()
                .enumerate()
                .map(|(i, v)| C64::from_polar(v * v, -2.0 * PI * (m * i) as f64 / n as f64))
                .sum();
            c.norm_sqr() / (s2 * s2)
        };
        let bin_corr = 1.0 + 2.0 * (1..4).map(rho_b).sum::<f64>();
        let mut ratios = Vec::new();
        let (mut dc, mut nyq) = (0.0, 0.0);
        for r in 0..reps {
            let x = noise(len, 100 + r as u64);
            let s = welch(&x, fs, &cfg).unwrap();
            ratios.extend(s.p[1..n / 2].iter().map(|p| p / (2.0 / fs)));
            dc += s.p[0] / reps as f64;
            nyq += s.p[n / 2] / reps as f64;
        }
        let m = ratios.len() as f64;
        let mean = ratios.iter().sum::<f64>() / m;
        let var = ratios.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1.0);
        // Level 2/fs: the bin mean has relative s.d. √(var·bin_corr/M).
        let sd_mean = (var_theory * bin_corr / m).sqrt();
        assert!(
            (mean - 1.0).abs() < 5.0 * sd_mean,
            "mean {mean} ± {sd_mean}"
        );
        // Spread: the sample variance of M_eff ≈ M/bin_corr near-Gaussian values
        // has relative s.d. √(2·bin_corr/M).
        let sd_var = (2.0 * bin_corr / m).sqrt();
        assert!(
            (var / var_theory - 1.0).abs() < 4.0 * sd_var,
            "var {var} vs Welch {var_theory} (± {sd_var})"
        );
        // Undoubled, real-valued edge bins (χ²₁ per segment: twice the relative
        // variance). Nyquist: E = Σw²/(fs Σw²) = 1/fs, half the level. DC after
        // mean removal: X₀ = Σ xᵢ(wᵢ − w̄) ⇒ E = (Σw² − (Σw)²/N)/(fs Σw²) =
        // (1/3)/fs for Hann.
        let sd_edge = (2.0 * var_theory / reps as f64).sqrt();
        assert!(rel(nyq, 1.0 / fs) < 5.0 * sd_edge, "Nyquist {nyq}");
        let (s1, _) = window_sums(&w);
        let dc_theory = (s2 - s1 * s1 / n as f64) / (fs * s2);
        assert!(rel(dc_theory, 1.0 / (3.0 * fs)) < 1e-12);
        assert!(rel(dc, dc_theory) < 6.0 * sd_edge, "DC {dc} vs {dc_theory}");
    }

    // ---- cross spectra and FRF -------------------------------------------------

    #[test]
    fn csd_conventions() {
        let x = noise(8192, 2);
        let cfg = WelchConfig::new(256);
        let pxx = welch(&x, 10.0, &cfg).unwrap();
        let pxy = csd(&x, &x, 10.0, &cfg).unwrap();
        for (a, b) in pxx.p.iter().zip(&pxy.pxy) {
            assert_eq!(*a, b.re);
            assert_eq!(b.im, 0.0);
        }
        // y = x delayed by d samples: Y = X e^{−jωd} ⇒ arg Pxy = −ωd (conj(X)·Y).
        let (n, k0, d) = (256usize, 10usize, 3usize);
        let r = k0 as f64 / n as f64;
        let xs = sine(8 * n, 1.0, r, 0.2);
        let ys = sine(8 * n, 1.0, r, 0.2 - 2.0 * PI * r * d as f64);
        let c = csd(&xs, &ys, 1.0, &WelchConfig::new(n)).unwrap();
        let expected = -2.0 * PI * r * d as f64;
        assert!((c.pxy[k0].arg() - expected).abs() < 1e-12);
    }

    #[test]
    fn h1_of_fir_and_iir_converges_to_analytic_response() {
        let fs = 10_000.0;
        let x = noise(1 << 19, 3);
        // FIR: H(f) = Σ h_k e^{−j2πfk/fs}.
        let h = [0.2, 0.5, 0.3, -0.1];
        let y = fir(&h, &x);
        let cfg = WelchConfig::new(1024);
        let e = frf(&x, &y, fs, &cfg).unwrap();
        for k in 1..e.f.len() {
            let hk = fir_response(&h, e.f[k], fs);
            // Without measurement noise, the only error is leakage through the
            // window edges (y inside a segment also depends on x before it),
            // which lowers γ² slightly; it acts like noise with the random
            // error of |H1| (Bendat & Piersol, ch. 9) ε = √((1 − γ²)/(2 γ² K)).
            let g = e.coherence[k];
            let eps = ((1.0 - g) / (2.0 * g * e.n_segments as f64)).sqrt();
            let err = (e.h1[k] - hk).norm() / hk.norm();
            assert!(err < 6.0 * eps + 2e-4, "k={k}: {err} (ε={eps})");
            // Time-delay bias (Bendat & Piersol, ch. 9): γ̂² ≳ (1 − τ/T)² γ²
            // with τ ≤ len(h) − 1 samples and T = nperseg.
            assert!(g > (1.0 - 3.0 / 1024.0f64).powi(2), "k={k}: γ²={g}");
        }
        // IIR y[n] = b x[n] + a y[n−1]: H = b/(1 − a e^{−jω}), from DC-ish to Nyquist.
        let (a, b) = (0.9, 0.1);
        let mut prev = 0.0;
        let y: Vec<f64> = x
            .iter()
            .map(|&v| {
                prev = b * v + a * prev;
                prev
            })
            .collect();
        let cfg = WelchConfig::new(4096);
        let e = frf(&x, &y, fs, &cfg).unwrap();
        for k in 1..e.f.len() {
            let w = 2.0 * PI * e.f[k] / fs;
            let hk = b / (1.0 - a * C64::from_polar(1.0, -w));
            // Same criterion: 6ε plus 0.02 % for the delay (edge) bias.
            let g = e.coherence[k];
            let eps = ((1.0 - g) / (2.0 * g * e.n_segments as f64)).sqrt();
            let err = (e.h1[k] - hk).norm() / hk.norm();
            assert!(err < 6.0 * eps + 2e-4, "k={k}: {err} (ε={eps})");
            // Group delay ≤ a/(1 − a) = 9 samples (at DC).
            assert!(g > (1.0 - 9.0 / 4096.0f64).powi(2), "k={k}: γ²={g}");
        }
        // Noiseless identity system: coherence is exactly 1 (to rounding).
        let e = frf(&x, &x, fs, &cfg).unwrap();
        assert!(e.coherence[1..].iter().all(|&c| (c - 1.0).abs() < 1e-12));
        assert!(e.h1[1..].iter().all(|h| (h - 1.0).norm() < 1e-12));
        assert!(e.h2[1..].iter().all(|h| (h - 1.0).norm() < 1e-12));
    }

    /// Mean over interior bins of `f(k)`.
    fn bin_mean(e: &FrfEstimate, f: impl Fn(usize) -> f64) -> f64 {
        let n = e.f.len();
        (1..n - 1).map(f).sum::<f64>() / (n - 2) as f64
    }

    #[test]
    fn output_noise_biases_h2_not_h1_and_sets_coherence() {
        // y = h*x + n: H1 → H, H2 → H(1 + 1/SNR), γ² → SNR/(1 + SNR),
        // SNR(f) = |H|² Sxx/Snn (Bendat & Piersol, ch. 9).
        let fs = 1000.0;
        let len = 1 << 18;
        let x = noise(len, 21);
        let h = [1.0, 0.5];
        let sn = 0.7; // noise s.d.; σx = 1
        let y: Vec<f64> = fir(&h, &x)
            .iter()
            .zip(noise(len, 22))
            .map(|(a, b)| a + sn * b)
            .collect();
        let e = frf(&x, &y, fs, &WelchConfig::new(512)).unwrap();
        let hk = |k: usize| fir_response(&h, e.f[k], fs);
        let snr = |k: usize| hk(k).norm_sqr() / (sn * sn);
        let kk = e.n_segments as f64;
        // Bin-averaged ratios; each bin has random error ≲ √((1−γ²)/(2γ²K)).
        let r1 = bin_mean(&e, |k| e.h1[k].norm() / hk(k).norm());
        let r2 = bin_mean(&e, |k| {
            e.h2[k].norm() / (hk(k).norm() * (1.0 + 1.0 / snr(k)))
        });
        let rc = bin_mean(&e, |k| e.coherence[k] / (snr(k) / (1.0 + snr(k))));
        let r2_naive = bin_mean(&e, |k| e.h2[k].norm() / hk(k).norm());
        let tol = 5.0 * (1.0 / kk).sqrt() / (e.f.len() as f64).sqrt() + 2e-3;
        assert!((r1 - 1.0).abs() < tol, "H1 bias {r1}");
        assert!((r2 - 1.0).abs() < tol, "H2 {r2}");
        assert!((rc - 1.0).abs() < tol, "γ² {rc}");
        assert!(r2_naive > 1.2, "H2 is biased up: {r2_naive}");
        // Phase of H1 and H2 are both unbiased (the bias is real).
        let dphi = bin_mean(&e, |k| (e.h2[k] / e.h1[k]).arg().abs());
        assert!(dphi < 0.02, "{dphi}");
    }

    #[test]
    fn input_noise_biases_h1_not_h2() {
        // x_meas = x + m, y = h*x: H1 → H·Sxx/(Sxx + Smm), H2 → H.
        let fs = 1000.0;
        let len = 1 << 18;
        let x = noise(len, 31);
        let h = [0.3, -0.8, 0.4];
        let sm = 0.5;
        let y = fir(&h, &x);
        let xm: Vec<f64> = x
            .iter()
            .zip(noise(len, 32))
            .map(|(a, b)| a + sm * b)
            .collect();
        let e = frf(&xm, &y, fs, &WelchConfig::new(512)).unwrap();
        let hk = |k: usize| fir_response(&h, e.f[k], fs);
        let gain = 1.0 / (1.0 + sm * sm);
        let r1 = bin_mean(&e, |k| e.h1[k].norm() / (hk(k).norm() * gain));
        let r2 = bin_mean(&e, |k| e.h2[k].norm() / hk(k).norm());
        let rc = bin_mean(&e, |k| e.coherence[k] / gain);
        let tol = 5.0 / ((e.n_segments * e.f.len()) as f64).sqrt() + 2e-3;
        assert!((r1 - 1.0).abs() < tol, "H1 {r1}");
        assert!((r2 - 1.0).abs() < tol, "H2 {r2}");
        assert!((rc - 1.0).abs() < tol, "γ² {rc}");
    }

    #[test]
    fn matches_scipy_reference_values() {
        // Reference: scipy 1.17.1,
        //   t = np.arange(5000.)
        //   x = sin(0.05t + 1e-4t²) + 0.3cos(1.3t) + 0.001t
        //   y = 0.7sin(0.05t + 1e-4t² − 0.4) + 0.2sin(2.1t) − 0.0005t + 0.1
        //   welch/csd/coherence(…, fs=123.0, nperseg=256)      (case a)
        //   welch/csd(…, fs=123.0, nperseg=255, noverlap=100,
        //             window='hamming', detrend='linear', scaling='spectrum') (case b)
        // (all bins of both cases and of two more configurations agree to
        // ≤ 6e-15 of the spectrum maximum; a few bins are checked here).
        let n = 5000;
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64;
                (0.05 * t + 1e-4 * t * t).sin() + 0.3 * (1.3 * t).cos() + 0.001 * t
            })
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64;
                0.7 * (0.05 * t + 1e-4 * t * t - 0.4).sin() + 0.2 * (2.1 * t).sin() - 0.0005 * t
                    + 0.1
            })
            .collect();
        let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-10 * scale;
        let cfg = WelchConfig::new(256);
        let p = welch(&x, 123.0, &cfg).unwrap();
        let e = frf(&x, &y, 123.0, &cfg).unwrap();
        let pmax = p.p.iter().fold(0.0f64, |m, v| m.max(*v));
        let cmax = e.pxy.iter().fold(0.0f64, |m, v| m.max(v.norm()));
        // (bin, Pxx, Re Pxy, Im Pxy, γ²)
        let case_a = [
            (
                0,
                0.0003005391266139439,
                0.0001733063627158774,
                0.0,
                0.8078692481554114,
            ),
            (
                1,
                0.002970057793881745,
                -0.0011262393878883718,
                -0.00010121954373629242,
                0.6082777395899387,
            ),
            (
                10,
                0.026259547154851598,
                0.016928159731920675,
                -0.007158621181837309,
                0.999999518319093,
            ),
            (
                53,
                0.062350913931309836,
                3.417235054394646e-07,
                1.0839441689971907e-07,
                0.0019159475958015519,
            ),
            (
                128,
                2.146827478330908e-14,
                -2.1670129901132397e-14,
                0.0,
                f64::NAN,
            ),
        ];
        for (k, pxx, re, im, coh) in case_a {
            assert!(close(p.p[k], pxx, pmax), "a P[{k}]");
            assert!(close(e.pxx[k], pxx, pmax), "a Pxx[{k}]");
            assert!(close(e.pxy[k].re, re, cmax), "a Re Pxy[{k}]");
            assert!(close(e.pxy[k].im, im, cmax), "a Im Pxy[{k}]");
            if coh.is_finite() {
                assert!((e.coherence[k] - coh).abs() < 1e-9, "a γ²[{k}]");
            }
        }
        let cfg = WelchConfig::new(255)
            .with_noverlap(100)
            .with_window(Window::Hamming)
            .with_detrend(Detrend::Linear)
            .with_scaling(Scaling::Spectrum);
        let p = welch(&x, 123.0, &cfg).unwrap();
        let c = csd(&x, &y, 123.0, &cfg).unwrap();
        assert_eq!(p.p.len(), 128);
        let pmax = p.p.iter().fold(0.0f64, |m, v| m.max(*v));
        let cmax = c.pxy.iter().fold(0.0f64, |m, v| m.max(v.norm()));
        let case_b = [
            (0, 0.00031258587246763426, 0.00020702409865397408, 0.0),
            (
                2,
                0.003018902714326273,
                0.001969990740398744,
                -0.0008191769104467706,
            ),
            (
                53,
                0.04107634496877238,
                -3.036348378835304e-07,
                -4.808533211031411e-05,
            ),
            (
                127,
                2.185602424905462e-07,
                1.4117491997134354e-07,
                -2.4912938640470617e-10,
            ),
        ];
        for (k, pxx, re, im) in case_b {
            assert!(close(p.p[k], pxx, pmax), "b P[{k}]");
            assert!(close(c.pxy[k].re, re, cmax), "b Re Pxy[{k}]");
            assert!(close(c.pxy[k].im, im, cmax), "b Im Pxy[{k}]");
        }
    }

    #[test]
    fn mls_identifies_zoh_haptuator_channel_exactly() {
        // Paper §3.2: PRBS input, Welch estimate. Channel: eq. 2,
        // G_H(s) = (250 s + 6.40e5)/(s² + 2135 s + 4.56e6), driven through a
        // zero-order hold at fs = 10 kHz (the DAC). Step-invariant (ZOH)
        // equivalent from partial fractions of G(s)/s:
        //   G_d(z) = r0 + (1 − z⁻¹) Σᵢ rᵢ/(1 − qᵢ z⁻¹),  qᵢ = e^{pᵢ T}.
        let fs = 10_000.0;
        let dt = 1.0 / fs;
        let tf = crate::Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).unwrap();
        let poles = tf.poles().unwrap();
        let (p1, p2) = (poles[0], poles[1]);
        let num = |s: C64| 250.0 * s + 6.40e5;
        let r0 = tf.dc_gain();
        let r1 = num(p1) / (p1 * (p1 - p2));
        let r2 = num(p2) / (p2 * (p2 - p1));
        let (q1, q2) = ((p1 * dt).exp(), (p2 * dt).exp());
        let a1 = -(q1 + q2).re;
        let a2 = (q1 * q2).re;
        let b1 = (-r0 * (q1 + q2) - r1 * q2 - r2 * q1 - r1 - r2).re;
        let b2 = (r0 * q1 * q2 + r1 * q2 + r2 * q1).re;
        // Cross-check of this discretisation against
        // scipy.signal.cont2discrete(..., method='zoh') (printed to 8 digits).
        assert!((a1 + 1.76684694).abs() < 1e-8 && (a2 - 0.80775216).abs() < 1e-8);
        assert!((b1 - 0.02531365).abs() < 1e-8 && (b2 + 0.01957257).abs() < 1e-8);
        let gd = |f: f64| {
            let zi = C64::from_polar(1.0, -2.0 * PI * f / fs);
            r0 + (1.0 - zi) * (r1 / (1.0 - q1 * zi) + r2 / (1.0 - q2 * zi))
        };
        // ±1 MLS of order 12, four periods; the transient (|q| ≈ 0.9) is over
        // after the first period, so each later period is in periodic steady
        // state and Y_k = G_d(e^{jω_k}) X_k exactly.
        let x = crate::excitation::mls_signal(12, 1.0, 1, 4).unwrap();
        let mut y = vec![0.0; x.len()];
        for n in 0..x.len() {
            let xm1 = if n >= 1 { x[n - 1] } else { 0.0 };
            let xm2 = if n >= 2 { x[n - 2] } else { 0.0 };
            let ym1 = if n >= 1 { y[n - 1] } else { 0.0 };
            let ym2 = if n >= 2 { y[n - 2] } else { 0.0 };
            y[n] = b1 * xm1 + b2 * xm2 - a1 * ym1 - a2 * ym2;
        }
        let period = 4095;
        let cfg = WelchConfig::new(period)
            .with_noverlap(0)
            .with_window(Window::Boxcar)
            .with_detrend(Detrend::None);
        let e = frf(&x[period..], &y[period..], fs, &cfg).unwrap();
        assert_eq!(e.n_segments, 3);
        for k in 1..e.f.len() {
            let h = gd(e.f[k]);
            assert!((e.h1[k] - h).norm() < 1e-10 * h.norm(), "k={k}");
            assert!((e.h2[k] - h).norm() < 1e-10 * h.norm(), "k={k}");
            assert!((e.coherence[k] - 1.0).abs() < 1e-10);
            // Up to 1 kHz the ZOH channel is the continuous G_H with a half-
            // sample delay, within the aliasing error (|G_d/G − 1| ≤ 1.3 % at
            // 1 kHz for this roll-off).
            if e.f[k] <= 1000.0 {
                let g = tf.response_hz(e.f[k]) * C64::from_polar(1.0, -PI * e.f[k] / fs);
                assert!((e.h1[k] / g - 1.0).norm() < 0.015, "f={}", e.f[k]);
            }
        }
        // The magnitude at the bin nearest 1 kHz against REFERENCE-VALUES.md
        // (|G_H(1 kHz)| = 0.0453443): same aliasing allowance.
        let k = (1000.0 * period as f64 / fs).round() as usize;
        assert!((e.h1[k].norm() / 0.0453443 - 1.0).abs() < 0.015);
    }

    // ---- streaming ---------------------------------------------------------------

    fn random_chunks(len: usize, seed: u64, max: usize) -> Vec<usize> {
        let mut rng = StdRng::seed_from_u64(seed);
        let mut v = Vec::new();
        let mut total = 0;
        while total < len {
            let c = rng.random_range(0..=max).min(len - total);
            v.push(c);
            total += c;
        }
        v
    }

    #[test]
    fn streaming_welch_equals_batch_bit_for_bit() {
        let x = noise(50_000, 41);
        for cfg in [
            WelchConfig::new(1024),
            WelchConfig::new(1000)
                .with_noverlap(999)
                .with_detrend(Detrend::Linear),
            WelchConfig::new(333)
                .with_noverlap(0)
                .with_nfft(512)
                .with_window(Window::Hamming)
                .with_scaling(Scaling::Spectrum),
        ] {
            let batch = welch(&x, 48_000.0, &cfg).unwrap();
            let mut s = StreamingWelch::new(48_000.0, &cfg).unwrap();
            assert!(s.estimate().is_none());
            let mut pos = 0;
            let mut segs = 0;
            for c in random_chunks(x.len(), 7, 3000) {
                segs += s.feed(&x[pos..pos + c]).unwrap();
                pos += c;
            }
            assert_eq!(segs, batch.n_segments);
            assert_eq!(s.estimate().unwrap(), batch);
            assert_eq!(s.frequencies(), &batch.f[..]);
            // estimate_into reuses the output without reallocating.
            let mut out = Spectrum::default();
            assert!(s.estimate_into(&mut out));
            let ptr = out.p.as_ptr();
            assert!(s.estimate_into(&mut out));
            assert_eq!(ptr, out.p.as_ptr());
            // Reset = fresh accumulator.
            s.reset();
            assert_eq!(s.n_segments(), 0);
            assert!(!s.estimate_into(&mut out));
            s.feed(&x).unwrap();
            assert_eq!(s.estimate().unwrap(), batch);
        }
    }

    #[test]
    fn streaming_frf_equals_batch_bit_for_bit() {
        let x = noise(40_000, 51);
        let y: Vec<f64> = fir(&[0.5, 0.25, -0.1], &x)
            .iter()
            .zip(noise(40_000, 52))
            .map(|(a, b)| a + 0.1 * b)
            .collect();
        let cfg = WelchConfig::new(512);
        let batch = frf(&x, &y, 1000.0, &cfg).unwrap();
        let mut s = StreamingFrf::new(1000.0, &cfg).unwrap();
        let mut pos = 0;
        for c in random_chunks(x.len(), 8, 1500) {
            s.feed(&x[pos..pos + c], &y[pos..pos + c]).unwrap();
            pos += c;
        }
        assert_eq!(s.estimate().unwrap(), batch);
        // The batch helpers agree with the one-pass estimate.
        assert_eq!(frf_h1(&x, &y, 1000.0, &cfg).unwrap().h, batch.h1);
        assert_eq!(frf_h2(&x, &y, 1000.0, &cfg).unwrap().h, batch.h2);
        assert_eq!(coherence(&x, &y, 1000.0, &cfg).unwrap().c, batch.coherence);
        assert_eq!(csd(&x, &y, 1000.0, &cfg).unwrap().pxy, batch.pxy);
        assert_eq!(welch(&y, 1000.0, &cfg).unwrap().p, batch.pyy);
        // Mismatched blocks are rejected without consuming anything.
        let n0 = s.n_segments();
        assert!(s.feed(&x[..10], &y[..9]).is_err());
        assert_eq!(s.n_segments(), n0);
        s.reset();
        assert!(s.estimate().is_none());
    }

    #[test]
    fn streaming_rejects_non_finite_blocks_and_survives() {
        let x = noise(10_000, 61);
        let cfg = WelchConfig::new(256);
        let batch = welch(&x, 1.0, &cfg).unwrap();
        let mut s = StreamingWelch::new(1.0, &cfg).unwrap();
        s.feed(&x[..5000]).unwrap();
        assert!(matches!(
            s.feed(&[1.0, f64::NAN, 2.0]),
            Err(DspError::InvalidInput(_))
        ));
        assert!(s.feed(&[f64::INFINITY]).is_err());
        s.feed(&x[5000..]).unwrap();
        assert_eq!(s.estimate().unwrap(), batch);
        // Overflowing segments are discarded; the estimate stays finite.
        let mut s = StreamingWelch::new(1.0, &cfg).unwrap();
        s.feed(&x[..2000]).unwrap();
        let before = s.n_segments();
        let huge = vec![1e300; 512];
        assert!(matches!(s.feed(&huge), Err(DspError::Numerical(_))));
        assert_eq!(s.n_segments(), before);
        assert!(s.estimate().unwrap().p.iter().all(|v| v.is_finite()));
        assert!(matches!(
            welch(&vec![1e300; 1024], 1.0, &cfg.with_detrend(Detrend::None)),
            Err(DspError::Numerical(_))
        ));
    }

    // ---- errors --------------------------------------------------------------------

    fn param_name<T: fmt::Debug>(r: Result<T>) -> &'static str {
        match r {
            Err(DspError::InvalidParameter { name, .. }) => name,
            other => panic!("expected InvalidParameter, got {other:?}"),
        }
    }

    #[test]
    fn parameter_errors_name_the_parameter() {
        let x = noise(1000, 71);
        let c = WelchConfig::new(256);
        assert_eq!(param_name(welch(&x, 0.0, &c)), "fs");
        assert_eq!(param_name(welch(&x, -1.0, &c)), "fs");
        assert_eq!(param_name(welch(&x, f64::NAN, &c)), "fs");
        assert_eq!(param_name(welch(&x, 1.0, &WelchConfig::new(0))), "nperseg");
        assert_eq!(
            param_name(welch(&x, 1.0, &WelchConfig::new(1001))),
            "nperseg"
        );
        assert_eq!(
            param_name(welch(&x, 1.0, &c.with_noverlap(256))),
            "noverlap"
        );
        assert_eq!(param_name(welch(&x, 1.0, &c.with_nfft(255))), "nfft");
        assert_eq!(
            param_name(csd(&x, &x, 1.0, &c.with_noverlap(300))),
            "noverlap"
        );
        assert_eq!(
            param_name(frf(&x, &x, 1.0, &WelchConfig::new(2000))),
            "nperseg"
        );
        assert_eq!(param_name(StreamingWelch::new(0.0, &c)), "fs");
        assert_eq!(
            param_name(StreamingFrf::new(1.0, &WelchConfig::new(0))),
            "nperseg"
        );
        let mut bad = x.clone();
        bad[999] = f64::NEG_INFINITY;
        assert!(
            matches!(welch(&bad, 1.0, &c), Err(DspError::InvalidInput(m)) if m.contains("999"))
        );
        assert!(
            matches!(csd(&x, &bad, 1.0, &c), Err(DspError::InvalidInput(m)) if m.contains("`y`"))
        );
        assert!(matches!(
            frf(&x, &x[..999], 1.0, &c),
            Err(DspError::InvalidInput(_))
        ));
        assert!(matches!(
            welch(&[], 1.0, &c),
            Err(DspError::InvalidInput(_))
        ));
        // nperseg = len: exactly one segment.
        assert_eq!(
            welch(&x, 1.0, &WelchConfig::new(1000)).unwrap().n_segments,
            1
        );
    }

    #[test]
    fn zero_denominators_give_zero_not_nan() {
        // x = 0 (no excitation): Pxx = 0 everywhere.
        let x = vec![0.0; 2048];
        let y = noise(2048, 81);
        let e = frf(&x, &y, 1.0, &WelchConfig::new(256)).unwrap();
        assert!(e.h1.iter().chain(&e.h2).all(|h| *h == C64::new(0.0, 0.0)));
        assert!(e.coherence.iter().all(|&c| c == 0.0));
    }
}
