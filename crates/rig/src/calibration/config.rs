//! Settings of the calibration procedure. Every field has a default
//! ([`CalibrationConfig::default`]); the whole struct is stored in the
//! calibration file so that a calibration can be repeated exactly.
//!
//! Amplitudes are fractions of the rig's limits ([`super::ActuatorLimits`]),
//! so one configuration suits rigs of different strength.

use super::error::{CalibrationError, Result};
use serde::{Deserialize, Serialize};

/// All settings of the procedure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationConfig {
    /// Excitation of the low channel (step 2).
    pub low: ExcitationConfig,
    /// Excitation of the high channel (step 3).
    pub high: ExcitationConfig,
    /// Welch estimation and band detection (steps 2–3).
    pub analysis: AnalysisConfig,
    /// Fit of Ĝ_H (step 3).
    pub high_fit: HighFitConfig,
    /// Crossover selection (step 4).
    pub crossover: CrossoverConfig,
    /// Compensator design (step 5).
    pub design: DesignConfig,
    /// Verification (step 6).
    pub verify: VerifyConfig,
    /// Check (step 1).
    pub check: CheckConfig,
    /// Divide out the rig's known accelerometer response
    /// ([`super::CalibrationRig::sensor_response`]) so that flatness holds at
    /// the fingertip, not only at the sensor output.
    pub correct_sensor: bool,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self {
            low: ExcitationConfig {
                amplitude_fraction: 0.5,
                ..ExcitationConfig::default()
            },
            high: ExcitationConfig::default(),
            analysis: AnalysisConfig::default(),
            high_fit: HighFitConfig::default(),
            crossover: CrossoverConfig::default(),
            design: DesignConfig::default(),
            verify: VerifyConfig::default(),
            check: CheckConfig::default(),
            correct_sensor: true,
        }
    }
}

/// Maximum-length-sequence excitation of one channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExcitationConfig {
    /// MLS order n (period 2ⁿ − 1 chips).
    pub order: u32,
    /// Chip amplitude as a fraction of the channel's drive limit, in (0, 1].
    pub amplitude_fraction: f64,
    /// Samples per chip (zero-order hold; the spectrum has nulls at k·fs/hold).
    pub hold: u32,
    /// Periods analysed.
    pub periods: usize,
    /// Periods played first and discarded (transients die out).
    pub lead_in_periods: usize,
    /// How many times the amplitude may be reduced after a saturated run.
    pub max_backoffs: u32,
    /// Factor applied to the amplitude at each back-off, in (0, 1).
    pub backoff_factor: f64,
    /// Optional 2nd-order Butterworth high-pass (Hz) applied to the sequence
    /// before it is played (keeps a moving-magnet actuator inside its stroke
    /// while keeping the power where the channel works). The H1 estimate uses
    /// the signal actually played, so the filter does not bias it.
    pub highpass_hz: Option<f64>,
}

impl Default for ExcitationConfig {
    fn default() -> Self {
        Self {
            order: 13,
            amplitude_fraction: 1.0,
            hold: 1,
            periods: 4,
            lead_in_periods: 1,
            max_backoffs: 4,
            backoff_factor: 0.5,
            highpass_hz: None,
        }
    }
}

/// Spectral estimation and band detection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AnalysisConfig {
    /// Welch segment length (Hann, 50 % overlap): resolution fs/nperseg.
    pub nperseg: usize,
    /// Magnitude-squared coherence a bin needs to count as reliable.
    pub coherence_min: f64,
    /// Fractional-octave width of the smoothing applied before band detection
    /// (0 = none).
    pub smoothing_octaves: f64,
    /// Lowest frequency analysed, Hz.
    pub f_min_hz: f64,
    /// Highest frequency analysed, Hz.
    pub f_max_hz: f64,
    /// Half-width of the low channel's flat band around G0_L, dB.
    pub flat_tol_db: f64,
}

impl Default for AnalysisConfig {
    fn default() -> Self {
        Self {
            nperseg: 2048,
            coherence_min: 0.9,
            smoothing_octaves: 1.0 / 12.0,
            f_min_hz: 20.0,
            f_max_hz: 2000.0,
            flat_tol_db: 1.0,
        }
    }
}

