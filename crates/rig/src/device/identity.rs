//! Who a rig is and what state it is in.

use serde::{Deserialize, Serialize};

/// Kind of rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RigKind {
    /// The embedded simulation.
    Simulated,
    /// A DAQ over a serial link.
    SerialDaq,
    /// An audio interface.
    Audio,
}

/// Identity of a rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RigIdentity {
    /// Kind.
    pub kind: RigKind,
    /// Human-readable name.
    pub name: String,
    /// Serial number / port / device id.
    pub serial: String,
    /// Firmware or model version.
    pub firmware: String,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Pantograph force limit per axis, N.
    pub force_max_n: f64,
    /// Haptuator drive limit, V.
    pub haptuator_max_v: f64,
    /// Accelerometer range, ±m/s².
    pub accel_range_m_s2: f64,
}

/// Life-cycle state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RigState {
    /// Not exchanging frames; actuators at zero.
    Idle,
    /// Exchanging frames.
    Running,
    /// Stopped by a device fault (e.g. watchdog); `start` to resume.
    Faulted,
    /// Device gone.
    Disconnected,
}

/// Counters and state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigStatus {
    /// State.
    pub state: RigState,
    /// Frames exchanged since creation.
    pub frames: u64,
    /// Frames lost.
    pub lost_frames: u64,
    /// Samples skipped after long stalls.
    pub skipped_samples: u64,
    /// Frames with the accelerometer clipped.
    pub clipped_frames: u64,
    /// Frames with a command clamped to the limits.
    pub limited_frames: u64,
    /// Frames with the Haptuator magnet on an end stop.
    pub end_stop_frames: u64,
    /// Frames with a non-finite command.
    pub nonfinite_commands: u64,
    /// Faults waiting in the queue.
    pub faults_pending: usize,
    /// Faults dropped because the queue was full.
    pub faults_dropped: u64,
    /// Samples a live device executed with a held command because the
    /// host's command arrived late (`CMD_LATE`).
    #[serde(default)]
    pub late_commands: u64,
}
