//! Opening a rig from its `--rig` specification and a tweezer from its
//! `--tweezer` specification: the one place that turns a [`RigSpec`]
//! (`sim`, `serial:PATH[,…]`, `audio[:DEVICE]`) into a running device, for
//! the engine, the study's live station, `rig check`, `calibrate` and the
//! trap-calibration recorder alike, and a [`TweezerSpec`] (`sim`,
//! `serial:PATH[,…]`) into an [`AnyTweezer`].
//!
//! [`AnyRig`] is one concrete type for every backend (an enum, so a closed
//! loop over it stays monomorphic and nothing is boxed per call). On the
//! simulated rig the hand is set by software ([`AnyRig::set_hand`]); on a
//! live rig it is the real handle, read by the encoders, and hand requests
//! are ignored.

use crate::config::RigConfig;
use crate::device::{
    ActuatorFrame, BlockReport, HostInfo, LinkErrorKind, Rig, RigFault, RigIdentity, RigKind,
    RigSpec, RigStatus, SensorFrame, TweezerSpec,
};
use crate::error::RigError;
use crate::serial::{LinkTweezer, SerialRig};
use crate::sim::SimRig;
use crate::tweezer::{AppliedTrap, DetectedTweezer, Tweezer, TweezerParams, TweezerSample};

/// The device behind an [`AnyRig`].
#[derive(Debug)]
pub enum Device {
    /// The simulated rig (batch: the caller paces it, or wall-clock paced
    /// when opened with [`AnyRig::sim_paced`]).
    Sim(Box<SimRig>),
    /// A DAQ on a serial port, or its emulator on a pty (paced by the device).
    Serial(Box<SerialRig>),
    /// An audio interface (paced by the device's clock; cargo feature `audio`).
    #[cfg(feature = "audio")]
    Audio(Box<crate::audio::AudioRig>),
}

/// Any rig (module docs): a [`Device`], the specification it was opened
/// from, and the next sequence number.
#[derive(Debug)]
pub struct AnyRig {
    dev: Device,
    spec: RigSpec,
    next_seq: u64,
}

/// Open the rig `spec` names. A serial rig handshakes here (blocks up to the
/// handshake time-out, 2 s, when a device does not answer); an audio rig
/// opens its devices; the simulated rig is built from `cfg` in batch mode
/// (the caller paces it). `cfg` also gives the audio rig's limits.
///
/// # Errors
/// The device cannot be opened or refuses the handshake; an invalid rig
/// file; an audio rig in a build without the `audio` feature.
pub fn open_rig(spec: &RigSpec, cfg: &RigConfig) -> Result<AnyRig, RigError> {
    AnyRig::open(spec, cfg)
}

impl AnyRig {
    /// The simulated rig of `cfg` in batch mode (the caller paces it).
    ///
    /// # Errors
    /// An invalid rig file.
    pub fn sim(cfg: &RigConfig) -> Result<Self, RigError> {
        Ok(Self::from_sim(SimRig::new(cfg)?))
    }

    /// The simulated rig of `cfg`, paced by the wall clock (it sleeps to
    /// each frame's time and tolerates `max_lag_s` of lag), as a device
    /// would be: for checks that time the stream (`rig check --rig sim`).
    ///
    /// # Errors
    /// An invalid rig file.
    pub fn sim_paced(cfg: &RigConfig, max_lag_s: f64) -> Result<Self, RigError> {
        Ok(Self::from_sim(SimRig::paced(cfg, max_lag_s)?))
    }

    /// Wrap a simulated rig.
    pub fn from_sim(rig: SimRig) -> Self {
        Self {
            dev: Device::Sim(Box::new(rig)),
            spec: RigSpec::Sim,
            next_seq: 0,
        }
    }

