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
