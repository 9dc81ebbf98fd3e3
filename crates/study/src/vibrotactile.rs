//! Vibrotactile sensitivity of the fingertip: the Pacinian (P) channel's
//! U-shaped detection threshold as a frequency weighting of acceleration,
//! the one place the simulated participant and the paper's figures take it
//! from.
//!
//! Measured with large contactors (≥ 2.9 cm², the regime of a finger on a
//! plate), the displacement threshold is flat up to ≈ 40 Hz (the non-Pacinian
//! channel), then falls at ≈ 12 dB/octave to its minimum of ≈ 0.1 µm peak at
//! ≈ 250–300 Hz and rises again above it (Verrillo 1963, *J. Acoust. Soc. Am.*
//! 35:1962; Bolanowski et al. 1988, *J. Acoust. Soc. Am.* 84:1680). A
//! −12 dB/octave fall in displacement is a *flat* threshold in acceleration
//! (a = (2πf)²·d), so in acceleration the P channel is a band:
//!
//! * flat between [`PacinianCurve::low_hz`] (40 Hz) and
//!   [`PacinianCurve::high_hz`] (300 Hz), at [`PacinianCurve::threshold_m_s2`]
//!   = 0.17 m/s² RMS (0.1 µm peak at 250 Hz: (2π·250)²·0.1 µm / √2);
//! * below `low_hz` a second-order Butterworth high-pass (the P channel's
//!   sensitivity falls; slower vibration is the force percept's band);
//! * above `high_hz` a fourth-order Butterworth low-pass: the acceleration
//!   threshold rises 24 dB/octave, the displacement threshold 12 dB/octave
//!   (≈ 0.19 µm at 500 Hz, ≈ 0.37 µm at 700 Hz against 0.1 µm at 250 Hz —
//!   within the spread of the published curves).
//!
//! A vibration is felt when the RMS of the acceleration passed through this
//! weighting exceeds `threshold_m_s2`. The weighting is implemented as
//! second-order sections (bilinear, pre-warped at each corner); its analytic
//! magnitude ([`PacinianCurve::weight`]) is what the docs' curve and the tests
//! use.

use kilotouch_dsp::design::{FilterKind, Prewarp, butter};
use kilotouch_dsp::filter::BiquadCoeffs;
use serde::{Deserialize, Serialize};

/// The P channel's threshold curve (module docs). SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PacinianCurve {
    /// Lower corner (second-order high-pass), Hz.
    pub low_hz: f64,
    /// Upper corner (fourth-order low-pass), Hz.
    pub high_hz: f64,
    /// Threshold in the flat band, m/s² RMS of the weighted acceleration.
    pub threshold_m_s2: f64,
}

impl Default for PacinianCurve {
    fn default() -> Self {
        Self {
            low_hz: 40.0,
            high_hz: 300.0,
            threshold_m_s2: 0.17,
        }
    }
}

impl PacinianCurve {
    /// Magnitude of the weighting at `f_hz` (analog Butterworth prototypes),
    /// 1 in the flat band.
    pub fn weight(&self, f_hz: f64) -> f64 {
        let hp = (f_hz / self.low_hz).powi(2);
        let lp = (f_hz / self.high_hz).powi(4);
        // |HP2|² = r⁴/(1 + r⁴), |LP4|² = 1/(1 + r⁸).
        (hp * hp / (1.0 + hp * hp)).sqrt() / (1.0 + lp * lp).sqrt()
    }

    /// Detection threshold of a sinusoid at `f_hz`, m/s² RMS.
    pub fn threshold_rms_m_s2(&self, f_hz: f64) -> f64 {
        self.threshold_m_s2 / self.weight(f_hz)
    }

    /// Detection threshold of a sinusoid at `f_hz` as peak displacement, m.
    pub fn threshold_displacement_m(&self, f_hz: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * f_hz;
        self.threshold_rms_m_s2(f_hz) * std::f64::consts::SQRT_2 / (w * w)
    }

    /// The weighting as second-order sections at `sample_rate_hz`.
    ///
    /// # Errors
    /// A corner outside (0, Nyquist).
    pub fn sections(
        &self,
        sample_rate_hz: f64,
    ) -> Result<Vec<BiquadCoeffs>, kilotouch_dsp::DspError> {
        let mut s = butter(
            2,
            self.low_hz,
            sample_rate_hz,
            FilterKind::Highpass,
            Prewarp::AtCutoff,
        )?;
        s.extend(butter(
            4,
            self.high_hz,
            sample_rate_hz,
            FilterKind::Lowpass,
            Prewarp::AtCutoff,
        )?);
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use kilotouch_dsp::filter::Sos;

    #[test]
    fn the_minimum_is_a_tenth_of_a_micron_near_250_hz() {
        let c = PacinianCurve::default();
        let d250 = c.threshold_displacement_m(250.0);
        // 0.1 µm peak at 250 Hz (Verrillo 1963), within the −0.7 dB the
        // low-pass corner at 300 Hz costs there.
        assert!((0.1e-6..0.11e-6).contains(&d250), "{d250}");
        // The U: displacement threshold falls ≈ 12 dB/octave from 40 to
        // 160 Hz, is lowest between 200 and 300 Hz, rises above.
        let db = |f: f64| 20.0 * (c.threshold_displacement_m(f) / d250).log10();
        let slope = (db(80.0) - db(160.0)) / 1.0;
        assert!((11.0..13.0).contains(&slope), "{slope}");
        let fmin = (100..=600)
            .map(f64::from)
            .min_by(|a, b| db(*a).total_cmp(&db(*b)))
            .unwrap_or(0.0);
        assert!((200.0..=300.0).contains(&fmin), "{fmin}");
        assert!(db(500.0) > 3.0 && db(700.0) > 9.0);
    }

    #[test]
    fn the_sections_match_the_analytic_weight() {
        let c = PacinianCurve::default();
        let fs = 10_000.0;
        for f in [30.0, 60.0, 150.0, 250.0, 400.0, 800.0] {
            let mut sos = Sos::new(c.sections(fs).unwrap()).unwrap();
            let n = 40_000;
            let w = 2.0 * std::f64::consts::PI * f / fs;
            let (mut num, mut den) = (0.0, 0.0);
            for k in 0..n {
                let x = (w * k as f64).sin();
                let y = sos.process(x);
                if k >= n / 2 {
                    num += y * y;
                    den += x * x;
                }
            }
            let g = (num / den).sqrt();
            // Bilinear warping away from the corners: (tan(πf/fs)/(πf/fs))⁴
            // on the fourth-order slope, 0.6 dB at 800 Hz.
            let db = 20.0 * (g / c.weight(f)).log10();
            assert!(db.abs() < 0.7, "{f} Hz: {g} vs {} ({db} dB)", c.weight(f));
        }
    }
}
