//! Fingertip accelerometer after the MMA7361L (paper §2.1, Fig. 1).
//!
//! Per axis i, with a(t_n) the true acceleration (m/s²) plus a static part
//! (gravity), w\[n\] white Gaussian noise and α_i = e^{−2π f_i/f_s}:
//!
//! s_i\[n\] = α_i s_i\[n−1\] + (1 − α_i)(a_i\[n\] + w_i\[n\]),
//! y_i\[n\] = Q(clip(s_i\[n\], ±range)),
//!
//! i.e. a one-pole low-pass with corner f_i (datasheet bandwidth: 400 Hz x/y,
//! 300 Hz z), noise added before the pole so that the output density in the
//! pass band is the datasheet's ρ (350 µg/√Hz): var w = ρ² f_s/2. `range` is
//! ±6 g (the MMA7361L's high-g setting, as in the paper) and Q rounds to the
//! acquisition step (16 bit over ±10 V at 206 mV/g → 1.453e-2 m/s²).
//!
//! The known linear part is exposed so calibration can divide it out:
//! [`Accelerometer::response`] is the exact response of the discrete pole,
//! (1 − α)/(1 − α e^{−jω/f_s}); [`Accelerometer::analog_response`] the
//! datasheet's 1/(1 + j f/f_i).

use crate::config::AccelerometerConfig;
use crate::error::RigError;
use crate::normal::NormalStream;
use num_complex::Complex64 as C64;
use std::f64::consts::PI;

/// Standard gravity, m/s².
pub const STANDARD_GRAVITY: f64 = 9.806_65;

/// One accelerometer reading.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AccelReading {
    /// Acceleration (x, y, z) as the acquisition sees it, m/s².
    pub m_s2: [f64; 3],
    /// True if any axis hit the ±range rails this sample.
    pub clipped: bool,
}

/// Simulated three-axis accelerometer (module docs).
#[derive(Debug, Clone)]
pub struct Accelerometer {
    fs: f64,
    corner_hz: [f64; 3],
    alpha: [f64; 3],
    /// 1 − α per axis (the same value the update formula computes).
    beta: [f64; 3],
    state: [f64; 3],
    noise_sigma: f64,
    noise_density: f64,
    range: f64,
    lsb: f64,
    /// lsb > 0 and range/lsb < 2⁵¹: every unclipped reading divided by the
    /// step is below 2⁵², so the fast path rounds without the large-value
    /// test of [`crate::round_half_away`].
    quant_fast: bool,
    offset: [f64; 3],
    noise: NormalStream,
    seed: u64,
    clipped: u64,
    nonfinite: u64,
}

impl Accelerometer {
    /// Build from a rig-file section at sample rate `fs` (Hz).
    pub fn new(cfg: &AccelerometerConfig, fs: f64) -> Result<Self, RigError> {
        RigError::require_positive("fs", fs)?;
        for &fc in &cfg.corner_hz {
            if !(fc.is_finite() && fc > 0.0 && fc < 0.5 * fs) {
                return Err(RigError::InvalidParameter {
                    name: "corner_hz",
                    value: fc,
                    reason: format!("must be in (0, {}) Hz", 0.5 * fs),
                });
            }
        }
        RigError::require_positive("range_g", cfg.range_g)?;
        if !(cfg.noise_density_ug_per_rthz.is_finite() && cfg.noise_density_ug_per_rthz >= 0.0) {
            return Err(RigError::InvalidParameter {
                name: "noise_density_ug_per_rthz",
                value: cfg.noise_density_ug_per_rthz,
                reason: "must be finite and ≥ 0".into(),
            });
        }
        if !(cfg.lsb_m_s2.is_finite() && cfg.lsb_m_s2 >= 0.0) {
            return Err(RigError::InvalidParameter {
                name: "lsb_m_s2",
                value: cfg.lsb_m_s2,
                reason: "must be finite and ≥ 0".into(),
            });
        }
        let alpha = cfg.corner_hz.map(|fc| (-2.0 * PI * fc / fs).exp());
        let rho = cfg.noise_density_ug_per_rthz * 1e-6 * STANDARD_GRAVITY;
        let offset = cfg.static_m_s2;
        Ok(Self {
            fs,
            corner_hz: cfg.corner_hz,
            alpha,
            beta: alpha.map(|a| 1.0 - a),
            // Start settled on the static acceleration.
            state: offset,
            noise_sigma: rho * (0.5 * fs).sqrt(),
            noise_density: rho,
            range: cfg.range_g * STANDARD_GRAVITY,
            lsb: cfg.lsb_m_s2,
            quant_fast: cfg.lsb_m_s2 > 0.0
                && cfg.range_g * STANDARD_GRAVITY / cfg.lsb_m_s2 < 2_251_799_813_685_248.0,
            offset,
            noise: NormalStream::new(cfg.seed),
            seed: cfg.seed,
            clipped: 0,
            nonfinite: 0,
        })
    }

