//! [`AudioRig`]: the [`Rig`] interface on a sound card (module docs of
//! `crate::audio`).

use super::{POLL_S, cpal_err, f32_config, find_device};
use crate::config::RigConfig;
use crate::device::{
    ActuatorFrame, BlockReport, FrameFlags, Rig, RigFault, RigIdentity, RigKind, RigState,
    RigStatus, SensorFrame, StatusCounters, open_block,
};
use crate::error::RigError;
use crate::safety::{HardLimits, hard_limit};
use cpal::traits::{DeviceTrait, StreamTrait};
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Where the host loop's timing comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AudioPacing {
    /// The device clock: `process_block` waits for the input frames (or, with
    /// no input channel, for room in the output ring). The normal mode.
    Device,
    /// The device clock, and in addition the wall clock: a block returns no
    /// earlier than its due time (first_seq + n)/f_s after `start`. For
    /// devices without a clock, such as ALSA's `null` PCM, which consumes
    /// and produces samples as fast as it is called.
    WallClock,
}

/// Settings of an [`AudioRig`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AudioRigConfig {
    /// Output device (id such as `null` or `hw:CARD=0,DEV=0`, full id
    /// `alsa:null`, or name); `None` = the default device.
    pub device: Option<String>,
    /// Input device when different from `device` (then the two clocks
    /// differ and the rings drift: prefer one duplex interface).
    pub input_device: Option<String>,
    /// Sample rate, Hz; `None` = the device's default rate.
    pub sample_rate_hz: Option<u32>,
    /// Output channels to open; `None` = the device default (at least what
    /// the channel map needs).
    pub output_channels: Option<u16>,
    /// Input channels to open; `None` = the device default.
    pub input_channels: Option<u16>,
    /// Output channel (0-based) of the Haptuator amplifier.
    pub haptuator_channel: u16,
    /// Output channels (x, y) of the Pantograph amplifiers; DC-coupled
    /// interfaces only (an AC-coupled output cannot hold a force).
    pub pantograph_channels: Option<[u16; 2]>,
    /// Haptuator drive at digital full scale (sample ±1.0), V.
    pub haptuator_full_scale_v: f64,
    /// Pantograph force at digital full scale, N.
    pub pantograph_full_scale_n: f64,
    /// Input channel (0-based) of the accelerometer's x axis; `None` = no
    /// input stream (acceleration reads 0).
    pub accel_channel: Option<u16>,
    /// Acceleration at digital full scale of the input, m/s² (for an
    /// MMA7361L at 206 mV/g into a 1.236 V-peak input: 6 g = 58.84 m/s²).
    /// Audio inputs are AC-coupled: gravity and slow motion are lost.
    pub accel_full_scale_m_s2: f64,
    /// Largest Pantograph force per axis, N (`[limits]`).
    pub force_max_n: f64,
    /// Largest force-vector norm, N (`[safety]`).
    pub force_norm_max_n: f64,
    /// Largest Haptuator drive, V (`[limits]`).
    pub haptuator_max_v: f64,
    /// Zero frames queued on the output before the first command: the
    /// output latency with an input-paced loop, frames.
    pub latency_frames: u32,
    /// Capacity of each ring buffer, frames (how far the host may run
    /// ahead of the device).
    pub ring_frames: u32,
    /// Device buffer (period) size, frames; `None` = the host's default.
    pub buffer_frames: Option<u32>,
    /// Longest wait for the device inside `process_block`, s; beyond it
    /// the rig reports the device as stalled.
    pub timeout_s: f64,
    /// Timing source.
    pub pacing: AudioPacing,
}

impl AudioRigConfig {
    /// Settings for `device` with the limits of a rig file; the Haptuator on
    /// output 0, the accelerometer on input 0, 2 V and 6 g at full scale,
    /// 1024 frames of latency, 8192-frame rings, device pacing.
    pub fn new(device: Option<&str>, cfg: &RigConfig) -> Self {
        Self {
            device: device.map(str::to_string),
            input_device: None,
            sample_rate_hz: None,
            output_channels: None,
            input_channels: None,
            haptuator_channel: 0,
            pantograph_channels: None,
            haptuator_full_scale_v: 2.0,
            pantograph_full_scale_n: cfg.limits.pantograph_force_max_n,
            accel_channel: Some(0),
            accel_full_scale_m_s2: 6.0 * 9.80665,
            force_max_n: cfg.limits.pantograph_force_max_n,
            force_norm_max_n: cfg.safety.force_norm_max_n,
            haptuator_max_v: cfg.limits.haptuator_drive_max_v,
            latency_frames: 1024,
            ring_frames: 8192,
            buffer_frames: None,
            timeout_s: 1.0,
            pacing: AudioPacing::Device,
        }
    }