    /// See [`open_rig`].
    ///
    /// # Errors
    /// As [`open_rig`].
    pub fn open(spec: &RigSpec, cfg: &RigConfig) -> Result<Self, RigError> {
        let dev = match spec {
            RigSpec::Sim => return Self::sim(cfg),
            RigSpec::Serial(c) => Device::Serial(Box::new(SerialRig::open(c)?)),
            #[cfg(feature = "audio")]
            RigSpec::Audio(d) => {
                let ac = crate::audio::AudioRigConfig::new(d.as_deref(), cfg);
                Device::Audio(Box::new(crate::audio::AudioRig::open(&ac)?))
            }
            #[cfg(not(feature = "audio"))]
            RigSpec::Audio(_) => return Err(RigSpec::audio_not_built()),
        };
        Ok(Self {
            dev,
            spec: spec.clone(),
            next_seq: 0,
        })
    }

    /// The specification this rig was opened from.
    pub fn spec(&self) -> &RigSpec {
        &self.spec
    }

    /// The device.
    pub fn device(&self) -> &Device {
        &self.dev
    }

    /// The device, mutably (backend-specific calls: link statistics,
    /// deadlines).
    pub fn device_mut(&mut self) -> &mut Device {
        &mut self.dev
    }

    /// A live rig (the hand is the real handle; the device paces the loop)?
    pub fn is_live(&self) -> bool {
        !matches!(self.dev, Device::Sim(_))
    }

    /// The simulated rig, if this is one.
    pub fn as_sim(&self) -> Option<&SimRig> {
        match &self.dev {
            Device::Sim(r) => Some(r),
            _ => None,
        }
    }

    /// Sequence number of the next frame.
    pub fn next_seq(&self) -> u64 {
        match &self.dev {
            Device::Sim(r) => r.seq(),
            _ => self.next_seq,
        }
    }

    /// Move the simulated hand to `pos` (m); ignored by live rigs, whose
    /// handle is moved by a real hand.
    #[inline]
    pub fn set_hand(&mut self, pos: [f64; 2]) {
        if let Device::Sim(r) = &mut self.dev {
            r.set_hand(pos);
        }
    }

    /// Swap the simulated rig for `other` (a fresh one for a new trial,
    /// built off the real-time path); the old one is left in `other` to be
    /// dropped there. Returns `false` (nothing swapped) on a live rig.
    pub fn swap_sim(&mut self, other: &mut Box<SimRig>) -> bool {
        match &mut self.dev {
            Device::Sim(r) => {
                std::mem::swap(r, other);
                true
            }
            _ => false,
        }
    }

    /// Reconnect after a disconnect: `None` reopens the same device
    /// ([`SerialRig::reconnect`] for a serial rig; the simulated rig has
    /// nothing to reopen), `Some(spec)` opens that rig instead (e.g. the
    /// emulator restarted on another pty). The rig is idle afterwards
    /// (`start` to resume). Allocates: call only while the loop is stopped.
    ///
    /// # Errors
    /// As [`open_rig`].
    pub fn reconnect(&mut self, spec: Option<&RigSpec>, cfg: &RigConfig) -> Result<(), RigError> {
        match spec {
            Some(s) if *s != self.spec => {
                let new = Self::open(s, cfg)?;
                let _ = self.dev_stop();
                *self = new;
                Ok(())
            }
            _ => match &mut self.dev {
                Device::Sim(_) => Ok(()),
                Device::Serial(r) => r.reconnect(),
                #[cfg(feature = "audio")]
                Device::Audio(_) => {
                    let new = Self::open(&self.spec.clone(), cfg)?;
                    *self = new;
                    Ok(())
                }
            },
        }
    }

    fn dev_stop(&mut self) -> Result<(), RigError> {
        match &mut self.dev {
            Device::Sim(r) => r.stop(),
            Device::Serial(r) => r.stop(),
            #[cfg(feature = "audio")]
            Device::Audio(r) => r.stop(),
        }
    }
}

/// Delegate a call to the device.
macro_rules! each {
    ($self:expr, $r:ident => $e:expr) => {
        match $self {
            Device::Sim($r) => $e,
            Device::Serial($r) => $e,
            #[cfg(feature = "audio")]
            Device::Audio($r) => $e,
        }
    };
}

impl Rig for AnyRig {
    fn identity(&self) -> &RigIdentity {
        each!(&self.dev, r => r.identity())
    }

