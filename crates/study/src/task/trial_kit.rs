//! What a trial runs on, built from its scene and its rig generator: a
//! fresh simulated rig (its accelerometer noise seeded by the trial), the
//! tweezer with the scene's obstacle and the trial's Brownian seed, and a
//! fresh armed safety layer — one builder for the simulated station and the
//! app's real-time engine, so a trial is the same function of its key on
//! both. Building allocates (the plant's state, the tweezer's tables): it
//! runs off the real-time path, and the engine swaps the parts in.

use kilotouch_rig::Condition;
use kilotouch_rig::config::RigConfig;
use kilotouch_rig::device::RigIdentity;
use kilotouch_rig::safety::SafetyLayer;
use kilotouch_rig::sim::SimRig;
use kilotouch_rig::tweezer::{SimTweezer, TweezerParams};
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::Rng;

use super::Scene;
use crate::error::RunError;
use crate::fidelity::{Fidelity, FidelityPlan};

/// The parts of one trial (module docs).
#[derive(Debug)]
pub struct TrialKit {
    /// A fresh simulated rig at the trial's rate (`None` for a live rig).
    pub rig: Option<SimRig>,
    /// The tweezer of the trial's scene.
    pub tweezer: SimTweezer,
    /// A fresh safety layer, armed.
    pub safety: SafetyLayer,
    /// What the trial runs ([`FidelityPlan`]).
    pub plan: FidelityPlan,
}

/// Builds [`TrialKit`]s for one rig file (module docs).
#[derive(Debug, Clone)]
pub struct KitBuilder {
    cfg: RigConfig,
    // Rigs as built for the rig file at the rate divisor of the key (the
    // plant's modal decomposition is computed once per rate, not per
    // trial: [`SimRig::rebuilt`]).
    rigs: Vec<(u32, SimRig)>,
    fidelity: Fidelity,
    live: Option<RigIdentity>,
}

impl KitBuilder {
    /// A builder for the simulated rig of `cfg`, at [`Fidelity::Full`].
    pub fn new(cfg: &RigConfig) -> Self {
        Self {
            cfg: cfg.clone(),
            rigs: Vec::new(),
            fidelity: Fidelity::Full,
            live: None,
        }
    }

    /// A builder for a live rig that identifies itself as `id`: no
    /// simulated rig, the safety layer for the device's limits, every trial
    /// at the device's rate ([`Fidelity::Full`]).
    pub fn live(cfg: &RigConfig, id: &RigIdentity) -> Self {
        let mut cfg = cfg.clone();
        cfg.rig.sample_rate_hz = id.sample_rate_hz;
        Self {
            cfg,
            rigs: Vec::new(),
            fidelity: Fidelity::Full,
            live: Some(id.clone()),
        }
    }

    /// Build trials at `fidelity` (simulated rigs only; a live rig runs
    /// every trial in full).
    pub fn set_fidelity(&mut self, fidelity: Fidelity) {
        if self.live.is_none() {
            self.fidelity = fidelity;
        }
    }

    /// The fidelity trials are built at.
    pub fn fidelity(&self) -> Fidelity {
        self.fidelity
    }

    /// The rig configuration.
    pub fn config(&self) -> &RigConfig {
        &self.cfg
    }

    /// The parts of a trial on `scene` in `condition` with the escape
    /// distance `escape_distance_m` (m), at a rate divisor that divides
    /// `max_decimation`, seeded from the trial's rig generator `rng`: the
    /// accelerometer's seed is drawn first (also for a live rig, so the
    /// tweezer's seed is the one the simulated trial draws), then the
    /// tweezer's.
    ///
    /// # Errors
    /// Invalid rig file or scene.
    pub fn build(
        &mut self,
        scene: &Scene,
        condition: Condition,
        escape_distance_m: f64,
        max_decimation: u32,
        rng: &mut ChaCha20Rng,
    ) -> Result<TrialKit, RunError> {
        let plan = FidelityPlan::for_trial(self.fidelity, condition, max_decimation);
        let fs = self.cfg.rig.sample_rate_hz / f64::from(plan.decimation);
        let mut cfg = self.cfg.clone();
        cfg.rig.sample_rate_hz = fs;
        let accel_seed = rng.next_u64();
        let rig = match self.live {
            Some(_) => None,
            None => {
                let mut rig = self.rig_at(&cfg, plan.decimation, accel_seed)?;
                // What P and D's participant feels is the fingertip
                // acceleration: rendered at every rate P and D run at.
                rig.set_accelerometer_rendering(plan.decimation == 1 || condition != Condition::V);
                Some(rig)
            }
        };
        scene.geometry.apply_to(&mut cfg.tweezer, escape_distance_m);
        let mut p = TweezerParams::from_config(&cfg.tweezer);
        p.seed = rng.next_u64();
        let mut tweezer = SimTweezer::new(p, fs)?;
        tweezer.set_contact_exact(plan.contact_exact);
        // A fresh, armed safety layer per trial: forces come on through the
        // ramp once the command is small, and a resumed study reproduces
        // every row exactly.
        let mut safety = match &self.live {
            Some(id) => SafetyLayer::for_rig(id, &cfg.safety)?,
            None => SafetyLayer::from_config(&cfg)?,
        };
        safety.arm()?;
        Ok(TrialKit {
            rig,
            tweezer,
            safety,
            plan,
        })
    }

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
