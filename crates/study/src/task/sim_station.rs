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

    /// The closed loop (ground truth for tests: `lp.rig.truth()`).
    pub fn closed_loop(&self) -> &SimLoop {
        &self.lp
    }

    /// The simulated rig (ground truth for tests).
    pub fn rig(&self) -> &SimRig {
        &self.lp.rig
    }

    /// The safety layer's state, trip and counters.
    pub fn safety_status(&self) -> SafetyStatus {
        self.lp.safety_status()
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
        for (h, o) in hands.iter().zip(out.iter_mut()) {
            self.lp.rig.set_hand(*h);
            self.lp.advance()?;
            *o = StationSample::from_loop(self.lp.last());
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
        self.lp.coupling.set_lean(kit.plan.lean_coupling);
        self.plan = kit.plan;
        self.lp.restart(rig, kit.tweezer, condition, kit.safety)?;
        Ok(())
    }
}
