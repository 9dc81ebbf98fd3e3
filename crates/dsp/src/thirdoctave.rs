//! One-third-octave bands (IEC 61260-1:2014, base 10), band levels and a
//! flatness report.
//!
//! Band x (an integer, x = 0 is the 1 kHz band) has the exact mid-band
//! frequency and edges (IEC 61260-1:2014, base-10 system; ANSI S1.11)
//!
//! ```text
//! G = 10^(3/10)                      (octave frequency ratio, base 10)
//! f_m = 1000 Hz · G^(x/3) = 1000 Hz · 10^(x/10)
//! f_1 = f_m · G^(−1/6),  f_2 = f_m · G^(+1/6)   (lower, upper edge)
//! ```
//!
//! so the upper edge of band x is the lower edge of band x + 1 and every band
//! has the same relative bandwidth f_2/f_1 = G^(1/3) = 10^(0.1).
//! Nominal mid-band frequencies are the R10 preferred numbers
//! (1, 1.25, 1.6, 2, 2.5, 3.15, 4, 5, 6.3, 8) × 10^k, e.g. 31.5, 63, 125, 1000.

use crate::error::{check_fs, check_non_negative, check_positive};
use crate::{DspError, Result};
use realfft::RealFftPlanner;
use serde::{Deserialize, Serialize};

/// Octave frequency ratio G = 10^(3/10) ≈ 1.99526 (IEC 61260-1 base 10).
pub const OCTAVE_RATIO: f64 = 1.995_262_314_968_879_5;

/// Reference frequency of band 0 in Hz.
pub const REFERENCE_HZ: f64 = 1000.0;

/// R10 preferred-number mantissas ×100 for x mod 10 = 0 … 9
/// (the nominal mid-band frequencies of IEC 61260-1 / ISO 266).
const R10_MANTISSA: [u32; 10] = [100, 125, 160, 200, 250, 315, 400, 500, 630, 800];

/// A one-third-octave band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Band {
    /// Band number x relative to the 1 kHz band (x = 0); 63 Hz is x = −12.
    pub index: i32,
    /// Exact mid-band frequency f_m = 1000·10^(x/10) Hz.
    pub centre_hz: f64,
    /// Lower edge f_m·G^(−1/6) = 1000·10^((2x − 1)/20) Hz.
    pub lower_hz: f64,
    /// Upper edge f_m·G^(+1/6) = 1000·10^((2x + 1)/20) Hz.
    pub upper_hz: f64,
    /// Nominal mid-band frequency (R10 preferred number) in Hz, e.g. 31.5.
    pub nominal_hz: f64,
    /// Nominal mid-band frequency as printed, e.g. "31.5", "63", "1000".
    pub nominal: String,
}

impl Band {
    /// Band number `index` (x). Errors when the frequencies are not
    /// representable (|x| beyond about ±3000).
    pub fn new(index: i32) -> Result<Self> {
        let x = f64::from(index);
        let centre_hz = REFERENCE_HZ * 10f64.powf(x / 10.0);
        // Edges from the same exponent expression, so that band x's upper
        // edge and band x+1's lower edge are bit-for-bit equal.
        let lower_hz = edge_hz(index);
        let upper_hz = edge_hz(index.saturating_add(1));
        if ![centre_hz, lower_hz, upper_hz]
            .iter()
            .all(|v| v.is_normal() && *v > 0.0)
        {
            return Err(DspError::InvalidParameter {
                name: "band index",
                value: x,
                reason: "band frequencies are not representable in f64".into(),
            });
        }
        let nominal = nominal_label(index);
        let nominal_hz = nominal.parse::<f64>().unwrap_or(centre_hz);
        Ok(Self {
            index,
            centre_hz,
            lower_hz,
            upper_hz,
            nominal_hz,
            nominal,
        })
    }

    /// Bandwidth f_2 − f_1 in Hz (≈ 0.2316 f_m).
    pub fn bandwidth_hz(&self) -> f64 {
        self.upper_hz - self.lower_hz
    }

    /// True when lower ≤ f < upper (the half-open rule used for FFT bins).
    pub fn contains(&self, f_hz: f64) -> bool {
        f_hz >= self.lower_hz && f_hz < self.upper_hz
    }
}

