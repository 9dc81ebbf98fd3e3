//! HELLO, STATUS, FAULT and SCENE payloads (`docs/PROTOCOL.md` §5.1, §6.3,
//! §6.4, §6.5).

use crate::frame::{PROTOCOL_VERSION, WireError, rd};

/// Kind of device announced in [`Hello`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// Haptic DAQ: encoders, accelerometer, Pantograph and Haptuator outputs.
    Daq,
    /// Optical tweezer: trap positioning, bead tracking.
    Tweezer,
}

impl DeviceKind {
    /// Wire code.
    pub fn code(self) -> u8 {
        match self {
            DeviceKind::Daq => 1,
            DeviceKind::Tweezer => 2,
        }
    }
    /// From the wire code.
    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            1 => Some(DeviceKind::Daq),
            2 => Some(DeviceKind::Tweezer),
            _ => None,
        }
    }
}

/// Capabilities of a DAQ (handshake). Output codes are i16 with full scale
/// ±32767 = ±the limit: value = code · limit / 32767.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DaqCaps {
    /// Encoder counts per metre of handle travel.
    pub encoder_counts_per_m: f64,
    /// Accelerometer scale, (m/s²) per code.
    pub accel_m_s2_per_code: f64,
    /// Accelerometer full scale, ±m/s².
    pub accel_range_m_s2: f64,
    /// Pantograph force limit per axis, N (code ±32767).
    pub force_max_n: f64,
    /// Haptuator drive limit, V (code ±32767).
    pub drive_max_v: f64,
}

/// Capabilities of a tweezer (handshake).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TweezerCaps {
    /// Trap stiffness κ, N/m.
    pub stiffness_n_per_m: f64,
}

/// Kind-specific capabilities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Caps {
    /// DAQ.
    Daq(DaqCaps),
    /// Tweezer.
    Tweezer(TweezerCaps),
}

impl Caps {
    /// Device kind.
    pub fn kind(&self) -> DeviceKind {
        match self {
            Caps::Daq(_) => DeviceKind::Daq,
            Caps::Tweezer(_) => DeviceKind::Tweezer,
        }
    }

    /// Encoded size, bytes.
    pub fn size(&self) -> usize {
        match self {
            Caps::Daq(_) => 40,
            Caps::Tweezer(_) => 8,
        }
    }
}

/// Longest `str8` string, bytes.
pub const MAX_STR: usize = 255;

/// Handshake answer (device → host, [`crate::ty::HELLO`]), borrowing its
/// identity strings: the firmware's `&'static str`s when it encodes, the
/// payload when the host parses. The strings are `str8` on the wire
/// (UTF-8, at most [`MAX_STR`] bytes: longer ones are cut at a character
/// boundary when encoded); a parsed string is the device's bytes, which
/// need not be valid UTF-8.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hello<'a> {
    /// Protocol version of the device.
    pub version: u16,
    /// Sample rate, Hz.
    pub sample_rate_hz: u32,
    /// Watchdog window, ms.
    pub watchdog_ms: u16,
    /// Samples per device frame at most.
    pub batch: u8,
    /// Capabilities (the kind follows from the variant).
    pub caps: Caps,
    /// Device name.
    pub name: &'a [u8],
    /// Serial number.
    pub serial: &'a [u8],
    /// Firmware version.
    pub firmware: &'a [u8],
}

/// Length of `s` as a `str8`: at most [`MAX_STR`] bytes, cut before a UTF-8
/// continuation byte.
fn str8_len(s: &[u8]) -> usize {
    let mut n = s.len().min(MAX_STR);
    while n > 0 && n < s.len() && (s[n] & 0xC0) == 0x80 {
        n -= 1;
    }
    n
}

impl<'a> Hello<'a> {
    /// Largest HELLO payload, bytes (DAQ capabilities, three 255-byte strings).
    pub const MAX_SIZE: usize = 10 + 40 + 3 * (1 + MAX_STR);

    /// Device kind.
    pub fn kind(&self) -> DeviceKind {
        self.caps.kind()
    }

    /// Encoded payload size, bytes.
    pub fn size(&self) -> usize {
        10 + self.caps.size()
            + [self.name, self.serial, self.firmware]
                .iter()
                .map(|s| 1 + str8_len(s))
                .sum::<usize>()
    }