    fn start(&mut self) -> Result<(), RigError> {
        each!(&mut self.dev, r => r.start())
    }

    fn stop(&mut self) -> Result<(), RigError> {
        self.dev_stop()
    }

    #[inline]
    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError> {
        let r = each!(&mut self.dev, d => d.process_block(commands, sensors))?;
        self.next_seq = r.first_seq + r.frames as u64;
        Ok(r)
    }

    /// One frame through the device's own frame path (the simulated rig's
    /// is cheaper than a one-frame block; the others use the block path).
    #[inline]
    fn process_frame(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        let r = each!(&mut self.dev, d => d.process_frame(command, sensors))?;
        self.next_seq = r.first_seq + r.frames as u64;
        Ok(r)
    }

    fn status(&self) -> RigStatus {
        each!(&self.dev, r => r.status())
    }

    fn pop_fault(&mut self) -> Option<RigFault> {
        each!(&mut self.dev, r => r.pop_fault())
    }

    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        each!(&self.dev, r => r.loop_delay_samples(block_len))
    }

    fn round_trip_s(&self) -> Option<f64> {
        each!(&self.dev, r => r.round_trip_s())
    }

    fn send_info(&mut self, info: &HostInfo) -> Result<(), RigError> {
        each!(&mut self.dev, r => r.send_info(info))
    }
}

/// Is `kind` a live rig?
pub fn is_live_kind(kind: RigKind) -> bool {
    kind != RigKind::Simulated
}

/// Any tweezer the loop can run (module docs): the simulated tweezer with
/// its simulated position detector, or a live one on a serial link. One
/// concrete type (an enum), so the loop over it stays monomorphic.
#[derive(Debug)]
pub enum AnyTweezer {
    /// The simulated tweezer of the rig file (a new one per trial in a
    /// study; obstacles replaceable in Explore).
    Sim(Box<DetectedTweezer>),
    /// A live tweezer (or its emulator): its micro-world is its own.
    Link(Box<LiveTweezer>),
}

/// A live tweezer and where the loop's frame sits in the instrument's.
/// The loop (the hand↔trap mapping, the trial's scene, the metrics) works
/// in its own frame; the instrument's obstacles are where they are. For
/// each trial the frame is translated so that the instrument's obstacle
/// appears where the trial's scene puts it (the physics in the focal plane
/// is invariant under translation): trap set-points go out as
/// trap + origin, bead positions come back as bead − origin.
#[derive(Debug)]
pub struct LiveTweezer {
    link: LinkTweezer,
    origin_m: [f64; 2],
}

impl AnyTweezer {
    /// The simulated tweezer of `cfg`'s `[tweezer]` section at `fs_hz`.
    ///
    /// # Errors
    /// An invalid tweezer or detector section.
    pub fn sim(cfg: &RigConfig, fs_hz: f64) -> Result<Self, RigError> {
        Ok(Self::Sim(Box::new(DetectedTweezer::new(
            TweezerParams::from_config(&cfg.tweezer),
            &cfg.tweezer.detector,
            fs_hz,
        )?)))
    }

    /// Open the tweezer `spec` names for a loop at `fs_hz`. A live tweezer
    /// handshakes and starts here, and must run at the loop's rate.
    ///
    /// # Errors
    /// The device cannot be opened, refuses the handshake or runs at
    /// another rate; an invalid rig file.
    pub fn open(spec: &TweezerSpec, cfg: &RigConfig, fs_hz: f64) -> Result<Self, RigError> {
        match spec {
            TweezerSpec::Sim => Self::sim(cfg, fs_hz),
            TweezerSpec::Serial(c) => {
                let t = LinkTweezer::open(c)?;
                let rate = t.sample_rate_hz();
                if rate != fs_hz {
                    return Err(RigError::Device(format!(
                        "the tweezer on {} runs at {rate} Hz, the haptic loop at {fs_hz} Hz: \
                         both devices must stream at the same rate",
                        c.path
                    )));
                }
                Ok(Self::Link(Box::new(LiveTweezer {
                    link: t,
                    origin_m: [0.0; 2],
                })))
            }
        }
    }

