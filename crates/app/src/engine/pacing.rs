//! Wall-clock pacing of the engine's blocks and the deadline-miss count.
//!
//! Block k after the anchor (t_a) covers the samples
//! [kN, (k+1)N) and is *due* at its deadline D_k = t_a + (k+1)·N/f_s, the
//! wall time at which its last sample is played. The engine computes a block,
//! then sleeps until its deadline; deadlines come from the anchor and the
//! block count, never from accumulated sleeps, so a late wake-up is caught
//! up by the following blocks (they run without sleeping).
//!
//! **Deadline miss** (precise definition): a block whose computation ended
//! at t_end > D_k + L_tol, with L_tol the *tolerated latency* (the output
//! buffer a live rig keeps ahead of the device; default 2 ms = two blocks).
//! The lateness t_end − D_k of every block is tracked (worst value per
//! health window and overall).
//!
//! **Stall**: a lateness beyond `max_lag_s` is not caught up: the pacer
//! re-anchors at the present (the simulated time then lags the wall clock by
//! the stall) and counts an *overrun*.
//!
//! **Device-paced** ([`Pacer::set_device_paced`], live rigs): the rig
//! blocks in `process_block` until the device has played the block, so the
//! pacer never sleeps; deadlines, misses and stalls are measured as above
//! (the device's clock and the host's run at the same nominal rate).
//!
//! **Load** = busy time / wall time over a health window, busy time being
//! the time from the start of a block's computation to its end (sleep
//! excluded).

use kilotouch_rig::device::Clock;
use std::time::Duration;

/// Timing of one block.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BlockTiming {
    /// t_end − deadline, s (negative = early).
    pub lateness_s: f64,
    /// The block missed its deadline (module docs).
    pub missed: bool,
    /// The pacer re-anchored after a stall.
    pub overrun: bool,
    /// Busy time of the block, s.
    pub busy_s: f64,
}

/// Deadline bookkeeping (module docs).
#[derive(Debug)]
pub struct Pacer<C: Clock> {
    clock: C,
    period_s: f64,
    tolerance_s: f64,
    max_lag_s: f64,
    paced: bool,
    sleeps: bool,
    anchor: Duration,
    blocks: u64,
    block_start: Duration,
    /// Blocks that missed their deadline since creation.
    pub misses: u64,
    /// Re-anchors after stalls since creation.
    pub overruns: u64,
    /// Worst lateness since creation, s.
    pub worst_lateness_s: f64,
}

impl<C: Clock> Pacer<C> {
    /// Pacer for blocks of `period_s` seconds; `paced = false` never sleeps
    /// (batch runs) but still measures.
    pub fn new(clock: C, period_s: f64, tolerance_s: f64, max_lag_s: f64, paced: bool) -> Self {
        let now = clock.now();
        Self {
            clock,
            period_s,
            tolerance_s,
            max_lag_s,
            paced,
            sleeps: paced,
            anchor: now,
            blocks: 0,
            block_start: now,
            misses: 0,
            overruns: 0,
            worst_lateness_s: f64::NEG_INFINITY,
        }
    }

    /// The clock.
    pub fn clock(&self) -> &C {
        &self.clock
    }

    /// Block period, s.
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Tolerated latency, s.
    pub fn tolerance_s(&self) -> f64 {
        self.tolerance_s
    }

    /// Device-paced from now on (module docs): measure as a paced pacer
    /// but never sleep.
    pub fn set_device_paced(&mut self) {
        self.paced = true;
        self.sleeps = false;
    }

    /// Sleep to the deadlines (`true`, when not device-paced) or run as
    /// fast as possible (`false`); the schedule restarts at the present.
    pub fn set_paced(&mut self, on: bool) {
        let device_paced = self.paced && !self.sleeps;
        if !device_paced {
            self.paced = on;
            self.sleeps = on;
        }
        self.reanchor();
    }

    /// Does the pacer sleep to the deadlines?
    pub fn sleeps(&self) -> bool {
        self.sleeps
    }

    /// Restart the schedule at the present (after a pause).
    pub fn reanchor(&mut self) {
        self.anchor = self.clock.now();
        self.blocks = 0;
    }

    /// Deadline of the current block.
    fn deadline(&self) -> Duration {
        self.anchor + Duration::from_secs_f64((self.blocks + 1) as f64 * self.period_s)
    }

    /// Mark the start of a block's computation.
    pub fn begin_block(&mut self) {
        self.block_start = self.clock.now();
    }

