//! Step 6: verification with stepped sines through the full chain
//! (paper §3.4, Fig. 7).
//!
//! For each third-octave centre from `f_min_hz` to `f_max_hz` (IEC 61260-1
//! base-10 centres; 63 Hz–1 kHz by default), plus the bands below that lie
//! inside the low channel's flat band, a sine of amplitude A (haptic-signal
//! units) is passed through the designed chain ([`kilotouch_dsp::chain`]),
//! the two drives are played on the rig and, after the settling time, the
//! tip acceleration amplitude is measured over a whole number of cycles by a
//! single-bin DFT ([`kilotouch_dsp::excitation::sine_dft`]; exact for
//! coherent sampling), divided by |S(f)| of the sensor when configured. The
//! target is K_sys·A; each band's deviation is 20·log10(|a|/(K_sys·A)) dB
//! ([`kilotouch_dsp::thirdoctave::flatness`]). The same table is measured
//! with the crossover alone (constant gains, no C_H dynamics), and the
//! chain's group delay is reported.

use super::bands::bands;
use super::config::CalibrationConfig;
use super::crossover::CrossoverChoice;
use super::design::CompensatorDesign;
use super::error::{CalibrationError, Result};
use super::identify::LowChannelId;
use super::interface::CalibrationRig;
use super::measure::{RawRecord, run_both};
use super::prediction::chain_group_delay;
use super::progress::{Step, StepContext};
use kilotouch_dsp::chain::{Chain, ChainCoefficients};
use kilotouch_dsp::excitation::{SteppedSineConfig, sine_dft, stepped_sine};
use kilotouch_dsp::thirdoctave::flatness;
use serde::{Deserialize, Serialize};

/// One line of the verification table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VerificationBand {
    /// Nominal band label, e.g. "63".
    pub nominal: String,
    /// Exact third-octave centre, Hz.
    pub centre_hz: f64,
    /// Frequency played (whole cycles in the window), Hz.
    pub f_hz: f64,
    /// True for a band below `verify.f_min_hz` (added inside the low
    /// channel's flat band).
    pub extended: bool,
    /// Measured tip acceleration amplitude, m/s².
    pub magnitude_m_s2: f64,
    /// Deviation from the target, dB.
    pub db: f64,
    /// |db| ≤ tolerance.
    pub within: bool,
    /// Deviation with the crossover alone (no compensation), dB.
    pub uncompensated_db: f64,
    /// Group delay of the compensated chain at `f_hz`, ms.
    pub group_delay_ms: f64,
    /// The rig saturated during this band (compensated run).
    pub saturated: bool,
}

/// Result of step 6.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Verification {
    /// The table, ascending in frequency.
    pub bands: Vec<VerificationBand>,
    /// Haptic test amplitude, units of the haptic signal.
    pub amplitude: f64,
    /// Target tip acceleration amplitude K_sys·A, m/s².
    pub target_m_s2: f64,
    /// Tolerance, dB.
    pub tolerance_db: f64,
    /// max |db| over the bands.
    pub max_abs_dev_db: f64,
    /// Peak-to-peak spread of db, dB.
    pub spread_db: f64,
    /// max |uncompensated_db| over the bands.
    pub uncompensated_max_abs_dev_db: f64,
    /// Group delay of the compensated chain at low frequency (f → 0), ms.
    pub group_delay_ms: f64,
    /// Every band within tolerance and none saturated.
    pub passed: bool,
    /// True when the sensor response was divided out.
    pub sensor_corrected: bool,
    /// Raw records (not stored in the calibration file).
    #[serde(skip)]
    pub raw: Vec<RawRecord>,
}

/// Which outputs of the chain drive the rig in a band measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Paths {
    /// Both channels (the verification).
    Both,
    /// The low path alone (Haptuator silent).
    LowOnly,
    /// The high path alone (Pantograph silent).
    HighOnly,
}

/// Measure the tip acceleration amplitude of a sine of `f` through
/// `coeffs`: returns (played frequency, amplitude m/s², record).
fn measure_band<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    coeffs: &ChainCoefficients,
    f: f64,
    cfg: &CalibrationConfig,
    label: String,
) -> Result<(f64, f64, RawRecord)> {
    measure_band_paths(rig, coeffs, f, cfg, label, Paths::Both)
}

