//! Step 4: choice of the crossover frequency f_c.
//!
//! The paper chose "the highest [f_c] that the Pantograph could allow in
//! order to minimize the delay introduced by the filters" (§3.1). Made an
//! algorithm: with the low path L·C_L and the high path H·C_H of the chain
//! designed for a candidate f_c (Linkwitz–Riley L, H; C_L = K/G0_L(f_c),
//! C_H = K·F/Ĝ_H), the tip response to be expected is the chain applied to
//! the *measured* channel responses,
//!
//! ```text
//! P(f) = [L(f) C_L Ĥ_L(f) + H(f) C_H(f) Ĥ_H(f)] / K_sys ,
//! ```
//!
//! which differs from 1 where a channel departs from its model (G0_L above
//! the low channel's flat band, Ĝ_H below the high channel's reliable band)
//! and the crossover skirt lets that departure through, and where the two
//! paths' phases disagree around f_c. G0_L(f_c) is the static gain over the
//! part of the flat band at or below f_c, where the low channel carries the
//! signal ([`super::identify::gain_below`]): the minimax midpoint of its
//! magnitude there, so that the in-band ripple the compensation cannot
//! remove is split evenly. The candidates are a 1/48-octave grid
//! from min(f_b, `max_hz`) (f_b: upper edge of the low channel's flat band)
//! down to `min_hz`; f_c is the **highest** candidate whose predicted
//! deviation max |20·log10|P(f)|| over the verification bands is within
//! `budget_db`. When none is (the channels do not overlap enough), the
//! candidate with the smallest predicted deviation is taken and
//! `over_budget` is set.
//!
//! Two leakage figures are reported as diagnostics at the chosen f_c
//! (upper bounds of each channel's contribution by the triangle inequality,
//! |L + H| = 1):
//!
//! ```text
//! e_L = max_{f_b < f ≤ f_top} |L(f)|·|Ĥ_L(f)/G0_L(f_c) − 1|
//! e_H = max_{f < f_r}        |H(f)|·|Ĥ_H(f)/(Ĝ_H(f) e^{−j2πfτ}) − 1|   (1 where incoherent)
//! ```

use super::bands::band_centres;
use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::identify::{HighChannelId, LowChannelId, gain_below};
use super::measure::{smooth_octave, smooth_octave_complex};
use super::prediction::{predicted_max_abs_dev_db, unit_chain};
use super::progress::{Step, StepContext};
use kilotouch_dsp::C64;
use kilotouch_dsp::crossover::LinkwitzRiley;
use serde::{Deserialize, Serialize};

/// How the crossover frequency was set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CrossoverRule {
    /// The algorithm of the module documentation.
    Automatic,
    /// `crossover.crossover_hz` of the configuration.
    Override,
}

/// Result of step 4.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrossoverChoice {
    /// Crossover frequency, Hz (`fc_hz` in calibration files of
    /// `format_version` 1).
    #[serde(alias = "fc_hz")]
    pub crossover_hz: f64,
    /// Linkwitz–Riley order.
    pub order: usize,
    /// How `crossover_hz` was set.
    pub rule: CrossoverRule,
    /// Low-channel static gain over the flat band at or below `crossover_hz`,
    /// (m/s²)/N: the G0_L of C_L = K_sys/G0_L.
    pub g0_l: f64,
    /// Highest candidate (upper edge of the low channel's flat band, or
    /// `max_hz`), Hz.
    pub fc_max_hz: f64,
    /// Predicted max |deviation| over the verification bands at `crossover_hz`, dB.
    pub predicted_max_abs_dev_db: f64,
    /// Leakage bound of the low channel at `crossover_hz`, 20·log10(1 + e_L), dB.
    pub low_leak_db: f64,
    /// Leakage bound of the high channel at `crossover_hz`, 20·log10(1 + e_H), dB.
    pub high_leak_db: f64,
    /// True when no candidate met the budget (the channels do not overlap
    /// enough for it; the smallest predicted deviation was taken).
    pub over_budget: bool,
    /// Human-readable explanation.
    pub note: String,
}

/// Per-bin model error ε_H of the high channel below its reliable band
/// (module documentation): (bin frequency, ε_H).
fn high_errors(high: &HighChannelId, cfg: &CalibrationConfig) -> Vec<(f64, f64)> {
    let frf = &high.frf;
    let w = cfg.analysis.smoothing_octaves;
    let ratio: Vec<C64> = frf
        .f_hz
        .iter()
        .zip(&frf.h)
        .map(|(&f, &h)| h / high.response(f))
        .collect();
    let ratio = smooth_octave_complex(&frf.f_hz, &ratio, w);
    let coh = smooth_octave(&frf.f_hz, &frf.coherence, w);
    frf.range(0.0, high.reliable_band_hz[0] * (1.0 - 1e-12))
        .map(|i| {
            let e = (ratio[i] - 1.0).norm();
            let e = if coh[i] >= cfg.analysis.coherence_min && e.is_finite() {
                e
            } else {
                1.0
            };
            (frf.f_hz[i], e)
        })
        .collect()
}

