//! Power spectrum of a bead in a harmonic trap and its fit.
//!
//! For the exact (Ornstein–Uhlenbeck) sampled process x\[n+1\] = c x\[n\] + σ ξ,
//! c = e^{−x}, x = 2π f_c/f_s, the two-sided PSD is the *aliased Lorentzian*
//! (Berg-Sørensen & Flyvbjerg 2004, eq. 4; docs/REFERENCE-VALUES.md)
//!
//! P₂(f) = (D/(2π f_c f_s)) · sinh x / (cosh x − cos(2π f/f_s)),
//!
//! with D = k_B T/γ the diffusion coefficient (m²/s), so that ∫P₂ = k_B T/κ.
//! The one-sided density (what Welch returns) is twice that.
//!
//! [`fit_aliased_lorentzian`] fits (f_c, D) to a one-sided PSD estimate that
//! averages K periodograms. Each bin is then Gamma-distributed around the
//! model, so the Whittle (maximum-likelihood) criterion
//! Σ [ln P_model + P_meas/P_model] is used: for fixed f_c the optimal D is
//! closed-form (D̂ = mean of P_meas/g(f_c) with g the model for D = 1), which
//! leaves a 1-D search over ln f_c (grid scan, then golden section). Unlike
//! least squares on relative residuals, this has no O(1/K) bias.

use crate::error::DspError;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// One-sided aliased Lorentzian at `f` (Hz) for corner `fc` (Hz), diffusion
/// coefficient `d` (m²/s) and sample rate `fs` (Hz): m²/Hz.
pub fn aliased_lorentzian_one_sided(f: f64, fc: f64, d: f64, fs: f64) -> f64 {
    let x = 2.0 * PI * fc / fs;
    // sinh x/(cosh x − cos θ) written to stay accurate for small x and θ.
    let th = 2.0 * PI * f / fs;
    let num = x.sinh();
    // cosh x − cos θ = 2 sinh²(x/2) + 2 sin²(θ/2)
    let den = 2.0 * (0.5 * x).sinh().powi(2) + 2.0 * (0.5 * th).sin().powi(2);
    2.0 * d / (2.0 * PI * fc * fs) * num / den
}

/// One-sided plain (continuous) Lorentzian D/(π²(f_c² + f²)), m²/Hz.
pub fn lorentzian_one_sided(f: f64, fc: f64, d: f64) -> f64 {
    d / (PI * PI * (fc * fc + f * f))
}

/// Result of a Lorentzian fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LorentzianFit {
    /// Corner frequency, Hz.
    pub fc_hz: f64,
    /// Diffusion coefficient, m²/s.
    pub d_m2_s: f64,
    /// Number of spectral bins used.
    pub n_bins: usize,
}

