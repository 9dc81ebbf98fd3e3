//! Stepped sines: one sine per frequency, with a settle window and a
//! measurement window of whole cycles, and the per-step schedule that says
//! where each window lies.

use super::buffer::alloc_len;
use crate::error::{check_fs, check_non_negative, check_positive};
use crate::{DspError, Result};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::ops::Range;

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
    check_positive("amplitude", cfg.amplitude)?;
    check_non_negative("settle_time", cfg.settle_time)?;
    check_positive("measure_time", cfg.measure_time)?;
    let limit = 1e15; // samples; keeps all integer arithmetic exact in f64
    let settle = (cfg.settle_time * fs).ceil();
    if settle > limit {
        return Err(DspError::param("settle_time", cfg.settle_time, "too long"));
    }
    let settle = settle as u64;
    let mut steps = Vec::with_capacity(cfg.frequencies.len());
    let mut pos: u64 = 0;
    for &f in &cfg.frequencies {
        if !(f.is_finite() && f > 0.0 && f < fs / 2.0) {
            return Err(DspError::param(
                "frequencies",
                f,
                "each must be in (0, fs/2)",
            ));
        }
        let k = (f * cfg.measure_time).ceil().max(1.0);
        let m = (k * fs / f).round();
        if m > limit || k > limit {
            return Err(DspError::param(
                "measure_time",
                cfg.measure_time,
                "too long",
            ));
        }
        let k = k as u64;
        let m = (m as u64).max(2 * k + 1);
        let start = pos;
        let measure_start = start + settle;
        let end = measure_start + m;
        let to_usize = |v: u64| {
            usize::try_from(v)
                .map_err(|_| DspError::param("measure_time", cfg.measure_time, "too long"))
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
            return Err(DspError::param(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::excitation::sine_estimate::tests::wrap;
    use crate::excitation::{sine_dft, sine_fit};

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
    fn stepped_sine_rejects_frequencies_at_or_above_nyquist() {
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