/// Leakage bounds (e_L, e_H) of a crossover at `fc` Hz (module
/// documentation).
pub fn leakage(
    fc: f64,
    fs: f64,
    low: &LowChannelId,
    high: &HighChannelId,
    cfg: &CalibrationConfig,
) -> Result<(f64, f64)> {
    let xo = LinkwitzRiley::new(cfg.crossover.order, fc, fs)
        .map_err(|e| CalibrationError::dsp("crossover design", e))?;
    let g0 = gain_below(low, fc, cfg);
    let f_b = low.flat_band_hz[1];
    let f_top = cfg.verify.f_max_hz * 10f64.powf(0.05);
    let frf = &low.frf;
    let e_l = frf
        .range(f_b * (1.0 + 1e-12), f_top)
        .map(|i| xo.response(frf.f_hz[i]).0.norm() * (frf.h[i] / g0 - 1.0).norm())
        .fold(0.0, f64::max);
    let e_h = high_errors(high, cfg)
        .iter()
        .map(|&(f, e)| xo.response(f).1.norm() * e)
        .fold(0.0, f64::max);
    Ok((e_l, e_h))
}

fn db(e: f64) -> f64 {
    20.0 * (1.0 + e).log10()
}

/// Step 4 (see the module documentation).
pub fn choose_crossover(
    fs: f64,
    low: &LowChannelId,
    high: &HighChannelId,
    cfg: &CalibrationConfig,
    ctx: &mut StepContext<'_>,
) -> Result<CrossoverChoice> {
    let step = Step::Crossover;
    ctx.begin(step, "choosing the crossover frequency")?;
    let c = &cfg.crossover;
    let cap = c
        .max_hz
        .map_or(low.flat_band_hz[1], |m| m.min(low.flat_band_hz[1]));
    if cap <= c.min_hz {
        return Err(CalibrationError::measurement(
            step,
            format!(
                "the low channel's flat band ends at {:.1} Hz, below crossover.min_hz = {} Hz",
                low.flat_band_hz[1], c.min_hz
            ),
        ));
    }
    let centres = band_centres(low, cfg)?;
    let predict = |fc: f64| -> Result<f64> {
        let chain = unit_chain(fs, fc, c.order, gain_below(low, fc, cfg), high, cfg)?;
        Ok(predicted_max_abs_dev_db(&chain, 1.0, low, high, &centres))
    };
    let (fc, predicted, rule, over_budget, note) = if let Some(fc) = c.crossover_hz {
        let p = predict(fc)?;
        (
            fc,
            p,
            CrossoverRule::Override,
            false,
            format!("set by configuration; predicted deviation {p:.2} dB"),
        )
    } else {
        let n = ((cap / c.min_hz).log2() * 48.0).floor() as usize;
        let mut best: Option<(f64, f64)> = None;
        let mut chosen = None;
        for k in 0..=n {
            let fc = cap * 2f64.powf(-(k as f64) / 48.0);
            let p = predict(fc)?;
            ctx.report(
                step,
                k as f64 / (n + 1) as f64,
                &format!("trying f_c = {fc:.1} Hz: predicted deviation {p:.2} dB"),
            );
            if p <= c.budget_db {
                chosen = Some((fc, p));
                break;
            }
            if best.is_none_or(|b| p < b.1) {
                best = Some((fc, p));
            }
        }
        match (chosen, best) {
            (Some((fc, p)), _) => (
                fc,
                p,
                CrossoverRule::Automatic,
                false,
                format!(
                    "highest frequency at or below the low channel's flat band edge ({cap:.1} Hz) \
                     with a predicted deviation within {} dB ({p:.2} dB)",
                    c.budget_db
                ),
            ),
            (None, Some((fc, p))) => (
                fc,
                p,
                CrossoverRule::Automatic,
                true,
                format!(
                    "over budget: no frequency from {:.1} to {cap:.1} Hz keeps the predicted deviation \
                     within {} dB; chose the smallest ({p:.2} dB)",
                    c.min_hz, c.budget_db
                ),
            ),
            (None, None) => {
                return Err(CalibrationError::measurement(step, "empty crossover grid"));
            }
        }
    };
    let (el, eh) = leakage(fc, fs, low, high, cfg)?;
    let out = CrossoverChoice {
        crossover_hz: fc,
        order: c.order,
        rule,
        g0_l: gain_below(low, fc, cfg),
        fc_max_hz: cap,
        predicted_max_abs_dev_db: predicted,
        low_leak_db: db(el),
        high_leak_db: db(eh),
        over_budget,
        note,
    };
    ctx.report(
        step,
        1.0,
        &format!(
            "crossover at {:.1} Hz (predicted {:.2} dB)",
            out.crossover_hz, predicted
        ),
    );
    Ok(out)
}
