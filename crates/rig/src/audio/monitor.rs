//! [`AudioMonitor`]: listen to a signal (e.g. the Haptuator channel at
//! 10 kHz) on an ordinary output device.

use super::{cpal_err, f32_config, find_device};
use crate::error::RigError;
use cpal::traits::{DeviceTrait, StreamTrait};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// Linear-interpolation sample-rate converter, f_in → f_out.
///
/// Output sample m is the straight line between the input samples around
/// position p_m = m·r − 1 (r = f_in/f_out; the −1 is one input sample of
/// delay, so that the next input sample is known before it is needed):
/// y[m] = x[k] + (p_m − k)(x[k+1] − x[k]), k = ⌊p_m⌋. For a sinusoid of
/// amplitude A at f the error is at most A(2πf/f_in)²/8 (the interpolation
/// error h²/8·max|x''| with h one input sample), e.g. 0.049·A (−26 dB) at
/// 1 kHz from 10 kHz; the images above f_in/2 are attenuated by sinc² of the
/// triangular kernel. Adequate for listening, not for measurement.
#[derive(Debug, Clone)]
pub struct LinearResampler {
    step: f64,
    phase: f64,
    prev: f32,
    next: f32,
}

impl LinearResampler {
    /// From `in_rate_hz` to `out_rate_hz` (both finite and > 0).
    pub fn new(in_rate_hz: f64, out_rate_hz: f64) -> Result<Self, RigError> {
        for (name, v) in [("in_rate_hz", in_rate_hz), ("out_rate_hz", out_rate_hz)] {
            RigError::require_positive(name, v)?;
        }
        Ok(Self {
            step: in_rate_hz / out_rate_hz,
            // The first call pulls x[0]: position p_0 = −1.
            phase: 1.0,
            prev: 0.0,
            next: 0.0,
        })
    }

    /// Input samples per output sample, r = f_in/f_out.
    pub fn ratio(&self) -> f64 {
        self.step
    }

    /// Next output sample; `pull` supplies the next input sample (`None`:
    /// none available, read as 0). Allocation-free, O(⌈r⌉).
    #[inline]
    pub fn next_sample(&mut self, mut pull: impl FnMut() -> Option<f32>) -> f32 {
        while self.phase >= 1.0 {
            self.prev = self.next;
            self.next = pull().unwrap_or(0.0);
            self.phase -= 1.0;
        }
        let y = self.prev + (self.next - self.prev) * self.phase as f32;
        self.phase += self.step;
        y
    }
}

/// Settings of an [`AudioMonitor`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MonitorConfig {
    /// Output device (as for [`super::AudioRigConfig::device`]); `None` =
    /// the default device.
    pub device: Option<String>,
    /// Rate of the pushed signal, Hz (e.g. the rig's 10 kHz).
    pub source_rate_hz: f64,
    /// Digital full scale per signal unit (e.g. 1/2 V⁻¹ to play ±2 V of
    /// Haptuator drive at full scale). Samples are clamped to ±1.
    pub gain: f64,
    /// Ring length, s of source signal (how far the producer may run ahead).
    pub capacity_s: f64,
    /// Device buffer (period) size, frames; `None` = the host's default.
    pub buffer_frames: Option<u32>,
}

impl MonitorConfig {
    /// `device` at the default rate, 10 kHz source, unit gain, 0.5 s ring.
    pub fn new(device: Option<&str>, source_rate_hz: f64) -> Self {
        Self {
            device: device.map(str::to_string),
            source_rate_hz,
            gain: 1.0,
            capacity_s: 0.5,
            buffer_frames: None,
        }
    }
}

#[derive(Debug, Default)]
struct MonShared {
    callbacks: AtomicU64,
    frames: AtomicU64,
    underruns: AtomicU64,
}

/// Counters of an [`AudioMonitor`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MonitorCounters {
    /// Output callbacks.
    pub callbacks: u64,
    /// Frames played.
    pub frames: u64,
    /// Source samples the callback needed but found missing (played as 0).
    pub underrun_samples: u64,
    /// Source samples accepted by [`AudioMonitor::push`].
    pub pushed: u64,
    /// Source samples dropped by [`AudioMonitor::push`] (ring full).
    pub dropped: u64,
}

/// Plays a mono signal on every channel of an output device through a
/// lock-free ring, resampled to the device's rate ([`LinearResampler`]).
pub struct AudioMonitor {
    prod: rtrb::Producer<f32>,
    _stream: cpal::Stream,
    shared: Arc<MonShared>,
    gain: f64,
    device_rate: u32,
    channels: u16,
    name: String,
    pushed: u64,
    dropped: u64,
}

