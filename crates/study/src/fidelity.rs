//! Simulation fidelity: which parts of the model a simulated trial runs.
//!
//! [`Fidelity::Full`] runs the whole model at every sample whatever the
//! trial needs: the reference. [`Fidelity::Scene`] runs only what the
//! trial's scene, condition and recording use ([`FidelityPlan::for_trial`]):
//!
//! | shortcut | when | what is skipped | effect on the trial |
//! |---|---|---|---|
//! | no haptic rendering in V | condition V | the coupling's filters (P paths, D chain, wall damper), whose outputs V zeroes ([`kilotouch_rig::coupling::Coupling::set_lean`]) | none (bit for bit) |
//! | no D chain in P | condition P (unless `p_mode = low-channel`) | the crossover and both compensators (the Haptuator's lane), whose outputs P ignores (the same switch) | none (bit for bit) |
//! | exact contact step | every condition | the tweezer's sub-steps while the bead sits in the contact zone, replaced by one exact OU step ([`kilotouch_rig::tweezer::SimTweezer::set_contact_exact`]) | same distribution of the bead; a different noise sequence |
//! | P and D at a lower loop rate (draft only) | [`Fidelity::Draft`], conditions P and D, no raw file | the samples between two draft loop instants ([`DRAFT_LOOP_DIVISOR`]): rig, coupling (its chain designed again at the lower rate), tweezer and runner step at the rig's rate / divisor; the accelerometer is rendered at that rate (the participant feels it in D); the loop is armed only if the stability analysis at that rate meets the minimum margins, else the trial is refused ([`crate::error::RunError::DraftLoopNotSafe`]) | a longer loop delay (one sample at the lower rate), different margins and what the participant feels: measured, not bit for bit (`kilotouch bench fidelity`, 240 test trials per condition: every metric within 1.26 pooled SE of `full`, but D's displacement error rises to P's and a power analysis of P − D no longer finds an n: D's advantage is lost at 2 kHz, `docs/PERFORMANCE.md`) |
//! | V at the control rate | condition V, no raw file | the samples between two control instants: the rig (the plant's exact ZOH map at the control rate), the tweezer and the runner step once per control period ([`FidelityPlan::decimation`]); the accelerometer is not rendered ([`kilotouch_rig::sim::SimRig::set_accelerometer_rendering`]) | same distributions; 1 ms instead of 0.1 ms time resolution |
//!
//! V may leave the rig's rate because it closes no loop through the device:
//! the hand drives the plant, the encoder sets the trap, the participant
//! only sees the bead. The plant still runs (replacing it by a handle that
//! follows the hand rigidly changed V's success rate by 3.5 pooled standard
//! errors: the device's own dynamics shake the trap), at the control rate,
//! where its exact sampled map keeps those dynamics. P and D close the
//! haptic loop at the rig's rate at `scene` and keep it; [`Fidelity::Draft`]
//! runs that loop at a fifth of the rig's rate (the chain designed again and
//! the margins analysed at that rate: the shipped rig clears the minimum
//! margins at 2 kHz; with the trap twice as stiff D's phase margin there is
//! 22.6° against the 30° minimum and the draft trial is refused). Each
//! level's speed and change of the study metrics are measured by
//! `kilotouch bench fidelity` (`docs/PERFORMANCE.md`, "Fidelity levels").

use std::fmt;
use std::str::FromStr;

use kilotouch_rig::Condition;
use serde::{Deserialize, Serialize};

/// How much of the model a simulated study runs (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Fidelity {
    /// Only what each trial's scene needs (the default).
    #[default]
    Scene,
    /// The whole model at every sample (the reference).
    Full,
    /// [`Fidelity::Scene`] plus P and D's haptic loop at the rig's rate
    /// divided by [`DRAFT_LOOP_DIVISOR`], its stability clearance checked
    /// at that rate (module docs): for power planning.
    Draft,
}

/// Rate divisor of P and D's haptic loop at [`Fidelity::Draft`] (used when
/// it divides the runner's largest allowed divisor; else 1).
pub const DRAFT_LOOP_DIVISOR: u32 = 5;

impl Fidelity {
    /// Every fidelity.
    pub const ALL: [Fidelity; 3] = [Fidelity::Scene, Fidelity::Full, Fidelity::Draft];

