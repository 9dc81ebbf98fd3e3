//! The chain a calibration designs, and how it will respond: the unit-gain
//! chain of a candidate crossover, the response predicted from the measured
//! channels, and the chain's group delay. Shared by the crossover choice,
//! the design and the verification.

use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::identify::{HighChannelId, LowChannelId};
use kilotouch_dsp::C64;
use kilotouch_dsp::chain::{ChainCoefficients, ChainDesign};
use kilotouch_dsp::compensator::HighCompensatorConfig;
use kilotouch_dsp::design::Prewarp;
use kilotouch_dsp::filter::sections_response_and_derivative;
use std::f64::consts::PI;

/// Group delay (s) of the chain's electrical sum low + high at `f_hz`:
/// τ = −Im((L' + H')/(L + H))/fs, derivatives with respect to ω in
/// rad/sample (analytic, per section).
pub fn chain_group_delay(c: &ChainCoefficients, f_hz: f64) -> f64 {
    let w = 2.0 * PI * f_hz / c.fs();
    let (l, dl) = sections_response_and_derivative(c.low(), w);
    let (h, dh) = sections_response_and_derivative(c.high(), w);
    -((dl + dh) / (l + h)).im / c.fs()
}

/// Chain coefficients with K_sys = 1 for a crossover at `fc` Hz, low-channel
/// gain `g0_l`, the identified high channel and the design settings of
/// `cfg`.
pub fn unit_chain(
    fs: f64,
    fc: f64,
    order: usize,
    g0_l: f64,
    high: &HighChannelId,
    cfg: &CalibrationConfig,
) -> Result<ChainCoefficients> {
    let d = &cfg.design;
    let design = ChainDesign {
        fs,
        crossover_order: order,
        crossover_hz: fc,
        k_sys: 1.0,
        g0_l,
        g_h: high.model.clone(),
        high: HighCompensatorConfig {
            f_corner_hz: d.band_limit_hz,
            zeta: d.band_limit_zeta,
        },
        c_h_prewarp: Prewarp::AtHz(d.c_h_prewarp_hz.unwrap_or(cfg.verify.f_max_hz)),
    };
    ChainCoefficients::design(&design).map_err(|e| CalibrationError::dsp("compensated chain", e))
}

/// Response predicted at `centres` (Hz) when `chain` (overall gain `k_sys`)
/// drives channels with the measured responses of `low` and `high`:
/// max over f of |20·log10|(L(f) Ĥ_L(f) + H(f) Ĥ_H(f))/K_sys||, dB.
pub fn predicted_max_abs_dev_db(
    chain: &ChainCoefficients,
    k_sys: f64,
    low: &LowChannelId,
    high: &HighChannelId,
    centres: &[f64],
) -> f64 {
    centres
        .iter()
        .map(|&f| {
            let (l, h) = chain.response(f);
            let p: C64 = (l * low.frf.at(f) + h * high.frf.at(f)) / k_sys;
            (20.0 * p.norm().log10()).abs()
        })
        .fold(0.0, f64::max)
}
