//! The experimental station a trial runs on: a rig, a tweezer and the
//! bilateral coupling between them, behind the [`Station`] trait so the
//! session runner serves the simulated rig, live rigs and the GUI alike.
//! The simulated implementation is [`super::sim_station::SimStation`].
//!
//! One sample is one step of the rig crate's closed loop
//! ([`kilotouch_rig::HapticLoop`]): the handle position of the previous
//! sensor frame sets the trap, the tweezer advances one sample, the optical
//! force's reaction (plus the wall damper in contact) becomes the haptic
//! image, the coupling routes it by [`Condition`] (V: zero force, the
//! filters still run), the safety layer limits it and the rig applies it.

use kilotouch_rig::Condition;
use kilotouch_rig::coupling::ChainSource;
use kilotouch_rig::device::{ActuatorFrame, SensorFrame};
use kilotouch_rig::tweezer::TweezerSample;
use rand_chacha::ChaCha20Rng;

pub use kilotouch_rig::coupling::HandMapping;

use super::Scene;
use crate::error::RunError;

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
    /// Image of the optical force rendered at the hand, N (zero in V): what
    /// the force metrics use (the wall damper is not part of it).
    pub force_hand_n: [f64; 2],
}

/// A rig + tweezer + coupling that trials run on.
pub trait Station: Send {
    /// Loop rate, Hz.
    fn sample_rate_hz(&self) -> f64;
    /// The hand ↔ trap mapping.
    fn mapping(&self) -> HandMapping;
    /// Trap position when the handle rests at its origin, m: where each
    /// trial starts.
    fn rest_trap_m(&self) -> [f64; 2] {
        self.mapping().rest_trap_m()
    }
    /// The chain the D condition runs (calibrated or as designed).
    fn chain_source(&self) -> ChainSource;
    /// Sets up a trial: the scene's obstacle, the bead in the trap at the
    /// start, the condition; `rng` is the trial's rig generator
    /// ([`crate::seeds::STREAM_RIG`]) for all noise seeds, so the trial does
    /// not depend on anything that ran before it. `max_decimation` is the
    /// largest rate divisor the runner can take for this trial (1: the
    /// trial must run at [`Self::sample_rate_hz`], e.g. for a raw file);
    /// the station says which it chose through [`Self::trial_decimation`].
    ///
    /// # Errors
    /// Rig or tweezer construction errors.
    fn prepare(
        &mut self,
        scene: &Scene,
        condition: Condition,
        escape_distance_m: f64,
        max_decimation: u32,
        rng: &mut ChaCha20Rng,
    ) -> Result<(), RunError>;
    /// The rate divisor of the trial prepared last: one [`Self::step`]
    /// advances this many samples of [`Self::sample_rate_hz`] (1, the
    /// default: every sample; a divisor of `max_decimation`).
    fn trial_decimation(&self) -> u32 {
        1
    }
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
