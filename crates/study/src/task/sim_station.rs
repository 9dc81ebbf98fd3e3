//! The simulated [`Station`]: the rig crate's closed loop on the simulated
//! rig ([`SimLoop`]), with the chain the study was started with (a
//! calibration or the model's as-designed chain), at a [`Fidelity`]: each
//! trial runs what its [`FidelityPlan`] asks for.

use kilotouch_rig::Condition;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::{ChainSource, HandMapping, LoopChain};
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::safety::SafetyStatus;
use kilotouch_rig::sim::SimRig;
use rand_chacha::ChaCha20Rng;

use super::Scene;
use super::station::{PrepareStation, Station, StationSample};
use super::trial_kit::KitBuilder;
use crate::error::RunError;
use crate::fidelity::{Fidelity, FidelityPlan};

/// The simulated station (module docs). A fresh rig and tweezer are built
/// for every trial from the trial's seeds (so resumed studies reproduce rows
/// exactly); the chain and its stability clearance are set up once.
#[derive(Debug)]
pub struct SimStation {
    chain: LoopChain,
    lp: SimLoop,
    /// P and D's loop at the draft rate ([`crate::fidelity::Fidelity::Draft`]),
    /// built and cleared on the first draft trial, with its divisor.
    draft: Option<(u32, SimLoop)>,
    /// The trial prepared last runs on `draft`.
    on_draft: bool,
    kits: KitBuilder,
    plan: FidelityPlan,
}

impl SimStation {
    /// A station for the rig configuration `cfg` with the model's
    /// as-designed chain (uncalibrated).
    ///
    /// # Errors
    /// Invalid configuration; a loop whose margins are below the minimum.
    pub fn new(cfg: &RigConfig) -> Result<Self, RunError> {
        Self::with_chain(cfg, LoopChain::as_designed(cfg)?)
    }

    /// A station running `chain` (e.g. from a calibration file).
    ///
    /// # Errors
    /// Invalid configuration; a loop whose margins are below the minimum
    /// (the error names the margin and the largest safe force scale).
    pub fn with_chain(cfg: &RigConfig, chain: LoopChain) -> Result<Self, RunError> {
        let clearance = Clearance::check(cfg, &chain)?;
        let lp = SimLoop::simulated(cfg, &chain, clearance)?;
        Ok(Self {
            chain,
            lp,
            draft: None,
            on_draft: false,
            kits: KitBuilder::new(cfg),
            plan: FidelityPlan::FULL,
        })
    }

    /// Run trials at `fidelity` (a new station runs at [`Fidelity::Full`]).
    pub fn set_fidelity(&mut self, fidelity: Fidelity) {
        self.kits.set_fidelity(fidelity);
    }

    /// The fidelity trials run at.
    pub fn fidelity(&self) -> Fidelity {
        self.kits.fidelity()
    }

    /// The plan of the trial prepared last.
    pub fn plan(&self) -> FidelityPlan {
        self.plan
    }

    /// The rig configuration.
    pub fn config(&self) -> &RigConfig {
        self.kits.config()
    }

    /// The closed loop of the trial prepared last (ground truth for
    /// tests: `lp.rig.truth()`).
    pub fn closed_loop(&self) -> &SimLoop {
        match (&self.draft, self.on_draft) {
            (Some((_, lp)), true) => lp,
            _ => &self.lp,
        }
    }

    /// The simulated rig (ground truth for tests).
    pub fn rig(&self) -> &SimRig {
        &self.closed_loop().rig
    }

    /// The safety layer's state, trip and counters.
    pub fn safety_status(&self) -> SafetyStatus {
        self.closed_loop().safety_status()
    }

    fn active_mut(&mut self) -> &mut SimLoop {
        match (&mut self.draft, self.on_draft) {
            (Some((_, lp)), true) => lp,
            _ => &mut self.lp,
        }
    }
}

impl Station for SimStation {
    fn sample_rate_hz(&self) -> f64 {
        self.kits.config().rig.sample_rate_hz
    }

    fn mapping(&self) -> HandMapping {
        *self.lp.coupling.mapping()
    }

    fn chain_source(&self) -> ChainSource {
        self.chain.source.clone()
    }

    fn trial_decimation(&self) -> u32 {
        self.plan.decimation
    }

    #[inline]
    fn step_block(
        &mut self,
        hands: &[[f64; 2]],
        out: &mut [StationSample],
    ) -> Result<(), RunError> {
        let lp = self.active_mut();
        for (h, o) in hands.iter().zip(out.iter_mut()) {
            lp.rig.set_hand(*h);
            lp.advance()?;
            *o = StationSample::from_loop(lp.last());
        }
        Ok(())
    }
}

impl PrepareStation for SimStation {
    fn camera(&self) -> kilotouch_rig::config::CameraConfig {
        self.kits.config().camera
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        condition: Condition,
        escape_distance_m: f64,
        max_decimation: u32,
        rng: &mut ChaCha20Rng,
    ) -> Result<(), RunError> {
        let kit = self
            .kits
            .build(scene, condition, escape_distance_m, max_decimation, rng)?;
        let rig = kit
            .rig
            .ok_or_else(|| RunError::State("a simulated trial without a rig".into()))?;
        // P and D below the rig's rate (draft) close the loop through a
        // coupling designed and cleared at that rate.
        let d = kit.plan.decimation;
        self.on_draft = d > 1 && condition != Condition::V;
        if self.on_draft && self.draft.as_ref().is_none_or(|(dd, _)| *dd != d) {
            self.draft = Some((d, draft_loop(self.kits.config(), &self.chain, d)?));
        }
        self.plan = kit.plan;
        let lp = self.active_mut();
        lp.coupling.set_lean(kit.plan.lean_coupling);
        lp.restart(rig, kit.tweezer, condition, kit.safety)?;
        Ok(())
    }
}

/// The closed loop of `cfg` with `chain` at the rig's rate divided by
/// `divisor` ([`crate::fidelity::Fidelity::Draft`]): the chain designed
/// again at that rate and its stability clearance checked at that rate.
///
/// # Errors
/// [`RunError::DraftLoopNotSafe`] when a margin at that rate is below the
/// minimum (the reason names the margin, the minimum and the largest safe
/// force scale) or the chain comes from a calibration, which is for the
/// rig's rate only; configuration errors.
pub fn draft_loop(cfg: &RigConfig, chain: &LoopChain, divisor: u32) -> Result<SimLoop, RunError> {
    let mut cfg = cfg.clone();
    cfg.rig.sample_rate_hz /= f64::from(divisor.max(1));
    let rate_hz = cfg.rig.sample_rate_hz;
    let refuse = |why: String| RunError::DraftLoopNotSafe {
        rate_hz,
        divisor,
        why,
    };
    if chain.source != ChainSource::AsDesigned {
        return Err(refuse(format!(
            "the chain ({}) is for the rig's rate only",
            chain.source.describe()
        )));
    }
    let draft_chain = LoopChain::as_designed(&cfg)?;
    let clearance = match Clearance::check(&cfg, &draft_chain) {
        Ok(c) => c,
        Err(kilotouch_rig::RigError::LoopNotSafe(why)) => return Err(refuse(why)),
        Err(e) => return Err(e.into()),
    };
    Ok(SimLoop::simulated(&cfg, &draft_chain, clearance)?)
}
