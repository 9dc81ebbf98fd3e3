//! The third-octave bands a calibration verifies (IEC 61260-1 centres from
//! the configured range, optionally extended down into the low channel's
//! flat band).

use super::config::CalibrationConfig;
use super::error::{CalibrationError, Result};
use super::identify::LowChannelId;
use kilotouch_dsp::thirdoctave::{Band, bands_between};

/// Third-octave bands to verify, ascending, each with its `extended` flag.
pub fn bands(low: &LowChannelId, cfg: &CalibrationConfig) -> Result<Vec<(Band, bool)>> {
    let v = &cfg.verify;
    let err = |e| CalibrationError::dsp("third-octave bands", e);
    let main = bands_between(v.f_min_hz, v.f_max_hz).map_err(err)?;
    let mut out = Vec::new();
    if v.extend_below {
        let lo = v.extend_min_hz.max(low.flat_band_hz[0]);
        if lo < v.f_min_hz {
            for b in bands_between(lo, v.f_min_hz).map_err(err)? {
                if b.centre_hz >= lo && main.iter().all(|m| m.index != b.index) {
                    out.push((b, true));
                }
            }
        }
    }
    out.extend(main.into_iter().map(|b| (b, false)));
    Ok(out)
}

/// Centre frequencies of [`bands`], Hz.
pub fn band_centres(low: &LowChannelId, cfg: &CalibrationConfig) -> Result<Vec<f64>> {
    Ok(bands(low, cfg)?
        .into_iter()
        .map(|(b, _)| b.centre_hz)
        .collect())
}
