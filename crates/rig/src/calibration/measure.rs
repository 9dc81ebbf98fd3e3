//! Running excitations on the rig and turning the records into
//! sensor-corrected frequency-response estimates (steps 2 and 3).
//!
//! One measurement plays `lead_in_periods + periods` periods of a ±A
//! maximum-length sequence on one channel (the other channel's drive is
//! zero), discards the lead-in and estimates, with Welch averaging (Hann,
//! 50 % overlap, [`kilotouch_dsp::spectral::frf`]),
//!
//! ```text
//! H1(f) = Pxy(f)/Pxx(f),   γ²(f) = |Pxy|²/(Pxx·Pyy)
//! ```
//!
//! (Bendat & Piersol, *Random Data*, ch. 9), x = drive actually played,
//! y = recorded acceleration. If the run saturated (accelerometer clipping,
//! Haptuator end stops, clamped drive) the amplitude is multiplied by the
//! back-off factor and the run repeated, up to `max_backoffs` times. Finally
//! the known sensor response S(f) is divided out: H_tip = H1/S, γ² unchanged.

use super::config::{CalibrationConfig, ExcitationConfig};
use super::error::{CalibrationError, Result};
use super::interface::{CalibrationRig, Channel, RunStats, channel_name};
use super::progress::{Step, StepContext};
use kilotouch_dsp::C64;
use kilotouch_dsp::design::{self, FilterKind, Prewarp};
use kilotouch_dsp::excitation::mls_signal;
use kilotouch_dsp::filter::Sos;
use kilotouch_dsp::spectral::{WelchConfig, frf};
use serde::{Deserialize, Serialize};

/// A recorded run, kept so that every step's raw data can be inspected or
/// re-analysed.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RawRecord {
    /// What the run was, e.g. `identify-high run 2`.
    pub label: String,
    /// Sample rate, Hz.
    pub fs: f64,
    /// Pantograph drive played, N.
    pub low_drive: Vec<f64>,
    /// Haptuator drive played.
    pub high_drive: Vec<f64>,
    /// Acceleration recorded, m/s² (as the sensor reported it).
    pub accel: Vec<f64>,
    /// The rig's saturation counts.
    pub stats: RunStats,
}

/// Frequency-response estimate of one channel: fingertip acceleration per
/// unit drive ((m/s²)/N for the Pantograph), with coherence.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ChannelFrf {
    /// Bin frequencies, Hz (DC excluded).
    pub f_hz: Vec<f64>,
    /// H1 estimate, sensor response divided out when `sensor_corrected`.
    pub h: Vec<C64>,
    /// Magnitude-squared coherence γ² per bin.
    pub coherence: Vec<f64>,
    /// Welch segments averaged.
    pub n_segments: usize,
    /// True when the rig's sensor response was divided out.
    pub sensor_corrected: bool,
    /// Sample rate of the record, Hz.
    pub fs: f64,
}

impl ChannelFrf {
    /// Indices of the bins with `lo ≤ f ≤ hi`.
    pub fn range(&self, lo: f64, hi: f64) -> std::ops::Range<usize> {
        let a = self.f_hz.partition_point(|&f| f < lo);
        let b = self.f_hz.partition_point(|&f| f <= hi);
        a..b.max(a)
    }

    /// The estimate with a delay of `tau_s` seconds removed:
    /// H(f)·e^{+j2πfτ} (a negative τ removes an advance).
    pub fn without_delay(&self, tau_s: f64) -> ChannelFrf {
        let mut out = self.clone();
        for (h, &f) in out.h.iter_mut().zip(&self.f_hz) {
            *h *= C64::from_polar(1.0, 2.0 * std::f64::consts::PI * f * tau_s);
        }
        out
    }

    /// Complex response at `f_hz` by linear interpolation of real and
    /// imaginary parts between the neighbouring bins (clamped at the ends);
    /// zero for an empty estimate.
    pub fn at(&self, f_hz: f64) -> C64 {
        let n = self.f_hz.len();
        if n == 0 {
            return C64::new(0.0, 0.0);
        }
        let i = self.f_hz.partition_point(|&f| f < f_hz);
        if i == 0 {
            return self.h[0];
        }
        if i >= n {
            return self.h[n - 1];
        }
        let (f0, f1) = (self.f_hz[i - 1], self.f_hz[i]);
        let t = (f_hz - f0) / (f1 - f0);
        self.h[i - 1] * (1.0 - t) + self.h[i] * t
    }
}

/// One attempt of a measurement: amplitude played and what the rig saw.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RunAttempt {
    /// Chip amplitude (N for the Pantograph, drive unit for the Haptuator).
    pub amplitude: f64,
    /// Saturation counts of the run.
    pub stats: RunStats,
}

