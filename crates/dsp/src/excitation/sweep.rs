//! Farina's exponential (logarithmic) swept sine (Farina 2000, AES 108th
//! Convention, preprint 5093), with optional raised-cosine fades.

use super::buffer::alloc_len;
use crate::error::{check_fs, check_non_negative, check_positive};
use crate::{DspError, Result};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

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
        check_positive("f1", self.f1)?;
        if !(self.f2.is_finite() && self.f2 > self.f1 && self.f2 <= fs / 2.0) {
            return Err(DspError::param(
                "f2",
                self.f2,
                "must satisfy f1 < f2 ≤ fs/2",
            ));
        }
        if !(self.duration.is_finite() && self.duration * fs >= 2.0) {
            return Err(DspError::param(
                "duration",
                self.duration,
                "must be finite and last at least 2 samples",
            ));
        }
        check_positive("amplitude", self.amplitude)?;
        check_non_negative("fade_in", self.fade_in)?;
        check_non_negative("fade_out", self.fade_out)?;
        if self.fade_in + self.fade_out > self.duration {
            return Err(DspError::param(
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
            return Err(DspError::param("duration", self.duration, "sweep too long"));
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
