//! The host's watchdog on *stream progress*: a device that keeps sending
//! valid frames that never advance the sample stream (only STATUS frames,
//! frames of unknown type, SAMPLES with stray sequence numbers) is as dead
//! as a silent one, and must not hold the host for ever.
//!
//! Two checks, both on samples rather than frames:
//!
//! * **progress** — inside one exchange, no sample owed by the block was
//!   accounted for (received, or declared lost by a STATUS frame) for
//!   [`super::SerialConfig::timeout`];
//! * **rate** — over every [`RATE_WINDOW`] spent waiting for the device,
//!   the samples *received* are at least [`MIN_RATE_FRACTION`] of what the
//!   device's rate (its HELLO) delivers in that time. Only time inside
//!   exchanges counts, so a host busy between blocks (a calibration
//!   computing) never trips it.
//!
//! Either failure ends the exchange with a [`Stall`] report of what the
//! device sent instead; the rig then commands the outputs to zero (STOP)
//! and reports itself disconnected (`docs/PROTOCOL.md`, "Host watchdog").
//! Nothing here allocates.

use std::time::Duration;

/// Time waited for the device over which the received rate is judged.
pub const RATE_WINDOW: Duration = Duration::from_millis(500);

/// Least fraction of the device's nominal rate that must be received over
/// a [`RATE_WINDOW`] (at 10 kHz: 500 of 5000 samples).
pub const MIN_RATE_FRACTION: f64 = 0.1;

/// What the device sent while the stream did not advance (counters since
/// the last progress, or over the rate window).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Activity {
    /// Valid frames of any type.
    pub frames: u64,
    /// STATUS frames.
    pub status: u64,
    /// FAULT frames (other than a watchdog trip, which ends the exchange).
    pub faults: u64,
    /// Frames of a type the host does not expect here.
    pub unknown: u64,
    /// Samples whose sequence numbers were already accounted for or lie
    /// beyond the block (stray sequence numbers).
    pub stray_samples: u64,
    /// Samples received and accounted for.
    pub new_samples: u64,
    /// Candidate frames that failed their CRC.
    pub crc_errors: u64,
}

impl std::fmt::Display for Activity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.frames == 0 && self.crc_errors == 0 {
            return f.write_str("nothing at all (stalled or unplugged)");
        }
        let mut parts: Vec<String> = Vec::new();
        for (n, what) in [
            (self.status, "STATUS frame(s) only"),
            (self.unknown, "frame(s) of unknown type"),
            (self.stray_samples, "sample(s) with stray sequence numbers"),
            (self.faults, "FAULT frame(s)"),
            (self.new_samples, "new sample(s)"),
            (self.crc_errors, "corrupted frame(s) (bad CRC)"),
        ] {
            if n > 0 {
                parts.push(format!("{n} {what}"));
            }
        }
        if parts.is_empty() {
            parts.push(format!(
                "{} frame(s) that carried no new sample",
                self.frames
            ));
        }
        // "STATUS frame(s) only" reads wrong next to other kinds.
        let text = parts.join(", ");
        if parts.len() > 1 {
            f.write_str(&text.replace(" only", ""))
        } else {
            f.write_str(&text)
        }
    }
}

impl Activity {
    /// What arrived after `earlier` (a snapshot of the same counters).
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            frames: self.frames - earlier.frames,
            status: self.status - earlier.status,
            faults: self.faults - earlier.faults,
            unknown: self.unknown - earlier.unknown,
            stray_samples: self.stray_samples - earlier.stray_samples,
            new_samples: self.new_samples - earlier.new_samples,
            crc_errors: self.crc_errors - earlier.crc_errors,
        }
    }
}

/// Why the stream was declared stalled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stall {
    /// No sample accounted for within the timeout.
    NoProgress {
        /// How long the host waited, ms.
        waited_ms: u64,
        /// The sample it waited for.
        expected_seq: u64,
        /// What the device sent meanwhile.
        activity: Activity,
    },
    /// Too few samples received over a rate window.
    TooSlow {
        /// Samples received in the window.
        received: u64,
        /// Least number required.
        required: u64,
        /// Time waited for the device in the window, ms.
        window_ms: u64,
        /// Nominal rate, Hz.
        rate_hz: u32,
        /// What the device sent in the window.
        activity: Activity,
    },
    /// The caller's hard time bound passed (`--duration`).
    Deadline {
        /// What the device sent since the last progress.
        activity: Activity,
    },
}

