//! The real-time engine: the closed loop (rig + tweezer + coupling + dsp
//! chain) on its own thread at the rig rate, independent of any GUI.
//!
//! # Architecture
//!
//! ```text
//!  GUI thread                                   engine thread
//!  ──────────                                   ─────────────
//!  EngineHandle ── Command (rtrb, 256) ───────▶ EngineCore::run_block
//!               ◀─ TelemetrySample (rtrb) ────   every sample (drop + count when full)
//!               ◀─ EngineEvent (rtrb, 256) ───   health every 100 ms, swaps done, faults,
//!                                                boxes to drop
//!  estop counter (AtomicU64) ─────────────────▶  checked every block
//! ```
//!
//! The engine runs blocks of `block_len` samples (default 10 = 1 ms at
//! 10 kHz). Each sample is one step of the rig crate's closed loop
//! ([`kilotouch_rig::HapticLoop`]): sensors → trap (coupling) → tweezer → haptic image →
//! condition routing and chain → safety layer → rig. After a block it
//! sleeps until the block's deadline ([`pacing`]). It never waits on the GUI: a full
//! telemetry queue drops the sample and counts it; a command that must hand
//! a box back waits in its queue until the event queue has room. Nothing in
//! the loop allocates, frees or locks: coefficient sets and tweezers with
//! new obstacles are built (boxed) on the GUI thread, swapped in by the
//! engine, and the old ones travel back to be dropped on the GUI side.
//!
//! Pacing is the engine's, with the rig in batch mode: [`kilotouch_rig::HapticLoop`]
//! exchanges one sample per `process_frame` call (so the force computed
//! from sample n acts at n + 1), and a wall-clock-paced `SimRig` would sleep
//! after every sample.
//!
//! # Live rigs
//!
//! The rig is any [`AnyRig`]: simulated (default), a serial DAQ
//! (`serial:PATH`, or the emulator on a pty) or, with the `audio` feature,
//! an audio interface, chosen with the `--rig` syntax
//! ([`kilotouch_rig::device::RigSpec`]). A live rig differs in three ways:
//!
//! * **Block exchange.** One round trip per sample would cost a serial
//!   link's latency 10 000 times a second; the engine exchanges one block of
//!   `block_len` frames per call instead. The commands of block b are
//!   computed sample by sample (coupling, tweezer, safety layer) from the
//!   sensor frames of block b − 1, so the loop delay is `block_len` samples
//!   (1 ms at the default 10 samples and 10 kHz) instead of one sample. The
//!   delay is uniform across the block (no stair-stepped trap motion that
//!   would put a 1 kHz component into the Haptuator drive).
//! * **The device paces.** `process_block` blocks until the device has
//!   played the block; the engine's [`pacing::Pacer`] never sleeps then but
//!   still measures lateness and deadline misses.
//! * **The hand is the real handle** (encoder positions); hand requests
//!   from the GUI are ignored.
//!
//! When the device vanishes or stalls, the rig returns an error (a serial
//! rig after its timeout, 100 ms by default, or at once on end of file):
//! the safety layer trips, outputs go to zero (the rig sends STOP where the
//! device still listens; the device's own watchdog zeroes them otherwise),
//! the loop stops (the safety layer in [`SafetyState::Fault`]) and an
//! [`EngineEvent::RigError`] reaches the GUI. [`Command::Reconnect`] reopens
//! the device (or opens another, e.g. a restarted emulator on a new pty)
//! on the engine thread and resumes; forces come back through the safety
//! layer's arming and ramp.
//!
//! # Drivers
//!
//! What runs in a block is the [`BlockDriver`]'s: free exploration (the
//! default, [`FreeExploration`]: the hand follows the GUI's mouse on the
//! simulated rig, the real handle on a live one) or a study sitting
//! (`crate::session`: the study's trials on this same loop). The engine
//! keeps what every activity shares: the commands, the emergency stop, the
//! pacing, the telemetry and the health reports.

mod driver;
mod handle;
pub mod pacing;
mod runner;
pub mod soak;
pub mod splitter;

pub use driver::EngineLoop;
pub use driver::{BlockCtx, BlockDriver, FreeExploration, Publisher, run_live_block};
pub use handle::{
    EngineHandle, EstopTrigger, LiveTweezerInfo, engine_pair, engine_pair_with_devices,
    engine_pair_with_rig,
};
pub use kilotouch_rig::AnyRig;
pub use runner::EngineCore;

use kilotouch_rig::ActuatorFrame;
use kilotouch_rig::coupling::CouplingCounters;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::device::{RigFault, RigIdentity, RigStatus};
use kilotouch_rig::error::RigError;
use kilotouch_rig::tweezer::{AppliedTrap, DetectedTweezer};
use splitter::{ChainSwap, SwapOutcome};

