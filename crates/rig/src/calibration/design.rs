//! Step 5: compensator design (paper §3.3) and the overall gain K_sys.
//!
//! * C_L = K_sys/G0_L (a gain), C_H(s) = K_sys·F(s)/Ĝ_H(s) with
//!   F(s) = ω_f²/(s² + 2ζω_f s + ω_f²) ([`kilotouch_dsp::compensator`]),
//!   digitised by the bilinear transform prewarped at `c_h_prewarp_hz`, and
//!   the Linkwitz–Riley crossover at f_c ([`kilotouch_dsp::chain`]).
//! * **K_sys** is the overall gain of the haptic chain: fingertip
//!   acceleration (m/s²) per unit of haptic signal (the signal's full scale
//!   is ±1), so the target response is |a_tip/u| = K_sys at every
//!   frequency. It is the largest value for which a full-scale sine at any
//!   frequency keeps both drives within the actuator limits (and the
//!   demanded acceleration within the accelerometer range), times the
//!   `headroom` factor:
//!
//!   ```text
//!   K_max = min( F_max / max_f |L(f)/G0_L|,
//!                D_max / max_f |H(f)·F(f)/Ĝ_H(f)|,
//!                a_range )
//!   K_sys = headroom · K_max
//!   ```
//!
//!   (maxima over a 1/96-octave grid from 0.1 Hz to Nyquist of the digital
//!   paths with K_sys = 1).

use super::config::CalibrationConfig;
use super::crossover::CrossoverChoice;
use super::error::{CalibrationError, Result};
use super::identify::{HighChannelId, LowChannelId};
use super::interface::ActuatorLimits;
pub use super::prediction::{chain_group_delay, predicted_max_abs_dev_db, unit_chain};
use super::progress::{Step, StepContext};
use kilotouch_dsp::Tf;
use kilotouch_dsp::chain::{ChainCoefficients, ChainDesign};
use kilotouch_dsp::compensator::{self, HighCompensatorConfig};
use kilotouch_dsp::crossover::LinkwitzRiley;
use kilotouch_dsp::design::Prewarp;
use serde::{Deserialize, Serialize};

/// Result of step 5: with the crossover of step 4 ([`CrossoverChoice`],
/// which holds its frequency and order), everything needed to build the
/// chain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompensatorDesign {
    /// Sample rate, Hz.
    pub fs: f64,
    /// Overall gain, (m/s²) per unit haptic signal.
    pub k_sys: f64,
    /// Largest admissible K_sys (before headroom), (m/s²) per unit.
    pub k_sys_max: f64,
    /// Which limit set `k_sys_max` ("Pantograph force", "Haptuator drive",
    /// "accelerometer range"), or "configuration" when K_sys was given.
    pub k_sys_limited_by: String,
    /// Low-channel static gain G0_L over the flat band below the crossover
    /// ([`CrossoverChoice::g0_l`]), (m/s²)/N.
    pub g0_l: f64,
    /// High-channel model Ĝ_H(s).
    pub g_h: Tf,
    /// C_L = K_sys/G0_L, N per unit haptic signal.
    pub c_l: f64,
    /// C_H(s) = K_sys·F(s)/Ĝ_H(s), drive units per unit haptic signal.
    pub c_h: Tf,
    /// Corner of F(s), Hz.
    pub band_limit_hz: f64,
    /// Damping ratio of F(s).
    pub band_limit_zeta: f64,
    /// Prewarping frequency of C_H's bilinear transform, Hz.
    pub c_h_prewarp_hz: f64,
    /// Largest Pantograph force per unit haptic signal over frequency, N.
    pub low_drive_per_unit: f64,
    /// Largest Haptuator drive per unit haptic signal over frequency.
    pub high_drive_per_unit: f64,
    /// Deviation from K_sys predicted from the measured channel responses
    /// at the verification frequencies, max |dB| (a diagnostic).
    pub predicted_max_abs_dev_db: f64,
}

impl CompensatorDesign {
    /// The dsp chain design (the crossover `xo` + C_L + C_H).
    pub fn chain_design(&self, xo: &CrossoverChoice) -> ChainDesign {
        ChainDesign {
            fs: self.fs,
            crossover_order: xo.order,
            crossover_hz: xo.crossover_hz,
            k_sys: self.k_sys,
            g0_l: self.g0_l,
            g_h: self.g_h.clone(),
            high: HighCompensatorConfig {
                f_corner_hz: self.band_limit_hz,
                zeta: self.band_limit_zeta,
            },
            c_h_prewarp: Prewarp::AtHz(self.c_h_prewarp_hz),
        }
    }

    /// The chain the closed loop runs, whose input is a force in newtons:
    /// the same crossover, Ĝ_H and F with K_sys = G0_L, so C_L = 1 N/N and
    /// C_H = G0_L·F/Ĝ_H V/N. The rendered force at low frequency is then the
    /// force asked for whatever the calibration (`docs/theory/calibration.md`, what K_sys
    /// means for a force input).
    pub fn force_chain_design(&self, xo: &CrossoverChoice) -> ChainDesign {
        ChainDesign {
            k_sys: self.g0_l,
            ..self.chain_design(xo)
        }
    }

    /// Digital coefficients of [`Self::force_chain_design`].
    pub fn force_chain_coefficients(&self, xo: &CrossoverChoice) -> Result<ChainCoefficients> {
        ChainCoefficients::design(&self.force_chain_design(xo))
            .map_err(|e| CalibrationError::dsp("force chain", e))
    }