    /// A live tweezer?
    pub fn is_live(&self) -> bool {
        matches!(self, Self::Link(_))
    }

    /// The simulated tweezer, if this is one.
    pub fn as_sim(&self) -> Option<&DetectedTweezer> {
        match self {
            Self::Sim(t) => Some(t),
            Self::Link(_) => None,
        }
    }

    /// The live tweezer, if this is one.
    pub fn as_link(&self) -> Option<&LinkTweezer> {
        match self {
            Self::Link(t) => Some(&t.link),
            Self::Sim(_) => None,
        }
    }

    /// Put the loop frame's origin at `origin_m` of a live instrument's
    /// frame (m; [`LiveTweezer`]); nothing for a simulated tweezer, whose
    /// scene is built in the loop's frame. Takes effect at the next
    /// [`Tweezer::reset`].
    pub fn set_frame_origin(&mut self, origin_m: [f64; 2]) {
        if let Self::Link(t) = self
            && origin_m.iter().all(|v| v.is_finite())
        {
            t.origin_m = origin_m;
        }
    }

    /// Bead centre of the last sample, m.
    pub fn bead(&self) -> [f64; 2] {
        match self {
            Self::Sim(t) => t.bead(),
            Self::Link(t) => {
                let b = t.link.bead();
                [b[0] - t.origin_m[0], b[1] - t.origin_m[1]]
            }
        }
    }

    /// Put the simulated bead at `bead` (m); a live bead is where it is.
    pub fn set_bead(&mut self, bead: [f64; 2]) {
        if let Self::Sim(t) = self {
            t.set_bead(bead);
        }
    }

    /// The trap calibration the tweezer reports through (None: its own
    /// bead position and κ).
    pub fn calibration(&self) -> Option<AppliedTrap> {
        match self {
            Self::Sim(t) => t.calibration(),
            Self::Link(t) => t.link.calibration(),
        }
    }

    /// Report through the trap calibration `c` from now on (None: the
    /// tweezer's own bead position and κ). On a live tweezer it sets the κ
    /// and the detector sensitivity the loop's optical force is computed
    /// with.
    ///
    /// # Errors
    /// A non-finite or non-positive κ, a non-finite sensitivity.
    pub fn set_calibration(&mut self, c: Option<AppliedTrap>) -> Result<(), RigError> {
        match self {
            Self::Sim(t) => t.set_calibration(c),
            Self::Link(t) => t.link.set_calibration(c),
        }
    }

    /// Start a live tweezer's stream again (after a stop or a link failure:
    /// the port is reopened when it was lost); nothing for a simulated one.
    /// Blocks for the handshake: call only while the loop is stopped.
    ///
    /// # Errors
    /// The device does not answer or refuses to start.
    pub fn start(&mut self) -> Result<(), RigError> {
        match self {
            Self::Sim(_) => Ok(()),
            Self::Link(t) => t.link.recover(),
        }
    }

    /// Stop a live tweezer's stream (its trap held); nothing for a
    /// simulated one.
    pub fn stop(&mut self) {
        if let Self::Link(t) = self {
            t.link.stop();
        }
    }
}

impl LiveTweezer {
    /// A sample from the instrument's frame into the loop's.
    #[inline]
    fn to_loop(&self, mut s: TweezerSample) -> TweezerSample {
        for k in 0..2 {
            s.bead_m[k] -= self.origin_m[k];
            s.trap_m[k] -= self.origin_m[k];
        }
        s
    }

