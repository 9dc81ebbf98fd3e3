//! What the Pantograph receives in condition P besides the D chain's low
//! channel ([`crate::condition::PMode`]): the force as it is, or a
//! 2nd-order Butterworth low-pass.

use crate::condition::PMode;
use crate::error::RigError;
use kilotouch_dsp::design::{FilterKind, Prewarp, butter};
use kilotouch_dsp::filter::Biquad;

/// One axis's P-mode filter.
#[derive(Debug, Clone)]
pub enum PPath {
    /// Unfiltered (full band; also the y axis for `low-channel`, which has
    /// no crossover).
    Identity,
    /// 2nd-order Butterworth low-pass (one section).
    Lowpass(Biquad),
}

impl PPath {
    /// The filter of `mode` at rate `fs`.
    ///
    /// # Errors
    /// A corner at or above Nyquist.
    pub fn new(mode: PMode, fs: f64) -> Result<Self, RigError> {
        match mode {
            PMode::FullBand | PMode::LowChannel => Ok(Self::Identity),
            PMode::Lowpass { hz } => {
                let s = butter(2, hz, fs, FilterKind::Lowpass, Prewarp::AtCutoff)?;
                match s.as_slice() {
                    [c] => Ok(Self::Lowpass(Biquad::new(*c)?)),
                    _ => Err(RigError::InvalidParameter {
                        name: "p_mode.lowpass.hz",
                        value: hz,
                        reason: format!("expected one section, got {}", s.len()),
                    }),
                }
            }
        }
    }

    /// One sample.
    #[inline]
    pub fn process(&mut self, x: f64) -> f64 {
        match self {
            Self::Identity => x,
            Self::Lowpass(b) => b.process(x),
        }
    }

    /// Clear the state.
    pub fn reset(&mut self) {
        if let Self::Lowpass(b) = self {
            b.reset();
        }
    }
}