    /// The name used on the command line and in `session.json`.
    pub fn name(self) -> &'static str {
        match self {
            Fidelity::Scene => "scene",
            Fidelity::Full => "full",
            Fidelity::Draft => "draft",
        }
    }
}

impl fmt::Display for Fidelity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Fidelity {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "scene" => Ok(Fidelity::Scene),
            "full" => Ok(Fidelity::Full),
            "draft" => Ok(Fidelity::Draft),
            other => Err(format!(
                "unknown fidelity `{other}` (expected scene, full or draft)"
            )),
        }
    }
}

/// What one trial runs (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FidelityPlan {
    /// Skip filters whose outputs the condition ignores (the D chain in P).
    pub lean_coupling: bool,
    /// Step the bead in sustained contact exactly instead of sub-stepping.
    pub contact_exact: bool,
    /// Rate divisor of the trial (1: the rig's rate): V without a raw file
    /// runs at the control rate, with the accelerometer not rendered.
    pub decimation: u32,
}

impl FidelityPlan {
    /// The whole model.
    pub const FULL: FidelityPlan = FidelityPlan {
        lean_coupling: false,
        contact_exact: false,
        decimation: 1,
    };

    /// The plan of a trial in `condition` at `fidelity`, when the runner
    /// can take a rate divisor up to `max_decimation` (1 with a raw file:
    /// [`crate::task::station::Station::prepare`]).
    pub fn for_trial(fidelity: Fidelity, condition: Condition, max_decimation: u32) -> Self {
        match fidelity {
            Fidelity::Full => Self::FULL,
            Fidelity::Draft => {
                let scene = Self::for_trial(Fidelity::Scene, condition, max_decimation);
                let d = DRAFT_LOOP_DIVISOR;
                FidelityPlan {
                    decimation: if condition != Condition::V
                        && max_decimation.max(1).is_multiple_of(d)
                    {
                        d
                    } else {
                        scene.decimation
                    },
                    ..scene
                }
            }
            Fidelity::Scene => FidelityPlan {
                // V and P ignore some filters' outputs; D uses them all.
                lean_coupling: condition != Condition::D,
                contact_exact: true,
                // V has no loop to keep at the rig's rate: nothing the
                // participant feels depends on the hand's path between two
                // control instants.
                decimation: if condition == Condition::V {
                    max_decimation.max(1)
                } else {
                    1
                },
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_follow_the_condition() {
        for c in Condition::ALL {
            assert_eq!(
                FidelityPlan::for_trial(Fidelity::Full, c, 10),
                FidelityPlan::FULL
            );
            assert!(FidelityPlan::for_trial(Fidelity::Scene, c, 10).contact_exact);
            // A raw file keeps every trial at the rig's rate.
            assert_eq!(FidelityPlan::for_trial(Fidelity::Scene, c, 1).decimation, 1);
        }
        let scene = |c| FidelityPlan::for_trial(Fidelity::Scene, c, 10);
        assert!(scene(Condition::V).lean_coupling);
        assert!(scene(Condition::P).lean_coupling);
        assert!(!scene(Condition::D).lean_coupling);
        assert_eq!(scene(Condition::V).decimation, 10);
        assert_eq!(scene(Condition::P).decimation, 1);
        assert_eq!(scene(Condition::D).decimation, 1);
        assert_eq!("scene".parse::<Fidelity>(), Ok(Fidelity::Scene));
        assert_eq!("full".parse::<Fidelity>(), Ok(Fidelity::Full));
        assert!("fast".parse::<Fidelity>().is_err());
        assert_eq!("draft".parse::<Fidelity>(), Ok(Fidelity::Draft));
        let draft = |c| FidelityPlan::for_trial(Fidelity::Draft, c, 10);
        assert_eq!(draft(Condition::V), scene(Condition::V));
        for c in [Condition::P, Condition::D] {
            assert_eq!(draft(c).decimation, DRAFT_LOOP_DIVISOR);
            assert_eq!(draft(c).lean_coupling, scene(c).lean_coupling);
            assert_eq!(FidelityPlan::for_trial(Fidelity::Draft, c, 1).decimation, 1);
        }
        assert_eq!(
            serde_json::to_string(&Fidelity::Scene).ok().as_deref(),
            Some("\"scene\"")
        );
    }
}
