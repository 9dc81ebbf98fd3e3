//! Records with a prescribed one-sided spectrum, synthesised in the
//! frequency domain (as pylake's tests do): every DFT bin an independent
//! complex Gaussian whose periodogram has mean P(f_k), so the periodogram of
//! the record is exactly P(f_k)·Exp(1) (χ²₂/2) bin by bin. The record is
//! periodic: no leakage, no aliasing — the ideal anti-aliased record that
//! the Lorentzian and hydrodynamic models describe. For tests, references
//! and benchmarks.

use crate::error::DspError;
use realfft::RealFftPlanner;

/// A record of `n` samples at `fs_hz` whose periodogram has mean
/// `psd(f_k)` (u²/Hz, one-sided) at f_k = k f_s/n, k = 1 … n/2 (zero mean).
/// `normal` supplies independent standard normal numbers (2 per bin).
pub fn synthesize_record(
    psd: impl Fn(f64) -> f64,
    n: usize,
    fs_hz: f64,
    normal: &mut impl FnMut() -> f64,
) -> Result<Vec<f64>, DspError> {
    if n < 4 || !n.is_multiple_of(2) {
        return Err(DspError::InvalidInput(format!(
            "synthesised records need an even length ≥ 4, got {n}"
        )));
    }
    let ifft = RealFftPlanner::<f64>::new().plan_fft_inverse(n);
    let mut spec = ifft.make_input_vec();
    let df = fs_hz / n as f64;
    let half = n / 2;
    for (k, c) in spec.iter_mut().enumerate().skip(1) {
        let p = psd(k as f64 * df);
        if !(p.is_finite() && p >= 0.0) {
            return Err(DspError::Numerical(format!(
                "the spectrum is {p} at {} Hz",
                k as f64 * df
            )));
        }
        let var = p * fs_hz * n as f64 / 2.0;
        if k == half {
            *c = num_complex::Complex64::new(var.sqrt() * normal(), 0.0);
        } else {
            let s = (var / 2.0).sqrt();
            *c = num_complex::Complex64::new(s * normal(), s * normal());
        }
    }
    let mut x = ifft.make_output_vec();
    ifft.process(&mut spec, &mut x)
        .map_err(|e| DspError::Numerical(format!("inverse FFT: {e}")))?;
    let inv_n = 1.0 / n as f64;
    x.iter_mut().for_each(|v| *v *= inv_n);
    Ok(x)
}
