//! Faults a rig reports, the fixed-capacity queue that holds them, and the
//! counters behind `Rig::status` shared by every backend.

use super::frame::FrameFlags;
use super::identity::{RigState, RigStatus};
use serde::{Deserialize, Serialize};

/// A fault or notable event reported by a rig.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum RigFault {
    /// Frames missing from the device stream.
    LostFrames {
        /// First missing sequence number.
        first_seq: u64,
        /// How many.
        count: u32,
    },
    /// Wall-clock stall beyond the tolerated lag; samples skipped.
    Overrun {
        /// Sequence number at which the stall was detected.
        seq: u64,
        /// Samples skipped.
        skipped: u64,
    },
    /// A non-finite command was replaced by zero.
    NonFiniteCommand {
        /// Sequence number.
        seq: u64,
    },
    /// A command exceeded an actuator limit and was clamped.
    ActuatorLimited {
        /// Sequence number.
        seq: u64,
    },
    /// The accelerometer clipped.
    SensorClipped {
        /// Sequence number.
        seq: u64,
    },
    /// The Haptuator magnet hit an end stop.
    EndStop {
        /// Sequence number.
        seq: u64,
    },
    /// The device watchdog zeroed the outputs.
    WatchdogTripped {
        /// Sequence number.
        seq: u64,
    },
    /// The device disconnected.
    Disconnected,
}

/// Fixed-capacity FIFO of faults (no allocation after creation; the oldest
/// entry is dropped when full).
#[derive(Debug, Clone)]
pub struct FaultQueue {
    buf: [Option<RigFault>; Self::CAPACITY],
    head: usize,
    len: usize,
    dropped: u64,
}

impl Default for FaultQueue {
    fn default() -> Self {
        Self {
            buf: [None; Self::CAPACITY],
            head: 0,
            len: 0,
            dropped: 0,
        }
    }
}

impl FaultQueue {
    /// Capacity.
    pub const CAPACITY: usize = 64;

    /// Append (dropping the oldest when full).
    pub fn push(&mut self, f: RigFault) {
        if self.len == Self::CAPACITY {
            self.head = (self.head + 1) % Self::CAPACITY;
            self.len -= 1;
            self.dropped += 1;
        }
        let tail = (self.head + self.len) % Self::CAPACITY;
        self.buf[tail] = Some(f);
        self.len += 1;
    }

    /// Remove the oldest.
    pub fn pop(&mut self) -> Option<RigFault> {
        if self.len == 0 {
            return None;
        }
        let f = self.buf[self.head].take();
        self.head = (self.head + 1) % Self::CAPACITY;
        self.len -= 1;
        f
    }

    /// Entries waiting.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Entries dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// The counters and the fault queue behind [`Rig::status`] and
/// [`Rig::pop_fault`], shared by the simulated and the live rigs. Fixed
/// size: nothing here allocates, locks or panics.
#[derive(Debug, Clone)]
pub(crate) struct StatusCounters {
    /// Counters (frame counts in frames, samples in samples); `state` and
    /// the `faults_*` fields are filled in by [`Self::status`].
    pub(crate) counts: RigStatus,
    /// Faults waiting for [`Rig::pop_fault`].
    pub(crate) faults: FaultQueue,
}

impl Default for StatusCounters {
    fn default() -> Self {
        Self {
            counts: RigStatus {
                state: RigState::Idle,
                frames: 0,
                lost_frames: 0,
                skipped_samples: 0,
                clipped_frames: 0,
                limited_frames: 0,
                end_stop_frames: 0,
                nonfinite_commands: 0,
                faults_pending: 0,
                faults_dropped: 0,
                late_commands: 0,
            },
            faults: FaultQueue::default(),
        }
    }
}

impl StatusCounters {
    /// The counters with the rig's `state` and the queue's occupancy.
    pub(crate) fn status(&self, state: RigState) -> RigStatus {
        RigStatus {
            state,
            faults_pending: self.faults.len(),
            faults_dropped: self.faults.dropped(),
            ..self.counts
        }
    }

    /// Queue a fault (the oldest is dropped when the queue is full).
    #[inline]
    pub(crate) fn push(&mut self, f: RigFault) {
        self.faults.push(f);
    }

    /// Oldest queued fault, if any.
    pub(crate) fn pop_fault(&mut self) -> Option<RigFault> {
        self.faults.pop()
    }

    /// Count the command and sensor flags of frame `seq` (non-finite
    /// command, limited, clipped, end stop) and queue each kind of fault
    /// once per block: `noted` collects the [`FrameFlags`] bits already
    /// queued in this block (start each block at 0).
    #[inline]
    pub(crate) fn note_flags(&mut self, ff: FrameFlags, seq: u64, noted: &mut u8) {
        const COUNTED: u8 = FrameFlags::NONFINITE_COMMAND
            | FrameFlags::LIMITED
            | FrameFlags::CLIPPED
            | FrameFlags::END_STOP;
        if ff.0 & COUNTED == 0 {
            return;
        }
        let kinds = [
            (
                FrameFlags::NONFINITE_COMMAND,
                RigFault::NonFiniteCommand { seq },
            ),
            (FrameFlags::LIMITED, RigFault::ActuatorLimited { seq }),
            (FrameFlags::CLIPPED, RigFault::SensorClipped { seq }),
            (FrameFlags::END_STOP, RigFault::EndStop { seq }),
        ];
        for (bit, fault) in kinds {
            if ff.has(bit) {
                let c = &mut self.counts;
                match bit {
                    FrameFlags::NONFINITE_COMMAND => c.nonfinite_commands += 1,
                    FrameFlags::LIMITED => c.limited_frames += 1,
                    FrameFlags::CLIPPED => c.clipped_frames += 1,
                    _ => c.end_stop_frames += 1,
                }
                if *noted & bit == 0 {
                    self.faults.push(fault);
                    *noted |= bit;
                }
            }
        }
    }
}