    fn validate(&self) -> Result<HardLimits, RigError> {
        let lim = HardLimits::new(
            self.force_max_n,
            self.force_norm_max_n,
            self.haptuator_max_v,
        )?;
        for (name, v) in [
            ("haptuator_full_scale_v", self.haptuator_full_scale_v),
            ("pantograph_full_scale_n", self.pantograph_full_scale_n),
            ("accel_full_scale_m_s2", self.accel_full_scale_m_s2),
            ("timeout_s", self.timeout_s),
        ] {
            RigError::require_positive(name, v)?;
        }
        if self.ring_frames < 2 || self.latency_frames >= self.ring_frames {
            return Err(RigError::InvalidParameter {
                name: "latency_frames",
                value: self.latency_frames as f64,
                reason: format!(
                    "must be below ring_frames ({}), which must be ≥ 2",
                    self.ring_frames
                ),
            });
        }
        if let Some([x, y]) = self.pantograph_channels
            && (x == y || x == self.haptuator_channel || y == self.haptuator_channel)
        {
            return Err(RigError::InvalidInput(format!(
                "output channels overlap: Haptuator {}, Pantograph {x}, {y}",
                self.haptuator_channel
            )));
        }
        Ok(lim)
    }

    fn output_channels_needed(&self) -> u16 {
        let mut n = self.haptuator_channel + 1;
        if let Some([x, y]) = self.pantograph_channels {
            n = n.max(x + 1).max(y + 1);
        }
        n
    }
}

/// Callback-side counters (atomics shared with the cpal threads).
#[derive(Debug, Default)]
struct Shared {
    out_callbacks: AtomicU64,
    out_frames: AtomicU64,
    underrun_frames: AtomicU64,
    in_callbacks: AtomicU64,
    in_frames: AtomicU64,
    overflow_frames: AtomicU64,
    clamped_samples: AtomicU64,
    stream_errors: AtomicU64,
    failed: AtomicBool,
}

/// Snapshot of the callback counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct AudioCounters {
    /// Output callbacks so far.
    pub out_callbacks: u64,
    /// Frames written to the device.
    pub out_frames: u64,
    /// Of those, frames written as silence because the host had queued
    /// nothing (under-runs).
    pub underrun_frames: u64,
    /// Input callbacks so far.
    pub in_callbacks: u64,
    /// Frames received from the device.
    pub in_frames: u64,
    /// Of those, frames dropped because the input ring was full.
    pub overflow_frames: u64,
    /// Output samples clamped to ±1 or replaced (non-finite) in the callback.
    pub clamped_samples: u64,
    /// Errors reported by the audio host.
    pub stream_errors: u64,
}

impl Shared {
    fn snapshot(&self) -> AudioCounters {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        AudioCounters {
            out_callbacks: l(&self.out_callbacks),
            out_frames: l(&self.out_frames),
            underrun_frames: l(&self.underrun_frames),
            in_callbacks: l(&self.in_callbacks),
            in_frames: l(&self.in_frames),
            overflow_frames: l(&self.overflow_frames),
            clamped_samples: l(&self.clamped_samples),
            stream_errors: l(&self.stream_errors),
        }
    }
}

/// One output frame: Haptuator, Pantograph x, Pantograph y, in units of
/// digital full scale.
#[derive(Debug, Clone, Copy, Default)]
struct OutFrame([f32; 3]);

/// Running streams and the host ends of the rings.
struct Engine {
    _out_stream: cpal::Stream,
    _in_stream: Option<cpal::Stream>,
    out: rtrb::Producer<OutFrame>,
    inp: Option<rtrb::Consumer<f32>>,
}

/// The audio-interface rig (module docs of `crate::audio`).
pub struct AudioRig {
    cfg: AudioRigConfig,
    limits: HardLimits,
    identity: RigIdentity,
    out_device: cpal::Device,
    in_device: Option<cpal::Device>,
    out_config: cpal::StreamConfig,
    in_config: Option<cpal::StreamConfig>,
    engine: Option<Engine>,
    shared: Arc<Shared>,
    seq: u64,
    state: RigState,
    started_at: Instant,
    anchor_seq: u64,
    counters: StatusCounters,
    seen_underruns: u64,
    seen_overflows: u64,
}

