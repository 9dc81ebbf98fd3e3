//! What the calibration needs from a rig ([`CalibrationRig`]), and the small
//! records a rig returns.
//!
//! The procedure plays drive signals on the two channels of the x axis (the
//! Haptuator axis) and records the fingertip acceleration along x. Any rig —
//! simulated or live — that can do that at a fixed sample rate can be
//! calibrated; the same code runs on both.

use super::error::{CalibrationError, Result};
use kilotouch_dsp::C64;
use serde::{Deserialize, Serialize};

/// The record of who a calibration belongs to: the rig's name and serial
/// (from its [`crate::device::RigIdentity`]), the hash of the rig configuration
/// the calibration measured ([`super::sim::rig_config_hash`]) and the sample
/// rate. A calibration file is only valid for the rig it records.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigRecord {
    /// Rig name, e.g. `sim` or `pantograph-haptuator`.
    pub name: String,
    /// Serial number or instance name (`-` when not applicable).
    pub serial: String,
    /// Hash of the rig configuration (e.g. `fnv1a64:0123456789abcdef`, see
    /// [`super::hash`]); a changed configuration invalidates a calibration.
    pub config_hash: String,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
}

impl RigRecord {
    /// The record of a rig's identity with the hash of its configuration.
    pub fn of(id: &crate::device::RigIdentity, config_hash: String) -> Self {
        Self {
            name: id.name.clone(),
            serial: id.serial.clone(),
            config_hash,
            sample_rate_hz: id.sample_rate_hz,
        }
    }
}

impl std::fmt::Display for RigRecord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "`{}` serial `{}` config {} at {} Hz",
            self.name, self.serial, self.config_hash, self.sample_rate_hz
        )
    }
}

/// The rig's own self-test (step 1, "Check").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckReport {
    /// The accelerometer answers (data arrive, not stuck).
    pub sensor_alive: bool,
    /// The accelerometer reading at rest is inside its range (not clipped).
    pub sensor_in_range: bool,
    /// The rig accepts drive and returns data (no fault, no timeout).
    pub responding: bool,
    /// Safety limits (force clamps, Haptuator drive clamp, watchdog) are armed.
    pub safety_armed: bool,
    /// Free-text remarks (reasons for a `false`, warnings).
    pub messages: Vec<String>,
}

impl CheckReport {
    /// True when every item passed.
    pub fn ok(&self) -> bool {
        self.sensor_alive && self.sensor_in_range && self.responding && self.safety_armed
    }
}

/// What happened during one [`CalibrationRig::run`]: saturation counts, so
/// that the procedure can back off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RunStats {
    /// Samples played and recorded.
    pub samples: usize,
    /// Samples at which the accelerometer was at (or beyond) its range.
    pub accel_clipped: usize,
    /// Samples at which the Haptuator's moving magnet was at an end stop;
    /// `None` when the rig cannot observe it (a live rig without a stroke
    /// sensor).
    pub end_stop_hits: Option<usize>,
    /// Drive samples the rig had to clamp to its limits.
    pub drive_clipped: usize,
}

impl RunStats {
    /// True when any saturation was seen (sensor clipping, end-stop hits or
    /// clamped drive): the run was not in the linear regime.
    pub fn saturated(&self) -> bool {
        self.accel_clipped > 0 || self.end_stop_hits.unwrap_or(0) > 0 || self.drive_clipped > 0
    }
}

/// Actuator (and sensor) limits of the rig.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ActuatorLimits {
    /// Largest Pantograph force along x, N (|f| ≤ this).
    pub max_force_n: f64,
    /// Largest Haptuator drive (|f_v| ≤ this), in the rig's drive unit
    /// (N of Laplace force for the simulated rig).
    pub max_high_drive: f64,
    /// Accelerometer full scale, m/s² (e.g. 6 g for the MMA7361L), if known.
    pub accel_range_m_s2: Option<f64>,
}

/// What calibration needs from a rig.
///
/// Units: Pantograph drive in N (force along x), Haptuator drive in the rig's
/// drive unit, acceleration in m/s² along x (the Haptuator axis), sample rate
/// in Hz.
pub trait CalibrationRig {
    /// Sample rate of [`run`](Self::run) in Hz.
    fn sample_rate(&self) -> f64;

    /// Record of this rig (stored in and checked against calibration files).
    fn record(&self) -> RigRecord;

    /// Self-test: sensor alive and in range, rig responding, safety armed.
    fn check(&mut self) -> Result<CheckReport>;

    /// Play `low_drive` (Pantograph force, N) and `high_drive` (Haptuator
    /// drive) sample by sample at [`sample_rate`](Self::sample_rate) and
    /// record the fingertip acceleration (m/s², as the accelerometer reports
    /// it) into `accel`. All three slices have the same length. The run
    /// continues from the rig's present state (the procedure discards
    /// lead-in time itself). Drives beyond [`limits`](Self::limits) are
    /// clamped by the rig and counted in [`RunStats::drive_clipped`].
    fn run(&mut self, low_drive: &[f64], high_drive: &[f64], accel: &mut [f64])
    -> Result<RunStats>;

    /// Actuator and sensor limits.
    fn limits(&self) -> ActuatorLimits;

    /// Known response of the accelerometer chain at `f_hz` (sensor output
    /// per unit true fingertip acceleration), to be divided out; `None` when
    /// unknown.
    fn sensor_response(&self, f_hz: f64) -> Option<C64>;
}

/// Which channel a measurement drives: the plant's [`Channel`] (`Low`:
/// Pantograph on, Haptuator off; `High`: the reverse).
pub use crate::plant::Channel;

/// "low" or "high".
pub fn channel_name(channel: Channel) -> &'static str {
    match channel {
        Channel::Low => "low",
        Channel::High => "high",
    }
}

impl ActuatorLimits {
    /// The drive limit of `channel` (N for the Pantograph, drive unit for the
    /// Haptuator).
    pub fn of(&self, channel: Channel) -> f64 {
        match channel {
            Channel::Low => self.max_force_n,
            Channel::High => self.max_high_drive,
        }
    }
}

/// Length check shared by every [`CalibrationRig::run`]: both drive records
/// must be as long as the acceleration record. Returns that length.
pub fn check_run_lengths(low_drive: &[f64], high_drive: &[f64], accel: &[f64]) -> Result<usize> {
    let n = accel.len();
    if low_drive.len() != n || high_drive.len() != n {
        return Err(CalibrationError::Rig(format!(
            "drive lengths {} and {} differ from the record length {n}",
            low_drive.len(),
            high_drive.len()
        )));
    }
    Ok(n)
}
