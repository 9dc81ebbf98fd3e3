//! Audio-interface rig and monitor (cargo feature `audio`, cpal; on Linux
//! ALSA, needs `libasound2-dev` to build).
//!
//! * [`AudioRig`]: a [`Rig`](crate::device::Rig) on a sound card. Output
//!   channels drive the Haptuator (and, on DC-coupled interfaces, the
//!   Pantograph amplifiers: [`AudioRigConfig::pantograph_channels`]); one
//!   input channel reads the fingertip accelerometer (scaled by
//!   [`AudioRigConfig::accel_full_scale_m_s2`]). The engine runs at the
//!   device's sample rate. The handle position is not available from an
//!   audio interface: sensor frames carry zeros and
//!   [`AudioRig::handle_available`] is false (a DAQ must provide it for the
//!   coupling and the safety layer's velocity check).
//! * [`AudioMonitor`]: plays a mono signal (e.g. the high-frequency channel
//!   at 10 kHz) on an output device, resampled to the device's rate by
//!   linear interpolation ([`LinearResampler`]), so a user without a
//!   Haptuator can hear it.
//! * [`list_audio_devices`]: names, rates and channel counts for a GUI and
//!   `kilotouch rig list-audio`.
//!
//! The cpal callbacks allocate nothing and lock nothing: they exchange
//! frames with the host side through `rtrb` single-producer single-consumer
//! ring buffers and count events in atomics. Theory and operation:
//! `docs/theory/safety-and-audio.md`.

mod monitor;
mod rig;

pub use monitor::{AudioMonitor, LinearResampler, MonitorConfig, MonitorCounters};
pub use rig::{AudioCounters, AudioPacing, AudioRig, AudioRigConfig};

use crate::error::RigError;
use cpal::traits::{DeviceTrait, HostTrait};
use serde::{Deserialize, Serialize};

/// One direction (playback or capture) of a device.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AudioDirectionInfo {
    /// Channels of the default configuration.
    pub default_channels: u16,
    /// Sample rate of the default configuration, Hz.
    pub default_rate_hz: u32,
    /// Sample format of the default configuration (e.g. `f32`).
    pub default_format: String,
    /// Largest channel count among the supported configurations.
    pub max_channels: u16,
    /// Lowest supported sample rate, Hz.
    pub min_rate_hz: u32,
    /// Highest supported sample rate, Hz.
    pub max_rate_hz: u32,
}

/// A device as listed by [`list_audio_devices`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AudioDeviceInfo {
    /// Identifier to pass as `--rig audio:ID` (ALSA PCM name, e.g. `null`,
    /// `hw:CARD=0,DEV=0`).
    pub id: String,
    /// Human-readable name.
    pub name: String,
    /// Audio host (ALSA on Linux).
    pub host: String,
    /// Playback capabilities, if the device plays.
    pub output: Option<AudioDirectionInfo>,
    /// Capture capabilities, if the device records.
    pub input: Option<AudioDirectionInfo>,
}

fn cpal_err(what: &str, e: impl std::fmt::Display) -> RigError {
    RigError::Device(format!("{what}: {e}"))
}

fn direction_info(
    default: Result<cpal::SupportedStreamConfig, cpal::Error>,
    ranges: Result<Vec<cpal::SupportedStreamConfigRange>, cpal::Error>,
) -> Option<AudioDirectionInfo> {
    let d = default.ok()?;
    let ranges = ranges.unwrap_or_default();
    Some(AudioDirectionInfo {
        default_channels: d.channels(),
        default_rate_hz: d.sample_rate(),
        default_format: d.sample_format().to_string(),
        max_channels: ranges
            .iter()
            .map(|r| r.channels())
            .max()
            .unwrap_or(d.channels()),
        min_rate_hz: ranges
            .iter()
            .map(|r| r.min_sample_rate())
            .min()
            .unwrap_or(d.sample_rate()),
        max_rate_hz: ranges
            .iter()
            .map(|r| r.max_sample_rate())
            .max()
            .unwrap_or(d.sample_rate()),
    })
}