impl std::fmt::Debug for AudioRig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AudioRig")
            .field("identity", &self.identity)
            .field("out_config", &self.out_config)
            .field("in_config", &self.in_config)
            .field("running", &self.engine.is_some())
            .field("seq", &self.seq)
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

#[inline]
fn to_sample(v: f64, full_scale: f64) -> f32 {
    (v / full_scale) as f32
}

impl AudioRig {
    /// Under-runs (the device played silence) and input overflows (frames
    /// dropped) since the last block: counted, reported and queued.
    fn note_stream_losses(&mut self, report: &mut BlockReport, shared: &Shared) {
        let c = shared.snapshot();
        let under = c.underrun_frames - self.seen_underruns;
        let over = c.overflow_frames - self.seen_overflows;
        self.seen_underruns = c.underrun_frames;
        self.seen_overflows = c.overflow_frames;
        if under > 0 {
            report.skipped_samples = under;
            self.counters.counts.skipped_samples += under;
            self.counters.push(RigFault::Overrun {
                seq: report.first_seq,
                skipped: under,
            });
        }
        if over > 0 {
            let count = u32::try_from(over).unwrap_or(u32::MAX);
            report.lost_frames = count;
            self.counters.counts.lost_frames += over;
            self.counters.push(RigFault::LostFrames {
                first_seq: report.first_seq,
                count,
            });
        }
    }

    /// Wall-clock pacing: sleep until the block is due, or report the lag.
    fn pace(&mut self, report: &mut BlockReport) {
        if self.cfg.pacing == AudioPacing::WallClock {
            let fs = self.identity.sample_rate_hz;
            let due =
                self.started_at + Duration::from_secs_f64((self.seq - self.anchor_seq) as f64 / fs);
            let now = Instant::now();
            if now < due {
                std::thread::sleep(due - now);
            } else {
                report.lag_s = (now - due).as_secs_f64();
            }
        }
    }

    /// Open the devices and choose the stream configurations (streams start
    /// with [`Rig::start`]).
    pub fn open(cfg: &AudioRigConfig) -> Result<Self, RigError> {
        let limits = cfg.validate()?;
        let out_device = find_device(cfg.device.as_deref(), true)?;
        let out_config = f32_config(
            &out_device,
            true,
            cfg.sample_rate_hz,
            cfg.output_channels,
            cfg.output_channels_needed(),
            cfg.buffer_frames,
        )?;
        let fs = out_config.sample_rate;
        let (in_device, in_config) = match cfg.accel_channel {
            None => (None, None),
            Some(ch) => {
                let name = cfg.input_device.as_deref().or(cfg.device.as_deref());
                let d = find_device(name, false)?;
                let c = f32_config(
                    &d,
                    false,
                    Some(fs),
                    cfg.input_channels,
                    ch + 1,
                    cfg.buffer_frames,
                )?;
                (Some(d), Some(c))
            }
        };
        let id = out_device
            .id()
            .map(|i| i.to_string())
            .unwrap_or_else(|_| "?".into());
        let name = out_device
            .description()
            .map(|d| d.name().to_string())
            .unwrap_or_else(|_| id.clone());
        let identity = RigIdentity {
            kind: RigKind::Audio,
            name,
            serial: id,
            firmware: format!("cpal 0.18 ({})", cpal::default_host().id().name()),
            sample_rate_hz: fs as f64,
            force_max_n: limits.force_axis_max_n,
            haptuator_max_v: limits.drive_max_v,
            accel_range_m_s2: if cfg.accel_channel.is_some() {
                cfg.accel_full_scale_m_s2
            } else {
                f64::NAN
            },
        };
        Ok(Self {
            cfg: cfg.clone(),
            limits,
            identity,
            out_device,
            in_device,
            out_config,
            in_config,
            engine: None,
            shared: Arc::new(Shared::default()),
            seq: 0,
            state: RigState::Idle,
            started_at: Instant::now(),
            anchor_seq: 0,
            counters: StatusCounters::default(),
            seen_underruns: 0,
            seen_overflows: 0,
        })
    }

    /// False: an audio interface has no handle encoders; sensor frames carry
    /// handle position (0, 0). Pair with a DAQ for the coupling and the
    /// safety layer's handle-velocity check.
    pub fn handle_available(&self) -> bool {
        false
    }

    /// Callback counters.
    pub fn counters(&self) -> AudioCounters {
        self.shared.snapshot()
    }