    /// Sample rate, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    /// Corner frequencies (x, y, z), Hz.
    pub fn corner_hz(&self) -> [f64; 3] {
        self.corner_hz
    }

    /// The discrete pole per axis, α_i = e^{−2π f_i/f_s} (module docs).
    pub fn alpha(&self) -> [f64; 3] {
        self.alpha
    }

    /// Static acceleration (gravity) per axis, m/s².
    pub fn offset_m_s2(&self) -> [f64; 3] {
        self.offset
    }

    /// White-noise density in the pass band, (m/s²)/√Hz.
    pub fn noise_density_m_s2_per_rthz(&self) -> f64 {
        self.noise_density
    }

    /// Full-scale range, ±m/s².
    pub fn range_m_s2(&self) -> f64 {
        self.range
    }

    /// Quantisation step, m/s² (0 = none).
    pub fn lsb_m_s2(&self) -> f64 {
        self.lsb
    }

    /// Samples in which some axis was clipped.
    pub fn clipped_samples(&self) -> u64 {
        self.clipped
    }

    /// Non-finite inputs replaced by the previous state.
    pub fn nonfinite_inputs(&self) -> u64 {
        self.nonfinite
    }

    /// [`Self::reset`] with a new noise seed: the sensor as
    /// [`Self::new`] builds it with `seed`.
    pub fn reseed(&mut self, seed: u64) {
        self.seed = seed;
        self.reset();
    }

    /// Reset the filter to the static acceleration and re-seed the noise.
    pub fn reset(&mut self) {
        self.state = self.offset;
        self.noise = NormalStream::new(self.seed);
        self.clipped = 0;
        self.nonfinite = 0;
    }

    /// Exact frequency response of axis `axis` (0 = x, 1 = y, 2 = z) of the
    /// simulated (discrete) sensor at `f` Hz: (1 − α)/(1 − α e^{−j2πf/fs}).
    /// Returns 0 for an invalid axis.
    pub fn response(&self, axis: usize, f_hz: f64) -> C64 {
        match self.alpha.get(axis) {
            Some(&a) => {
                let z1 = C64::from_polar(1.0, -2.0 * PI * f_hz / self.fs);
                C64::new(1.0 - a, 0.0) / (C64::new(1.0, 0.0) - a * z1)
            }
            None => C64::new(0.0, 0.0),
        }
    }

    /// Datasheet (continuous) response 1/(1 + j f/f_i) of axis `axis`.
    pub fn analog_response(&self, axis: usize, f_hz: f64) -> C64 {
        match self.corner_hz.get(axis) {
            Some(&fc) => C64::new(1.0, 0.0) / C64::new(1.0, f_hz / fc),
            None => C64::new(0.0, 0.0),
        }
    }

    /// The reading of the sensor at rest without noise: its static output
    /// (`static_m_s2`), unquantised, m/s².
    pub fn at_rest(&self) -> AccelReading {
        AccelReading {
            m_s2: self.offset,
            clipped: false,
        }
    }

