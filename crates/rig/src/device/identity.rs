//! Who a rig is and what state it is in.

use serde::{Deserialize, Serialize};

use crate::error::RigError;

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

/// The physical bounds of a value a device announces when it connects (the
/// serial HELLO, `docs/PROTOCOL.md` §5.1): a value outside them — NaN,
/// infinite, zero, negative or absurd — is refused with the field named
/// before anything is streamed, by every command that connects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnnouncedBound {
    /// Field name as the protocol document spells it.
    pub field: &'static str,
    /// Smallest valid value.
    pub min: f64,
    /// Largest valid value.
    pub max: f64,
    /// Unit, for the message.
    pub unit: &'static str,
}

/// Every announced field and its bounds (the table of `docs/PROTOCOL.md`
/// §5.1 "Bounds").
pub const ANNOUNCED_BOUNDS: [AnnouncedBound; 9] = [
    // The loop and its filters are designed for audio-band rates; the
    // paper's rig runs at 10 kHz.
    bound("sample_rate_hz", 100.0, 200_000.0, "Hz"),
    bound("watchdog_ms", 1.0, 60_000.0, "ms"),
    // What fits a 1024-byte payload of 15-byte DAQ samples is 67.
    bound("batch", 1.0, 64.0, "samples per frame"),
    // 10 mm to 1 nm per count.
    bound("encoder_counts_per_m", 1e2, 1e9, "counts/m"),
    bound("accel_m_s2_per_code", 1e-6, 1.0, "(m/s²)/code"),
    // 0.1 g to 1000 g.
    bound("accel_range_m_s2", 1.0, 1e4, "m/s²"),
    bound("force_max_n", 1e-3, 1e3, "N"),
    bound("drive_max_v", 1e-3, 1e3, "V"),
    // 1 fN/nm to 1 N/m: far beyond any optical trap on both sides.
    bound("stiffness_n_per_m", 1e-9, 1.0, "N/m"),
];

const fn bound(field: &'static str, min: f64, max: f64, unit: &'static str) -> AnnouncedBound {
    AnnouncedBound {
        field,
        min,
        max,
        unit,
    }
}

/// Checks what a device announced, as (field, value) pairs with the field
/// names of [`ANNOUNCED_BOUNDS`], and that its accelerometer range fits its
/// 16-bit codes (`accel_range_m_s2 ≤ 32767 · accel_m_s2_per_code`).
/// `device` names the device in the message (e.g. its port).
///
/// # Errors
/// [`RigError::Device`] naming the first field out of bounds (an unknown
/// field name is a programming error, reported the same way).
pub fn validate_announced(device: &str, values: &[(&'static str, f64)]) -> Result<(), RigError> {
    for &(field, v) in values {
        let Some(b) = ANNOUNCED_BOUNDS.iter().find(|b| b.field == field) else {
            return Err(RigError::Device(format!(
                "{device}: the device announced `{field}`, which has no stated bounds"
            )));
        };
        if !(v.is_finite() && v >= b.min && v <= b.max) {
            return Err(RigError::Device(format!(
                "{device}: the device announced {field} = {v:e} {}, outside [{:e}, {:e}] {} \
                 (docs/PROTOCOL.md §5.1); refusing to connect",
                b.unit, b.min, b.max, b.unit
            )));
        }
    }
    let get = |f: &str| values.iter().find(|(n, _)| *n == f).map(|&(_, v)| v);
    if let (Some(range), Some(per_code)) = (get("accel_range_m_s2"), get("accel_m_s2_per_code"))
        && range > 32_767.0 * per_code * (1.0 + 1e-9)
    {
        return Err(RigError::Device(format!(
            "{device}: the device announced accel_range_m_s2 = {range:e} m/s², more than its \
             16-bit codes of {per_code:e} (m/s²)/code can represent ({:e} m/s²); refusing to \
             connect",
            32_767.0 * per_code
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn daq() -> Vec<(&'static str, f64)> {
        vec![
            ("sample_rate_hz", 10_000.0),
            ("watchdog_ms", 100.0),
            ("batch", 10.0),
            ("encoder_counts_per_m", 1e5),
            ("accel_m_s2_per_code", 1.4528e-2),
            ("accel_range_m_s2", 58.84),
            ("force_max_n", 5.0),
            ("drive_max_v", 2.0),
        ]
    }

    #[test]
    fn the_paper_rig_passes_and_each_absurd_value_is_refused_by_name() {
        validate_announced("dev", &daq()).unwrap();
        for (field, bad) in [
            ("accel_range_m_s2", f64::NAN),
            ("accel_m_s2_per_code", 1e308),
            ("encoder_counts_per_m", 5e-324),
            ("batch", 0.0),
            ("watchdog_ms", 0.0),
            ("sample_rate_hz", 1.0),
            ("force_max_n", f64::INFINITY),
            ("drive_max_v", -2.0),
        ] {
            let mut v = daq();
            v.iter_mut().find(|(f, _)| *f == field).unwrap().1 = bad;
            let e = validate_announced("dev", &v).unwrap_err().to_string();
            assert!(e.contains(&format!("{field} = ")), "{field}: {e}");
        }
        validate_announced("dev", &[("stiffness_n_per_m", 2e-5)]).unwrap();
        assert!(validate_announced("dev", &[("stiffness_n_per_m", 0.0)]).is_err());
    }

    #[test]
    fn an_accelerometer_range_beyond_its_codes_is_refused() {
        let mut v = daq();
        v.iter_mut()
            .find(|(f, _)| *f == "accel_range_m_s2")
            .unwrap()
            .1 = 1000.0;
        let e = validate_announced("dev", &v).unwrap_err().to_string();
        assert!(e.contains("16-bit codes"), "{e}");
    }
}