/// How a channel was excited.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ExcitationSummary {
    /// Amplitude of the run that was analysed.
    pub amplitude: f64,
    /// Every attempt, in order (back-offs after saturated runs).
    pub attempts: Vec<RunAttempt>,
    /// True when even the last attempt saturated.
    pub saturated: bool,
}

/// Result of [`measure_channel`].
#[derive(Debug, Clone)]
pub struct ChannelMeasurement {
    /// How the channel was excited.
    pub excitation: ExcitationSummary,
    /// Sensor-corrected H1 and coherence.
    pub frf: ChannelFrf,
    /// Raw records of every attempt.
    pub raw: Vec<RawRecord>,
}

/// Unit-amplitude excitation of `exc` (optionally high-passed and then
/// rescaled to peak 1) and the number of lead-in samples.
fn excitation_signal(exc: &ExcitationConfig, fs: f64) -> Result<(Vec<f64>, usize)> {
    let n_periods = exc.lead_in_periods + exc.periods;
    let mut x = mls_signal(exc.order, 1.0, exc.hold, n_periods)
        .map_err(|e| CalibrationError::dsp("MLS excitation", e))?;
    if let Some(hp) = exc.highpass_hz {
        let sections = design::butter(2, hp, fs, FilterKind::Highpass, Prewarp::AtCutoff)
            .map_err(|e| CalibrationError::dsp("excitation high-pass", e))?;
        let mut sos =
            Sos::new(sections).map_err(|e| CalibrationError::dsp("excitation high-pass", e))?;
        sos.process_in_place(&mut x);
        let peak = x.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        if !(peak.is_finite() && peak > 0.0) {
            return Err(CalibrationError::config(
                "highpass_hz",
                hp,
                "the filtered excitation vanished",
            ));
        }
        x.iter_mut().for_each(|v| *v /= peak);
    }
    let lead = x.len() / n_periods * exc.lead_in_periods;
    Ok((x, lead))
}

/// Run `rig` once with `drive` on `channel` (zero on the other) and return
/// the recorded acceleration and the rig's statistics. Non-finite
/// acceleration is an error.
pub(crate) fn run_channel<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    channel: Channel,
    drive: &[f64],
    label: String,
) -> Result<RawRecord> {
    let zeros = vec![0.0; drive.len()];
    let (low, high) = match channel {
        Channel::Low => (drive, zeros.as_slice()),
        Channel::High => (zeros.as_slice(), drive),
    };
    run_both(rig, low, high, label)
}

/// Run `rig` with both drives and keep the record.
pub(crate) fn run_both<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    low: &[f64],
    high: &[f64],
    label: String,
) -> Result<RawRecord> {
    let mut accel = vec![0.0; low.len()];
    let stats = rig.run(low, high, &mut accel)?;
    if let Some(i) = accel.iter().position(|v| !v.is_finite()) {
        return Err(CalibrationError::Rig(format!(
            "{label}: the rig returned a non-finite acceleration at sample {i}"
        )));
    }
    Ok(RawRecord {
        label,
        fs: rig.sample_rate(),
        low_drive: low.to_vec(),
        high_drive: high.to_vec(),
        accel,
        stats,
    })
}

/// Excite `channel` with the MLS of `exc`, backing off after saturated runs,
/// and estimate its sensor-corrected FRF (see the module documentation).
pub fn measure_channel<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    channel: Channel,
    cfg: &CalibrationConfig,
    step: Step,
    ctx: &mut StepContext<'_>,
) -> Result<ChannelMeasurement> {
    let exc = match channel {
        Channel::Low => &cfg.low,
        Channel::High => &cfg.high,
    };
    let fs = rig.sample_rate();
    let limit = rig.limits().of(channel);
    if !(limit.is_finite() && limit > 0.0) {
        return Err(CalibrationError::Rig(format!(
            "{} channel drive limit {limit} is not finite and > 0",
            channel_name(channel)
        )));
    }
    let (unit, lead) = excitation_signal(exc, fs)?;
    let mut amplitude = exc.amplitude_fraction * limit;
    let mut attempts = Vec::new();
    let mut raw = Vec::new();
    let total = exc.max_backoffs as f64 + 2.0;
    loop {
        ctx.check_cancel(step)?;
        let drive: Vec<f64> = unit.iter().map(|v| v * amplitude).collect();
        let n = attempts.len() + 1;
        let rec = run_channel(rig, channel, &drive, format!("{} run {n}", step.name()))?;
        let stats = rec.stats;
        attempts.push(RunAttempt { amplitude, stats });
        raw.push(rec);
        let saturated = stats.saturated();
        ctx.report(
            step,
            n as f64 / total,
            &format!(
                "{} channel: run {n}, amplitude {amplitude:.4}{}",
                channel_name(channel),
                if saturated { " — saturated" } else { "" }
            ),
        );
        if !saturated || attempts.len() > exc.max_backoffs as usize {
            break;
        }
        amplitude *= exc.backoff_factor;
    }
    let saturated = attempts.last().is_some_and(|a| a.stats.saturated());
    let last = raw
        .last()
        .ok_or_else(|| CalibrationError::Rig("no run recorded".into()))?;
    let x = &last.low_drive[..];
    let x = match channel {
        Channel::Low => x,
        Channel::High => &last.high_drive[..],
    };
    let frf = estimate_frf(&x[lead..], &last.accel[lead..], fs, rig, cfg)?;
    ctx.report(step, (total - 1.0) / total, "spectral estimate done");
    Ok(ChannelMeasurement {
        excitation: ExcitationSummary {
            amplitude,
            attempts,
            saturated,
        },
        frf,
        raw,
    })
}

