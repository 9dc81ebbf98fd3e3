//! The periodogram of a whole record and its blocking (module docs of
//! [`super`]).

use crate::error::DspError;
use realfft::RealFftPlanner;

/// Largest record [`Periodogram::new`] accepts, samples (2³¹: 16 GiB of
/// f64 at most in the transform buffers).
pub const MAX_RECORD: usize = 1 << 31;

/// One-sided periodogram of a record: P_k = (2/(f_s N)) |X_k|² at
/// f_k = k f_s/N, k = 0 … N/2, with X the DFT of the record minus its mean
/// (pylake `PowerSpectrum.from_data` without windowing). Units: u²/Hz for a
/// record in u.
#[derive(Debug, Clone, PartialEq)]
pub struct Periodogram {
    /// Frequencies, Hz.
    pub f: Vec<f64>,
    /// Power spectral density, u²/Hz.
    pub p: Vec<f64>,
    /// Sample rate, Hz.
    pub fs_hz: f64,
    /// Record length, samples.
    pub n_samples: usize,
}

/// A blocked spectrum: the periodogram's bins in (f_lo, f_hi] averaged in
/// consecutive blocks of `points_per_block` (a last, incomplete block is
/// dropped), frequencies averaged the same way.
#[derive(Debug, Clone, PartialEq)]
pub struct BlockedSpectrum {
    /// Block-mean frequencies, Hz.
    pub f: Vec<f64>,
    /// Block-mean powers, u²/Hz.
    pub p: Vec<f64>,
    /// Bins per block n (each block mean is Gamma(n, P/n) distributed).
    pub points_per_block: usize,
    /// Frequency range (f_lo, f_hi], Hz.
    pub range_hz: (f64, f64),
    /// Sample rate, Hz.
    pub fs_hz: f64,
    /// Duration of the record, s.
    pub duration_s: f64,
}

impl Periodogram {
    /// Periodogram of `x` sampled at `fs_hz` (Hz). Errors name the first
    /// non-finite sample.
    pub fn new(x: &[f64], fs_hz: f64) -> Result<Self, DspError> {
        if !(fs_hz.is_finite() && fs_hz > 0.0) {
            return Err(DspError::InvalidParameter {
                name: "fs",
                value: fs_hz,
                reason: "must be finite and > 0".into(),
            });
        }
        let n = x.len();
        if !(16..=MAX_RECORD).contains(&n) {
            return Err(DspError::InvalidInput(format!(
                "a record of {n} samples; need between 16 and {MAX_RECORD}"
            )));
        }
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(DspError::InvalidInput(format!(
                "sample {} (0-based {i}) is not a finite number ({})",
                i + 1,
                x[i]
            )));
        }
        let mean = x.iter().sum::<f64>() / n as f64;
        let mut buf: Vec<f64> = x.iter().map(|v| v - mean).collect();
        let fft = RealFftPlanner::<f64>::new().plan_fft_forward(n);
        let mut spec = fft.make_output_vec();
        fft.process(&mut buf, &mut spec)
            .map_err(|e| DspError::Numerical(format!("FFT: {e}")))?;
        let scale = 2.0 / (fs_hz * n as f64);
        let df = fs_hz / n as f64;
        Ok(Self {
            f: (0..spec.len()).map(|k| k as f64 * df).collect(),
            p: spec.iter().map(|c| scale * c.norm_sqr()).collect(),
            fs_hz,
            n_samples: n,
        })
    }

    /// Block the bins in (`f_lo`, `f_hi`] by `points_per_block`.
    pub fn blocked(
        &self,
        f_lo: f64,
        f_hi: f64,
        points_per_block: usize,
    ) -> Result<BlockedSpectrum, DspError> {
        if !(f_lo.is_finite() && f_hi.is_finite() && f_lo >= 0.0 && f_hi > f_lo) {
            return Err(DspError::InvalidInput(format!(
                "fit range {f_lo},{f_hi} Hz: need 0 ≤ low < high, both finite"
            )));
        }
        if points_per_block == 0 {
            return Err(DspError::InvalidParameter {
                name: "points_per_block",
                value: 0.0,
                reason: "must be ≥ 1".into(),
            });
        }
        let (mut f, mut p) = (Vec::new(), Vec::new());
        let sel = self
            .f
            .iter()
            .zip(&self.p)
            .filter(|(fi, _)| **fi > f_lo && **fi <= f_hi);
        let (mut sf, mut sp, mut k) = (0.0, 0.0, 0usize);
        for (fi, pi) in sel {
            sf += fi;
            sp += pi;
            k += 1;
            if k == points_per_block {
                f.push(sf / k as f64);
                p.push(sp / k as f64);
                (sf, sp, k) = (0.0, 0.0, 0);
            }
        }
        Ok(BlockedSpectrum {
            f,
            p,
            points_per_block,
            range_hz: (f_lo, f_hi),
            fs_hz: self.fs_hz,
            duration_s: self.n_samples as f64 / self.fs_hz,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parseval_and_scaling() {
        // Σ P_k Δf over k = 1 … N/2 − 1 plus half the Nyquist bin equals the
        // variance (one-sided density, 2/(fs N) scaling).
        let n = 1000;
        let x: Vec<f64> = (0..n).map(|i| ((i * 7919) % 113) as f64 * 0.01).collect();
        let fs = 250.0;
        let pg = Periodogram::new(&x, fs).unwrap();
        let df = fs / n as f64;
        let total: f64 = pg.p[1..n / 2].iter().sum::<f64>() * df + 0.5 * pg.p[n / 2] * df;
        let m = x.iter().sum::<f64>() / n as f64;
        let var = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n as f64;
        assert!((total / var - 1.0).abs() < 1e-12, "{total} vs {var}");
        assert!(pg.p[0].abs() < 1e-20);
    }

    #[test]
    fn blocking_takes_the_half_open_range_and_drops_the_remainder() {
        let x: Vec<f64> = (0..64).map(|i| (i as f64 * 0.3).sin()).collect();
        let pg = Periodogram::new(&x, 64.0).unwrap();
        // Bins are 1 Hz apart: (2, 12] holds 3 … 12, ten bins → 3 blocks of 3.
        let b = pg.blocked(2.0, 12.0, 3).unwrap();
        assert_eq!(b.f, vec![4.0, 7.0, 10.0]);
        let mean3 = (pg.p[3] + pg.p[4] + pg.p[5]) / 3.0;
        assert!((b.p[0] - mean3).abs() <= 1e-15 * mean3.abs().max(1e-300));
        assert!(pg.blocked(5.0, 2.0, 3).is_err());
        assert!(pg.blocked(0.0, 10.0, 0).is_err());
    }

    #[test]
    fn rejects_non_finite_samples_by_position() {
        let mut x = vec![0.0; 100];
        x[41] = f64::NAN;
        let e = Periodogram::new(&x, 1e3).unwrap_err().to_string();
        assert!(e.contains("sample 42"), "{e}");
        assert!(Periodogram::new(&[1.0; 100], f64::INFINITY).is_err());
        assert!(Periodogram::new(&[1.0; 3], 1.0).is_err());
    }
}
