//! Test frames (`docs/PROTOCOL.md` §13): [`crate::ty::TEST`] from the host,
//! [`crate::ty::TEST_ACK`] back. They configure what a test needs inside a
//! device — the plant model of the firmware's QEMU build, the late-command
//! policy, a simulated emergency stop, fault injection, the interrupt's
//! cost counters — and are refused (FAULT BAD_FRAME) by production builds.
//!
//! TEST payload: `u8 op` and the op's arguments (little-endian). TEST_ACK
//! payload: `u8 op`, `u8 result` ([`result`]), `u32 value` (op-specific),
//! then op-specific data.

use crate::frame::rd;

/// Operations of a TEST frame.
pub mod op {
    /// Remove every plant section; the plant outputs zero. No arguments.
    pub const PLANT_CLEAR: u8 = 0x01;
    /// Add a second-order section to a channel: `u8 input`, `u8 output`,
    /// then b0, b1, b2, a1, a2 as `f64` ([`Section`]).
    pub const PLANT_SECTION: u8 = 0x02;
    /// Sensors and output scales of the plant ([`PlantSensors`]).
    pub const PLANT_SENSORS: u8 = 0x03;
    /// Check the loaded plant and reset its state; the ack's value is the
    /// number of sections.
    pub const PLANT_COMMIT: u8 = 0x04;
    /// Late-command policy: `u8` 0 = wait for the command (emulator
    /// semantics, the default of the QEMU build), 1 = hold the previous
    /// command and flag CMD_LATE (a free-running device).
    pub const MODE: u8 = 0x05;
    /// Emergency-stop input: `u8` 1 = engaged, 0 = released.
    pub const ESTOP: u8 = 0x06;
    /// Fault injection on the device → host bytes: `u32` corruption and
    /// `u32` drop probability in parts per million, `u32` seed.
    pub const FAULTS: u8 = 0x07;
    /// Cost counters of the sample interrupt; the ack's data are
    /// [`Profile`]. `u8` 1 resets them after reading.
    pub const PROFILE: u8 = 0x08;
    /// The outputs applied now; the ack's data are one
    /// [`crate::DaqCommand`] (6 bytes). No arguments.
    pub const OUTPUTS: u8 = 0x09;
}

/// Results in a TEST_ACK.
pub mod result {
    /// Done.
    pub const OK: u8 = 0;
    /// Malformed arguments (length, index, non-finite number).
    pub const BAD_ARGUMENT: u8 = 1;
    /// No room for another plant section.
    pub const FULL: u8 = 2;
    /// Not while running (plant changes need an idle device).
    pub const BUSY: u8 = 3;
    /// The plant is unstable (a section with a pole on or outside the unit circle).
    pub const UNSTABLE: u8 = 4;
    /// This build does not implement the operation.
    pub const UNSUPPORTED: u8 = 5;
}

/// Plant inputs, in the order of [`Section::input`].
pub mod input {
    /// Pantograph force x, N.
    pub const FORCE_X: u8 = 0;
    /// Pantograph force y, N.
    pub const FORCE_Y: u8 = 1;
    /// Haptuator drive, V.
    pub const DRIVE: u8 = 2;
    /// Number of inputs.
    pub const COUNT: usize = 3;
}

/// Plant outputs, in the order of [`Section::output`].
pub mod output {
    /// Tip acceleration x (before the accelerometer), m/s².
    pub const ACCEL_X: u8 = 0;
    /// Tip acceleration y, m/s².
    pub const ACCEL_Y: u8 = 1;
    /// Handle (encoder) position x, m.
    pub const HANDLE_X: u8 = 2;
    /// Handle position y, m.
    pub const HANDLE_Y: u8 = 3;
    /// Number of outputs.
    pub const COUNT: usize = 4;
}

/// One second-order section of a plant channel, transposed direct form II:
/// H(z) = (b0 + b1 z⁻¹ + b2 z⁻²)/(1 + a1 z⁻¹ + a2 z⁻²). A channel's output
/// is the sum of its sections (parallel form).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Section {
    /// Input ([`input`]).
    pub input: u8,
    /// Output ([`output`]).
    pub output: u8,
    /// Numerator b0, b1, b2.
    pub b: [f64; 3],
    /// Denominator a1, a2 (a0 = 1).
    pub a: [f64; 2],
}

impl Section {
    /// Argument size, bytes.
    pub const SIZE: usize = 2 + 5 * 8;

