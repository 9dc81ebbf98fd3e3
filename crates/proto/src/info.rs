//! Host information frames ([`crate::ty::INFO`], host → device): what the
//! host tells a device about the experiment it is part of — the trial that
//! begins, its end, and what the participant's screen shows. They are
//! optional: a device without a participant at its handle (a DAQ) ignores
//! them, without a FAULT. A device hosting a simulated participant (the
//! emulator's hardware-in-the-loop mode) needs them to act as a person in
//! front of the screen would (`docs/PROTOCOL.md` §5.5).
//!
//! Payload: `u8` kind, then the kind's fields, little-endian.

use crate::frame::{WireError, rd};

/// Kinds of information frame.
pub mod kind {
    /// A trial begins ([`super::TrialBegin`]).
    pub const TRIAL_BEGIN: u8 = 1;
    /// The trial ended (no fields).
    pub const TRIAL_END: u8 = 2;
    /// The participant's screen shows a camera frame ([`super::View`]).
    pub const VIEW: u8 = 3;
}

/// A trial begins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrialBegin {
    /// 0-based participant index.
    pub participant: u32,
    /// Condition code: 0 V, 1 P, 2 D.
    pub condition: u8,
    /// 0 practice, 1 test.
    pub phase: u8,
    /// 1-based trial number within (participant, condition, phase), as in
    /// `trials.csv`.
    pub index: u32,
    /// Task: 0 circling, 1 blind navigation.
    pub task: u8,
    /// Hand → trap mapping: position scale s (m/m), handle origin x y (m),
    /// trap offset x y (m), trap workspace min x y and max x y (m), force
    /// scale g (N/N).
    pub mapping: [f64; 10],
    /// Trap position at the start, m.
    pub start_trap_m: [f64; 2],
    /// Instructed initial direction (unit vector).
    pub heading: [f64; 2],
    /// Retreat distance (blind task), m.
    pub retreat_m: f64,
    /// Low 32 bits of the sequence number of the trial's first sample.
    pub first_seq: u32,
}

impl TrialBegin {
    /// Payload size, bytes (kind byte included).
    pub const SIZE: usize = 1 + 4 + 1 + 1 + 4 + 1 + 8 * 10 + 8 * 2 + 8 * 2 + 8 + 4;
}

/// The participant's screen shows this camera frame (sample plane, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Frame number within the trial (low 32 bits).
    pub seq: u32,
    /// Capture time, s since the trial start.
    pub captured_s: f64,
    /// Manipulated bead centre, m.
    pub bead_m: [f64; 2],
    /// Trap centre, m.
    pub trap_m: [f64; 2],
    /// Obstacle centre, m.
    pub obstacle_m: [f64; 2],
    /// Obstacle radius, m.
    pub obstacle_radius_m: f64,
    /// Bead radius, m.
    pub bead_radius_m: f64,
}

impl View {
    /// Payload size, bytes (kind byte included).
    pub const SIZE: usize = 1 + 4 + 8 + 8 * 6 + 8 + 8;
}

/// An information frame's payload.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Info {
    /// A trial begins.
    TrialBegin(TrialBegin),
    /// The trial ended.
    TrialEnd,
    /// The screen shows a camera frame.
    View(View),
}

/// Writes little-endian values into a slice, refusing what does not fit.
struct Put<'a> {
    out: &'a mut [u8],
    at: usize,
}

impl Put<'_> {
    fn bytes(&mut self, b: &[u8]) -> Result<(), WireError> {
        let end = self.at + b.len();
        let Some(dst) = self.out.get_mut(self.at..end) else {
            return Err(WireError::BufferTooSmall(end));
        };
        dst.copy_from_slice(b);
        self.at = end;
        Ok(())
    }
    fn f64s(&mut self, v: &[f64]) -> Result<(), WireError> {
        v.iter().try_for_each(|x| self.bytes(&x.to_le_bytes()))
    }
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(rd::<8>(b, at))
}

fn f64s_at<const N: usize>(b: &[u8], at: usize) -> [f64; N] {
    core::array::from_fn(|i| f64_at(b, at + 8 * i))
}

impl Info {
    /// The largest payload, bytes.
    pub const MAX_SIZE: usize = TrialBegin::SIZE;

    /// Payload size of this frame, bytes.
    pub fn size(&self) -> usize {
        match self {
            Info::TrialBegin(_) => TrialBegin::SIZE,
            Info::TrialEnd => 1,
            Info::View(_) => View::SIZE,
        }
    }

