//! The simulated [`Station`]: the rig crate's closed loop on the simulated
//! rig ([`SimLoop`]), with the chain the study was started with (a
//! calibration or the model's as-designed chain), at a [`Fidelity`]: each
//! trial runs what its [`FidelityPlan`] asks for.

use kilotouch_rig::Condition;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::{ChainSource, HandMapping, LoopChain};
use kilotouch_rig::haptic_loop::{Clearance, SimLoop};
use kilotouch_rig::safety::{SafetyLayer, SafetyStatus};
use kilotouch_rig::sim::SimRig;
use kilotouch_rig::tweezer::{Obstacle, SimTweezer, TweezerParams};
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::Rng;

use super::Scene;
use super::station::{Station, StationSample};
use crate::error::RunError;
use crate::fidelity::{Fidelity, FidelityPlan};

/// The simulated station (module docs). A fresh rig and tweezer are built
/// for every trial from the trial's seeds (so resumed studies reproduce rows
/// exactly); the chain and its stability clearance are set up once.
#[derive(Debug)]
pub struct SimStation {
    cfg: RigConfig,
    chain: LoopChain,
    lp: SimLoop,
    // Rigs as built for the rig file at the rate divisor of the key (the
    // plant's modal decomposition is computed once per rate, not per trial:
    // [`SimRig::rebuilt`]).
    rigs: Vec<(u32, SimRig)>,
    fidelity: Fidelity,
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
            cfg: cfg.clone(),
            chain,
            lp,
            rigs: Vec::new(),
            fidelity: Fidelity::Full,
            plan: FidelityPlan::FULL,
        })
    }

    /// Run trials at `fidelity` (a new station runs at [`Fidelity::Full`]).
    pub fn set_fidelity(&mut self, fidelity: Fidelity) {
        self.fidelity = fidelity;
    }

    /// The fidelity trials run at.
    pub fn fidelity(&self) -> Fidelity {
        self.fidelity
    }

    /// The plan of the trial prepared last.
    pub fn plan(&self) -> FidelityPlan {
        self.plan
    }

    /// The rig configuration.
    pub fn config(&self) -> &RigConfig {
        &self.cfg
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

impl SimStation {
    /// A fresh rig for `cfg` (the rig file at rate divisor `decimation`)
    /// with the accelerometer seeded `accel_seed`.
    fn rig_at(
        &mut self,
        cfg: &RigConfig,
        decimation: u32,
        accel_seed: u64,
    ) -> Result<SimRig, RunError> {
        if let Some((_, r)) = self.rigs.iter().find(|(d, _)| *d == decimation) {
            return Ok(r.rebuilt(accel_seed));
        }
        let mut c = cfg.clone();
        c.accelerometer.seed = accel_seed;
        let rig = SimRig::new(&c)?;
        self.rigs.push((decimation, rig.rebuilt(accel_seed)));
        Ok(rig)
    }
}

impl Station for SimStation {
    fn sample_rate_hz(&self) -> f64 {
        self.cfg.rig.sample_rate_hz
    }

    fn mapping(&self) -> HandMapping {
        *self.lp.coupling.mapping()
    }

    fn chain_source(&self) -> ChainSource {
        self.chain.source.clone()
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        condition: Condition,
        escape_distance_m: f64,
        max_decimation: u32,
        rng: &mut ChaCha20Rng,
    ) -> Result<(), RunError> {
        let plan = FidelityPlan::for_trial(self.fidelity, condition, max_decimation);
        let fs = self.cfg.rig.sample_rate_hz / f64::from(plan.decimation);
        let mut cfg = self.cfg.clone();
        cfg.rig.sample_rate_hz = fs;
        let accel_seed = rng.next_u64();
        let mut rig = self.rig_at(&cfg, plan.decimation, accel_seed)?;
        rig.set_accelerometer_rendering(plan.decimation == 1);
        let mut p = TweezerParams::from_config(&cfg.tweezer);
        p.radius_m = scene.geometry.bead_radius_m;
        p.escape_distance_m = escape_distance_m;
        p.obstacles = vec![Obstacle {
            centre_m: scene.geometry.obstacle_m,
            radius_m: scene.geometry.obstacle_radius_m,
        }];
        p.seed = rng.next_u64();
        let mut tweezer = SimTweezer::new(p, fs)?;
        tweezer.set_contact_exact(plan.contact_exact);
        self.lp.coupling.set_lean(plan.lean_coupling);
        self.plan = plan;
        // A fresh, armed safety layer per trial: forces come on through the
        // ramp once the command is small, and a resumed study reproduces
        // every row exactly.
        let safety = SafetyLayer::from_config(&cfg)?;
        self.lp.restart(rig, tweezer, condition, safety)?;
        Ok(())
    }

    fn trial_decimation(&self) -> u32 {
        self.plan.decimation
    }

    #[inline]
    fn set_hand(&mut self, hand_m: [f64; 2]) {
        self.lp.rig.set_hand(hand_m);
    }

    #[inline]
    fn step(&mut self) -> Result<StationSample, RunError> {
        self.lp.advance()?;
        let s = self.lp.last();
        Ok(StationSample {
            sensors: s.sensors,
            command: s.command,
            tweezer: s.tweezer,
            force_hand_n: s.rendered.image_n,
        })
    }
}