/// The devices of the default audio host with their default configuration
/// and supported ranges. Opens each device briefly to query it (a busy
/// device is listed without the busy direction).
pub fn list_audio_devices() -> Result<Vec<AudioDeviceInfo>, RigError> {
    let host = cpal::default_host();
    let devices = host
        .devices()
        .map_err(|e| cpal_err("cannot enumerate audio devices", e))?;
    let mut v = Vec::new();
    for d in devices {
        let id = d.id().map(|i| i.id().to_string()).unwrap_or_default();
        let name = d
            .description()
            .map(|x| x.name().to_string())
            .unwrap_or_else(|_| id.clone());
        let output = if d.supports_output() {
            direction_info(
                d.default_output_config(),
                d.supported_output_configs().map(|i| i.collect()),
            )
        } else {
            None
        };
        let input = if d.supports_input() {
            direction_info(
                d.default_input_config(),
                d.supported_input_configs().map(|i| i.collect()),
            )
        } else {
            None
        };
        v.push(AudioDeviceInfo {
            id,
            name,
            host: host.id().name().to_string(),
            output,
            input,
        });
    }
    Ok(v)
}

/// Find a device by id (`null`), full id (`alsa:null`) or name; `None` →
/// the host's default device for the direction.
pub(crate) fn find_device(name: Option<&str>, output: bool) -> Result<cpal::Device, RigError> {
    let host = cpal::default_host();
    let dir = if output { "output" } else { "input" };
    let Some(name) = name else {
        let d = if output {
            host.default_output_device()
        } else {
            host.default_input_device()
        };
        return d.ok_or_else(|| RigError::Device(format!("no default audio {dir} device")));
    };
    let devices = host
        .devices()
        .map_err(|e| cpal_err("cannot enumerate audio devices", e))?;
    let mut names = Vec::new();
    for d in devices {
        let (short, full) = match d.id() {
            Ok(i) => (i.id().to_string(), i.to_string()),
            Err(_) => continue,
        };
        let desc = d.description().map(|x| x.name().to_string()).ok();
        if short == name || full == name || desc.as_deref() == Some(name) {
            return Ok(d);
        }
        names.push(short);
    }
    Err(RigError::Device(format!(
        "audio {dir} device `{name}` not found; available: {}",
        names.join(", ")
    )))
}

/// A stream configuration with f32 samples on `device`: the default
/// configuration, or the requested rate / at least `min_channels` channels
/// when the default does not fit.
pub(crate) fn f32_config(
    device: &cpal::Device,
    output: bool,
    rate: Option<u32>,
    channels: Option<u16>,
    min_channels: u16,
    buffer_frames: Option<u32>,
) -> Result<cpal::StreamConfig, RigError> {
    let dir = if output { "output" } else { "input" };
    let default = if output {
        device.default_output_config()
    } else {
        device.default_input_config()
    }
    .map_err(|e| cpal_err(&format!("no default {dir} configuration"), e))?;
    let want_rate = rate.unwrap_or(default.sample_rate());
    let want_ch = channels.unwrap_or(default.channels().max(min_channels));
    if want_ch < min_channels {
        return Err(RigError::InvalidInput(format!(
            "{want_ch} {dir} channels requested but the channel map needs {min_channels}"
        )));
    }
    let fits = |c: &cpal::SupportedStreamConfigRange| {
        c.sample_format() == cpal::SampleFormat::F32
            && c.channels() == want_ch
            && c.contains_rate(want_rate)
    };
    let ok = if default.sample_format() == cpal::SampleFormat::F32
        && default.channels() == want_ch
        && default.sample_rate() == want_rate
    {
        true
    } else {
        let ranges: Vec<_> = if output {
            device.supported_output_configs().map(|i| i.collect())
        } else {
            device.supported_input_configs().map(|i| i.collect())
        }
        .map_err(|e| cpal_err(&format!("cannot query {dir} configurations"), e))?;
        ranges.iter().any(fits)
    };
    if !ok {
        return Err(RigError::Device(format!(
            "the {dir} device offers no f32 configuration with {want_ch} channels at \
             {want_rate} Hz (ALSA: use a `plughw:` or `default` device, which convert)"
        )));
    }
    Ok(cpal::StreamConfig {
        channels: want_ch,
        sample_rate: want_rate,
        buffer_size: match buffer_frames {
            Some(n) => cpal::BufferSize::Fixed(n),
            None => cpal::BufferSize::Default,
        },
    })
}

/// Wait-poll interval of the host side, s.
pub(crate) const POLL_S: f64 = 2e-4;