    /// Encode the payload at the start of `out`; returns its length.
    ///
    /// # Errors
    /// [`WireError::BufferTooSmall`] when `out` is too short.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, WireError> {
        let mut p = Put { out, at: 0 };
        match self {
            Info::TrialBegin(t) => {
                p.bytes(&[kind::TRIAL_BEGIN])?;
                p.bytes(&t.participant.to_le_bytes())?;
                p.bytes(&[t.condition, t.phase])?;
                p.bytes(&t.index.to_le_bytes())?;
                p.bytes(&[t.task])?;
                p.f64s(&t.mapping)?;
                p.f64s(&t.start_trap_m)?;
                p.f64s(&t.heading)?;
                p.f64s(&[t.retreat_m])?;
                p.bytes(&t.first_seq.to_le_bytes())?;
            }
            Info::TrialEnd => p.bytes(&[kind::TRIAL_END])?,
            Info::View(v) => {
                p.bytes(&[kind::VIEW])?;
                p.bytes(&v.seq.to_le_bytes())?;
                p.f64s(&[v.captured_s])?;
                p.f64s(&v.bead_m)?;
                p.f64s(&v.trap_m)?;
                p.f64s(&v.obstacle_m)?;
                p.f64s(&[v.obstacle_radius_m, v.bead_radius_m])?;
            }
        }
        Ok(p.at)
    }

    /// Parse a payload (`None`: unknown kind or wrong length).
    pub fn parse(payload: &[u8]) -> Option<Self> {
        let (&k, _) = payload.split_first()?;
        match (k, payload.len()) {
            (kind::TRIAL_BEGIN, TrialBegin::SIZE) => {
                let b = payload;
                Some(Info::TrialBegin(TrialBegin {
                    participant: u32::from_le_bytes(rd::<4>(b, 1)),
                    condition: b[5],
                    phase: b[6],
                    index: u32::from_le_bytes(rd::<4>(b, 7)),
                    task: b[11],
                    mapping: f64s_at::<10>(b, 12),
                    start_trap_m: f64s_at::<2>(b, 92),
                    heading: f64s_at::<2>(b, 108),
                    retreat_m: f64_at(b, 124),
                    first_seq: u32::from_le_bytes(rd::<4>(b, 132)),
                }))
            }
            (kind::TRIAL_END, 1) => Some(Info::TrialEnd),
            (kind::VIEW, View::SIZE) => {
                let b = payload;
                Some(Info::View(View {
                    seq: u32::from_le_bytes(rd::<4>(b, 1)),
                    captured_s: f64_at(b, 5),
                    bead_m: f64s_at::<2>(b, 13),
                    trap_m: f64s_at::<2>(b, 29),
                    obstacle_m: f64s_at::<2>(b, 45),
                    obstacle_radius_m: f64_at(b, 61),
                    bead_radius_m: f64_at(b, 69),
                }))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_round_trips_at_its_size() {
        let t = Info::TrialBegin(TrialBegin {
            participant: 7,
            condition: 2,
            phase: 1,
            index: 9,
            task: 0,
            mapping: [1e-3, 0.1, -0.2, 1e-6, 2e-6, -5e-5, -5e-5, 5e-5, 5e-5, 1e11],
            start_trap_m: [1e-6, -2e-6],
            heading: [0.6, 0.8],
            retreat_m: 3e-6,
            first_seq: 0xDEAD_BEEF,
        });
        let v = Info::View(View {
            seq: 42,
            captured_s: 1.25,
            bead_m: [1.0, 2.0],
            trap_m: [3.0, 4.0],
            obstacle_m: [5.0, 6.0],
            obstacle_radius_m: 7.0,
            bead_radius_m: 8.0,
        });
        for info in [t, Info::TrialEnd, v] {
            let mut buf = [0u8; Info::MAX_SIZE];
            let n = info.encode(&mut buf).unwrap_or(0);
            assert_eq!(n, info.size());
            assert_eq!(Info::parse(&buf[..n]), Some(info));
            // One byte short or long: refused, never misread.
            assert_eq!(Info::parse(&buf[..n - 1]), None);
            assert!(info.encode(&mut buf[..n - 1]).is_err());
        }
        assert_eq!(Info::parse(&[]), None);
        assert_eq!(Info::parse(&[9]), None);
    }
}
