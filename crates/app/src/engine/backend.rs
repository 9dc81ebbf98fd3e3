//! The rig behind the engine: the simulated rig, a serial DAQ (or its
//! emulator on a pty), or an audio interface (cargo feature `audio`),
//! chosen with the `--rig` syntax of [`RigSpec`] (`sim`,
//! `serial:PATH[,baud=N][,timeout-ms=N]`, `audio[:DEVICE]`).
//!
//! [`EngineRig`] is one concrete type for all of them (an enum, so the
//! engine's closed loop stays monomorphic and nothing is boxed per call).
//! On the simulated rig the hand is the GUI's mouse ([`EngineRig::set_hand`]);
//! on a live rig it is the real handle, read by the encoders, and hand
//! requests are ignored.
//!
//! The engine exchanges frames with a *live* rig in blocks of
//! `block_len` samples (module docs of [`crate::engine`]): one round trip
//! per block, not per sample.

use kilotouch_rig::device::RigSpec;
use kilotouch_rig::device::{BlockReport, RigFault, RigIdentity, RigKind, RigStatus};
use kilotouch_rig::error::RigError;
use kilotouch_rig::serial::SerialRig;
use kilotouch_rig::{ActuatorFrame, Rig, RigConfig, SensorFrame, SimRig};

/// The device (see [`EngineRig`]).
#[derive(Debug)]
pub enum Device {
    /// The simulated rig (batch; the engine paces it).
    Sim(Box<SimRig>),
    /// A DAQ on a serial port (paced by the device).
    Serial(Box<SerialRig>),
    /// An audio interface (paced by the device's clock).
    #[cfg(feature = "audio")]
    Audio(Box<kilotouch_rig::audio::AudioRig>),
}

/// The engine's rig: a [`Device`] and the next sequence number (module docs).
#[derive(Debug)]
pub struct EngineRig {
    dev: Device,
    spec: RigSpec,
    next_seq: u64,
}

impl EngineRig {
    /// The simulated rig of `cfg` (batch: the engine paces it).
    pub fn sim(cfg: &RigConfig) -> Result<Self, RigError> {
        Ok(Self {
            dev: Device::Sim(Box::new(SimRig::new(cfg)?)),
            spec: RigSpec::Sim,
            next_seq: 0,
        })
    }

    /// Open the rig `spec` names. A serial rig handshakes here (blocks up to
    /// the handshake timeout, 2 s, when a device does not answer); an audio
    /// rig opens its devices. `cfg` gives the simulated rig and the audio
    /// rig's limits.
    pub fn open(spec: &RigSpec, cfg: &RigConfig) -> Result<Self, RigError> {
        let dev = match spec {
            RigSpec::Sim => return Self::sim(cfg),
            RigSpec::Serial(c) => Device::Serial(Box::new(SerialRig::open(c)?)),
            #[cfg(feature = "audio")]
            RigSpec::Audio(d) => {
                let ac = kilotouch_rig::audio::AudioRigConfig::new(d.as_deref(), cfg);
                Device::Audio(Box::new(kilotouch_rig::audio::AudioRig::open(&ac)?))
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

    /// A live rig (the hand is the real handle; the device paces the loop)?
    pub fn is_live(&self) -> bool {
        !matches!(self.dev, Device::Sim(_))
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

    /// Reconnect after a disconnect: `None` reopens the same device
    /// ([`SerialRig::reconnect`] for a serial rig; the simulated rig has
    /// nothing to reopen), `Some(spec)` opens that rig instead (e.g. the
    /// emulator restarted on another pty). The rig is idle afterwards
    /// (`start` to resume). Allocates: call only while the loop is stopped.
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

impl Rig for EngineRig {
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
}

/// Is `kind` a live rig?
pub fn is_live_kind(kind: RigKind) -> bool {
    kind != RigKind::Simulated
}