/// Fit of the high channel Ĝ_H(s) = B(s)/A(s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HighFitConfig {
    /// Numerator order (paper eq. 2: 1).
    pub num_order: usize,
    /// Denominator order (paper eq. 2: 2).
    pub den_order: usize,
    /// Upper edge of the fitted band, Hz.
    pub fit_max_hz: f64,
    /// Never trust the estimate below this frequency (Hz), whatever the
    /// coherence says.
    pub min_reliable_hz: Option<f64>,
    /// The model must match the (smoothed) estimate within this over the
    /// reliable band, dB: the band's lower edge is raised until it does.
    pub model_tol_db: f64,
    /// When the model of the configured orders misfits, try orders raised by
    /// 1, 2, … up to this (numerator and denominator together) at each band
    /// edge before raising the edge.
    pub max_order_increase: usize,
    /// Numbers of zeros at s = 0 to impose, tried in this order for each
    /// order pair (an inertial actuator's acceleration response has a
    /// double zero at DC, below the band a fit sees; see
    /// `docs/theory/calibration.md`).
    pub origin_zeros: Vec<usize>,
}

impl Default for HighFitConfig {
    fn default() -> Self {
        Self {
            num_order: 1,
            den_order: 2,
            fit_max_hz: 1200.0,
            min_reliable_hz: None,
            model_tol_db: 0.5,
            max_order_increase: 3,
            origin_zeros: vec![0, 2],
        }
    }
}

/// Crossover selection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CrossoverConfig {
    /// Linkwitz–Riley order (2, 4 or 8; the paper uses 4).
    pub order: usize,
    /// Use this crossover frequency (Hz) instead of the automatic choice
    /// (`fc_hz` in files written before it was named `crossover_hz`).
    #[serde(alias = "fc_hz")]
    pub crossover_hz: Option<f64>,
    /// Largest predicted deviation accepted for the automatic choice, dB
    /// (see `docs/theory/calibration.md`).
    pub budget_db: f64,
    /// Never choose a crossover above this (Hz).
    pub max_hz: Option<f64>,
    /// Never choose a crossover below this (Hz).
    pub min_hz: f64,
}

impl Default for CrossoverConfig {
    fn default() -> Self {
        Self {
            order: 4,
            crossover_hz: None,
            budget_db: 0.5,
            max_hz: None,
            min_hz: 20.0,
        }
    }
}

/// Compensator design.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DesignConfig {
    /// Use this K_sys ((m/s²) per unit haptic signal) instead of the largest
    /// one the limits allow.
    pub k_sys: Option<f64>,
    /// Fraction of the largest admissible K_sys used, in (0, 1]: room for
    /// the peaks of broadband signals.
    pub headroom: f64,
    /// Corner of the band-limiting low-pass F(s) of C_H, Hz.
    pub band_limit_hz: f64,
    /// Damping ratio of F(s).
    pub band_limit_zeta: f64,
    /// Frequency (Hz) at which the bilinear transform of C_H is prewarped
    /// (exact there); `None` = `verify.f_max_hz`, where |C_H| is steepest.
    pub c_h_prewarp_hz: Option<f64>,
}

impl Default for DesignConfig {
    fn default() -> Self {
        Self {
            k_sys: None,
            headroom: 0.5,
            band_limit_hz: 2000.0,
            band_limit_zeta: std::f64::consts::FRAC_1_SQRT_2,
            c_h_prewarp_hz: None,
        }
    }
}

/// Stepped-sine verification.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VerifyConfig {
    /// Lowest third-octave centre of the main table, Hz (paper: 63).
    pub f_min_hz: f64,
    /// Highest third-octave centre, Hz (paper: 1000).
    pub f_max_hz: f64,
    /// Add bands below `f_min_hz` that lie inside the low channel's flat band.
    pub extend_below: bool,
    /// Never extend below this centre frequency, Hz.
    pub extend_min_hz: f64,
    /// Haptic test-signal amplitude, units of the haptic signal (full scale
    /// 1), in (0, 1].
    pub amplitude: f64,
    /// Settling time before each measurement window, s.
    pub settle_s: f64,
    /// Minimum measurement time per band (whole cycles), s.
    pub measure_s: f64,
    /// Pass when every band is within ± this, dB.
    pub tolerance_db: f64,
}

impl Default for VerifyConfig {
    fn default() -> Self {
        Self {
            f_min_hz: 63.0,
            f_max_hz: 1000.0,
            extend_below: true,
            extend_min_hz: 20.0,
            amplitude: 0.5,
            settle_s: 0.1,
            measure_s: 0.1,
            tolerance_db: 1.0,
        }
    }
}

/// The check step's own measurements.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CheckConfig {
    /// Quiet recording (both drives zero), s.
    pub quiet_s: f64,
    /// MLS order of the short response test of each channel.
    pub burst_order: u32,
    /// Response-test amplitude as a fraction of the channel limit.
    pub burst_fraction: f64,
    /// The response must exceed the quiet noise by this much, dB.
    pub min_snr_db: f64,
}

impl Default for CheckConfig {
    fn default() -> Self {
        Self {
            quiet_s: 0.1,
            burst_order: 10,
            burst_fraction: 0.2,
            min_snr_db: 10.0,
        }
    }
}

