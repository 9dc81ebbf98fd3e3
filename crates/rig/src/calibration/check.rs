//! Step 1: check — the rig's own self-test, then two measurements of ours:
//! a quiet record (both drives zero: offset and noise of the sensor, no
//! clipping at rest) and a short MLS burst on each channel, whose response
//! must stand out of the noise by `min_snr_db` (the channel is connected,
//! the sensor is alive and not stuck).

use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::interface::{CalibrationRig, Channel, CheckReport, channel_name};
use super::measure::{RawRecord, run_channel};
use super::progress::{Step, StepContext};
use kilotouch_dsp::excitation::mls_signal;
use serde::{Deserialize, Serialize};

/// Ceiling of the reported signal-to-noise ratios (a noiseless simulation
/// would give +∞), dB.
pub const MAX_SNR_DB: f64 = 300.0;

/// Result of step 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckResult {
    /// The rig's self-test.
    pub rig: CheckReport,
    /// Mean acceleration at rest, m/s².
    pub offset_m_s2: f64,
    /// RMS acceleration at rest (offset removed), m/s².
    pub noise_rms_m_s2: f64,
    /// RMS response to the low-channel burst over the quiet RMS, dB.
    pub low_snr_db: f64,
    /// RMS response to the high-channel burst over the quiet RMS, dB.
    pub high_snr_db: f64,
    /// Raw records (not stored in the calibration file).
    #[serde(skip)]
    pub raw: Vec<RawRecord>,
}

fn mean_rms(x: &[f64]) -> (f64, f64) {
    let n = x.len().max(1) as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

fn snr_db(signal_rms: f64, noise_rms: f64) -> f64 {
    if noise_rms > 0.0 {
        (20.0 * (signal_rms / noise_rms).log10()).clamp(-MAX_SNR_DB, MAX_SNR_DB)
    } else if signal_rms > 0.0 {
        MAX_SNR_DB
    } else {
        -MAX_SNR_DB
    }
}

/// Step 1 (see the module documentation). Errors with
/// [`CalibrationError::CheckFailed`] listing every failed item.
pub fn check<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<CheckResult> {
    let step = Step::Check;
    ctx.begin(step, "rig self-test")?;
    let report = rig.check()?;
    let mut problems = Vec::new();
    if !report.ok() {
        for (ok, what) in [
            (report.sensor_alive, "accelerometer not alive"),
            (report.sensor_in_range, "accelerometer out of range at rest"),
            (report.responding, "rig not responding"),
            (report.safety_armed, "safety limits not armed"),
        ] {
            if !ok {
                problems.push(what.to_owned());
            }
        }
        problems.extend(report.messages.iter().cloned());
        return Err(CalibrationError::CheckFailed { problems });
    }
    let fs = rig.sample_rate();
    let limits = rig.limits();
    let mut raw = Vec::new();

    ctx.check_cancel(step)?;
    let n_quiet = ((cfg.check.quiet_s * fs).ceil() as usize).max(16);
    let quiet = run_channel(rig, Channel::Low, &vec![0.0; n_quiet], "check quiet".into())?;
    let (offset, noise) = mean_rms(&quiet.accel);
    if quiet.stats.accel_clipped > 0 {
        problems.push(format!(
            "accelerometer clipped at rest ({} of {n_quiet} samples, mean {offset:.3} m/s²)",
            quiet.stats.accel_clipped
        ));
    }
    raw.push(quiet);
    ctx.report(
        step,
        1.0 / 3.0,
        &format!("noise at rest {noise:.3e} m/s² RMS"),
    );

    let burst = mls_signal(cfg.check.burst_order, 1.0, 1, 1)
        .map_err(|e| CalibrationError::dsp("check burst", e))?;
    let mut snr = [0.0; 2];
    for (k, channel) in [Channel::Low, Channel::High].into_iter().enumerate() {
        ctx.check_cancel(step)?;
        let a = cfg.check.burst_fraction * limits.of(channel);
        let drive: Vec<f64> = burst.iter().map(|v| v * a).collect();
        let rec = run_channel(
            rig,
            channel,
            &drive,
            format!("check {} burst", channel_name(channel)),
        )?;
        let (_, rms) = mean_rms(&rec.accel);
        snr[k] = snr_db(rms, noise);
        if snr[k] < cfg.check.min_snr_db {
            problems.push(format!(
                "{} channel not responding: burst of amplitude {a:.3} gave {rms:.3e} m/s² RMS, \
                 {:.1} dB above the noise at rest (need {} dB)",
                channel_name(channel),
                snr[k],
                cfg.check.min_snr_db
            ));
        }
        raw.push(rec);
        ctx.report(
            step,
            (2.0 + k as f64) / 3.0,
            &format!(
                "{} channel responds {:.1} dB above noise",
                channel_name(channel),
                snr[k]
            ),
        );
    }
    if !problems.is_empty() {
        return Err(CalibrationError::CheckFailed { problems });
    }
    Ok(CheckResult {
        rig: report,
        offset_m_s2: offset,
        noise_rms_m_s2: noise,
        low_snr_db: snr[0],
        high_snr_db: snr[1],
        raw,
    })
}