    /// The arguments of [`op::PLANT_SECTION`].
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut o = [0u8; Self::SIZE];
        o[0] = self.input;
        o[1] = self.output;
        for (i, v) in self.b.iter().chain(&self.a).enumerate() {
            o[2 + 8 * i..10 + 8 * i].copy_from_slice(&v.to_le_bytes());
        }
        o
    }

    /// Parse the arguments (exact size, known input and output, finite).
    pub fn parse(p: &[u8]) -> Option<Self> {
        if p.len() != Self::SIZE
            || usize::from(p[0]) >= input::COUNT
            || usize::from(p[1]) >= output::COUNT
        {
            return None;
        }
        let f = |i: usize| f64::from_le_bytes(rd(p, 2 + 8 * i));
        let s = Self {
            input: p[0],
            output: p[1],
            b: [f(0), f(1), f(2)],
            a: [f(3), f(4)],
        };
        s.b.iter().chain(&s.a).all(|v| v.is_finite()).then_some(s)
    }
}

/// The plant's sensors and output scales ([`op::PLANT_SENSORS`]): what the
/// device announces in HELLO and how it turns plant outputs into codes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantSensors {
    /// Accelerometer pole per axis (x, y, z): s ← α s + (1 − α)(a + offset).
    pub accel_alpha: [f64; 3],
    /// Static acceleration per axis (gravity), m/s².
    pub accel_offset_m_s2: [f64; 3],
    /// Accelerometer full scale, ±m/s² (clipped there, flag CLIPPED).
    pub accel_range_m_s2: f64,
    /// Accelerometer code step, m/s² per code.
    pub accel_m_s2_per_code: f64,
    /// Encoder counts per metre of handle travel.
    pub encoder_counts_per_m: f64,
    /// Pantograph force at code 32767, N.
    pub force_max_n: f64,
    /// Haptuator drive at code 32767, V.
    pub drive_max_v: f64,
}

impl PlantSensors {
    /// Argument size, bytes.
    pub const SIZE: usize = 11 * 8;

    fn values(&self) -> [f64; 11] {
        let (a, o) = (self.accel_alpha, self.accel_offset_m_s2);
        [
            a[0],
            a[1],
            a[2],
            o[0],
            o[1],
            o[2],
            self.accel_range_m_s2,
            self.accel_m_s2_per_code,
            self.encoder_counts_per_m,
            self.force_max_n,
            self.drive_max_v,
        ]
    }

    /// The arguments of [`op::PLANT_SENSORS`].
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut o = [0u8; Self::SIZE];
        for (i, v) in self.values().iter().enumerate() {
            o[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
        }
        o
    }

    /// Parse the arguments: exact size, α in [0, 1), finite offsets, the
    /// scales finite and > 0, the range within 32767 codes.
    pub fn parse(p: &[u8]) -> Option<Self> {
        if p.len() != Self::SIZE {
            return None;
        }
        let f = |i: usize| f64::from_le_bytes(rd(p, 8 * i));
        let s = Self {
            accel_alpha: [f(0), f(1), f(2)],
            accel_offset_m_s2: [f(3), f(4), f(5)],
            accel_range_m_s2: f(6),
            accel_m_s2_per_code: f(7),
            encoder_counts_per_m: f(8),
            force_max_n: f(9),
            drive_max_v: f(10),
        };
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let ok = s.accel_alpha.iter().all(|a| (0.0..1.0).contains(a))
            && s.accel_offset_m_s2.iter().all(|v| v.is_finite())
            && pos(s.accel_range_m_s2)
            && pos(s.accel_m_s2_per_code)
            && s.accel_range_m_s2 / s.accel_m_s2_per_code <= 32767.0
            && pos(s.encoder_counts_per_m)
            && pos(s.force_max_n)
            && pos(s.drive_max_v);
        ok.then_some(s)
    }
}

/// Cost counters of the sample interrupt (the ack data of [`op::PROFILE`]):
/// counts of the device's cycle counter — CPU cycles on a board (DWT
/// CYCCNT), executed instructions under QEMU with `-icount shift=0`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Profile {
    /// Interrupts measured.
    pub ticks: u32,
    /// Largest count of one interrupt (whole sample period's work).
    pub max: u32,
    /// Sum over the interrupts (mean = sum / ticks).
    pub sum: u64,
    /// Largest count of the plant model alone (QEMU build; 0 otherwise).
    pub plant_max: u32,
    /// Sum of the plant model's counts.
    pub plant_sum: u64,
    /// Frames the device dropped whole because its transmit queue was
    /// full (not counts: frames).
    pub tx_dropped: u32,
}