    /// Encode the payload into the start of `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, WireError> {
        let n = self.size();
        let Some(out) = out.get_mut(..n) else {
            return Err(WireError::BufferTooSmall(n));
        };
        let mut at = 0;
        let mut put = |b: &[u8]| {
            out[at..at + b.len()].copy_from_slice(b);
            at += b.len();
        };
        put(&self.version.to_le_bytes());
        put(&[self.kind().code()]);
        put(&self.sample_rate_hz.to_le_bytes());
        put(&self.watchdog_ms.to_le_bytes());
        put(&[self.batch]);
        match self.caps {
            Caps::Daq(c) => {
                for v in [
                    c.encoder_counts_per_m,
                    c.accel_m_s2_per_code,
                    c.accel_range_m_s2,
                    c.force_max_n,
                    c.drive_max_v,
                ] {
                    put(&v.to_le_bytes());
                }
            }
            Caps::Tweezer(c) => put(&c.stiffness_n_per_m.to_le_bytes()),
        }
        for s in [self.name, self.serial, self.firmware] {
            let k = str8_len(s);
            put(&[k as u8]);
            put(&s[..k]);
        }
        Ok(n)
    }

    /// Parse a HELLO payload (trailing bytes are ignored, as by every
    /// version-2 host).
    pub fn parse(payload: &'a [u8]) -> Option<Self> {
        let mut r = Rd { b: payload, at: 0 };
        let version = r.u16()?;
        let kind = DeviceKind::from_code(r.u8()?)?;
        let sample_rate_hz = r.u32()?;
        let watchdog_ms = r.u16()?;
        let batch = r.u8()?;
        let caps = match kind {
            DeviceKind::Daq => Caps::Daq(DaqCaps {
                encoder_counts_per_m: r.f64()?,
                accel_m_s2_per_code: r.f64()?,
                accel_range_m_s2: r.f64()?,
                force_max_n: r.f64()?,
                drive_max_v: r.f64()?,
            }),
            DeviceKind::Tweezer => Caps::Tweezer(TweezerCaps {
                stiffness_n_per_m: r.f64()?,
            }),
        };
        Some(Self {
            version,
            sample_rate_hz,
            watchdog_ms,
            batch,
            caps,
            name: r.str8()?,
            serial: r.str8()?,
            firmware: r.str8()?,
        })
    }

    /// A HELLO of the current protocol version.
    pub fn current(caps: Caps, sample_rate_hz: u32, watchdog_ms: u16, batch: u8) -> Self {
        Self {
            version: PROTOCOL_VERSION,
            sample_rate_hz,
            watchdog_ms,
            batch,
            caps,
            name: &[],
            serial: &[],
            firmware: &[],
        }
    }
}

/// Sequential little-endian reader over a payload.
struct Rd<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Rd<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let s = self.b.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|s| s[0])
    }
    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|s| u16::from_le_bytes(rd(s, 0)))
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4).map(|s| u32::from_le_bytes(rd(s, 0)))
    }
    fn f64(&mut self) -> Option<f64> {
        self.take(8).map(|s| f64::from_le_bytes(rd(s, 0)))
    }
    fn str8(&mut self) -> Option<&'a [u8]> {
        let n = self.u8()? as usize;
        self.take(n)
    }
}

/// Device state in [`Status`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceState {
    /// Outputs zero, not streaming.
    Idle,
    /// Streaming samples.
    Running,
    /// Stopped by the watchdog (outputs zero) until the next START.
    Tripped,
}

impl DeviceState {
    /// Wire code.
    pub fn code(self) -> u8 {
        match self {
            DeviceState::Idle => 0,
            DeviceState::Running => 1,
            DeviceState::Tripped => 2,
        }
    }
    /// From the wire code.
    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(DeviceState::Idle),
            1 => Some(DeviceState::Running),
            2 => Some(DeviceState::Tripped),
            _ => None,
        }
    }
}

/// Device status ([`crate::ty::STATUS`]): sent on START/STOP, and every
/// 10 ms while the device waits for commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status {
    /// Sequence number of the next sample the device will execute (every
    /// earlier sample has been sent).
    pub next_seq: u32,
    /// State.
    pub state: DeviceState,
    /// Valid host frames received.
    pub host_frames: u32,
    /// Host frames rejected (CRC errors seen by the device's decoder).
    pub host_crc_errors: u32,
    /// Samples executed with a held command (late or missing).
    pub late_commands: u32,
}

impl Status {
    /// Payload size, bytes.
    pub const SIZE: usize = 17;

    /// The payload.
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut o = [0u8; Self::SIZE];
        o[..4].copy_from_slice(&self.next_seq.to_le_bytes());
        o[4] = self.state.code();
        o[5..9].copy_from_slice(&self.host_frames.to_le_bytes());
        o[9..13].copy_from_slice(&self.host_crc_errors.to_le_bytes());
        o[13..].copy_from_slice(&self.late_commands.to_le_bytes());
        o
    }

    /// Parse a payload (exactly [`Self::SIZE`] bytes, a known state).
    pub fn parse(payload: &[u8]) -> Option<Self> {
        if payload.len() != Self::SIZE {
            return None;
        }
        Some(Self {
            next_seq: u32::from_le_bytes(rd(payload, 0)),
            state: DeviceState::from_code(payload[4])?,
            host_frames: u32::from_le_bytes(rd(payload, 5)),
            host_crc_errors: u32::from_le_bytes(rd(payload, 9)),
            late_commands: u32::from_le_bytes(rd(payload, 13)),
        })
    }
}