/// Fit the one-sided aliased Lorentzian to (`f`, `psd`) over
/// `f_lo` ≤ f ≤ `f_hi` (Hz) by the Whittle criterion (module docs).
pub fn fit_aliased_lorentzian(
    f: &[f64],
    psd: &[f64],
    fs: f64,
    f_lo: f64,
    f_hi: f64,
) -> Result<LorentzianFit, DspError> {
    if f.len() != psd.len() {
        return Err(DspError::InvalidInput(format!(
            "f and psd differ in length ({} vs {})",
            f.len(),
            psd.len()
        )));
    }
    if !(fs.is_finite() && fs > 0.0) {
        return Err(DspError::InvalidParameter {
            name: "fs",
            value: fs,
            reason: "must be finite and > 0".into(),
        });
    }
    let pts: Vec<(f64, f64)> = f
        .iter()
        .zip(psd)
        .filter(|(fi, pi)| **fi >= f_lo && **fi <= f_hi && pi.is_finite() && **pi > 0.0)
        .map(|(a, b)| (*a, *b))
        .collect();
    if pts.len() < 8 {
        return Err(DspError::InvalidInput(format!(
            "only {} usable bins in [{f_lo}, {f_hi}] Hz",
            pts.len()
        )));
    }
    // Whittle objective with D profiled out.
    let objective = |ln_fc: f64| -> (f64, f64) {
        let fc = ln_fc.exp();
        let mut sum_r = 0.0;
        let mut sum_ln_g = 0.0;
        for &(fi, pi) in &pts {
            let g = aliased_lorentzian_one_sided(fi, fc, 1.0, fs);
            sum_r += pi / g;
            sum_ln_g += g.ln();
        }
        let n = pts.len() as f64;
        let d = sum_r / n;
        (n * d.ln() + sum_ln_g, d)
    };
    let (lo, hi) = ((fs * 1e-5).ln(), (fs * 2.0).ln());
    let n_grid = 200;
    let mut best = (f64::INFINITY, lo);
    for i in 0..=n_grid {
        let t = lo + (hi - lo) * i as f64 / n_grid as f64;
        let (v, _) = objective(t);
        if v < best.0 {
            best = (v, t);
        }
    }
    let step = (hi - lo) / n_grid as f64;
    let (mut a, mut b) = (best.1 - step, best.1 + step);
    let g = 0.5 * (5.0_f64.sqrt() - 1.0);
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let (mut fc_v, mut fd_v) = (objective(c).0, objective(d).0);
    for _ in 0..100 {
        if fc_v < fd_v {
            b = d;
            d = c;
            fd_v = fc_v;
            c = b - g * (b - a);
            fc_v = objective(c).0;
        } else {
            a = c;
            c = d;
            fc_v = fd_v;
            d = a + g * (b - a);
            fd_v = objective(d).0;
        }
        if (b - a).abs() < 1e-10 {
            break;
        }
    }
    let t = 0.5 * (a + b);
    let (v, dhat) = objective(t);
    if !(v.is_finite() && dhat.is_finite() && dhat > 0.0) {
        return Err(DspError::Numerical(
            "Lorentzian fit did not converge".into(),
        ));
    }
    Ok(LorentzianFit {
        fc_hz: t.exp(),
        d_m2_s: dhat,
        n_bins: pts.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aliased_lorentzian_reference_ratios() {
        // REFERENCE-VALUES.md: fs = 10 kHz, fc = 281 Hz → aliased/plain ratio
        // 1.036 at 1 kHz and 2.47 at 5 kHz.
        let (fs, fc, d) = (10e3, 281.0, 1.0);
        let r1 =
            aliased_lorentzian_one_sided(1000.0, fc, d, fs) / lorentzian_one_sided(1000.0, fc, d);
        let r5 =
            aliased_lorentzian_one_sided(5000.0, fc, d, fs) / lorentzian_one_sided(5000.0, fc, d);
        assert!((r1 - 1.036).abs() < 1e-3, "{r1}");
        assert!((r5 - 2.47).abs() < 5e-3, "{r5}");
    }

    #[test]
    fn aliased_lorentzian_integrates_to_equipartition() {
        // ∫₀^{fs/2} P₁ df = D/(2π fc) = kT/κ, for any fc (even above Nyquist).
        for (fc, fs) in [(50.0, 1e4), (281.0, 1e4), (8000.0, 1e4)] {
            let d = 2.0;
            let n = 200_000;
            let h = 0.5 * fs / n as f64;
            let mut s = 0.0;
            for i in 0..=n {
                let w = if i == 0 || i == n { 0.5 } else { 1.0 };
                s += w * aliased_lorentzian_one_sided(i as f64 * h, fc, d, fs);
            }
            s *= h;
            let expect = d / (2.0 * PI * fc);
            assert!((s / expect - 1.0).abs() < 1e-6, "fc {fc}: {s} vs {expect}");
        }
    }

    #[test]
    fn fit_recovers_noise_free_model() {
        let (fs, fc, d) = (10e3, 170.0, 1.4e-13);
        let f: Vec<f64> = (1..2048).map(|k| k as f64 * fs / 4096.0).collect();
        let p: Vec<f64> = f
            .iter()
            .map(|&f| aliased_lorentzian_one_sided(f, fc, d, fs))
            .collect();
        let fit = fit_aliased_lorentzian(&f, &p, fs, 5.0, 4900.0).unwrap();
        assert!((fit.fc_hz / fc - 1.0).abs() < 1e-5, "{fit:?}");
        assert!((fit.d_m2_s / d - 1.0).abs() < 1e-5, "{fit:?}");
    }

    #[test]
    fn fit_rejects_bad_input() {
        assert!(fit_aliased_lorentzian(&[1.0, 2.0], &[1.0], 1e4, 0.0, 10.0).is_err());
        assert!(fit_aliased_lorentzian(&[1.0; 4], &[1.0; 4], 1e4, 0.0, 10.0).is_err());
        assert!(fit_aliased_lorentzian(&[1.0; 20], &[1.0; 20], f64::NAN, 0.0, 10.0).is_err());
    }
}