    /// Read one sample given the true acceleration (x, y, z) in m/s² (the
    /// static part is added here). Allocation-free; non-finite inputs hold
    /// the previous state.
    #[inline(always)]
    pub fn sample(&mut self, a_true: [f64; 3]) -> AccelReading {
        // Noise first (x, y, z: the order of the draws), from the buffered
        // generator.
        let mut w = [0.0; 3];
        if self.noise_sigma > 0.0 {
            for wi in w.iter_mut() {
                *wi = self.noise_sigma * self.noise.sample();
            }
        }
        // Common case: finite inputs, no axis at the rails, quantiser step
        // in the fast range. The new states are computed first and kept only
        // if all three are within ±range (which implies finite inputs and
        // states): then nothing is held, reset or clipped, and the result is
        // the general path's bit for bit.
        let mut s = [0.0; 3];
        for i in 0..3 {
            let x = a_true[i] + self.offset[i] + w[i];
            s[i] = self.alpha[i] * self.state[i] + self.beta[i] * x;
        }
        let r = self.range;
        if self.quant_fast && s[0].abs() <= r && s[1].abs() <= r && s[2].abs() <= r {
            self.state = s;
            let (lsb, q) = (self.lsb, crate::round_half_away_small);
            return AccelReading {
                m_s2: [
                    q(s[0] / lsb) * lsb,
                    q(s[1] / lsb) * lsb,
                    q(s[2] / lsb) * lsb,
                ],
                clipped: false,
            };
        }
        self.sample_general(a_true, w)
    }

    /// [`Self::sample`] by the general path alone (the same noise draws):
    /// the reference its common-case path must equal bit for bit, for the
    /// equivalence harness (`tests/equivalence.rs`).
    #[doc(hidden)]
    pub fn sample_reference(&mut self, a_true: [f64; 3]) -> AccelReading {
        let mut w = [0.0; 3];
        if self.noise_sigma > 0.0 {
            for wi in w.iter_mut() {
                *wi = self.noise_sigma * self.noise.sample();
            }
        }
        self.sample_general(a_true, w)
    }

    /// Whether the common-case path applies to this configuration (a
    /// quantisation step in the fast range).
    #[doc(hidden)]
    pub fn has_fast_path(&self) -> bool {
        self.quant_fast
    }