/// Welch H1 and γ² of drive `x` → acceleration `y`, DC dropped, sensor
/// response divided out when configured and known.
pub(crate) fn estimate_frf<R: CalibrationRig + ?Sized>(
    x: &[f64],
    y: &[f64],
    fs: f64,
    rig: &R,
    cfg: &CalibrationConfig,
) -> Result<ChannelFrf> {
    let welch = WelchConfig::new(cfg.analysis.nperseg);
    let est = frf(x, y, fs, &welch).map_err(|e| CalibrationError::dsp("H1 estimate", e))?;
    let bins = || est.f.iter().zip(&est.h1).zip(&est.coherence).skip(1);
    // Correct only when the response is known (finite, non-zero) at every
    // bin: a half-corrected estimate would be worse than none.
    let sensor: Option<Vec<C64>> = if cfg.correct_sensor {
        bins()
            .map(|((&f, _), _)| {
                rig.sensor_response(f)
                    .filter(|s| s.is_finite() && s.norm() > 0.0)
            })
            .collect()
    } else {
        None
    };
    let mut out = ChannelFrf {
        fs,
        n_segments: est.n_segments,
        sensor_corrected: sensor.is_some(),
        ..ChannelFrf::default()
    };
    for (i, ((&f, &h), &c)) in bins().enumerate() {
        out.f_hz.push(f);
        out.h.push(sensor.as_ref().map_or(h, |s| h / s[i]));
        out.coherence.push(c.clamp(0.0, 1.0));
    }
    Ok(out)
}

/// [`smooth_octave`] of a complex response, real and imaginary parts apart.
pub fn smooth_octave_complex(f_hz: &[f64], v: &[C64], width_octaves: f64) -> Vec<C64> {
    let part = |g: fn(&C64) -> f64| {
        smooth_octave(f_hz, &v.iter().map(g).collect::<Vec<_>>(), width_octaves)
    };
    let (re, im) = (part(|z| z.re), part(|z| z.im));
    re.into_iter()
        .zip(im)
        .map(|(r, i)| C64::new(r, i))
        .collect()
}

/// Fractional-octave moving average: value i is the mean of the values whose
/// frequency lies within [f_i·2^(−w/2), f_i·2^(w/2)] (`f_hz` ascending, > 0).
/// `width_octaves` = 0 returns the input.
pub fn smooth_octave(f_hz: &[f64], v: &[f64], width_octaves: f64) -> Vec<f64> {
    if width_octaves <= 0.0 || v.is_empty() {
        return v.to_vec();
    }
    let r = 2f64.powf(width_octaves / 2.0);
    let mut prefix = Vec::with_capacity(v.len() + 1);
    prefix.push(0.0);
    for x in v {
        let last = prefix.last().copied().unwrap_or(0.0);
        prefix.push(last + x);
    }
    let (mut lo, mut hi) = (0usize, 0usize);
    f_hz.iter()
        .map(|&f| {
            while f_hz[lo] < f / r {
                lo += 1;
            }
            while hi < f_hz.len() && f_hz[hi] <= f * r {
                hi += 1;
            }
            (prefix[hi] - prefix[lo]) / (hi - lo) as f64
        })
        .collect()
}

/// Smoothed magnitude (dB) and coherence of `frf`.
pub(crate) fn smoothed(frf: &ChannelFrf, width_octaves: f64) -> (Vec<f64>, Vec<f64>) {
    let db: Vec<f64> = frf
        .h
        .iter()
        .map(|h| 20.0 * h.norm().max(1e-300).log10())
        .collect();
    (
        smooth_octave(&frf.f_hz, &db, width_octaves),
        smooth_octave(&frf.f_hz, &frf.coherence, width_octaves),
    )
}
