//! The experimental station a trial runs on: a rig, a tweezer and the
//! bilateral coupling between them, behind the [`Station`] trait so the
//! trial logic serves the simulated rig and live rigs alike. Two
//! implementations: [`super::sim_station::SimStation`] (simulated, prepares
//! its own trials: [`PrepareStation`]) and the app's real-time engine,
//! which runs trials on its own closed loop and installs each trial's
//! tweezer and safety layer built off the real-time path.
//!
//! One sample is one step of the rig crate's closed loop
//! ([`kilotouch_rig::HapticLoop`]): the handle position of the previous
//! sensor frame sets the trap, the tweezer advances one sample, the optical
//! force's reaction (plus the wall damper in contact) becomes the haptic
//! image, the coupling routes it by [`Condition`] (V: zero force, the
//! filters still run), the safety layer limits it and the rig applies it.
//! A station advances in blocks ([`Station::step_block`]): a live rig
//! exchanges a block per round trip, the simulated rig steps each sample.

use kilotouch_rig::coupling::ChainSource;
use kilotouch_rig::device::{ActuatorFrame, SensorFrame};
use kilotouch_rig::tweezer::TweezerSample;
use kilotouch_rig::{Condition, LoopSample};
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

impl StationSample {
    /// The station sample of one step of the closed loop: its sensor frame,
    /// command and tweezer output, and the rendered image of the optical
    /// force at the hand (N).
    #[inline]
    pub fn from_loop(l: &LoopSample) -> Self {
        Self {
            sensors: l.sensors,
            command: l.command,
            tweezer: l.tweezer,
            force_hand_n: l.rendered.image_n,
        }
    }
}

/// The largest block a station advances at once, samples (the closed
/// loop's [`kilotouch_rig::haptic_loop::MAX_BLOCK`]).
pub const MAX_STATION_BLOCK: usize = kilotouch_rig::haptic_loop::MAX_BLOCK;

/// A rig + tweezer + coupling that trials run on.
pub trait Station {
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
    /// The rate divisor of the trial prepared last: one sample of
    /// [`Self::step_block`] advances this many samples of
    /// [`Self::sample_rate_hz`] (1, the default: every sample).
    fn trial_decimation(&self) -> u32 {
        1
    }
    /// Is the participant's hand real (a live rig, whose handle a person —
    /// or the device's own simulated participant — moves)? Then the hand
    /// positions given to [`Self::step_block`] are ignored, and what a trial
    /// records as the hand is the measured handle. Default `false`.
    fn hand_is_real(&self) -> bool {
        false
    }
    /// Advances `hands.len()` (≤ [`MAX_STATION_BLOCK`]) samples; `hands[i]`
    /// is where the participant's hand is during sample i (m; simulated
    /// rigs move the hand there linearly over the sample, live rigs ignore
    /// it), `out[i]` receives sample i (`out.len() == hands.len()`). Must
    /// not allocate.
    ///
    /// # Errors
    /// Rig errors (disconnect, not started).
    fn step_block(&mut self, hands: &[[f64; 2]], out: &mut [StationSample])
    -> Result<(), RunError>;
}

/// A station that builds each trial itself (the simulated station):
/// fresh rig noise and tweezer from the trial's seeds.
pub trait PrepareStation: Station + Send {
    /// Sets up a trial: the scene's obstacle, the bead in the trap at the
    /// start, the condition; `rng` is the trial's rig generator
    /// ([`crate::seeds::STREAM_RIG`]) for all noise seeds, so the trial does
    /// not depend on anything that ran before it. `max_decimation` is the
    /// largest rate divisor the runner can take for this trial (1: the
    /// trial must run at [`Station::sample_rate_hz`], e.g. for a raw file);
    /// the station says which it chose through
    /// [`Station::trial_decimation`]. Allocates (not real-time).
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

    /// The camera the participant watches (the rig file's `[camera]`).
    fn camera(&self) -> kilotouch_rig::config::CameraConfig;
}