/// Lower edge of band x = upper edge of band x − 1: 1000·10^((2x − 1)/20) Hz.
fn edge_hz(index: i32) -> f64 {
    REFERENCE_HZ * 10f64.powf((2.0 * f64::from(index) - 1.0) / 20.0)
}

/// Nominal (R10) label of band x: mantissa R10[x mod 10] × 10^(⌊x/10⌋ + 3 − 2),
/// printed without trailing zeros ("0.8", "12.5", "63", "1000", "12500").
pub fn nominal_label(index: i32) -> String {
    // Index into R10 and decimal exponent of the ×100 mantissa.
    let r = index.rem_euclid(10) as usize;
    let e = i64::from(index.div_euclid(10)) + 1;
    let digits = R10_MANTISSA[r].to_string();
    if e >= 0 {
        let mut s = digits;
        s.extend(std::iter::repeat_n('0', e as usize));
        return s;
    }
    let point = digits.len() as i64 + e;
    let mut s = if point > 0 {
        let (a, b) = digits.split_at(point as usize);
        format!("{a}.{b}")
    } else {
        format!("0.{}{digits}", "0".repeat((-point) as usize))
    };
    while s.ends_with('0') {
        s.pop();
    }
    if s.ends_with('.') {
        s.pop();
    }
    s
}

/// Number x of the band that contains `f_hz` (lower ≤ f < upper):
/// x = ⌊10·log10(f/1000) + 1/2⌋. Errors on non-finite or non-positive f.
pub fn band_index(f_hz: f64) -> Result<i32> {
    check_positive("f_hz", f_hz)?;
    let x = (10.0 * (f_hz / REFERENCE_HZ).log10() + 0.5).floor();
    Ok(x as i32)
}

/// All bands whose exact centre or nominal frequency lies in [fmin, fmax] Hz,
/// in ascending order. `bands_between(63.0, 1000.0)` gives the paper's 13
/// bands 63 … 1000 Hz (§3.4); `bands_between(20.0, 20_000.0)` the 31 audio bands.
pub fn bands_between(fmin_hz: f64, fmax_hz: f64) -> Result<Vec<Band>> {
    check_positive("fmin_hz", fmin_hz)?;
    if !fmax_hz.is_finite() || fmax_hz < fmin_hz {
        return Err(DspError::InvalidParameter {
            name: "fmax_hz",
            value: fmax_hz,
            reason: format!("must be finite and ≥ fmin_hz = {fmin_hz}"),
        });
    }
    // Nominal and exact centres differ by < 2 %, far less than one band.
    let lo = band_index(fmin_hz)?.saturating_sub(1);
    let hi = band_index(fmax_hz)?.saturating_add(1);
    let inside = |f: f64| f >= fmin_hz && f <= fmax_hz;
    let mut out = Vec::new();
    for x in lo..=hi {
        let b = Band::new(x)?;
        if inside(b.centre_hz) || inside(b.nominal_hz) {
            out.push(b);
        }
    }
    Ok(out)
}

/// Mean-square content of a signal in one band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BandLevel {
    /// The band.
    pub band: Band,
    /// Mean square in the band (signal units²), from the one-sided power spectrum.
    pub mean_square: f64,
    /// 10·log10(mean_square) in dB re 1 unit² (−∞ for an empty band).
    pub level_db: f64,
    /// Number of FFT bins that fell in the band (0: band narrower than the
    /// resolution fs/N, or above fs/2).
    pub bins: usize,
}

impl BandLevel {
    /// RMS value in the band (signal units).
    pub fn rms(&self) -> f64 {
        self.mean_square.sqrt()
    }

    /// Level in dB re a reference RMS value: 10·log10(mean_square/ref²).
    pub fn level_db_re(&self, reference_rms: f64) -> f64 {
        10.0 * (self.mean_square / (reference_rms * reference_rms)).log10()
    }
}

