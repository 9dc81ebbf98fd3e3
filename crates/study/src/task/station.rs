//! The experimental station a trial runs on: a rig, a tweezer and the
//! bilateral coupling between them, behind the [`Station`] trait so the
//! session runner serves the simulated rig, live rigs and the GUI alike.
//!
//! Per sample (block size 1, as `kilotouch_rig::coupling::ClosedLoop`): the
//! handle position of the previous sensor frame sets the trap
//! ([`Coupling::trap_target`]), the tweezer advances one sample, the optical
//! force's reaction becomes the haptic image ([`Coupling::handle_force`]),
//! which the coupling splits into actuator commands. In condition V the
//! commands are replaced by zero (no force at the handle; the coupling's
//! filters still run so that nothing else differs). The rig then applies the
//! command and returns the next sensor frame.

use kilotouch_rig::config::RigConfig;
use kilotouch_rig::coupling::{Coupling, CouplingMode};
use kilotouch_rig::rig::{ActuatorFrame, Rig, SensorFrame, SimRig};
use kilotouch_rig::safety::{SafetyLayer, SafetyStatus};
use kilotouch_rig::tweezer::{Obstacle, SimTweezer, Tweezer, TweezerParams, TweezerSample};
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::Rng;

use super::{Feedback, Scene};
use crate::runner::RunError;

/// Handle ↔ trap position mapping (the coupling's, learned by participants
/// during training): trap = offset + scale·(hand − origin).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandMapping {
    /// Trap displacement per hand displacement, m/m.
    pub scale: f64,
    /// Hand position mapped to `trap_offset_m`, m.
    pub handle_origin_m: [f64; 2],
    /// Trap position at the origin, m.
    pub trap_offset_m: [f64; 2],
}

impl HandMapping {
    /// Trap position of a hand position, m.
    pub fn to_trap(&self, hand_m: [f64; 2]) -> [f64; 2] {
        [
            self.trap_offset_m[0] + self.scale * (hand_m[0] - self.handle_origin_m[0]),
            self.trap_offset_m[1] + self.scale * (hand_m[1] - self.handle_origin_m[1]),
        ]
    }

    /// Hand position that puts the trap at `trap_m`, m.
    pub fn to_hand(&self, trap_m: [f64; 2]) -> [f64; 2] {
        [
            self.handle_origin_m[0] + (trap_m[0] - self.trap_offset_m[0]) / self.scale,
            self.handle_origin_m[1] + (trap_m[1] - self.trap_offset_m[1]) / self.scale,
        ]
    }
}

/// One sample of a station.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StationSample {
    /// Sensor frame read at the end of the sample (handle position m,
    /// fingertip acceleration m/s²).
    pub sensors: SensorFrame,
    /// Command applied during the sample (zero in V).
    pub command: ActuatorFrame,
    /// Tweezer output of the sample.
    pub tweezer: TweezerSample,
    /// Haptic image rendered at the hand, N (zero in V).
    pub force_hand_n: [f64; 2],
}

/// A rig + tweezer + coupling that trials run on.
pub trait Station: Send {
    /// Loop rate, Hz.
    fn sample_rate_hz(&self) -> f64;
    /// The hand → trap mapping.
    fn mapping(&self) -> HandMapping;
    /// Trap position when the handle rests at its origin, m: where each
    /// trial starts.
    fn rest_trap_m(&self) -> [f64; 2];
    /// Sets up a trial: the scene's obstacle, the bead in the trap at the
    /// start, the feedback of the condition; `rng` is the trial's rig
    /// generator ([`crate::seeds::STREAM_RIG`]) for all noise seeds, so the
    /// trial does not depend on anything that ran before it.
    ///
    /// # Errors
    /// Rig or tweezer construction errors.
    fn prepare(
        &mut self,
        scene: &Scene,
        feedback: Feedback,
        escape_distance_m: f64,
        rng: &mut ChaCha20Rng,
    ) -> Result<(), RunError>;
    /// Where the participant's hand is, m (simulated rigs move the hand
    /// there linearly over the next sample; live rigs ignore it — the hand
    /// is real).
    fn set_hand(&mut self, hand_m: [f64; 2]);
    /// Advances one sample. Must not allocate.
    ///
    /// # Errors
    /// Rig errors (disconnect, not started).
    fn step(&mut self) -> Result<StationSample, RunError>;
}

/// The simulated station: [`SimRig`] (batch pacing), [`SimTweezer`] and the
/// model's as-designed [`Coupling`]. A fresh rig and tweezer are built for
/// every trial from the trial's seeds (so resumed studies reproduce rows
/// exactly); the coupling's chain is designed once.
#[derive(Debug)]
pub struct SimStation {
    cfg: RigConfig,
    rig: SimRig,
    tweezer: SimTweezer,
    coupling: Coupling,
    /// Every command passes through the rig's safety layer (limits, slew,
    /// ramp-on, handle-speed trip, e-stop), as in `ClosedLoop`.
    safety: SafetyLayer,
    sensors: SensorFrame,
    haptic: bool,
}