    /// Output stream configuration (channels, rate, buffer).
    pub fn output_config(&self) -> &cpal::StreamConfig {
        &self.out_config
    }

    /// Input stream configuration, if any.
    pub fn input_config(&self) -> Option<&cpal::StreamConfig> {
        self.in_config.as_ref()
    }

    fn build(&mut self) -> Result<Engine, RigError> {
        let cap = self.cfg.ring_frames as usize;
        let (mut out_p, mut out_c) = rtrb::RingBuffer::<OutFrame>::new(cap);
        for _ in 0..self.cfg.latency_frames {
            // Cannot fail: latency_frames < ring_frames (validated).
            let _ = out_p.push(OutFrame::default());
        }
        let ch = self.out_config.channels as usize;
        let map: [Option<usize>; 3] = [
            Some(self.cfg.haptuator_channel as usize),
            self.cfg.pantograph_channels.map(|c| c[0] as usize),
            self.cfg.pantograph_channels.map(|c| c[1] as usize),
        ];
        let sh = Arc::clone(&self.shared);
        let sh_err = Arc::clone(&self.shared);
        let out_stream = self
            .out_device
            .build_output_stream(
                self.out_config,
                move |data: &mut [f32], _: &cpal::OutputCallbackInfo| {
                    let (mut under, mut clamped, mut frames) = (0u64, 0u64, 0u64);
                    for frame in data.chunks_exact_mut(ch) {
                        frame.fill(0.0);
                        frames += 1;
                        let Ok(f) = out_c.pop() else {
                            under += 1;
                            continue;
                        };
                        for (slot, v) in map.iter().zip(f.0) {
                            if let Some(s) = slot.and_then(|i| frame.get_mut(i)) {
                                *s = if !v.is_finite() {
                                    clamped += 1;
                                    0.0
                                } else if v.abs() > 1.0 {
                                    clamped += 1;
                                    v.signum()
                                } else {
                                    v
                                };
                            }
                        }
                    }
                    sh.out_callbacks.fetch_add(1, Ordering::Relaxed);
                    sh.out_frames.fetch_add(frames, Ordering::Relaxed);
                    sh.underrun_frames.fetch_add(under, Ordering::Relaxed);
                    sh.clamped_samples.fetch_add(clamped, Ordering::Relaxed);
                },
                move |_e: cpal::Error| {
                    sh_err.stream_errors.fetch_add(1, Ordering::Relaxed);
                    sh_err.failed.store(true, Ordering::Release);
                },
                None,
            )
            .map_err(|e| cpal_err("cannot open the audio output", e))?;
        let (in_stream, inp) = match (&self.in_device, &self.in_config, self.cfg.accel_channel) {
            (Some(dev), Some(conf), Some(ach)) => {
                let (mut in_p, in_c) = rtrb::RingBuffer::<f32>::new(cap);
                let ich = conf.channels as usize;
                let ach = ach as usize;
                let sh = Arc::clone(&self.shared);
                let sh_err = Arc::clone(&self.shared);
                let s = dev
                    .build_input_stream(
                        *conf,
                        move |data: &[f32], _: &cpal::InputCallbackInfo| {
                            let (mut over, mut frames) = (0u64, 0u64);
                            for frame in data.chunks_exact(ich) {
                                frames += 1;
                                let v = frame.get(ach).copied().unwrap_or(0.0);
                                if in_p.push(v).is_err() {
                                    over += 1;
                                }
                            }
                            sh.in_callbacks.fetch_add(1, Ordering::Relaxed);
                            sh.in_frames.fetch_add(frames, Ordering::Relaxed);
                            sh.overflow_frames.fetch_add(over, Ordering::Relaxed);
                        },
                        move |_e: cpal::Error| {
                            sh_err.stream_errors.fetch_add(1, Ordering::Relaxed);
                            sh_err.failed.store(true, Ordering::Release);
                        },
                        None,
                    )
                    .map_err(|e| cpal_err("cannot open the audio input", e))?;
                (Some(s), Some(in_c))
            }
            _ => (None, None),
        };
        out_stream
            .play()
            .map_err(|e| cpal_err("cannot start the audio output", e))?;
        if let Some(s) = &in_stream {
            s.play()
                .map_err(|e| cpal_err("cannot start the audio input", e))?;
        }
        Ok(Engine {
            _out_stream: out_stream,
            _in_stream: in_stream,
            out: out_p,
            inp,
        })
    }