    /// Step the link in pieces of at most [`crate::haptic_loop::MAX_BLOCK`]
    /// with the set-points moved into the instrument's frame and the
    /// samples back into the loop's (with the detector volts when `volts`
    /// is given; `false` if the link gives none).
    fn translated(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        mut volts: Option<&mut [[f64; 2]]>,
    ) -> bool {
        let mut dev = [[0.0; 2]; crate::haptic_loop::MAX_BLOCK];
        let mut detected = true;
        let n_all = traps.len().min(out.len());
        for chunk in (0..n_all).step_by(dev.len()) {
            let end = (chunk + dev.len()).min(n_all);
            for (d, t) in dev.iter_mut().zip(&traps[chunk..end]) {
                *d = self.to_instrument(*t);
            }
            let n = end - chunk;
            match volts.as_deref_mut() {
                Some(v) if v.len() >= end => {
                    detected &= self.link.step_block_detected(
                        &dev[..n],
                        &mut out[chunk..end],
                        &mut v[chunk..end],
                    );
                }
                Some(_) => {
                    detected = false;
                    self.link.step_block(&dev[..n], &mut out[chunk..end]);
                }
                None => self.link.step_block(&dev[..n], &mut out[chunk..end]),
            }
            for o in &mut out[chunk..end] {
                *o = self.to_loop(*o);
            }
        }
        detected
    }

    /// A trap set-point from the loop's frame into the instrument's.
    #[inline]
    fn to_instrument(&self, t: [f64; 2]) -> [f64; 2] {
        [t[0] + self.origin_m[0], t[1] + self.origin_m[1]]
    }
}

impl Tweezer for LiveTweezer {
    fn sample_rate_hz(&self) -> f64 {
        self.link.sample_rate_hz()
    }
    fn stiffness_n_per_m(&self) -> f64 {
        self.link.stiffness_n_per_m()
    }
    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        let s = self.link.step(self.to_instrument(trap_m));
        self.to_loop(s)
    }
    fn step_block(&mut self, traps: &[[f64; 2]], out: &mut [TweezerSample]) {
        self.translated(traps, out, None);
    }
    fn step_block_detected(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        volts: &mut [[f64; 2]],
    ) -> bool {
        self.translated(traps, out, Some(volts))
    }
    fn reset(&mut self, trap_m: [f64; 2]) {
        let t = self.to_instrument(trap_m);
        self.link.reset(t);
    }
    fn detector_v(&self) -> Option<[f64; 2]> {
        self.link.detector_v()
    }
    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        self.link.loop_delay_samples(block_len)
    }
    fn link_error(&self) -> Option<LinkErrorKind> {
        self.link.link_error()
    }
    fn round_trip_s(&self) -> Option<f64> {
        self.link.round_trip_s()
    }
}

/// Delegate a call to the tweezer.
macro_rules! each_tw {
    ($self:expr, $t:ident => $e:expr) => {
        match $self {
            AnyTweezer::Sim($t) => $e,
            AnyTweezer::Link($t) => $e,
        }
    };
}

impl Tweezer for AnyTweezer {
    #[inline]
    fn sample_rate_hz(&self) -> f64 {
        each_tw!(self, t => t.sample_rate_hz())
    }
    #[inline]
    fn stiffness_n_per_m(&self) -> f64 {
        each_tw!(self, t => t.stiffness_n_per_m())
    }
    #[inline]
    fn step(&mut self, trap_m: [f64; 2]) -> TweezerSample {
        each_tw!(self, t => t.step(trap_m))
    }
    #[inline]
    fn step_block(&mut self, traps: &[[f64; 2]], out: &mut [TweezerSample]) {
        each_tw!(self, t => t.step_block(traps, out))
    }
    fn step_block_detected(
        &mut self,
        traps: &[[f64; 2]],
        out: &mut [TweezerSample],
        volts: &mut [[f64; 2]],
    ) -> bool {
        each_tw!(self, t => t.step_block_detected(traps, out, volts))
    }
    fn reset(&mut self, trap_m: [f64; 2]) {
        each_tw!(self, t => t.reset(trap_m))
    }
    fn detector_v(&self) -> Option<[f64; 2]> {
        each_tw!(self, t => t.detector_v())
    }
    fn loop_delay_samples(&self, block_len: usize) -> u32 {
        each_tw!(self, t => t.loop_delay_samples(block_len))
    }
    #[inline]
    fn link_error(&self) -> Option<LinkErrorKind> {
        each_tw!(self, t => t.link_error())
    }
    fn round_trip_s(&self) -> Option<f64> {
        each_tw!(self, t => t.round_trip_s())
    }
}