/// A fault ([`crate::ty::FAULT`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultReport {
    /// Fault code ([`crate::fault`]).
    pub code: u8,
    /// Sequence number at which it happened.
    pub seq: u32,
}

impl FaultReport {
    /// Payload size, bytes.
    pub const SIZE: usize = 5;

    /// The payload.
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut o = [0u8; Self::SIZE];
        o[0] = self.code;
        o[1..].copy_from_slice(&self.seq.to_le_bytes());
        o
    }

    /// Parse a payload (exactly [`Self::SIZE`] bytes).
    pub fn parse(payload: &[u8]) -> Option<Self> {
        (payload.len() == Self::SIZE).then(|| Self {
            code: payload[0],
            seq: u32::from_le_bytes(rd(payload, 1)),
        })
    }
}

/// Most obstacles a [`Scene`] carries (9 + 32 · 24 = 777 payload bytes).
pub const MAX_SCENE_OBSTACLES: usize = 32;

/// One obstacle of a [`Scene`]: a sphere whose centre lies in the focal
/// plane, in the trap's frame (the frame of the trap set-points), m.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SceneObstacle {
    /// Centre (x, y), m.
    pub centre_m: [f64; 2],
    /// Radius, m.
    pub radius_m: f64,
}

/// A tweezer's scene ([`crate::ty::SCENE`], `docs/PROTOCOL.md` §6.5): the
/// bead's radius and the fixed obstacles around it, so that the host
/// computes the bead's surface gap and contact normal from the same
/// geometry as the instrument. Payload: `f64` bead radius (m), `u8` count
/// n ≤ [`MAX_SCENE_OBSTACLES`], n × (`f64` x, `f64` y, `f64` radius, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scene {
    /// Bead radius R, m.
    pub bead_radius_m: f64,
    /// Obstacles in use (≤ [`MAX_SCENE_OBSTACLES`]).
    pub count: u8,
    /// The obstacles; the first `count` are the scene's.
    pub obstacles: [SceneObstacle; MAX_SCENE_OBSTACLES],
}

impl Scene {
    /// Largest payload, bytes.
    pub const MAX_SIZE: usize = 9 + 24 * MAX_SCENE_OBSTACLES;

    /// A scene of `obstacles` (`None` when there are more than
    /// [`MAX_SCENE_OBSTACLES`]).
    pub fn new(bead_radius_m: f64, obstacles: &[SceneObstacle]) -> Option<Self> {
        if obstacles.len() > MAX_SCENE_OBSTACLES {
            return None;
        }
        let mut o = [SceneObstacle::default(); MAX_SCENE_OBSTACLES];
        o[..obstacles.len()].copy_from_slice(obstacles);
        Some(Self {
            bead_radius_m,
            count: obstacles.len() as u8,
            obstacles: o,
        })
    }

    /// The scene's obstacles.
    pub fn obstacles(&self) -> &[SceneObstacle] {
        &self.obstacles[..usize::from(self.count).min(MAX_SCENE_OBSTACLES)]
    }

    /// Encoded payload size, bytes.
    pub fn size(&self) -> usize {
        9 + 24 * self.obstacles().len()
    }

