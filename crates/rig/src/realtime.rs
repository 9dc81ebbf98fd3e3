//! Real-time scheduling of the threads that run a closed loop or serve a
//! device: `SCHED_FIFO` at a middle priority where the system allows it
//! (root, or `CAP_SYS_NICE`, or an `rtprio` limit), the normal time-sharing
//! policy otherwise. A real-time thread preempts ordinary work (a compiler,
//! a browser), so a 1 ms block is late only when the machine's own
//! interrupts are; the kernel still reserves 5 % of each second for
//! ordinary threads (`/proc/sys/kernel/sched_rt_runtime_us`).
//!
//! Only threads that sleep or block between blocks may be promoted: a
//! real-time thread that runs without pause (an unpaced simulation) would
//! starve the ordinary threads on its core. Hand-written through the
//! `thread-priority` crate (a maintained wrapper of `pthread_setschedparam`,
//! which needs `unsafe` this workspace denies).

use thread_priority::{
    NormalThreadSchedulePolicy, RealtimeThreadSchedulePolicy, ThreadPriority, ThreadSchedulePolicy,
    set_thread_priority_and_policy, thread_native_id,
};

/// The `SCHED_FIFO` priority of kilotouch's real-time threads (1–99): above
/// ordinary real-time helpers (IRQ threads run at 50 on PREEMPT_RT kernels
/// and stay above), below the watchdogs.
pub const REALTIME_PRIORITY: u8 = 40;

/// Stack of every thread that builds or runs a simulated rig, trial or
/// closed loop (the engine, a sitting's worker, the simulation and
/// calibration workers), bytes. Rust's default for spawned threads is
/// 2 MiB; an unoptimised (`cargo build`) binary overflowed it while
/// building the plant (frames of ≈ 60 kB each, measured with gdb in
/// `AxisSim::new`), where 4 MiB sufficed. 16 MiB leaves room; only the
/// pages a thread touches are committed.
pub const THREAD_STACK_BYTES: usize = 16 << 20;

/// How the calling thread is scheduled after [`promote_current_thread`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Scheduling {
    /// `SCHED_FIFO` at this priority.
    Realtime(u8),
    /// The normal policy (why real-time scheduling was not granted).
    Normal(String),
}

impl Scheduling {
    /// Real-time?
    pub fn is_realtime(&self) -> bool {
        matches!(self, Scheduling::Realtime(_))
    }
}

/// Schedule the calling thread `SCHED_FIFO` at [`REALTIME_PRIORITY`];
/// when the system refuses, it stays as it was and the reason is returned.
pub fn promote_current_thread() -> Scheduling {
    let prio = ThreadPriority::Crossplatform(
        REALTIME_PRIORITY
            .try_into()
            .unwrap_or(thread_priority::ThreadPriorityValue::MAX),
    );
    match set_thread_priority_and_policy(
        thread_native_id(),
        prio,
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    ) {
        Ok(()) => Scheduling::Realtime(REALTIME_PRIORITY),
        Err(e) => Scheduling::Normal(format!(
            "real-time scheduling not granted ({e:?}): run as root, give the binary \
             CAP_SYS_NICE, or raise the rtprio limit"
        )),
    }
}

/// Back to the normal time-sharing policy (before running without pause).
pub fn demote_current_thread() {
    let _ = set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(0u8.try_into().unwrap_or_default()),
        ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Other),
    );
}

/// CPU time the calling thread has run, ns: the first field of Linux
/// `/proc/thread-self/schedstat`, which leaves out time spent descheduled
/// (so a loaded machine does not inflate it). `None` where the file is
/// missing (other systems) or unreadable. For benchmarks and reports, not
/// for the real-time path (it reads a file).
pub fn thread_cpu_ns() -> Option<u64> {
    first_number("/proc/thread-self/schedstat")
}

/// CPU time the whole process has run, all threads together, ns
/// (`clock_gettime(CLOCK_PROCESS_CPUTIME_ID)`, POSIX). Threads that have
/// ended still count, so it measures work spread over worker threads.
/// `None` where the clock is unavailable. For benchmarks and reports, not
/// for the real-time path.
pub fn process_cpu_ns() -> Option<u64> {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID).ok()?;
    let s = u64::try_from(t.tv_sec()).ok()?;
    let ns = u64::try_from(t.tv_nsec()).ok()?;
    s.checked_mul(1_000_000_000)?.checked_add(ns)
}

/// The 1-minute load average (Linux `/proc/loadavg`); `None` elsewhere.
pub fn load_average() -> Option<f64> {
    first_number("/proc/loadavg")
}

fn first_number<T: std::str::FromStr>(path: &str) -> Option<T> {
    std::fs::read_to_string(path)
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Work done on another thread, which has ended, counts in the
    /// process's CPU time: at least the CPU time that thread measured of
    /// itself.
    #[test]
    fn process_cpu_time_counts_ended_threads() {
        let Some(before) = process_cpu_ns() else {
            return; // no process clock on this system
        };
        let worker = std::thread::spawn(|| {
            let start = thread_cpu_ns();
            let mut x = 0_u64;
            // Spin until this thread has run ≥ 20 ms of CPU time.
            loop {
                for i in 0..10_000_u64 {
                    x = std::hint::black_box(
                        x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(i),
                    );
                }
                match (start, thread_cpu_ns()) {
                    (Some(a), Some(b)) if b - a >= 20_000_000 => return Some(b - a),
                    (None, _) | (_, None) => return None,
                    _ => {}
                }
            }
        });
        let Ok(Some(worker_ns)) = worker.join() else {
            return; // no per-thread clock (non-Linux)
        };
        let after = process_cpu_ns().expect("the process clock worked before");
        assert!(
            after - before >= worker_ns,
            "process CPU grew by {} ns, the ended worker alone ran {worker_ns} ns",
            after - before
        );
    }
}