impl SimStation {
    /// A station for the rig configuration `cfg`.
    ///
    /// # Errors
    /// Invalid configuration, chain design failure.
    pub fn new(cfg: &RigConfig) -> Result<Self, RunError> {
        let fs = cfg.rig.sample_rate_hz;
        let mut rig = SimRig::new(cfg)?;
        rig.start()?;
        let tweezer = SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), fs)?;
        let coupling = Coupling::from_config(cfg)?;
        Ok(Self {
            cfg: cfg.clone(),
            rig,
            tweezer,
            coupling,
            safety: SafetyLayer::from_config(cfg)?,
            sensors: SensorFrame::default(),
            haptic: true,
        })
    }

    /// The rig configuration.
    pub fn config(&self) -> &RigConfig {
        &self.cfg
    }

    /// The simulated rig (ground truth for tests).
    pub fn rig(&self) -> &SimRig {
        &self.rig
    }

    /// The coupling.
    pub fn coupling(&self) -> &Coupling {
        &self.coupling
    }

    /// The safety layer's state, trip and counters.
    pub fn safety_status(&self) -> SafetyStatus {
        self.safety.status()
    }
}

impl Station for SimStation {
    fn sample_rate_hz(&self) -> f64 {
        self.cfg.rig.sample_rate_hz
    }

    fn mapping(&self) -> HandMapping {
        let c = &self.cfg.coupling;
        HandMapping {
            scale: c.position_scale,
            handle_origin_m: c.handle_origin_m,
            trap_offset_m: c.trap_offset_m,
        }
    }

    fn rest_trap_m(&self) -> [f64; 2] {
        let c = &self.cfg.coupling;
        let t = self.mapping().to_trap([0.0, 0.0]);
        [
            t[0].clamp(c.trap_min_m[0], c.trap_max_m[0]),
            t[1].clamp(c.trap_min_m[1], c.trap_max_m[1]),
        ]
    }

    fn prepare(
        &mut self,
        scene: &Scene,
        feedback: Feedback,
        escape_distance_m: f64,
        rng: &mut ChaCha20Rng,
    ) -> Result<(), RunError> {
        let fs = self.cfg.rig.sample_rate_hz;
        let mut cfg = self.cfg.clone();
        cfg.accelerometer.seed = rng.next_u64();
        let mut rig = SimRig::new(&cfg)?;
        rig.start()?;
        let mut p = TweezerParams::from_config(&cfg.tweezer);
        p.radius_m = scene.geometry.bead_radius_m;
        p.escape_distance_m = escape_distance_m;
        p.obstacles = vec![Obstacle {
            centre_m: scene.geometry.obstacle_m,
            radius_m: scene.geometry.obstacle_radius_m,
        }];
        p.seed = rng.next_u64();
        let mut tweezer = SimTweezer::new(p, fs)?;
        self.coupling.reset();
        self.coupling
            .set_mode(feedback.haptic.unwrap_or(CouplingMode::Pantograph));
        self.haptic = feedback.haptic.is_some();
        self.sensors = SensorFrame::default();
        let trap = self.coupling.trap_target(self.sensors.handle_m);
        tweezer.reset(trap);
        // A fresh, armed safety layer per trial: forces come on through the
        // ramp once the command is small, and a resumed study reproduces
        // every row exactly.
        let mut safety = SafetyLayer::from_config(&cfg)?;
        safety.arm()?;
        self.safety = safety;
        self.rig = rig;
        self.tweezer = tweezer;
        Ok(())
    }

    #[inline]
    fn set_hand(&mut self, hand_m: [f64; 2]) {
        self.rig.set_hand(hand_m);
    }

    #[inline]
    fn step(&mut self) -> Result<StationSample, RunError> {
        let trap = self.coupling.trap_target(self.sensors.handle_m);
        let tw = self.tweezer.step(trap);
        let image = self.coupling.handle_force(&tw);
        let cmd = self.coupling.actuate(image);
        let (command, force_hand_n) = if self.haptic {
            (cmd, image)
        } else {
            (ActuatorFrame::default(), [0.0; 2])
        };
        let command = self.safety.apply(command, &self.sensors, false);
        let mut out = [SensorFrame::default()];
        self.rig.process_block(&[command], &mut out)?;
        self.sensors = out[0];
        Ok(StationSample {
            sensors: out[0],
            command,
            tweezer: tw,
            force_hand_n,
        })
    }
}
