//! The rig interface: what every backend (simulated, serial DAQ, audio
//! interface) implements and every controller uses. The backends live in
//! their own modules: [`crate::sim`], [`crate::serial`], `crate::audio`.
//!
//! # Interface
//!
//! A [`Rig`] exchanges *blocks* of frames at its sample rate (default
//! 10 kHz): one [`ActuatorFrame`] per sample goes out (Pantograph force x, y
//! in N; Haptuator drive in V) and one [`SensorFrame`] per sample comes back
//! (handle position x, y in m; fingertip acceleration x, y, z in m/s²),
//! stamped with the device's sequence number. Command `i` of a block is
//! applied during sample `first_seq + i`; sensor frame `i` is read at the
//! end of that sample. Identity, status and faults are queried separately.
//!
//! How live backends fit the same calls without change:
//! * **Serial DAQ at 10 kHz.** Frames carry the device's sequence number;
//!   a gap in the numbers is filled with placeholder frames flagged
//!   [`FrameFlags::LOST`] (last good values held), counted in
//!   [`BlockReport::lost_frames`] and reported as [`RigFault::LostFrames`].
//! * **Audio interface via a cpal callback.** The callback thread owns the
//!   device; `process_block` only moves frames through lock-free SPSC rings,
//!   so it neither locks nor allocates; callback under-runs surface as
//!   [`RigFault::Overrun`] and lost frames.
//! * **Device watchdog.** A device that zeroes its outputs after missing
//!   commands reports [`RigFault::WatchdogTripped`], one whose emergency
//!   stop was engaged [`RigFault::EmergencyStop`]; the rig enters
//!   [`RigState::Faulted`] until `start` is called again.
//! * **Disconnects.** `process_block` returns [`RigError::Disconnected`] and
//!   the state becomes [`RigState::Disconnected`].
//!
//! `process_block` must not allocate, lock or panic in any implementation;
//! faults are queued in a fixed-capacity ring ([`FaultQueue`]).

mod clock;
mod fault;
mod frame;
mod identity;
mod info;
mod spec;

pub use clock::{Clock, ManualClock, SystemClock};
pub(crate) use fault::StatusCounters;
pub use fault::{FaultQueue, LinkErrorKind, RigFault};
pub use frame::{ActuatorFrame, BlockReport, FrameFlags, SensorFrame};
pub use identity::{
    ANNOUNCED_BOUNDS, AnnouncedBound, RigIdentity, RigKind, RigState, RigStatus, validate_announced,
};
pub use info::{HandAgent, HostInfo, PhaseCode, TaskCode, TrialInfo, VisualFrame};
pub use spec::{RigSpec, TweezerSpec};

use crate::error::RigError;

/// The opening every backend's [`Rig::process_block`] shares: a rig that is
/// not [`RigState::Running`] refuses ([`RigError::NotReady`]), and so does a
/// block with a different number of commands and sensor frames (one sensor
/// frame per command, [`RigError::InvalidInput`]); otherwise the block's
/// report, starting at sequence number `first_seq`, with `commands.len()`
/// frames and nothing else counted yet.
pub fn open_block(
    state: RigState,
    commands: &[ActuatorFrame],
    sensors: &[SensorFrame],
    first_seq: u64,
) -> Result<BlockReport, RigError> {
    if state != RigState::Running {
        return Err(RigError::NotReady(
            "call start() before process_block()".into(),
        ));
    }
    if commands.len() != sensors.len() {
        return Err(RigError::InvalidInput(format!(
            "{} commands but {} sensor frames",
            commands.len(),
            sensors.len()
        )));
    }
    Ok(BlockReport {
        first_seq,
        frames: commands.len(),
        ..Default::default()
    })
}

/// A haptic rig, simulated or live (module docs).
pub trait Rig: Send {
    /// Identity.
    fn identity(&self) -> &RigIdentity;
    /// Sample rate, Hz.
    fn sample_rate_hz(&self) -> f64 {
        self.identity().sample_rate_hz
    }
    /// Start exchanging frames (anchors the clock of paced rigs).
    fn start(&mut self) -> Result<(), RigError>;
    /// Stop; actuators go to zero.
    fn stop(&mut self) -> Result<(), RigError>;
    /// Exchange one block: `commands.len()` must equal `sensors.len()`.
    /// Paced and live rigs block until the block's frames are due; batch
    /// rigs return at once. Must not allocate, lock or panic.
    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError>;
    /// Exchange a block of one frame: exactly
    /// `process_block(&[*command], &mut [*sensors])` (the default
    /// implementation), which a rig may override with a cheaper path for the
    /// sample-by-sample [`HapticLoop`](crate::HapticLoop) (the
    /// batch [`SimRig`](crate::sim::SimRig) does). `sensors` is written only on success. Must not
    /// allocate, lock or panic.
    #[inline]
    fn process_frame(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        frame_as_block(self, command, sensors)
    }
    /// Current counters and state.
    fn status(&self) -> RigStatus;
    /// Oldest queued fault, if any.
    fn pop_fault(&mut self) -> Option<RigFault>;
    /// Loop delay, in samples, of a closed loop that exchanges blocks of
    /// `block_len` frames with this rig through
    /// [`HapticLoop::step_block`](crate::HapticLoop::step_block): from the
    /// sensor frame a command is computed from to the sample that command
    /// is applied in. The default is a block-synchronous exchange (the
    /// commands of block b come from the sensors of block b − 1: `block_len`
    /// samples); a rig that sends commands ahead (a command lead) adds it;
    /// the batch simulated rig, stepped one frame at a time, has 1.
    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        u32::try_from(block_len.max(1)).unwrap_or(u32::MAX)
    }
    /// The link round trip measured when the rig connected, s (`None`: not
    /// a link, or not measured).
    fn round_trip_s(&self) -> Option<f64> {
        None
    }
    /// Tell the device about the experiment ([`HostInfo`]); a device
    /// without a participant at its handle ignores it (the default). Must
    /// not allocate or block: a backend queues it with its next frames.
    ///
    /// # Errors
    /// Backend-specific (a link that is down).
    fn send_info(&mut self, info: &HostInfo) -> Result<(), RigError> {
        let _ = info;
        Ok(())
    }
}

/// One frame exchanged as a one-frame block: the default
/// [`Rig::process_frame`], also the fallback of rigs that override it.
/// `sensors` is written only on success.
#[inline]
pub fn frame_as_block<R: Rig + ?Sized>(
    rig: &mut R,
    command: &ActuatorFrame,
    sensors: &mut SensorFrame,
) -> Result<BlockReport, RigError> {
    let mut out = [*sensors];
    let r = rig.process_block(std::slice::from_ref(command), &mut out)?;
    *sensors = out[0];
    Ok(r)
}
