//! The experimental condition (paper §4.3): what the participant gets back
//! from the bead. One type from the protocol file to the actuators: the
//! study's plans, the engine's V/P/D switch and the coupling all use it.

use serde::{Deserialize, Serialize};
use std::fmt;

/// An experimental condition (paper §4.3).
///
/// Serialised as its letter (`"V"`, `"P"`, `"D"`); rig files may also
/// spell the haptic ones `"vision"`, `"pantograph"`, `"dual"`.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize, Default,
)]
pub enum Condition {
    /// Vision only: camera display of the scene, no haptic force (the
    /// coupling's filters still run, its outputs are zero).
    #[serde(alias = "vision")]
    V,
    /// Vision + the Pantograph alone, Haptuator off. What the Pantograph
    /// receives is the rig file's `coupling.p_mode` ([`PMode`]).
    #[serde(alias = "pantograph")]
    P,
    /// Vision + the dual stage: the paper's chain (Fig. 6), Linkwitz–Riley
    /// crossover, C_L on the Pantograph, C_H on the Haptuator.
    #[default]
    #[serde(alias = "dual")]
    D,
}

impl Condition {
    /// All conditions in the paper's order.
    pub const ALL: [Condition; 3] = [Condition::V, Condition::P, Condition::D];

    /// The haptic conditions (the closed loop's stability matters only there).
    pub const HAPTIC: [Condition; 2] = [Condition::P, Condition::D];

    /// One-letter code used in files and tables.
    pub fn code(self) -> &'static str {
        match self {
            Condition::V => "V",
            Condition::P => "P",
            Condition::D => "D",
        }
    }

    /// Human description.
    pub fn description(self) -> &'static str {
        match self {
            Condition::V => "vision only, no haptic force",
            Condition::P => "vision + Pantograph channel only",
            Condition::D => "vision + dual-stage interface (Pantograph + Haptuator)",
        }
    }

    /// Whether the Pantograph renders force.
    pub fn pantograph(self) -> bool {
        matches!(self, Condition::P | Condition::D)
    }

    /// Whether the Haptuator (high band) is driven.
    pub fn haptuator(self) -> bool {
        matches!(self, Condition::D)
    }

    /// Whether any haptic feedback is given.
    pub fn haptic(self) -> bool {
        self.pantograph()
    }
}

impl fmt::Display for Condition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.code())
    }
}

impl std::str::FromStr for Condition {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "V" | "v" | "vision" => Ok(Condition::V),
            "P" | "p" | "pantograph" => Ok(Condition::P),
            "D" | "d" | "dual" => Ok(Condition::D),
            other => Err(format!("unknown condition `{other}` (expected V, P or D)")),
        }
    }
}

/// What the Pantograph receives in condition P (`coupling.p_mode`).
///
/// The paper's P is "haptic feedback from the conventional Pantograph"
/// (§4.3): a conventional force-feedback device renders the force signal as
/// it is and its own mechanics limit the band (≈ 200 Hz in the dual-stage
/// arrangement, §3.2). That is [`PMode::FullBand`], the default. The two
/// alternatives are kept for protocols that want a stricter contrast; their
/// effect on the P-vs-D contrast is documented in `docs/theory/coupling-and-stability.md`
/// (bilateral coupling).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case", deny_unknown_fields)]
pub enum PMode {
    /// The force signal, unfiltered, on the Pantograph (times C_L, which is
    /// 1 for a force-normalised chain); Haptuator off.
    #[default]
    FullBand,
    /// The D chain's low path alone (Linkwitz–Riley low-pass and C_L): the
    /// dual-stage device with its Haptuator switched off.
    LowChannel,
    /// A 2nd-order Butterworth low-pass at `hz` (bilinear, prewarped) on the
    /// Pantograph; Haptuator off.
    Lowpass {
        /// Corner frequency, Hz.
        hz: f64,
    },
}

impl PMode {
    /// Short description for reports.
    pub fn describe(self) -> String {
        match self {
            PMode::FullBand => "full band on the Pantograph".into(),
            PMode::LowChannel => "the D chain's low channel (crossover low-pass, C_L)".into(),
            PMode::Lowpass { hz } => format!("2nd-order Butterworth low-pass at {hz} Hz"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serde_letters_and_rig_file_aliases() {
        #[derive(Deserialize, Serialize)]
        struct W {
            c: Condition,
            p: PMode,
        }
        for (text, want) in [
            ("c = \"V\"", Condition::V),
            ("c = \"vision\"", Condition::V),
            ("c = \"pantograph\"", Condition::P),
            ("c = \"dual\"", Condition::D),
            ("c = \"D\"", Condition::D),
        ] {
            let w: W = toml::from_str(&format!("{text}\np = \"full-band\"")).unwrap();
            assert_eq!(w.c, want, "{text}");
        }
        let w: W = toml::from_str("c = \"P\"\np = { lowpass = { hz = 200.0 } }").unwrap();
        assert_eq!(w.p, PMode::Lowpass { hz: 200.0 });
        let w: W = toml::from_str("c = \"P\"\np = \"low-channel\"").unwrap();
        assert_eq!(w.p, PMode::LowChannel);
        assert!(toml::from_str::<W>("c = \"X\"\np = \"full-band\"").is_err());
        assert_eq!(
            toml::to_string(&W {
                c: Condition::P,
                p: PMode::FullBand
            })
            .unwrap(),
            "c = \"P\"\np = \"full-band\"\n"
        );
    }

    #[test]
    fn parse_and_flags() {
        assert_eq!("pantograph".parse::<Condition>(), Ok(Condition::P));
        assert!("x".parse::<Condition>().is_err());
        assert!(!Condition::V.haptic() && Condition::P.pantograph() && !Condition::P.haptuator());
        assert!(Condition::D.haptuator());
    }
}
