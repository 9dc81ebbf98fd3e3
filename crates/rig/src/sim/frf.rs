//! The model's true (analytic, continuous, linear) response from a
//! channel's drive to the tip acceleration (`kilotouch sim frf --channel
//! low|high [--rig-config FILE] --freqs F1,F2,…`, [`simulate_frf`]).

use crate::config::RigConfig;
use crate::error::RigError;
use crate::plant::{Axis, AxisModel, Channel};
use serde::{Deserialize, Serialize};

/// One point of a frequency response.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrfPoint {
    /// Frequency, Hz.
    pub f_hz: f64,
    /// Real part.
    pub re: f64,
    /// Imaginary part.
    pub im: f64,
    /// 20·log10|H|, dB re 1 (m/s²)/N or (m/s²)/V.
    pub mag_db: f64,
    /// arg H, degrees.
    pub phase_deg: f64,
}

/// Result of `kilotouch sim frf`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrfReport {
    /// Channel.
    pub channel: Channel,
    /// Units of H.
    pub units: String,
    /// Name of the rig the model came from.
    pub rig_name: String,
    /// Points, in the order requested.
    pub points: Vec<FrfPoint>,
}

/// Analytic response of `channel` (x axis, free regime of the end stops)
/// from drive to tip acceleration at each of `freqs_hz`.
pub fn simulate_frf(
    cfg: &RigConfig,
    channel: Channel,
    freqs_hz: &[f64],
) -> Result<FrfReport, RigError> {
    if freqs_hz.is_empty() {
        return Err(RigError::InvalidInput("no frequencies given".into()));
    }
    let m = AxisModel::new(cfg, Axis::X)?;
    let mut points = Vec::with_capacity(freqs_hz.len());
    for &f in freqs_hz {
        if !(f.is_finite() && f >= 0.0) {
            return Err(RigError::InvalidParameter {
                name: "freqs",
                value: f,
                reason: "must be finite and ≥ 0".into(),
            });
        }
        let h = m.channel_response(channel, f)?;
        points.push(FrfPoint {
            f_hz: f,
            re: h.re,
            im: h.im,
            mag_db: 20.0 * h.norm().log10(),
            phase_deg: h.arg().to_degrees(),
        });
    }
    let units = match channel {
        Channel::Low => "(m/s^2)/N",
        Channel::High => "(m/s^2)/V",
    };
    Ok(FrfReport {
        channel,
        units: units.into(),
        rig_name: cfg.rig.name.clone(),
        points,
    })
}

/// Parse a comma-separated frequency list ("63,80,100.5").
pub fn parse_freq_list(s: &str) -> Result<Vec<f64>, RigError> {
    s.split(',')
        .map(|t| t.trim())
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.parse::<f64>()
                .map_err(|e| RigError::InvalidInput(format!("bad frequency `{t}`: {e}")))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frf_report_matches_the_model_and_serialises() {
        let cfg = RigConfig::default();
        let f = parse_freq_list("63, 250,1000").unwrap();
        let r = simulate_frf(&cfg, Channel::High, &f).unwrap();
        let m = AxisModel::new(&cfg, Axis::X).unwrap();
        for p in &r.points {
            let h = m.channel_response(Channel::High, p.f_hz).unwrap();
            assert_eq!((p.re, p.im), (h.re, h.im));
            assert!((p.mag_db - 20.0 * h.norm().log10()).abs() < 1e-12);
        }
        assert_eq!(r.points.len(), 3);
        assert!(parse_freq_list("1,x").is_err());
        assert!(simulate_frf(&cfg, Channel::Low, &[]).is_err());
        assert!(simulate_frf(&cfg, Channel::Low, &[f64::NAN]).is_err());
    }
}
