//! Step 4: choice of the crossover frequency f_c.
//!
//! The paper chose "the highest [f_c] that the Pantograph could allow in
//! order to minimize the delay introduced by the filters" (§3.1). Made an
//! algorithm: with the low path L and high path H of the Linkwitz–Riley
//! crossover at f_c (|L + H| = 1), the delivered response is
//! L·ĥ_L + H·ĥ_H with ĥ = channel response / its model. Each channel's
//! error outside its trusted band leaks through the other side of the
//! crossover:
//!
//! ```text
//! e_L(f_c) = max_{f_b < f ≤ f_top} |L(f)|·|Ĥ_L(f)/G0_L − 1|   (measured, above the flat band)
//! e_H(f_c) = max_{f ≤ f_r}       |H(f)|·1 = |H(f_r)|          (unknown below the reliable band:
//!                                                                 assume a 100 % error)
//! ```
//!
//! and | |L ĥ_L + H ĥ_H| − 1 | ≤ e_L + e_H by the triangle inequality. With
//! the budget δ = 10^(b/20) − 1 (b = `skirt_budget_db`), f_c is the highest
//! frequency on a 1/48-octave grid from min(f_b, `max_hz`) down to `min_hz`
//! with e_L ≤ δ and e_H ≤ δ. e_L only falls and e_H only rises as f_c
//! falls, so the admissible set is an interval [f_c,min,H, f_c,max,L]; when
//! it is empty (the channels do not overlap enough) the grid point that
//! minimises max(e_L, e_H) is taken and the conflict is reported. For LR4
//! e_H ≤ δ means f_c ≥ f_r·((1 − δ)/δ)^(1/4): 2.0·f_r for b = 0.5 dB — the
//! paper's 200 Hz over its unreliable 100 Hz.

use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::identify::{HighChannelId, LowChannelId};
use super::progress::{Step, StepContext};
use kilotouch_dsp::crossover::LinkwitzRiley;
use serde::{Deserialize, Serialize};

/// How the crossover frequency was set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CrossoverRule {
    /// The algorithm of the module documentation.
    Automatic,
    /// `crossover.fc_hz` of the configuration.
    Override,
}

/// Result of step 4.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrossoverChoice {
    /// Crossover frequency, Hz.
    pub fc_hz: f64,
    /// Linkwitz–Riley order.
    pub order: usize,
    /// How `fc_hz` was set.
    pub rule: CrossoverRule,
    /// Highest grid frequency with e_L ≤ δ (the low channel's limit), Hz.
    pub fc_max_low_hz: f64,
    /// Lowest grid frequency with e_H ≤ δ (the high channel's limit), Hz.
    pub fc_min_high_hz: f64,
    /// Leakage bound of the low channel at `fc_hz`, 20·log10(1 + e_L), dB.
    pub low_leak_db: f64,
    /// Leakage bound of the high channel at `fc_hz`, 20·log10(1 + e_H), dB.
    pub high_leak_db: f64,
    /// True when no frequency satisfied both bounds.
    pub conflict: bool,
    /// Human-readable explanation.
    pub note: String,
}

/// Leakage bounds (e_L, e_H) of a crossover at `fc` (module documentation).
pub fn leakage(
    fc: f64,
    fs: f64,
    low: &LowChannelId,
    high: &HighChannelId,
    cfg: &CalibrationConfig,
) -> Result<(f64, f64)> {
    let xo = LinkwitzRiley::new(cfg.crossover.order, fc, fs)
        .map_err(|e| CalibrationError::dsp("crossover design", e))?;
    let f_b = low.flat_band_hz[1];
    let f_top = cfg.verify.f_max_hz * 10f64.powf(0.05);
    let frf = &low.frf;
    let e_l = frf
        .range(f_b * (1.0 + 1e-12), f_top)
        .map(|i| xo.response(frf.f_hz[i]).0.norm() * (frf.h[i] / low.g0 - 1.0).norm())
        .fold(0.0, f64::max);
    let e_h = xo.response(high.reliable_band_hz[0]).1.norm();
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
    ctx.check_cancel(step)?;
    ctx.report(step, 0.0, "choosing the crossover frequency");
    let c = &cfg.crossover;
    let delta = 10f64.powf(c.skirt_budget_db / 20.0) - 1.0;
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
    let n = ((cap / c.min_hz).log2() * 48.0).floor() as usize;
    let mut grid = Vec::with_capacity(n + 1);
    for k in 0..=n {
        let fc = cap * 2f64.powf(-(k as f64) / 48.0);
        let (el, eh) = leakage(fc, fs, low, high, cfg)?;
        grid.push((fc, el, eh));
    }
    let fc_max_low = grid.iter().find(|g| g.1 <= delta).map_or(c.min_hz, |g| g.0);
    let fc_min_high = grid
        .iter()
        .rev()
        .find(|g| g.2 <= delta)
        .map_or(cap, |g| g.0);
    let feasible = grid.iter().find(|g| g.1 <= delta && g.2 <= delta).copied();
    let (choice, rule, conflict, note) = if let Some(fc) = c.fc_hz {
        let (el, eh) = leakage(fc, fs, low, high, cfg)?;
        (
            (fc, el, eh),
            CrossoverRule::Override,
            false,
            format!(
                "set by configuration; the automatic rule allows {fc_min_high:.1}–{fc_max_low:.1} Hz"
            ),
        )
    } else if let Some(g) = feasible {
        (
            g,
            CrossoverRule::Automatic,
            false,
            format!(
                "highest frequency the low channel allows ({fc_max_low:.1} Hz, flat band to {:.1} Hz) \
                 with the high channel's leakage below its reliable band within budget \
                 (needs ≥ {fc_min_high:.1} Hz)",
                low.flat_band_hz[1]
            ),
        )
    } else {
        let g = grid
            .iter()
            .copied()
            .min_by(|a, b| a.1.max(a.2).total_cmp(&b.1.max(b.2)))
            .ok_or_else(|| CalibrationError::measurement(step, "empty crossover grid"))?;
        (
            g,
            CrossoverRule::Automatic,
            true,
            format!(
                "conflict: the low channel allows at most {fc_max_low:.1} Hz but the high channel \
                 needs at least {fc_min_high:.1} Hz for a {} dB leakage budget; compromise at the \
                 smallest worst-case leakage",
                c.skirt_budget_db
            ),
        )
    };
    let out = CrossoverChoice {
        fc_hz: choice.0,
        order: c.order,
        rule,
        fc_max_low_hz: fc_max_low,
        fc_min_high_hz: fc_min_high,
        low_leak_db: db(choice.1),
        high_leak_db: db(choice.2),
        conflict,
        note,
    };
    ctx.report(step, 1.0, &format!("crossover at {:.1} Hz", out.fc_hz));
    Ok(out)
}
