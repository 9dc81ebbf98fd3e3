//! Amplitude, phase and offset of a sine of known frequency in a sampled
//! record: [`sine_fit`], the three-parameter least-squares fit (IEEE Std
//! 1057, known frequency) solved by Householder QR, and [`sine_dft`], the
//! single-bin DFT estimate of the same quantities.

use crate::error::check_fs;
use crate::{DspError, Result};
use nalgebra::{DMatrix, DVector};
use std::f64::consts::PI;

fn check_sine_args(x: &[f64], f: f64, fs: f64) -> Result<()> {
    check_fs(fs)?;
    if !(f.is_finite() && f > 0.0 && f < fs / 2.0) {
        return Err(DspError::param("f", f, "must be in (0, fs/2)"));
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
/// holds a whole number of cycles, as in [`stepped_sine`](super::stepped_sine) windows; otherwise
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

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand::rngs::StdRng;
    use rand_distr::{Distribution, Normal};

    /// Phase difference wrapped to [−π, π) (rad).
    pub(in crate::excitation) fn wrap(p: f64) -> f64 {
        (p + PI).rem_euclid(2.0 * PI) - PI
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
    }
}