/// The experimental condition: the rig crate's, one type from the protocol
/// to the actuators.
pub use kilotouch_rig::Condition;
/// The safety layer's state (the engine has no other output gate).
pub use kilotouch_rig::safety::SafetyState;

/// Bits of [`TelemetrySample::flags`].
pub mod flags {
    /// The bead is in an obstacle's contact zone.
    pub const IN_CONTACT: u16 = 1;
    /// The bead is held by the trap.
    pub const TRAPPED: u16 = 2;
    /// Contact began at this sample.
    pub const CONTACT_START: u16 = 4;
    /// Contact ended at this sample.
    pub const CONTACT_END: u16 = 8;
    /// The bead escaped at this sample.
    pub const ESCAPED: u16 = 16;
    /// The bead was recaptured at this sample.
    pub const RECAPTURED: u16 = 32;
    /// The emergency stop is latched (outputs zero).
    pub const ESTOP: u16 = 64;
    /// The rig flagged this frame (clipping, limiting, end stop, lost, …).
    pub const RIG_FLAG: u16 = 128;
}

/// One sample of the loop, as the plots and the scene need it. SI units.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TelemetrySample {
    /// Rig sequence number (sample time = seq / f_s).
    pub seq: u64,
    /// Hand position driving the rig (after smoothing), m.
    pub hand_m: [f64; 2],
    /// Handle position measured by the encoders, m.
    pub handle_m: [f64; 2],
    /// Force to render at the handle, before the split: the optical force's
    /// image g·sign(s)·κ(bead − trap) plus the wall damper in contact, N.
    pub handle_force_n: [f64; 2],
    /// What was sent to the device (after the safety layer): Pantograph force (N), Haptuator drive (V).
    pub output: ActuatorFrame,
    /// Fingertip acceleration (accelerometer, x y z), m/s².
    pub accel_m_s2: [f64; 3],
    /// Trap centre, m.
    pub trap_m: [f64; 2],
    /// Bead centre, m.
    pub bead_m: [f64; 2],
    /// Optical force on the bead, N.
    pub bead_force_n: [f64; 2],
    /// Surface gap to the nearest obstacle, m (∞ without obstacles).
    pub gap_m: f64,
    /// Bit set of [`flags`].
    pub flags: u16,
}

impl TelemetrySample {
    /// Is `bit` set?
    pub fn has(&self, bit: u16) -> bool {
        self.flags & bit != 0
    }
}

/// Engine health, sent every `health_interval_blocks` blocks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Health {
    /// Next rig sequence number.
    pub seq: u64,
    /// Samples per wall second over the last window, Hz.
    pub loop_rate_hz: f64,
    /// Busy time / wall time over the last window (0–1).
    pub load: f64,
    /// Blocks that missed their deadline since start ([`pacing`] defines it).
    pub deadline_misses: u64,
    /// Re-anchors after stalls longer than the tolerated lag.
    pub overruns: u64,
    /// Worst lateness (end − deadline) over the last window, s.
    pub worst_lateness_s: f64,
    /// Worst lateness since start, s.
    pub worst_lateness_total_s: f64,
    /// Blocks run since start.
    pub blocks: u64,
    /// Samples run since start (what the loop advanced; a sitting's
    /// simulated loop stands still between trials).
    pub samples: u64,
    /// Telemetry samples dropped because the GUI did not drain the queue.
    pub telemetry_dropped: u64,
    /// Health/notice events dropped (event queue full).
    pub events_dropped: u64,
    /// State of the safety layer (the rig may be stopped: see `running`).
    pub safety: SafetyState,
    /// The safety layer's latest trip (kept after a reset).
    pub last_trip: Option<kilotouch_rig::safety::Trip>,
    /// Current condition.
    pub condition: Condition,
    /// Exchanging frames.
    pub running: bool,
    /// Rig counters.
    pub rig: RigStatus,
    /// Coupling safety-net counters.
    pub coupling: CouplingCounters,
    /// Frames forced to zero in a latched state (emergency stop, fault).
    pub estop_zeroed_frames: u64,
    /// The bead is in the trap.
    pub trapped: bool,
    /// The trap calibration the tweezer reports through (None: the
    /// simulated bead and stiffness).
    pub trap_calibration: Option<AppliedTrap>,
    /// The engine thread runs real-time (`SCHED_FIFO`).
    pub realtime: bool,
}

impl Health {
    /// Status-bar label: "idle" while the rig is stopped (and nothing is
    /// latched), else the safety layer's state.
    pub fn status_label(&self) -> &'static str {
        if !self.running && !self.safety.latched() {
            "idle"
        } else {
            self.safety.label()
        }
    }
}