/// One-sided power spectrum P\[k\], k = 0 … ⌊N/2⌋, of `x` with a rectangular
/// window, normalised so that Σ_k P\[k\] = (1/N) Σ_n x\[n\]² (Parseval):
/// P\[k\] = c_k |X\[k\]|²/N², c_k = 1 at DC and at Nyquist (even N), 2 otherwise.
fn one_sided_power(x: &[f64]) -> Result<Vec<f64>> {
    let n = x.len();
    let mut planner = RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(n);
    let mut input = x.to_vec();
    let mut spectrum = fft.make_output_vec();
    fft.process(&mut input, &mut spectrum)
        .map_err(|e| DspError::Numerical(format!("FFT failed: {e}")))?;
    let n2 = (n as f64) * (n as f64);
    let last = spectrum.len() - 1;
    Ok(spectrum
        .iter()
        .enumerate()
        .map(|(k, z)| {
            let nyquist = k == last && 2 * last == n;
            let c = if k == 0 || nyquist { 1.0 } else { 2.0 };
            c * z.norm_sqr() / n2
        })
        .collect())
}

/// Mean-square level of `x` (sampled at `fs` Hz) in each band.
///
/// The whole record is transformed at once (rectangular window, resolution
/// fs/N); bin k at f_k = k·fs/N belongs to a band when lower ≤ f_k < upper,
/// so adjacent bands never share a bin and the band levels of a set of
/// contiguous bands add up to the mean square of the signal in that range
/// (Parseval). A sine of amplitude A with an integer number of periods in
/// the record gives exactly A²/2 in its band. Off-bin tones leak (rectangular
/// window) into neighbouring bins; a band several bins wide still captures
/// almost all of the power.
///
/// Errors on an empty or non-finite signal, or fs not finite and > 0.
pub fn band_levels(x: &[f64], fs: f64, bands: &[Band]) -> Result<Vec<BandLevel>> {
    if x.is_empty() {
        return Err(DspError::InvalidInput("empty signal".into()));
    }
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        return Err(DspError::InvalidInput(format!(
            "sample #{i} = {} is not finite",
            x[i]
        )));
    }
    check_fs(fs)?;
    let p = one_sided_power(x)?;
    let n = x.len() as f64;
    let freq = |k: usize| k as f64 * fs / n;
    let kmax = p.len() - 1;
    Ok(bands
        .iter()
        .map(|b| {
            // First bin with f_k ≥ lower, then walk while f_k < upper.
            let mut k = ((b.lower_hz * n / fs).ceil().max(0.0) as usize).min(kmax + 1);
            while k > 0 && freq(k - 1) >= b.lower_hz {
                k -= 1;
            }
            while k <= kmax && freq(k) < b.lower_hz {
                k += 1;
            }
            let mut ms = 0.0;
            let mut bins = 0;
            while k <= kmax && freq(k) < b.upper_hz {
                ms += p[k];
                bins += 1;
                k += 1;
            }
            BandLevel {
                band: b.clone(),
                mean_square: ms,
                level_db: 10.0 * ms.log10(),
                bins,
            }
        })
        .collect())
}

/// One line of a [`FlatnessReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlatnessBand {
    /// Measurement frequency in Hz.
    pub f_hz: f64,
    /// Nominal label of the third-octave band containing `f_hz`.
    pub nominal: String,
    /// Measured magnitude (same units as the target).
    pub magnitude: f64,
    /// Deviation from the target, 20·log10(magnitude/target) in dB
    /// (−∞ for a zero magnitude).
    pub db: f64,
    /// |db| ≤ tol_db.
    pub within: bool,
}

/// Per-band deviation of a measured magnitude response from a flat target
/// (the paper's Fig. 7 criterion: "flat within a few dB from DC to 1000 Hz").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlatnessReport {
    /// One entry per measured point, in input order.
    pub bands: Vec<FlatnessBand>,
    /// Target magnitude.
    pub target_magnitude: f64,
    /// Tolerance in dB (inclusive).
    pub tol_db: f64,
    /// max |db| over the bands.
    pub max_abs_dev_db: f64,
    /// Peak-to-peak spread max db − min db.
    pub spread_db: f64,
    /// True when every band is within the tolerance.
    pub passed: bool,
}