fn finite_pos(field: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(CalibrationError::config(field, v, "must be finite and > 0"))
    }
}

fn fraction(field: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 && v <= 1.0 {
        Ok(())
    } else {
        Err(CalibrationError::config(field, v, "must be in (0, 1]"))
    }
}

impl ExcitationConfig {
    fn validate(&self, name: &str, fs: f64) -> Result<()> {
        let f = |k: &str| format!("{name}.{k}");
        if !(4..=20).contains(&self.order) {
            return Err(CalibrationError::config(
                &f("order"),
                self.order,
                "must be in 4..=20",
            ));
        }
        fraction(&f("amplitude_fraction"), self.amplitude_fraction)?;
        if !(1..=64).contains(&self.hold) {
            return Err(CalibrationError::config(
                &f("hold"),
                self.hold,
                "must be in 1..=64",
            ));
        }
        if self.periods == 0 {
            return Err(CalibrationError::config(&f("periods"), 0, "must be ≥ 1"));
        }
        if !(self.backoff_factor.is_finite()
            && self.backoff_factor > 0.0
            && self.backoff_factor < 1.0)
        {
            return Err(CalibrationError::config(
                &f("backoff_factor"),
                self.backoff_factor,
                "must be in (0, 1)",
            ));
        }
        if let Some(hp) = self.highpass_hz
            && !(hp.is_finite() && hp > 0.0 && hp < fs / 2.0)
        {
            return Err(CalibrationError::config(
                &f("highpass_hz"),
                hp,
                "must be in (0, fs/2)",
            ));
        }
        Ok(())
    }
}

impl CalibrationConfig {
    /// Check every field for a rig running at `fs` Hz.
    pub fn validate(&self, fs: f64) -> Result<()> {
        finite_pos("fs", fs)?;
        self.low.validate("low", fs)?;
        self.high.validate("high", fs)?;
        self.validate_analysis(fs)?;
        self.validate_high_fit()?;
        self.validate_crossover(fs)?;
        self.validate_design(fs)?;
        self.validate_verify(fs)?;
        self.validate_check()
    }

    /// The `[analysis]` settings of the spectral analysis.
    fn validate_analysis(&self, fs: f64) -> Result<()> {
        let a = &self.analysis;
        if a.nperseg < 64 {
            return Err(CalibrationError::config(
                "analysis.nperseg",
                a.nperseg,
                "must be ≥ 64",
            ));
        }
        for (name, exc) in [("low", &self.low), ("high", &self.high)] {
            let period = ((1u64 << exc.order) - 1) * u64::from(exc.hold);
            if period * (exc.periods as u64) < a.nperseg as u64 * 4 {
                return Err(CalibrationError::config(
                    &format!("{name}.periods"),
                    exc.periods,
                    format!(
                        "the analysed record ({} samples) must hold at least 4 Welch segments of {}",
                        period * exc.periods as u64,
                        a.nperseg
                    ),
                ));
            }
        }
        if !(a.coherence_min.is_finite() && a.coherence_min > 0.0 && a.coherence_min < 1.0) {
            return Err(CalibrationError::config(
                "analysis.coherence_min",
                a.coherence_min,
                "must be in (0, 1)",
            ));
        }
        if !(a.smoothing_octaves.is_finite() && (0.0..=1.0).contains(&a.smoothing_octaves)) {
            return Err(CalibrationError::config(
                "analysis.smoothing_octaves",
                a.smoothing_octaves,
                "must be in [0, 1]",
            ));
        }
        finite_pos("analysis.f_min_hz", a.f_min_hz)?;
        if !(a.f_max_hz.is_finite() && a.f_max_hz > a.f_min_hz && a.f_max_hz < fs / 2.0) {
            return Err(CalibrationError::config(
                "analysis.f_max_hz",
                a.f_max_hz,
                "must be in (f_min_hz, fs/2)",
            ));
        }
        finite_pos("analysis.flat_tol_db", a.flat_tol_db)?;
        Ok(())
    }

