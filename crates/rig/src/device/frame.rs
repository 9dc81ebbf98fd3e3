//! The frames a rig exchanges, one per sample, and what one exchange reports.

use serde::{Deserialize, Serialize};

/// One sample of actuator commands (host → device).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ActuatorFrame {
    /// Pantograph force command (x, y), N.
    pub force_n: [f64; 2],
    /// Haptuator drive, V.
    pub haptuator_v: f64,
}

/// Per-frame flags (bit set).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct FrameFlags(pub u8);

impl FrameFlags {
    /// Placeholder for a frame the device did not deliver (values held).
    pub const LOST: u8 = 1;
    /// The accelerometer hit its range on some axis.
    pub const CLIPPED: u8 = 2;
    /// A command was clamped to the actuator limits.
    pub const LIMITED: u8 = 4;
    /// The Haptuator magnet was on an end stop.
    pub const END_STOP: u8 = 8;
    /// A non-finite command was replaced by zero.
    pub const NONFINITE_COMMAND: u8 = 16;

    /// Is `bit` set?
    pub fn has(self, bit: u8) -> bool {
        self.0 & bit != 0
    }
}

/// One sample of sensor data (device → host).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SensorFrame {
    /// Device sequence number of the sample.
    pub seq: u64,
    /// Handle position (x, y), m (encoders on the motors).
    pub handle_m: [f64; 2],
    /// Fingertip acceleration (x, y, z), m/s².
    pub accel_m_s2: [f64; 3],
    /// Flags.
    pub flags: FrameFlags,
}

/// What happened during one `process_block` call.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct BlockReport {
    /// Sequence number of the first frame.
    pub first_seq: u64,
    /// Frames exchanged.
    pub frames: usize,
    /// Frames the device failed to deliver (filled with placeholders).
    pub lost_frames: u32,
    /// Samples of wall time skipped because of a stall longer than the
    /// tolerated lag (paced rigs only).
    pub skipped_samples: u64,
    /// How far the block ended behind its wall-clock deadline, s (0 when on
    /// time or when not paced).
    pub lag_s: f64,
}