    /// [`Self::sample`] outside the common case: non-finite inputs or
    /// states, clipping, no or a tiny quantisation step.
    #[cold]
    #[inline(never)]
    fn sample_general(&mut self, a_true: [f64; 3], w: [f64; 3]) -> AccelReading {
        let mut out = [0.0; 3];
        let mut clipped = false;
        for i in 0..3 {
            let a = a_true[i];
            if a.is_finite() {
                let x = a + self.offset[i] + w[i];
                self.state[i] = self.alpha[i] * self.state[i] + self.beta[i] * x;
            } else {
                self.nonfinite += 1;
            }
            if !self.state[i].is_finite() {
                self.state[i] = self.offset[i];
            }
            let mut y = self.state[i];
            if y > self.range {
                y = self.range;
                clipped = true;
            } else if y < -self.range {
                y = -self.range;
                clipped = true;
            }
            if self.lsb > 0.0 {
                y = crate::round_half_away(y / self.lsb) * self.lsb;
            }
            out[i] = y;
        }
        if clipped {
            self.clipped += 1;
        }
        AccelReading { m_s2: out, clipped }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RigConfig;

    fn quiet() -> AccelerometerConfig {
        AccelerometerConfig {
            noise_density_ug_per_rthz: 0.0,
            lsb_m_s2: 0.0,
            static_m_s2: [0.0; 3],
            ..RigConfig::default().accelerometer
        }
    }

    #[test]
    fn sine_gain_and_phase_match_the_exposed_response() {
        let fs = 1e4;
        let mut a = Accelerometer::new(&quiet(), fs).unwrap();
        for f in [50.0, 400.0, 1000.0] {
            a.reset();
            let n = 20_000;
            let mut acc = C64::new(0.0, 0.0);
            let mut ref_ = C64::new(0.0, 0.0);
            for k in 0..n {
                let ph = 2.0 * PI * f * k as f64 / fs;
                let r = a.sample([ph.sin(), 0.0, ph.cos()]);
                if k >= n / 2 {
                    let e = C64::from_polar(1.0, -ph);
                    acc += r.m_s2[0] * e;
                    ref_ += ph.sin() * e;
                }
            }
            let h = acc / ref_;
            let expect = a.response(0, f);
            assert!((h - expect).norm() < 1e-6, "{f} Hz: {h} vs {expect}");
        }
        // The discrete pole tracks the datasheet response within 3 % to 1 kHz.
        for f in [10.0, 100.0, 400.0, 1000.0] {
            for axis in 0..3 {
                let r = a.response(axis, f).norm() / a.analog_response(axis, f).norm();
                assert!((r - 1.0).abs() < 0.03, "axis {axis} {f} Hz: {r}");
            }
        }
        // x/y corner 400 Hz, z 300 Hz: −3 dB there.
        assert!((a.analog_response(0, 400.0).norm() - 0.5_f64.sqrt()).abs() < 1e-12);
        assert!((a.analog_response(2, 300.0).norm() - 0.5_f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn noise_density_in_band_is_the_datasheet_value() {
        let cfg = AccelerometerConfig {
            lsb_m_s2: 0.0,
            static_m_s2: [0.0; 3],
            ..RigConfig::default().accelerometer
        };
        let fs = 1e4;
        let mut a = Accelerometer::new(&cfg, fs).unwrap();
        let n = 400_000;
        let x: Vec<f64> = (0..n).map(|_| a.sample([0.0; 3]).m_s2[0]).collect();
        let spec = kilotouch_dsp::spectral::welch(
            &x,
            fs,
            &kilotouch_dsp::spectral::WelchConfig::new(4096),
        )
        .unwrap();
        let band: Vec<f64> = spec
            .f
            .iter()
            .zip(&spec.p)
            .filter(|(f, _)| **f > 10.0 && **f < 100.0)
            .map(|(_, p)| *p)
            .collect();
        let mean = band.iter().sum::<f64>() / band.len() as f64;
        let rho = 350e-6 * STANDARD_GRAVITY;
        // |H|² ≈ 0.98 at 100 Hz for a 400 Hz pole; average over the band ≈ 0.99.
        assert!(
            (mean / (rho * rho) - 1.0).abs() < 0.05,
            "{} vs {}",
            mean.sqrt(),
            rho
        );
        // Total variance = ρ²·(f_s/2)·Σ|h|² = ρ² (f_s/2)(1 − α)/(1 + α).
        let al = (-2.0 * PI * 400.0 / fs).exp();
        let var_expect = rho * rho * 0.5 * fs * (1.0 - al) / (1.0 + al);
        let var = x.iter().map(|v| v * v).sum::<f64>() / n as f64;
        assert!(
            (var / var_expect - 1.0).abs() < 0.03,
            "{var} vs {var_expect}"
        );
    }

    #[test]
    fn clipping_quantisation_offset_and_nan() {
        let cfg = RigConfig::default().accelerometer;
        let mut a = Accelerometer::new(&cfg, 1e4).unwrap();
        let g = STANDARD_GRAVITY;
        let mut r = AccelReading::default();
        for _ in 0..2000 {
            r = a.sample([10.0 * g, -10.0 * g, 0.0]);
        }
        assert!(r.clipped);
        let lsb = cfg.lsb_m_s2;
        assert!((r.m_s2[0] - 6.0 * g).abs() <= 0.5 * lsb + 1e-12);
        assert!((r.m_s2[1] + 6.0 * g).abs() <= 0.5 * lsb + 1e-12);
        // Gravity on z (within noise: σ_out ≈ 0.05 m/s²).
        assert!((r.m_s2[2] - g).abs() < 0.3);
        // Outputs are multiples of the LSB.
        for v in r.m_s2 {
            assert!(((v / lsb) - (v / lsb).round()).abs() < 1e-9);
        }
        for _ in 0..10 {
            let r = a.sample([f64::NAN, f64::INFINITY, f64::NEG_INFINITY]);
            assert!(r.m_s2.iter().all(|v| v.is_finite()));
        }
        assert!(a.nonfinite_inputs() >= 30);
    }

    #[test]
    fn seeded_noise_is_reproducible() {
        let cfg = RigConfig::default().accelerometer;
        let mut a = Accelerometer::new(&cfg, 1e4).unwrap();
        let mut b = Accelerometer::new(&cfg, 1e4).unwrap();
        for _ in 0..100 {
            assert_eq!(a.sample([0.1, 0.2, 0.3]), b.sample([0.1, 0.2, 0.3]));
        }
        assert!(
            Accelerometer::new(
                &AccelerometerConfig {
                    corner_hz: [6000.0, 1.0, 1.0],
                    ..cfg
                },
                1e4
            )
            .is_err()
        );
    }
}