    /// Mark the end of a block's computation: measure, then (paced) sleep
    /// until its deadline.
    pub fn end_block(&mut self) -> BlockTiming {
        let now = self.clock.now();
        let busy_s = now.saturating_sub(self.block_start).as_secs_f64();
        let deadline = self.deadline();
        let lateness_s = if now >= deadline {
            (now - deadline).as_secs_f64()
        } else {
            -(deadline - now).as_secs_f64()
        };
        let missed = self.paced && lateness_s > self.tolerance_s;
        if missed {
            self.misses += 1;
        }
        if self.paced {
            self.worst_lateness_s = self.worst_lateness_s.max(lateness_s);
        }
        let mut overrun = false;
        if self.paced && lateness_s > self.max_lag_s {
            self.overruns += 1;
            overrun = true;
            self.anchor = now;
            self.blocks = 0;
        } else {
            self.blocks += 1;
            if self.sleeps && lateness_s < 0.0 {
                self.clock.sleep_until(deadline);
            }
        }
        BlockTiming {
            lateness_s,
            missed,
            overrun,
            busy_s,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kilotouch_rig::device::ManualClock;

    #[test]
    fn deadlines_come_from_the_anchor_and_stalls_are_caught_up() {
        let clock = ManualClock::default();
        let mut p = Pacer::new(clock.clone(), 1e-3, 2e-3, 50e-3, true);
        // On time: the pacer sleeps to each deadline (the manual clock jumps).
        for k in 1..=5u64 {
            p.begin_block();
            clock.advance(Duration::from_micros(100));
            let t = p.end_block();
            assert!(!t.missed);
            assert!((t.lateness_s + 0.9e-3).abs() < 1e-9, "{t:?}");
            assert!((t.busy_s - 1e-4).abs() < 1e-9);
            assert_eq!(clock.now(), Duration::from_millis(k));
        }
        // A 2.5 ms stall in block 6 (deadline 6 ms): late by 1.6 ms < 2 ms → no miss,
        let t0 = clock.now();
        p.begin_block();
        clock.advance(Duration::from_micros(2600));
        let t = p.end_block();
        assert!(!t.missed && (t.lateness_s - 1.6e-3).abs() < 1e-9, "{t:?}");
        // and the next blocks run without sleeping until caught up (deadline 7 ms).
        p.begin_block();
        clock.advance(Duration::from_micros(100));
        let t = p.end_block();
        assert!((t.lateness_s - 0.7e-3).abs() < 1e-9, "{t:?}");
        assert_eq!(clock.now(), t0 + Duration::from_micros(2700), "no sleep");
        p.begin_block();
        let t = p.end_block();
        assert!(t.lateness_s < 0.0, "caught up: {t:?}");
        assert_eq!(clock.now(), Duration::from_millis(8));
        // Beyond the tolerance: a miss; beyond max lag: an overrun and a re-anchor.
        p.begin_block();
        clock.advance(Duration::from_micros(4000));
        let t = p.end_block();
        assert!(t.missed && !t.overrun, "{t:?}");
        p.begin_block();
        clock.advance(Duration::from_millis(100));
        let t = p.end_block();
        assert!(t.missed && t.overrun, "{t:?}");
        assert_eq!((p.misses, p.overruns), (2, 1));
        let t_re = clock.now();
        p.begin_block();
        let t = p.end_block();
        assert!(!t.missed && t.lateness_s < 0.0);
        assert_eq!(clock.now(), t_re + Duration::from_millis(1));
    }

    #[test]
    fn device_paced_measures_like_paced_but_never_sleeps() {
        let clock = ManualClock::default();
        let mut p = Pacer::new(clock.clone(), 1e-3, 2e-3, 50e-3, true);
        p.set_device_paced();
        assert!(!p.sleeps());
        // Early block (the device returned before the deadline): no sleep.
        p.begin_block();
        clock.advance(Duration::from_micros(300));
        let t = p.end_block();
        assert!((t.lateness_s + 0.7e-3).abs() < 1e-9 && !t.missed, "{t:?}");
        assert_eq!(clock.sleeps(), 0);
        assert_eq!(clock.now(), Duration::from_micros(300));
        // The device stalled 5 ms: deadline 2 ms, late by 3.3 ms > 2 ms → a miss.
        p.begin_block();
        clock.advance(Duration::from_millis(5));
        let t = p.end_block();
        assert!(t.missed && !t.overrun, "{t:?}");
        assert!((p.worst_lateness_s - 3.3e-3).abs() < 1e-9);
        assert_eq!((p.misses, clock.sleeps()), (1, 0));
    }

    #[test]
    fn batch_never_sleeps_nor_misses() {
        let clock = ManualClock::default();
        let mut p = Pacer::new(clock.clone(), 1e-3, 2e-3, 50e-3, false);
        for _ in 0..10 {
            p.begin_block();
            clock.advance(Duration::from_millis(7));
            assert!(!p.end_block().missed);
        }
        assert_eq!(clock.sleeps(), 0);
        assert_eq!(p.misses, 0);
    }
}
