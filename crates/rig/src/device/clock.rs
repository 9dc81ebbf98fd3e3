//! Time sources of paced rigs: the system clock and a clock advanced by hand
//! (tests).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Time source for paced rigs.
pub trait Clock: Send {
    /// Time since an arbitrary fixed origin.
    fn now(&self) -> Duration;
    /// Block until `now() ≥ t` (returns at once if already past).
    fn sleep_until(&self, t: Duration);
}

/// The monotonic system clock.
#[derive(Debug, Clone)]
pub struct SystemClock {
    origin: Instant,
}

impl Default for SystemClock {
    fn default() -> Self {
        Self {
            origin: Instant::now(),
        }
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }
    fn sleep_until(&self, t: Duration) {
        let now = self.now();
        if t > now {
            std::thread::sleep(t - now);
        }
    }
}

/// A clock advanced by hand (tests): `sleep_until` jumps forward; another
/// handle can advance time to simulate a stall.
#[derive(Debug, Clone, Default)]
pub struct ManualClock {
    nanos: Arc<AtomicU64>,
    sleeps: Arc<AtomicU64>,
}

impl ManualClock {
    /// Advance by `d`.
    pub fn advance(&self, d: Duration) {
        self.nanos.fetch_add(d.as_nanos() as u64, Ordering::SeqCst);
    }
    /// Number of `sleep_until` calls that actually waited.
    pub fn sleeps(&self) -> u64 {
        self.sleeps.load(Ordering::SeqCst)
    }
}

impl Clock for ManualClock {
    fn now(&self) -> Duration {
        Duration::from_nanos(self.nanos.load(Ordering::SeqCst))
    }
    fn sleep_until(&self, t: Duration) {
        let target = t.as_nanos() as u64;
        let prev = self.nanos.fetch_max(target, Ordering::SeqCst);
        if prev < target {
            self.sleeps.fetch_add(1, Ordering::SeqCst);
        }
    }
}