    /// Digital coefficients of the compensated chain for a unit haptic
    /// signal (K_sys as designed; errors when a compensator would be
    /// unstable).
    pub fn chain_coefficients(&self, xo: &CrossoverChoice) -> Result<ChainCoefficients> {
        ChainCoefficients::design(&self.chain_design(xo))
            .map_err(|e| CalibrationError::dsp("compensated chain", e))
    }

    /// The crossover alone, each path scaled by a constant gain only:
    /// C_L = K_sys/G0_L and K_sys/|Ĝ_H(j2πf_c)| (signed by Re Ĝ_H(j2πf_c)) on
    /// the high path — what the chain does without the frequency-dependent
    /// compensation.
    pub fn uncompensated_coefficients(&self, xo: &CrossoverChoice) -> Result<ChainCoefficients> {
        let err = |e| CalibrationError::dsp("uncompensated chain", e);
        let gh = self.g_h.response_hz(xo.crossover_hz);
        let xo = LinkwitzRiley::new(xo.order, xo.crossover_hz, self.fs).map_err(err)?;
        let c_h = self.k_sys / gh.norm() * if gh.re < 0.0 { -1.0 } else { 1.0 };
        if !c_h.is_finite() {
            return Err(CalibrationError::measurement(
                Step::Design,
                "Ĝ_H vanishes at the crossover frequency",
            ));
        }
        let mut low = xo.low_sections().to_vec();
        let mut high = xo.high_sections().to_vec();
        low[0] = low[0].scaled(self.c_l);
        high[0] = high[0].scaled(c_h);
        ChainCoefficients::new(self.fs, low, high).map_err(err)
    }
}

/// 1/96-octave grid from 0.1 Hz to just below Nyquist.
fn log_grid(fs: f64) -> impl Iterator<Item = f64> {
    let top = 0.499 * fs;
    let n = ((top / 0.1).log2() * 96.0).ceil() as usize;
    (0..=n).map(move |k| (0.1 * 2f64.powf(k as f64 / 96.0)).min(top))
}

/// Step 5 (see the module documentation).
pub fn design(
    fs: f64,
    limits: &ActuatorLimits,
    low: &LowChannelId,
    high: &HighChannelId,
    xo: &CrossoverChoice,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<CompensatorDesign> {
    let step = Step::Design;
    ctx.begin(step, "designing C_L and C_H")?;
    let d = &cfg.design;
    let mut out = CompensatorDesign {
        fs,
        k_sys: 1.0,
        k_sys_max: 1.0,
        k_sys_limited_by: String::new(),
        g0_l: xo.g0_l,
        g_h: high.model.clone(),
        c_l: 0.0,
        c_h: high.model.clone(),
        band_limit_hz: d.band_limit_hz,
        band_limit_zeta: d.band_limit_zeta,
        c_h_prewarp_hz: d.c_h_prewarp_hz.unwrap_or(cfg.verify.f_max_hz),
        low_drive_per_unit: 0.0,
        high_drive_per_unit: 0.0,
        predicted_max_abs_dev_db: 0.0,
    };
    // Paths with K_sys = 1.
    let unit = out.chain_coefficients(xo)?;
    let (mut lmax, mut hmax) = (0.0_f64, 0.0_f64);
    for f in log_grid(fs) {
        let (l, h) = unit.response(f);
        lmax = lmax.max(l.norm());
        hmax = hmax.max(h.norm());
    }
    let mut candidates = vec![
        (limits.max_force_n / lmax, "Pantograph force"),
        (limits.max_high_drive / hmax, "Haptuator drive"),
    ];
    if let Some(a) = limits.accel_range_m_s2 {
        candidates.push((a, "accelerometer range"));
    }
    let (k_max, by) = candidates
        .into_iter()
        .filter(|(k, _)| k.is_finite() && *k > 0.0)
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .ok_or_else(|| {
            CalibrationError::Rig(format!(
                "actuator limits {limits:?} admit no positive K_sys"
            ))
        })?;
    out.k_sys_max = k_max;
    (out.k_sys, out.k_sys_limited_by) = match d.k_sys {
        Some(k) => (k, "configuration".to_owned()),
        None => (d.headroom * k_max, by.to_owned()),
    };
    out.c_l =
        compensator::low_gain(out.k_sys, out.g0_l).map_err(|e| CalibrationError::dsp("C_L", e))?;
    out.c_h = compensator::high(out.k_sys, &out.g_h, out.band_limit_hz, out.band_limit_zeta)
        .map_err(|e| CalibrationError::dsp("C_H", e))?;
    out.low_drive_per_unit = lmax * out.k_sys;
    out.high_drive_per_unit = hmax * out.k_sys;
    // Prediction from the measured responses at the verification bands.
    let chain = out.chain_coefficients(xo)?;
    let centres = super::bands::band_centres(low, cfg)?;
    let worst = predicted_max_abs_dev_db(&chain, out.k_sys, low, high, &centres);
    out.predicted_max_abs_dev_db = worst;
    ctx.report(
        step,
        1.0,
        &format!(
            "K_sys = {:.4} (m/s²)/unit (limited by {}), predicted deviation {:.2} dB",
            out.k_sys, out.k_sys_limited_by, worst
        ),
    );
    Ok(out)
}