impl std::fmt::Display for Stall {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NoProgress {
                waited_ms,
                expected_seq,
                activity,
            } => write!(
                f,
                "the sample stream did not advance for {waited_ms} ms (waiting for sample \
                 {expected_seq}); meanwhile the device sent {activity}"
            ),
            Self::TooSlow {
                received,
                required,
                window_ms,
                rate_hz,
                activity,
            } => write!(
                f,
                "only {received} new sample(s) in {window_ms} ms of waiting, at least \
                 {required} required (the device's rate is {rate_hz} Hz); meanwhile it sent \
                 {activity}"
            ),
            Self::Deadline { activity } => write!(
                f,
                "the command's time bound passed while waiting for samples; since the last new \
                 sample the device sent {activity}"
            ),
        }
    }
}

/// The rate check's window (module docs): time waited and samples
/// received since it opened.
#[derive(Debug, Clone, Copy, Default)]
pub struct RateWindow {
    waited: Duration,
    activity: Activity,
}

impl RateWindow {
    /// Adds `waited` (time inside an exchange) and what arrived in it;
    /// when the window is full, judges it against `fraction` (normally
    /// [`MIN_RATE_FRACTION`]) of `rate_hz` and opens a new one.
    pub fn add(
        &mut self,
        waited: Duration,
        seen: &Activity,
        rate_hz: u32,
        fraction: f64,
    ) -> Result<(), Stall> {
        self.waited += waited;
        let a = &mut self.activity;
        a.frames += seen.frames;
        a.status += seen.status;
        a.faults += seen.faults;
        a.unknown += seen.unknown;
        a.stray_samples += seen.stray_samples;
        a.new_samples += seen.new_samples;
        a.crc_errors += seen.crc_errors;
        if self.waited < RATE_WINDOW {
            return Ok(());
        }
        let secs = self.waited.as_secs_f64();
        let required = (fraction.clamp(0.0, 1.0) * f64::from(rate_hz) * secs).floor();
        // `required` ≤ 0.1 · u32::MAX · (window + one exchange), far below 2^53.
        let required = required as u64;
        let window = *self;
        *self = Self::default();
        if window.activity.new_samples >= required {
            return Ok(());
        }
        Err(Stall::TooSlow {
            received: window.activity.new_samples,
            required,
            window_ms: u64::try_from(window.waited.as_millis()).unwrap_or(u64::MAX),
            rate_hz,
            activity: window.activity,
        })
    }

    /// Forgets the window (after a restart of the stream).
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_healthy_stream_passes_and_a_trickle_fails_the_rate_check() {
        let mut w = RateWindow::default();
        let ok = Activity {
            frames: 500,
            new_samples: 5000,
            ..Activity::default()
        };
        assert!(
            w.add(Duration::from_millis(500), &ok, 10_000, MIN_RATE_FRACTION)
                .is_ok()
        );
        let trickle = Activity {
            frames: 400,
            status: 390,
            new_samples: 10,
            ..Activity::default()
        };
        let e = w
            .add(
                Duration::from_millis(600),
                &trickle,
                10_000,
                MIN_RATE_FRACTION,
            )
            .unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains("only 10 new sample(s)") && text.contains("600"),
            "{text}"
        );
        assert!(text.contains("390 STATUS frame(s)"), "{text}");
    }

    #[test]
    fn the_activity_names_what_the_device_did() {
        let only_status = Activity {
            frames: 9,
            status: 9,
            ..Activity::default()
        };
        assert_eq!(only_status.to_string(), "9 STATUS frame(s) only");
        assert_eq!(
            Activity::default().to_string(),
            "nothing at all (stalled or unplugged)"
        );
        let stray = Activity {
            frames: 4,
            stray_samples: 40,
            ..Activity::default()
        };
        assert_eq!(
            stray.to_string(),
            "40 sample(s) with stray sequence numbers"
        );
    }
}