    /// Encode the payload into the start of `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, WireError> {
        let n = self.size();
        let Some(out) = out.get_mut(..n) else {
            return Err(WireError::BufferTooSmall(n));
        };
        out[..8].copy_from_slice(&self.bead_radius_m.to_le_bytes());
        out[8] = self.obstacles().len() as u8;
        for (o, dst) in self.obstacles().iter().zip(out[9..].chunks_exact_mut(24)) {
            dst[..8].copy_from_slice(&o.centre_m[0].to_le_bytes());
            dst[8..16].copy_from_slice(&o.centre_m[1].to_le_bytes());
            dst[16..].copy_from_slice(&o.radius_m.to_le_bytes());
        }
        Ok(n)
    }

    /// Parse a payload (exactly `9 + 24 n` bytes, n ≤
    /// [`MAX_SCENE_OBSTACLES`]; the values are the device's, checked by
    /// the host).
    pub fn parse(payload: &[u8]) -> Option<Self> {
        let mut r = Rd { b: payload, at: 0 };
        let bead_radius_m = r.f64()?;
        let n = usize::from(r.u8()?);
        if n > MAX_SCENE_OBSTACLES || payload.len() != 9 + 24 * n {
            return None;
        }
        let mut s = Self::new(bead_radius_m, &[])?;
        for o in s.obstacles.iter_mut().take(n) {
            *o = SceneObstacle {
                centre_m: [r.f64()?, r.f64()?],
                radius_m: r.f64()?,
            };
        }
        s.count = n as u8;
        Some(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn daq_caps() -> Caps {
        Caps::Daq(DaqCaps {
            encoder_counts_per_m: 1e5,
            accel_m_s2_per_code: 1.4528e-2,
            accel_range_m_s2: 58.8399,
            force_max_n: 5.0,
            drive_max_v: 10.0,
        })
    }

    #[test]
    fn messages_round_trip() {
        let h = Hello {
            name: "rig é".as_bytes(),
            serial: b"0001",
            firmware: b"fw 1",
            ..Hello::current(daq_caps(), 10_000, 100, 10)
        };
        let mut b = [0u8; Hello::MAX_SIZE];
        let n = h.encode(&mut b).unwrap();
        assert_eq!(n, h.size());
        assert_eq!(n, 10 + 40 + 7 + 5 + 5);
        assert_eq!(Hello::parse(&b[..n]), Some(h));
        let t = Hello::current(
            Caps::Tweezer(TweezerCaps {
                stiffness_n_per_m: 1e-5,
            }),
            10_000,
            0,
            1,
        );
        let n = t.encode(&mut b).unwrap();
        assert_eq!(Hello::parse(&b[..n]), Some(t));
        assert_eq!(Hello::parse(&b[..n - 1]), None);
        let st = Status {
            next_seq: 77,
            state: DeviceState::Tripped,
            host_frames: 5,
            host_crc_errors: 2,
            late_commands: 1,
        };
        assert_eq!(Status::parse(&st.encode()), Some(st));
        let mut bad = st.encode();
        bad[4] = 3;
        assert_eq!(Status::parse(&bad), None);
        let fr = FaultReport {
            code: crate::fault::WATCHDOG,
            seq: 9,
        };
        assert_eq!(FaultReport::parse(&fr.encode()), Some(fr));
        assert_eq!(FaultReport::parse(&[1, 2]), None);
    }

    #[test]
    fn scenes_round_trip_and_are_bounded() {
        let obs: [SceneObstacle; 3] = core::array::from_fn(|i| SceneObstacle {
            centre_m: [1e-5 * i as f64, -2e-6],
            radius_m: 5e-6 + i as f64 * 1e-7,
        });
        let s = Scene::new(1.5e-6, &obs).unwrap();
        let mut b = [0u8; Scene::MAX_SIZE];
        let n = s.encode(&mut b).unwrap();
        assert_eq!(n, 9 + 3 * 24);
        let p = Scene::parse(&b[..n]).unwrap();
        assert_eq!(p.obstacles(), &obs);
        assert_eq!(p.bead_radius_m, 1.5e-6);
        assert_eq!(Scene::parse(&b[..n - 1]), None);
        assert!(s.encode(&mut b[..n - 1]).is_err());
        // An empty scene, and one over the bound.
        let e = Scene::new(1e-6, &[]).unwrap();
        let n = e.encode(&mut b).unwrap();
        assert_eq!(Scene::parse(&b[..n]).unwrap().obstacles(), &[]);
        let many = [SceneObstacle::default(); MAX_SCENE_OBSTACLES + 1];
        assert!(Scene::new(1e-6, &many).is_none());
        let full = Scene::new(1e-6, &many[..MAX_SCENE_OBSTACLES]).unwrap();
        assert_eq!(full.encode(&mut b), Ok(Scene::MAX_SIZE));
        b[8] = MAX_SCENE_OBSTACLES as u8 + 1;
        assert_eq!(Scene::parse(&b[..Scene::MAX_SIZE]), None);
    }

    /// Strings are bounded: 255 bytes at most, cut before a continuation
    /// byte (a 2-byte character straddling the limit is dropped whole).
    #[test]
    fn identity_strings_are_bounded_at_a_character_boundary() {
        let mut long = [b'a'; 300];
        long[254] = 0xC3; // "é" = C3 A9 at bytes 254..256
        long[255] = 0xA9;
        let h = Hello {
            name: &long,
            ..Hello::current(daq_caps(), 10_000, 100, 10)
        };
        let mut b = [0u8; Hello::MAX_SIZE];
        let n = h.encode(&mut b).unwrap();
        let p = Hello::parse(&b[..n]).unwrap();
        assert_eq!(p.name.len(), 254);
        assert!(n <= Hello::MAX_SIZE);
        assert!(h.encode(&mut b[..n - 1]).is_err());
    }
}