    fn fail(&mut self, msg: &str) -> RigError {
        self.engine = None;
        self.state = RigState::Disconnected;
        self.counters.push(RigFault::Disconnected);
        RigError::Disconnected(msg.to_string())
    }

    /// Wait (sleeping in `POLL_S` steps) until `ready`, at most `timeout`.
    /// Returns false on timeout or a failed stream.
    #[inline]
    fn wait(shared: &Shared, timeout: Duration, mut ready: impl FnMut() -> bool) -> bool {
        if ready() {
            return true;
        }
        let deadline = Instant::now() + timeout;
        loop {
            if ready() {
                return true;
            }
            if shared.failed.load(Ordering::Acquire) {
                return false;
            }
            let now = Instant::now();
            if now >= deadline {
                return false;
            }
            std::thread::sleep((deadline - now).min(Duration::from_secs_f64(POLL_S)));
        }
    }
}

impl Rig for AudioRig {
    fn identity(&self) -> &RigIdentity {
        &self.identity
    }

    fn start(&mut self) -> Result<(), RigError> {
        if self.engine.is_none() {
            self.shared.failed.store(false, Ordering::Release);
            let e = self.build()?;
            self.engine = Some(e);
        }
        self.state = RigState::Running;
        self.started_at = Instant::now();
        self.anchor_seq = self.seq;
        let c = self.shared.snapshot();
        self.seen_underruns = c.underrun_frames;
        self.seen_overflows = c.overflow_frames;
        Ok(())
    }

    /// Stops and closes the streams (the interface outputs silence).
    fn stop(&mut self) -> Result<(), RigError> {
        self.engine = None;
        if self.state != RigState::Disconnected {
            self.state = RigState::Idle;
        }
        Ok(())
    }

    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError> {
        let mut report = open_block(self.state, commands, sensors, self.seq)?;
        if self.shared.failed.load(Ordering::Acquire) {
            return Err(self.fail("the audio host reported a stream error"));
        }
        let timeout = Duration::from_secs_f64(self.cfg.timeout_s);
        let (hfs, pfs, afs) = (
            self.cfg.haptuator_full_scale_v,
            self.cfg.pantograph_full_scale_n,
            self.cfg.accel_full_scale_m_s2,
        );
        let shared = Arc::clone(&self.shared);
        let Some(engine) = self.engine.as_mut() else {
            return Err(RigError::NotReady("audio streams are not running".into()));
        };
        let mut noted = 0u8;
        let mut stalled = false;
        for (cmd, out) in commands.iter().zip(sensors.iter_mut()) {
            let (c, cflags) = hard_limit(*cmd, &self.limits);
            let frame = OutFrame([
                to_sample(c.haptuator_v, hfs),
                to_sample(c.force_n[0], pfs),
                to_sample(c.force_n[1], pfs),
            ]);
            let prod = &mut engine.out;
            if !Self::wait(&shared, timeout, || !prod.is_full()) {
                stalled = true;
                break;
            }
            let _ = engine.out.push(frame);
            let mut flags = cflags.0;
            let a = match engine.inp.as_mut() {
                Some(cons) => {
                    if !Self::wait(&shared, timeout, || !cons.is_empty()) {
                        stalled = true;
                        break;
                    }
                    let v = cons.pop().unwrap_or(0.0) as f64;
                    if !v.is_finite() {
                        flags |= FrameFlags::CLIPPED;
                        0.0
                    } else {
                        if v.abs() >= 1.0 {
                            flags |= FrameFlags::CLIPPED;
                        }
                        v.clamp(-1.0, 1.0) * afs
                    }
                }
                None => 0.0,
            };
            *out = SensorFrame {
                seq: self.seq,
                handle_m: [0.0, 0.0],
                accel_m_s2: [a, 0.0, 0.0],
                flags: FrameFlags(flags),
            };
            self.counters
                .note_flags(FrameFlags(flags), self.seq, &mut noted);
            self.seq += 1;
            self.counters.counts.frames += 1;
        }
        if stalled {
            return Err(if shared.failed.load(Ordering::Acquire) {
                self.fail("the audio host reported a stream error")
            } else {
                self.fail(&format!(
                    "the audio device stalled (no data for {} s)",
                    self.cfg.timeout_s
                ))
            });
        }
        self.note_stream_losses(&mut report, &shared);
        self.pace(&mut report);
        Ok(report)
    }

    fn status(&self) -> RigStatus {
        self.counters.status(self.state)
    }

    fn pop_fault(&mut self) -> Option<RigFault> {
        self.counters.pop_fault()
    }
}