impl Profile {
    /// Size, bytes.
    pub const SIZE: usize = 4 + 4 + 8 + 4 + 8 + 4;

    /// Encoding.
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut o = [0u8; Self::SIZE];
        o[..4].copy_from_slice(&self.ticks.to_le_bytes());
        o[4..8].copy_from_slice(&self.max.to_le_bytes());
        o[8..16].copy_from_slice(&self.sum.to_le_bytes());
        o[16..20].copy_from_slice(&self.plant_max.to_le_bytes());
        o[20..28].copy_from_slice(&self.plant_sum.to_le_bytes());
        o[28..32].copy_from_slice(&self.tx_dropped.to_le_bytes());
        o
    }

    /// Parse (exact size).
    pub fn parse(p: &[u8]) -> Option<Self> {
        (p.len() == Self::SIZE).then(|| Self {
            ticks: u32::from_le_bytes(rd(p, 0)),
            max: u32::from_le_bytes(rd(p, 4)),
            sum: u64::from_le_bytes(rd(p, 8)),
            plant_max: u32::from_le_bytes(rd(p, 16)),
            plant_sum: u64::from_le_bytes(rd(p, 20)),
            tx_dropped: u32::from_le_bytes(rd(p, 28)),
        })
    }
}

/// A TEST_ACK payload's fixed part.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ack {
    /// The operation answered.
    pub op: u8,
    /// [`result`].
    pub result: u8,
    /// Op-specific value.
    pub value: u32,
}

impl Ack {
    /// Size of the fixed part, bytes.
    pub const SIZE: usize = 6;

    /// Encoding of the fixed part.
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut o = [0u8; Self::SIZE];
        o[0] = self.op;
        o[1] = self.result;
        o[2..].copy_from_slice(&self.value.to_le_bytes());
        o
    }

    /// Parse the fixed part; the rest of the payload is the op's data.
    pub fn parse(p: &[u8]) -> Option<(Self, &[u8])> {
        (p.len() >= Self::SIZE).then(|| {
            (
                Self {
                    op: p[0],
                    result: p[1],
                    value: u32::from_le_bytes(rd(p, 2)),
                },
                &p[Self::SIZE..],
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn test_payloads_round_trip_and_refuse_nonsense() {
        let s = Section {
            input: input::DRIVE,
            output: output::HANDLE_X,
            b: [0.0, 1e-9, -2e-9],
            a: [-1.9, 0.91],
        };
        assert_eq!(Section::parse(&s.encode()), Some(s));
        let mut bad = s.encode();
        bad[1] = 4;
        assert_eq!(Section::parse(&bad), None);
        let mut nan = s.encode();
        nan[2..10].copy_from_slice(&f64::NAN.to_le_bytes());
        assert_eq!(Section::parse(&nan), None);
        let p = PlantSensors {
            accel_alpha: [0.8, 0.8, 0.83],
            accel_offset_m_s2: [0.0, 0.0, 9.81],
            accel_range_m_s2: 58.8,
            accel_m_s2_per_code: 1.4528e-2,
            encoder_counts_per_m: 1e7,
            force_max_n: 5.0,
            drive_max_v: 10.0,
        };
        assert_eq!(PlantSensors::parse(&p.encode()), Some(p));
        let wide = PlantSensors {
            accel_m_s2_per_code: 1e-4,
            ..p
        };
        assert_eq!(PlantSensors::parse(&wide.encode()), None);
        let pr = Profile {
            ticks: 3,
            max: 900,
            sum: 2000,
            plant_max: 700,
            plant_sum: 1500,
            tx_dropped: 2,
        };
        assert_eq!(Profile::parse(&pr.encode()), Some(pr));
        let a = Ack {
            op: op::PROFILE,
            result: result::OK,
            value: 7,
        };
        let mut b = [0u8; Ack::SIZE + 2];
        b[..Ack::SIZE].copy_from_slice(&a.encode());
        assert_eq!(Ack::parse(&b), Some((a, &[0u8, 0][..])));
        assert_eq!(Ack::parse(&b[..5]), None);
    }
}