impl std::fmt::Debug for AudioMonitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AudioMonitor")
            .field("name", &self.name)
            .field("device_rate", &self.device_rate)
            .field("channels", &self.channels)
            .field("counters", &self.counters())
            .finish_non_exhaustive()
    }
}

impl AudioMonitor {
    /// Open the device and start playing (silence until samples arrive).
    pub fn open(cfg: &MonitorConfig) -> Result<Self, RigError> {
        for (name, v) in [
            ("source_rate_hz", cfg.source_rate_hz),
            ("capacity_s", cfg.capacity_s),
        ] {
            RigError::require_positive(name, v)?;
        }
        if !cfg.gain.is_finite() {
            return Err(RigError::InvalidParameter {
                name: "gain",
                value: cfg.gain,
                reason: "must be finite".into(),
            });
        }
        let device = find_device(cfg.device.as_deref(), true)?;
        let conf = f32_config(&device, true, None, None, 1, cfg.buffer_frames)?;
        let mut rs = LinearResampler::new(cfg.source_rate_hz, conf.sample_rate as f64)?;
        let cap = ((cfg.capacity_s * cfg.source_rate_hz).ceil() as usize).max(16);
        let (prod, mut cons) = rtrb::RingBuffer::<f32>::new(cap);
        let shared = Arc::new(MonShared::default());
        let sh = Arc::clone(&shared);
        let ch = conf.channels as usize;
        let stream = device
            .build_output_stream(
                conf,
                move |data: &mut [f32], _: &cpal::OutputCallbackInfo| {
                    let (mut under, mut frames) = (0u64, 0u64);
                    for frame in data.chunks_exact_mut(ch) {
                        let y = rs.next_sample(|| match cons.pop() {
                            Ok(v) => Some(v),
                            Err(_) => {
                                under += 1;
                                None
                            }
                        });
                        let y = if y.is_finite() {
                            y.clamp(-1.0, 1.0)
                        } else {
                            0.0
                        };
                        frame.fill(y);
                        frames += 1;
                    }
                    sh.callbacks.fetch_add(1, Ordering::Relaxed);
                    sh.frames.fetch_add(frames, Ordering::Relaxed);
                    sh.underruns.fetch_add(under, Ordering::Relaxed);
                },
                |_e: cpal::Error| {},
                None,
            )
            .map_err(|e| cpal_err("cannot open the monitor output", e))?;
        stream
            .play()
            .map_err(|e| cpal_err("cannot start the monitor output", e))?;
        let name = device
            .description()
            .map(|d| d.name().to_string())
            .unwrap_or_default();
        Ok(Self {
            prod,
            _stream: stream,
            shared,
            gain: cfg.gain,
            device_rate: conf.sample_rate,
            channels: conf.channels,
            name,
            pushed: 0,
            dropped: 0,
        })
    }

    /// Queue source samples (signal units, scaled by the gain, clamped to
    /// full scale, non-finite → 0). Never blocks, never allocates; returns
    /// how many were accepted (the rest are dropped and counted).
    pub fn push(&mut self, samples: &[f64]) -> usize {
        let room = self.prod.slots().min(samples.len());
        for &x in &samples[..room] {
            let y = x * self.gain;
            let y = if y.is_finite() {
                y.clamp(-1.0, 1.0) as f32
            } else {
                0.0
            };
            // Cannot fail: `room` slots are free and only we produce.
            let _ = self.prod.push(y);
        }
        self.pushed += room as u64;
        self.dropped += (samples.len() - room) as u64;
        room
    }

    /// Source samples queued and not yet played.
    pub fn queued(&self) -> usize {
        self.prod.buffer().capacity() - self.prod.slots()
    }

    /// The device's sample rate, Hz.
    pub fn device_rate_hz(&self) -> f64 {
        self.device_rate as f64
    }

    /// Device channels (the signal plays on all of them).
    pub fn channels(&self) -> u16 {
        self.channels
    }

    /// Counters.
    pub fn counters(&self) -> MonitorCounters {
        MonitorCounters {
            callbacks: self.shared.callbacks.load(Ordering::Relaxed),
            frames: self.shared.frames.load(Ordering::Relaxed),
            underrun_samples: self.shared.underruns.load(Ordering::Relaxed),
            pushed: self.pushed,
            dropped: self.dropped,
        }
    }
}