/// Flatness of `measured` (pairs of frequency in Hz and magnitude ≥ 0, e.g.
/// one per third-octave band) against `target_magnitude`, with tolerance
/// `tol_db`: per band db = 20·log10(|H|/target), within = |db| ≤ tol_db.
///
/// Errors on empty input, frequencies not finite and > 0, magnitudes not
/// finite and ≥ 0, a target not finite and > 0, or a negative/non-finite tolerance.
pub fn flatness(
    measured: &[(f64, f64)],
    target_magnitude: f64,
    tol_db: f64,
) -> Result<FlatnessReport> {
    if measured.is_empty() {
        return Err(DspError::InvalidInput(
            "no measured points for the flatness report".into(),
        ));
    }
    check_positive("target_magnitude", target_magnitude)?;
    check_non_negative("tol_db", tol_db)?;
    let mut bands = Vec::with_capacity(measured.len());
    for &(f_hz, magnitude) in measured {
        if !magnitude.is_finite() || magnitude < 0.0 {
            return Err(DspError::InvalidParameter {
                name: "magnitude",
                value: magnitude,
                reason: format!("magnitude at {f_hz} Hz must be finite and ≥ 0"),
            });
        }
        let x = band_index(f_hz)?;
        let db = 20.0 * (magnitude / target_magnitude).log10();
        bands.push(FlatnessBand {
            f_hz,
            nominal: nominal_label(x),
            magnitude,
            db,
            within: db.abs() <= tol_db,
        });
    }
    let max_abs_dev_db = bands.iter().map(|b| b.db.abs()).fold(0.0, f64::max);
    let hi = bands.iter().map(|b| b.db).fold(f64::NEG_INFINITY, f64::max);
    let lo = bands.iter().map(|b| b.db).fold(f64::INFINITY, f64::min);
    Ok(FlatnessReport {
        passed: bands.iter().all(|b| b.within),
        bands,
        target_magnitude,
        tol_db,
        max_abs_dev_db,
        spread_db: hi - lo,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Tf;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};
    use std::f64::consts::PI;

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    #[test]
    fn octave_ratio_constant() {
        assert!(rel(OCTAVE_RATIO, 10f64.powf(0.3)) < 1e-15);
    }

    #[test]
    fn reference_centres_and_nominals_63_to_1000() {
        // REFERENCE-VALUES.md, x = −12 … 0.
        let centres = [
            63.096, 79.433, 100.0, 125.893, 158.489, 199.526, 251.189, 316.228, 398.107, 501.187,
            630.957, 794.328, 1000.0,
        ];
        let nominal = [
            "63", "80", "100", "125", "160", "200", "250", "315", "400", "500", "630", "800",
            "1000",
        ];
        let bands = bands_between(63.0, 1000.0).unwrap();
        assert_eq!(bands.len(), 13);
        for (i, b) in bands.iter().enumerate() {
            let x = i as i32 - 12;
            assert_eq!(b.index, x);
            assert!((b.centre_hz - centres[i]).abs() < 5e-4, "{b:?}");
            // And from the definition f_m = 1000·G^(x/3).
            assert!(rel(b.centre_hz, 1000.0 * OCTAVE_RATIO.powf(f64::from(x) / 3.0)) < 1e-13);
            assert_eq!(b.nominal, nominal[i]);
            assert_eq!(b.nominal_hz, nominal[i].parse::<f64>().unwrap());
            // Edges f_m·G^(±1/6).
            assert!(rel(b.lower_hz, b.centre_hz * OCTAVE_RATIO.powf(-1.0 / 6.0)) < 1e-13);
            assert!(rel(b.upper_hz, b.centre_hz * OCTAVE_RATIO.powf(1.0 / 6.0)) < 1e-13);
            // Nominal within 2 % of the exact centre (R10 rounding).
            assert!(rel(b.nominal_hz, b.centre_hz) < 0.02);
        }
    }

    #[test]
    fn nominal_labels_below_and_above() {
        let want = [
            (-13, "50"),
            (-14, "40"),
            (-15, "31.5"),
            (-16, "25"),
            (-17, "20"),
            (-18, "16"),
            (-19, "12.5"),
            (-20, "10"),
            (-21, "8"),
            (-22, "6.3"),
            (-23, "5"),
            (-30, "1"),
            (-31, "0.8"),
            (-39, "0.125"),
            (-50, "0.01"),
            (1, "1250"),
            (5, "3150"),
            (11, "12500"),
            (13, "20000"),
        ];
        for (x, s) in want {
            assert_eq!(nominal_label(x), s, "x = {x}");
        }
        // The audio range 20 Hz – 20 kHz has 31 bands.
        let audio = bands_between(20.0, 20_000.0).unwrap();
        assert_eq!(audio.len(), 31);
        assert_eq!(audio[0].nominal, "20");
        assert_eq!(audio[30].nominal, "20000");
    }

    #[test]
    fn edges_meet_and_bandwidth_is_constant_relative() {
        let bands = bands_between(0.5, 50_000.0).unwrap();
        for w in bands.windows(2) {
            assert_eq!(w[0].upper_hz, w[1].lower_hz, "{:?} / {:?}", w[0], w[1]);
            assert_eq!(w[1].index, w[0].index + 1);
        }
        for b in &bands {
            // f2/f1 = G^(1/3) = 10^0.1; centre is the geometric mean of the edges.
            assert!(rel(b.upper_hz / b.lower_hz, 10f64.powf(0.1)) < 1e-13);
            assert!(rel((b.lower_hz * b.upper_hz).sqrt(), b.centre_hz) < 1e-13);
            assert!(b.contains(b.centre_hz) && b.contains(b.lower_hz) && !b.contains(b.upper_hz));
            assert_eq!(band_index(b.centre_hz).unwrap(), b.index);
            assert_eq!(band_index(b.nominal_hz).unwrap(), b.index);
        }
    }

    #[test]
    fn bands_between_rejects_bad_ranges() {
        assert!(bands_between(0.0, 100.0).is_err());
        assert!(bands_between(100.0, 50.0).is_err());
        assert!(bands_between(f64::NAN, 50.0).is_err());
        assert!(bands_between(10.0, f64::INFINITY).is_err());
        assert!(band_index(-1.0).is_err());
        // A range inside one band's gap between centres returns nothing.
        assert!(bands_between(1010.0, 1200.0).unwrap().is_empty());
        assert_eq!(bands_between(1000.0, 1000.0).unwrap().len(), 1);
        assert!(Band::new(i32::MAX).is_err());
    }

    #[test]
    fn on_bin_sine_puts_a2_over_2_in_its_band_only() {
        // fs = 10 kHz, N = 10000 (1 Hz bins), sine of amplitude A at 315 Hz.
        let fs = 10_000.0;
        let n = 10_000;
        let a = 0.7;
        let f0 = 315.0;
        let x: Vec<f64> = (0..n)
            .map(|i| a * (2.0 * PI * f0 * i as f64 / fs + 0.3).sin())
            .collect();
        let bands = bands_between(63.0, 1000.0).unwrap();
        let levels = band_levels(&x, fs, &bands).unwrap();
        for l in &levels {
            if l.band.nominal == "315" {
                assert!(rel(l.mean_square, a * a / 2.0) < 1e-12, "{l:?}");
                assert!(rel(l.rms(), a / 2f64.sqrt()) < 1e-12);
                assert!((l.level_db - 10.0 * (a * a / 2.0_f64).log10()).abs() < 1e-10);
                assert!((l.level_db_re(a) - 10.0 * 0.5f64.log10()).abs() < 1e-10);
            } else {
                assert!(l.mean_square < 1e-20 * a * a, "{l:?}");
            }
            // Bin count = number of integers k with lower ≤ k < upper (1 Hz bins).
            let expect = (l.band.upper_hz.ceil() - l.band.lower_hz.ceil()) as usize;
            assert_eq!(l.bins, expect, "{:?}", l.band);
        }
    }

    #[test]
    fn off_bin_sine_is_mostly_captured() {
        // 1003.7 Hz, not on a bin: rectangular-window leakage outside a 231 Hz
        // wide band is ~2/(π² · 115 bins) ≈ 0.2 %.
        let fs = 10_000.0;
        let x: Vec<f64> = (0..10_000)
            .map(|i| (2.0 * PI * 1003.7 * i as f64 / fs).sin())
            .collect();
        let levels = band_levels(&x, fs, &bands_between(800.0, 1250.0).unwrap()).unwrap();
        let ms = 0.5;
        assert!(levels[1].band.nominal == "1000");
        assert!(levels[1].mean_square > 0.99 * ms && levels[1].mean_square <= 1.001 * ms);
        let total: f64 = levels.iter().map(|l| l.mean_square).sum();
        assert!(total <= 1.0001 * ms);
    }

    #[test]
    fn parseval_and_nyquist_bin() {
        // Odd and even N: the one-sided spectrum sums to the mean square.
        let mut rng = StdRng::seed_from_u64(3);
        let normal = Normal::new(0.2, 1.0).unwrap();
        for n in [1usize, 2, 7, 1000, 1001] {
            let x: Vec<f64> = (0..n).map(|_| normal.sample(&mut rng)).collect();
            let p = one_sided_power(&x).unwrap();
            let ms = x.iter().map(|v| v * v).sum::<f64>() / n as f64;
            assert!(rel(p.iter().sum::<f64>(), ms) < 1e-12, "n = {n}");
        }
        // x = A cos(π n) lives entirely at Nyquist: mean square A², not A²/2.
        let fs = 10_000.0;
        let x: Vec<f64> = (0..1000)
            .map(|i| if i % 2 == 0 { 1.5 } else { -1.5 })
            .collect();
        let bands = vec![Band::new(7).unwrap()]; // 5 kHz band: 4467 … 5623 Hz
        let l = band_levels(&x, fs, &bands).unwrap();
        assert!(rel(l[0].mean_square, 2.25) < 1e-12);
        // Contiguous bands covering 1 Hz … fs/2 sum to the mean square minus DC.
        let y: Vec<f64> = x
            .iter()
            .enumerate()
            .map(|(i, v)| v + (i as f64 * 0.37).sin() + 0.5)
            .collect();
        let bands = bands_between(1.0, 5000.0).unwrap();
        // Lowest edge below the first non-DC bin (10 Hz resolution).
        assert!(bands[0].lower_hz <= fs / 1000.0);
        let total: f64 = band_levels(&y, fs, &bands)
            .unwrap()
            .iter()
            .map(|l| l.mean_square)
            .sum();
        let mean = y.iter().sum::<f64>() / y.len() as f64;
        let ms_ac = y.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / y.len() as f64;
        assert!(rel(total, ms_ac) < 1e-12, "{total} vs {ms_ac}");
    }

    #[test]
    fn white_noise_band_power_proportional_to_bandwidth() {
        // Unit-variance white noise: E[P_k] = 2σ²/N per non-DC bin, so
        // E[band] = bins·2σ²/N ≈ σ²·B/(fs/2). Relative std 1/√bins.
        let fs = 10_000.0;
        let n = 1 << 20;
        let mut rng = StdRng::seed_from_u64(11);
        let normal = Normal::new(0.0, 1.0).unwrap();
        let x: Vec<f64> = (0..n).map(|_| normal.sample(&mut rng)).collect();
        let bands = bands_between(63.0, 1000.0).unwrap();
        let levels = band_levels(&x, fs, &bands).unwrap();
        for l in &levels {
            let expect = l.bins as f64 * 2.0 / n as f64;
            let sd = expect / (l.bins as f64).sqrt();
            assert!(
                (l.mean_square - expect).abs() < 5.0 * sd,
                "{l:?}: expect {expect}"
            );
            // Bin count tracks the bandwidth: bins ≈ B·N/fs.
            assert!((l.bins as f64 - l.band.bandwidth_hz() * n as f64 / fs).abs() <= 1.0);
            // Power density ∝ bandwidth: ms/B ≈ 2σ²/fs within 5 standard deviations.
            let density = l.mean_square / l.band.bandwidth_hz();
            assert!(rel(density, 2.0 / fs) < 5.0 / (l.bins as f64).sqrt() + 1.0 / l.bins as f64);
        }
        // Ten bands higher = ten times the bandwidth = +10 dB.
        let d = levels[12].level_db - levels[2].level_db;
        assert!((d - 10.0).abs() < 0.3, "{d}");
    }

    #[test]
    fn band_levels_edge_cases() {
        let fs = 1000.0;
        // Band narrower than the resolution: no bins, −∞ dB.
        let x = vec![1.0; 10]; // 100 Hz resolution
        let l = band_levels(&x, fs, &[Band::new(-20).unwrap()]).unwrap();
        assert_eq!(l[0].bins, 0);
        assert_eq!(l[0].mean_square, 0.0);
        assert_eq!(l[0].level_db, f64::NEG_INFINITY);
        // Band above Nyquist: no bins.
        let l = band_levels(&x, fs, &[Band::new(10).unwrap()]).unwrap();
        assert_eq!(l[0].bins, 0);
        assert!(band_levels(&[], fs, &[]).is_err());
        assert!(band_levels(&[1.0, f64::NAN], fs, &[]).is_err());
        assert!(band_levels(&[1.0, f64::INFINITY], fs, &[]).is_err());
        assert!(band_levels(&x, 0.0, &[]).is_err());
        assert!(band_levels(&x, f64::NAN, &[]).is_err());
        assert!(band_levels(&x, fs, &[]).unwrap().is_empty());
    }

    #[test]
    fn flatness_report_maths() {
        let target = 2.0;
        let devs = [0.0, 1.5, -2.9, 3.1, -0.4];
        let freqs = [63.0957, 125.893, 251.189, 501.187, 1000.0];
        let measured: Vec<(f64, f64)> = freqs
            .iter()
            .zip(devs)
            .map(|(&f, d)| (f, target * 10f64.powf(d / 20.0)))
            .collect();
        let r = flatness(&measured, target, 3.0).unwrap();
        for (b, d) in r.bands.iter().zip(devs) {
            assert!((b.db - d).abs() < 1e-12);
            assert_eq!(b.within, d.abs() <= 3.0);
        }
        let nominal: Vec<&str> = r.bands.iter().map(|b| b.nominal.as_str()).collect();
        assert_eq!(nominal, ["63", "125", "250", "500", "1000"]);
        assert!((r.max_abs_dev_db - 3.1).abs() < 1e-12);
        assert!((r.spread_db - 6.0).abs() < 1e-12);
        assert!(!r.passed);
        assert!(flatness(&measured, target, 3.2).unwrap().passed);
        // Zero magnitude: −∞ dB, fails.
        let r = flatness(&[(100.0, 0.0)], 1.0, 60.0).unwrap();
        assert!(!r.passed && r.bands[0].db == f64::NEG_INFINITY);
        // Errors.
        assert!(flatness(&[], 1.0, 3.0).is_err());
        assert!(flatness(&[(100.0, -1.0)], 1.0, 3.0).is_err());
        assert!(flatness(&[(100.0, f64::NAN)], 1.0, 3.0).is_err());
        assert!(flatness(&[(0.0, 1.0)], 1.0, 3.0).is_err());
        assert!(flatness(&[(100.0, 1.0)], 0.0, 3.0).is_err());
        assert!(flatness(&[(100.0, 1.0)], 1.0, -3.0).is_err());
    }

    #[test]
    fn flatness_of_uncompensated_haptuator_channel() {
        // |G_H| relative to its DC gain at the REFERENCE-VALUES frequencies:
        // 0.144449 (63.0957 Hz), 0.189021 (316.228 Hz), 0.0453443 (1000 Hz),
        // DC 0.140351 — the channel is not flat within 3 dB (−9.8 dB at 1 kHz).
        let g = Tf::new(vec![250.0, 6.40e5], vec![1.0, 2135.0, 4.56e6]).unwrap();
        let bands = bands_between(63.0, 1000.0).unwrap();
        let measured: Vec<(f64, f64)> = bands
            .iter()
            .map(|b| (b.centre_hz, g.response_hz(b.centre_hz).norm()))
            .collect();
        let r = flatness(&measured, g.dc_gain(), 3.0).unwrap();
        let db = |m: f64| 20.0 * (m / 0.140351_f64).log10();
        let check = |nominal: &str, m: f64| {
            let b = r.bands.iter().find(|b| b.nominal == nominal).unwrap();
            assert!((b.db - db(m)).abs() < 1e-4, "{b:?}");
        };
        check("63", 0.144449);
        check("315", 0.189021);
        check("1000", 0.0453443);
        assert!((r.max_abs_dev_db - db(0.0453443).abs()).abs() < 1e-4);
        assert!(!r.passed);
    }
}