/// [`verify`]'s measurement of one band with only some of the chain's
/// outputs played (the others silent): (played frequency, tip acceleration
/// amplitude m/s² as the sensor reported it, record). Divide by
/// [`sensor_gain`] for the tip's own acceleration.
///
/// # Errors
/// Excitation and rig errors.
pub fn measure_band_paths<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    coeffs: &ChainCoefficients,
    f: f64,
    cfg: &CalibrationConfig,
    label: String,
    paths: Paths,
) -> Result<(f64, f64, RawRecord)> {
    let fs = rig.sample_rate();
    let v = &cfg.verify;
    let sc = SteppedSineConfig {
        frequencies: vec![f],
        amplitude: v.amplitude,
        settle_time: v.settle_s,
        measure_time: v.measure_s,
    };
    let (x, steps) = stepped_sine(&sc, fs).map_err(|e| CalibrationError::dsp("stepped sine", e))?;
    let step = steps
        .first()
        .ok_or_else(|| CalibrationError::measurement(Step::Verify, "empty stepped sine"))?;
    let mut chain = Chain::new(coeffs);
    let mut low = vec![0.0; x.len()];
    let mut high = vec![0.0; x.len()];
    chain.process_block(&x, &mut low, &mut high);
    match paths {
        Paths::Both => {}
        Paths::LowOnly => high.fill(0.0),
        Paths::HighOnly => low.fill(0.0),
    }
    let rec = run_both(rig, &low, &high, label)?;
    let (amp, _) = sine_dft(&rec.accel[step.measure_range()], step.frequency, fs)
        .map_err(|e| CalibrationError::dsp("sine amplitude", e))?;
    Ok((step.frequency, amp, rec))
}

/// |S(f)| of the rig's sensor when known, finite and non-zero.
pub fn sensor_gain<R: CalibrationRig + ?Sized>(rig: &R, f: f64) -> Option<f64> {
    rig.sensor_response(f)
        .filter(|s| s.is_finite() && s.norm() > 0.0)
        .map(|s| s.norm())
}

/// Step 6 (see the module documentation).
pub fn verify<R: CalibrationRig + ?Sized>(
    rig: &mut R,
    design: &CompensatorDesign,
    xo: &CrossoverChoice,
    low: &LowChannelId,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<Verification> {
    let step = Step::Verify;
    ctx.begin(step, "stepped sines through the chain")?;
    let comp = design.chain_coefficients(xo)?;
    let uncomp = design.uncompensated_coefficients(xo)?;
    let list = bands(low, cfg)?;
    // Correct only when the sensor response is known at every band.
    let corrected = cfg.correct_sensor
        && list
            .iter()
            .all(|(b, _)| sensor_gain(rig, b.centre_hz).is_some());
    let total = 2.0 * list.len() as f64;
    let mut raw = Vec::with_capacity(2 * list.len());
    let mut rows = Vec::with_capacity(list.len());
    let (mut comp_pairs, mut uncomp_pairs) = (Vec::new(), Vec::new());
    for (k, (band, extended)) in list.iter().enumerate() {
        let mut amps = [0.0; 2];
        let mut played = band.centre_hz;
        let mut saturated = false;
        for (j, (coeffs, what)) in [(&comp, "compensated"), (&uncomp, "crossover alone")]
            .into_iter()
            .enumerate()
        {
            ctx.check_cancel(step)?;
            let (f, a, rec) = measure_band(
                rig,
                coeffs,
                band.centre_hz,
                cfg,
                format!("verify {} Hz {what}", band.nominal),
            )?;
            let s = if corrected {
                sensor_gain(rig, f).unwrap_or(1.0)
            } else {
                1.0
            };
            amps[j] = a / s;
            played = f;
            if j == 0 {
                saturated = rec.stats.saturated();
            }
            raw.push(rec);
            ctx.report(
                step,
                (2 * k + j + 1) as f64 / total,
                &format!("{} Hz ({what}): {:.4} m/s²", band.nominal, amps[j]),
            );
        }
        comp_pairs.push((played, amps[0]));
        uncomp_pairs.push((played, amps[1]));
        rows.push(VerificationBand {
            nominal: band.nominal.clone(),
            centre_hz: band.centre_hz,
            f_hz: played,
            extended: *extended,
            magnitude_m_s2: amps[0],
            db: 0.0,
            within: false,
            uncompensated_db: 0.0,
            group_delay_ms: 1e3 * chain_group_delay(&comp, played),
            saturated,
        });
    }
    let target = design.k_sys * cfg.verify.amplitude;
    let tol = cfg.verify.tolerance_db;
    let err = |e| CalibrationError::dsp("flatness", e);
    let fc = flatness(&comp_pairs, target, tol).map_err(err)?;
    let fu = flatness(&uncomp_pairs, target, tol).map_err(err)?;
    for ((row, c), u) in rows.iter_mut().zip(&fc.bands).zip(&fu.bands) {
        row.db = c.db;
        row.within = c.within;
        row.uncompensated_db = u.db;
    }
    let passed = fc.passed && rows.iter().all(|r| !r.saturated);
    let out = Verification {
        amplitude: cfg.verify.amplitude,
        target_m_s2: target,
        tolerance_db: tol,
        max_abs_dev_db: fc.max_abs_dev_db,
        spread_db: fc.spread_db,
        uncompensated_max_abs_dev_db: fu.max_abs_dev_db,
        group_delay_ms: 1e3 * chain_group_delay(&comp, 0.0),
        passed,
        sensor_corrected: corrected,
        bands: rows,
        raw,
    };
    ctx.report(
        step,
        1.0,
        &format!(
            "max deviation {:.2} dB ({}), crossover alone {:.2} dB",
            out.max_abs_dev_db,
            if out.passed { "pass" } else { "FAIL" },
            out.uncompensated_max_abs_dev_db
        ),
    );
    Ok(out)
}