    /// The `[high_fit]` settings of the high-channel fit.
    fn validate_high_fit(&self) -> Result<()> {
        let h = &self.high_fit;
        let a = &self.analysis;
        if h.den_order == 0 || h.num_order > h.den_order || h.den_order > 8 {
            return Err(CalibrationError::config(
                "high_fit.den_order",
                h.den_order,
                format!(
                    "need 1 ≤ den_order ≤ 8 and num_order ({}) ≤ den_order",
                    h.num_order
                ),
            ));
        }
        if h.den_order + h.max_order_increase > 8 {
            return Err(CalibrationError::config(
                "high_fit.max_order_increase",
                h.max_order_increase,
                "den_order + max_order_increase must be ≤ 8",
            ));
        }
        if h.den_order > h.num_order + 2 {
            return Err(CalibrationError::config(
                "high_fit.den_order",
                h.den_order,
                "relative degree above 2 cannot be inverted by a 2nd-order F(s)",
            ));
        }
        if !(h.fit_max_hz.is_finite() && h.fit_max_hz > a.f_min_hz && h.fit_max_hz <= a.f_max_hz) {
            return Err(CalibrationError::config(
                "high_fit.fit_max_hz",
                h.fit_max_hz,
                "must be in (analysis.f_min_hz, analysis.f_max_hz]",
            ));
        }
        if let Some(v) = h.min_reliable_hz {
            finite_pos("high_fit.min_reliable_hz", v)?;
        }
        finite_pos("high_fit.model_tol_db", h.model_tol_db)?;
        if h.origin_zeros.is_empty() || h.origin_zeros.iter().any(|&k| k > 4) {
            return Err(CalibrationError::config(
                "high_fit.origin_zeros",
                format!("{:?}", h.origin_zeros),
                "must be a non-empty list of counts in 0..=4",
            ));
        }
        Ok(())
    }

    /// The `[crossover]` settings of the crossover choice.
    fn validate_crossover(&self, fs: f64) -> Result<()> {
        let c = &self.crossover;
        if !matches!(c.order, 2 | 4 | 8) {
            return Err(CalibrationError::config(
                "crossover.order",
                c.order,
                "must be 2, 4 or 8",
            ));
        }
        if let Some(fc) = c.crossover_hz
            && !(fc.is_finite() && fc > 0.0 && fc < fs / 2.0)
        {
            return Err(CalibrationError::config(
                "crossover.crossover_hz",
                fc,
                "must be in (0, fs/2)",
            ));
        }
        finite_pos("crossover.budget_db", c.budget_db)?;
        finite_pos("crossover.min_hz", c.min_hz)?;
        if let Some(m) = c.max_hz
            && !(m.is_finite() && m > c.min_hz)
        {
            return Err(CalibrationError::config(
                "crossover.max_hz",
                m,
                "must be > crossover.min_hz",
            ));
        }
        Ok(())
    }

    /// The `[design]` settings of the compensator design.
    fn validate_design(&self, fs: f64) -> Result<()> {
        let d = &self.design;
        if let Some(k) = d.k_sys {
            finite_pos("design.k_sys", k)?;
        }
        fraction("design.headroom", d.headroom)?;
        if !(d.band_limit_hz.is_finite() && d.band_limit_hz > 0.0 && d.band_limit_hz < fs / 2.0) {
            return Err(CalibrationError::config(
                "design.band_limit_hz",
                d.band_limit_hz,
                "must be in (0, fs/2)",
            ));
        }
        finite_pos("design.band_limit_zeta", d.band_limit_zeta)?;
        if let Some(p) = d.c_h_prewarp_hz
            && !(p.is_finite() && p > 0.0 && p < fs / 2.0)
        {
            return Err(CalibrationError::config(
                "design.c_h_prewarp_hz",
                p,
                "must be in (0, fs/2)",
            ));
        }
        Ok(())
    }

    /// The `[verify]` settings of the verification.
    fn validate_verify(&self, fs: f64) -> Result<()> {
        let v = &self.verify;
        finite_pos("verify.f_min_hz", v.f_min_hz)?;
        if !(v.f_max_hz.is_finite() && v.f_max_hz >= v.f_min_hz && v.f_max_hz < fs / 2.0) {
            return Err(CalibrationError::config(
                "verify.f_max_hz",
                v.f_max_hz,
                "must be in [f_min_hz, fs/2)",
            ));
        }
        finite_pos("verify.extend_min_hz", v.extend_min_hz)?;
        fraction("verify.amplitude", v.amplitude)?;
        if !(v.settle_s.is_finite() && v.settle_s >= 0.0) {
            return Err(CalibrationError::config(
                "verify.settle_s",
                v.settle_s,
                "must be ≥ 0",
            ));
        }
        finite_pos("verify.measure_s", v.measure_s)?;
        finite_pos("verify.tolerance_db", v.tolerance_db)?;
        Ok(())
    }

    /// The `[check]` settings of the check.
    fn validate_check(&self) -> Result<()> {
        let k = &self.check;
        finite_pos("check.quiet_s", k.quiet_s)?;
        if !(6..=16).contains(&k.burst_order) {
            return Err(CalibrationError::config(
                "check.burst_order",
                k.burst_order,
                "must be in 6..=16",
            ));
        }
        fraction("check.burst_fraction", k.burst_fraction)?;
        if !k.min_snr_db.is_finite() {
            return Err(CalibrationError::config(
                "check.min_snr_db",
                k.min_snr_db,
                "must be finite",
            ));
        }
        Ok(())
    }
}
