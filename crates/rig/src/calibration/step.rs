//! The seven steps of the calibration procedure (paper §3).

use serde::{Deserialize, Serialize};

/// The seven steps of the procedure (paper §3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    /// Sensor alive and in range, rig responding, safety armed.
    Check,
    /// Low channel (Pantograph on, Haptuator off): MLS, H1, G0_L, flat band.
    IdentifyLow,
    /// High channel (Pantograph off, Haptuator on): MLS, H1, reliable band, Ĝ_H fit.
    IdentifyHigh,
    /// Crossover frequency selection.
    Crossover,
    /// K_sys, C_L = K_sys/G0_L and C_H = K_sys·F/Ĝ_H.
    Design,
    /// Stepped sines through the full chain at third-octave centres.
    Verify,
    /// Calibration file written.
    Save,
}

impl Step {
    /// All steps in procedure order.
    pub const ALL: [Step; 7] = [
        Step::Check,
        Step::IdentifyLow,
        Step::IdentifyHigh,
        Step::Crossover,
        Step::Design,
        Step::Verify,
        Step::Save,
    ];

    /// Short name, e.g. `identify-low`.
    pub fn name(self) -> &'static str {
        match self {
            Step::Check => "check",
            Step::IdentifyLow => "identify-low",
            Step::IdentifyHigh => "identify-high",
            Step::Crossover => "crossover",
            Step::Design => "design",
            Step::Verify => "verify",
            Step::Save => "save",
        }
    }

    /// Position in [`Step::ALL`] (0-based).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Fraction of the whole procedure done when this step is `fraction`
    /// done (steps weighted equally), in [0, 1].
    pub fn overall(self, fraction: f64) -> f64 {
        let f = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        (self.index() as f64 + f) / Step::ALL.len() as f64
    }
}