/// GUI → engine.
#[derive(Debug)]
pub enum Command {
    /// Move the hand to this position (m); the engine smooths it.
    SetHand([f64; 2]),
    /// Switch condition V / P / D at once (outputs ramp).
    SetCondition(Condition),
    /// Replace the tweezer (new obstacles); the bead, trap and trap
    /// calibration carry over.
    SetTweezer(Box<DetectedTweezer>),
    /// Use this trap calibration (κ, R_d; already validated) for the
    /// tweezer's bead and force, or the simulated ones (`None`).
    SetTrapCalibration(Option<AppliedTrap>),
    /// Swap in a new chain (calibration).
    ApplyChain(Box<ChainSwap>),
    /// Release the emergency stop, if `ack` equals the number of stops
    /// requested so far (a stop pressed after the reset wins).
    ResetEmergencyStop {
        /// [`EngineHandle::estop_count`] when the user confirmed the reset.
        ack: u64,
    },
    /// Put the bead back into the trap.
    ResetBead,
    /// Start exchanging frames.
    Start,
    /// Stop (actuators zero).
    Stop,
    /// Reopen the rig after a disconnect and resume (`None`: the same
    /// device; `Some`: open this one instead, same sample rate). Blocks the
    /// engine thread for the handshake; the loop is stopped meanwhile.
    Reconnect(Option<Box<RigSpec>>),
    /// Replace the block driver (returns the old one, detached).
    SetDriver(Box<dyn BlockDriver>),
    /// Sleep to the wall clock (`true`) or run as fast as possible
    /// (`false`: a simulated participant's dry run on the simulated rig;
    /// ignored by live rigs, which the device paces).
    SetPaced(bool),
    /// End the engine thread.
    Shutdown,
}

/// Boxes handed back to the GUI thread to be dropped there.
#[derive(Debug)]
pub enum Garbage {
    /// An old tweezer.
    Tweezer(Box<DetectedTweezer>),
    /// A swapped chain.
    Chain(Box<ChainSwap>),
    /// An old driver.
    Driver(Box<dyn BlockDriver>),
}

/// Engine → GUI (rare; the per-sample data go through the telemetry queue).
#[derive(Debug)]
pub enum EngineEvent {
    /// Periodic health.
    Health(Health),
    /// A chain swap finished.
    ChainSwapped(SwapOutcome),
    /// A fault reported by the rig.
    RigFault(RigFault),
    /// The rig returned an error; the loop stopped (outputs zero).
    RigError(RigError),
    /// A reconnect succeeded; the loop runs again on this device.
    Reconnected(Box<RigIdentity>),
    /// Something to drop on the GUI side.
    Garbage(Garbage),
    /// A command was refused (why): a study sitting owns the loop, and
    /// only the sitting sets the condition, the scene and the chain.
    Refused(&'static str),
}

/// Options of the engine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EngineOptions {
    /// Samples per block (1–[`kilotouch_rig::haptic_loop::MAX_BLOCK`], typical 10 = 1 ms at 10 kHz).
    pub block_len: usize,
    /// Sleep to the wall clock (`false`: as fast as possible, tests).
    pub paced: bool,
    /// Tolerated latency for the deadline-miss count, s.
    pub tolerance_s: f64,
    /// Stall beyond which the schedule re-anchors instead of catching up, s.
    pub max_lag_s: f64,
    /// Ramp-on time of the outputs, s (the safety layer's ramp).
    pub ramp_s: f64,
    /// Time constant of the hand smoothing (mouse steps → smooth motion), s.
    pub hand_smoothing_s: f64,
    /// Capacity of the telemetry queue, samples.
    pub telemetry_capacity: usize,
    /// Health event every this many blocks.
    pub health_interval_blocks: u64,
    /// Start exchanging frames at once.
    pub start: bool,
    /// Run the engine thread real-time (`SCHED_FIFO`,
    /// [`kilotouch_rig::realtime`]) while it is paced (by the wall clock or
    /// a live device), where the system allows it.
    pub realtime: bool,
}

impl Default for EngineOptions {
    fn default() -> Self {
        Self {
            block_len: 10,
            paced: true,
            tolerance_s: 2e-3,
            max_lag_s: 0.1,
            ramp_s: 0.1,
            hand_smoothing_s: 0.01,
            telemetry_capacity: 1 << 15,
            health_interval_blocks: 100,
            start: true,
            realtime: true,
        }
    }
}

/// Why the engine could not be built.
#[derive(Debug, thiserror::Error)]
pub enum EngineError {
    /// The rig, tweezer or coupling refused the configuration.
    #[error(transparent)]
    Rig(#[from] RigError),
    /// The options are unusable.
    #[error("invalid engine option `{name}`: {reason}")]
    Option {
        /// Option name.
        name: &'static str,
        /// Why.
        reason: &'static str,
    },
    /// The thread could not be spawned.
    #[error("cannot start the engine thread: {0}")]
    Thread(#[from] std::io::Error),
}
