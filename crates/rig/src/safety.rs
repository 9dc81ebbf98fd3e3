//! The safety layer between any controller and any rig: the one place where
//! commands are limited, ramped and stopped.
//!
//! Every sample of a closed-loop run passes through
//! [`SafetyLayer::apply`], which turns the controller's command into the
//! command the rig receives:
//!
//! 1. **Non-finite guard.** A command with any NaN/±Inf component is
//!    replaced by an all-zero frame and flagged
//!    [`FrameFlags::NONFINITE_COMMAND`]; while forces are on, it also trips
//!    the layer ([`TripReason::NonFiniteCommand`]). A non-finite value never
//!    reaches an output or the state.
//! 2. **Ramp gain** g ∈ [0, 1] (raised cosine, below) scales forces and drive.
//! 3. **Hard limits** ([`hard_limit`]): each Pantograph axis to
//!    ±`pantograph_force_max_n`, then the force vector to the norm limit
//!    `force_norm_max_n` (direction kept), the Haptuator drive to
//!    ±`haptuator_drive_max_v`. Flag [`FrameFlags::LIMITED`].
//! 4. **Slew limit** on the force vector: |F[n] − F[n−1]|₂ ≤ R/f_s with
//!    R = `force_slew_max_n_per_s`. The step is scaled along the segment
//!    from F[n−1] to the limited target, so the result stays inside both the
//!    axis box and the norm disk (both convex), and every axis obeys
//!    |ΔF_i| ≤ R/f_s too. The Haptuator drive is not slew-limited (its band
//!    reaches 1 kHz by design; the paper's C_H is band-limited at F(s)).
//!    The only exception to the slew limit is the **cut to zero** on entering
//!    a safe state (disarm, fault, emergency stop): removing force is never
//!    delayed.
//!
//! # State machine
//!
//! ```text
//!  Disabled ──arm──▶ Arming ──|F_cmd| < F_on, handle slow──▶ Ramping ──T_ramp──▶ Enabled
//!     ▲                 │ (zero output)                        │ (g rises 0→1)     │
//!     │                 └──────── trip / estop ────────────────┴───────────────────┤
//!  reset ◀─────────────────────── Fault (latched) / EStop (latched) ◀──────────────┘
//! ```
//!
//! * **Arming** outputs zero until the commanded force norm is below
//!   `enable_force_max_n` and the handle-speed estimate is available and
//!   below its limit: forces never start on a large command (no start-up
//!   kick).
//! * **Ramping**: g_k = ½(1 − cos(π k/N)), k = 1…N, N = round(T_ramp·f_s),
//!   a raised-cosine (Hann half-window) ramp, monotone, starting from 0 with
//!   zero slope at both ends. N = 0 skips straight to Enabled, where the first
//!   output then equals the (small) command.
//! * **Fault** (latched): handle speed above `handle_velocity_max_m_s`
//!   while forces are on, the software watchdog, a non-finite command, the
//!   handle position invalid for longer than the velocity span, or a rig
//!   error reported by the loop. Output exactly zero.
//! * **EStop** (latched): [`SafetyLayer::estop`] or an [`EStopHandle`] from
//!   any thread (one atomic flag, polled every sample). Output exactly zero.
//!
//! Leaving Fault or EStop needs [`SafetyLayer::reset`] (→ Disabled) and then
//! [`SafetyLayer::arm`], which goes through Arming and the ramp again.
//!
//! # Handle velocity
//!
//! From the handle positions p[n] (m): span estimates
//! v̂[n] = (p[n] − p[n−L])·f_s/L per axis (L = `velocity_span_samples` ≥ 3,
//! which averages the encoder quantisation: one count of 10 µm over L = 10
//! samples at 10 kHz is 0.01 m/s), then the per-axis median of the last three
//! span estimates, speed = ‖median‖₂. A single bad sample p[j] enters only
//! the two estimates ending or starting at j, which are L ≥ 3 samples apart,
//! so at most one of any three consecutive estimates is affected and the
//! median rejects it. A non-finite position is replaced by the last good one
//! (counted); more than L consecutive ones trip [`TripReason::SensorInvalid`].
//!
//! # Watchdog
//!
//! A sliding window of the last W = round(`watchdog_window_s`·f_s) samples
//! (a bit set, O(1) per sample) counts the samples whose deadline was missed;
//! more than M = round(`watchdog_max_missed_fraction`·W) of them trip
//! [`TripReason::Watchdog`].
//!
//! # Cost
//!
//! [`SafetyLayer::apply`] is O(1), allocates nothing, locks nothing (one
//! atomic load) and cannot panic. Benchmark: `safety/apply` in
//! `crates/rig/benches/rig.rs`.

use crate::config::{RigConfig, SafetyConfig};
use crate::device::{ActuatorFrame, FrameFlags, RigIdentity, SensorFrame};
use crate::error::RigError;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

pub use crate::config::{MAX_VELOCITY_SPAN, MAX_WATCHDOG_WINDOW};

/// Ring length of the velocity estimator (> L + 1, power of two).
const RING: usize = 256;

/// ‖(x, y)‖₂ ([`crate::lanes::norm2`]).
#[inline(always)]
fn norm2(x: f64, y: f64) -> f64 {
    crate::lanes::norm2([x, y])
}

/// Hard (stateless) actuator limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HardLimits {
    /// Largest Pantograph force per axis, N.
    pub force_axis_max_n: f64,
    /// Largest norm of the Pantograph force vector (x, y), N.
    pub force_norm_max_n: f64,
    /// Largest Haptuator drive, V.
    pub drive_max_v: f64,
}

impl HardLimits {
    /// Validated limits (each finite, > 0 and ≤ 1e6 N or V, so that squares
    /// of limited values cannot overflow).
    pub fn new(
        force_axis_max_n: f64,
        force_norm_max_n: f64,
        drive_max_v: f64,
    ) -> Result<Self, RigError> {
        for (name, v) in [
            ("force_axis_max_n", force_axis_max_n),
            ("force_norm_max_n", force_norm_max_n),
            ("drive_max_v", drive_max_v),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= crate::config::MAX_ACTUATOR_LIMIT) {
                return Err(RigError::InvalidParameter {
                    name,
                    value: v,
                    reason: format!(
                        "must be finite, > 0 and ≤ {:e}",
                        crate::config::MAX_ACTUATOR_LIMIT
                    ),
                });
            }
        }
        Ok(Self {
            force_axis_max_n,
            force_norm_max_n,
            drive_max_v,
        })
    }

    /// The limits of a rig file: `[limits]` per axis and drive, `[safety]`
    /// norm.
    pub fn from_config(cfg: &RigConfig) -> Result<Self, RigError> {
        Self::new(
            cfg.limits.pantograph_force_max_n,
            cfg.safety.force_norm_max_n,
            cfg.limits.haptuator_drive_max_v,
        )
    }
}

/// The hard limits alone, without state: what open-loop excitation
/// (calibration) and every rig backend apply. A frame with any non-finite
/// component becomes all zero with [`FrameFlags::NONFINITE_COMMAND`];
/// otherwise each force axis is clamped, then the force vector is scaled
/// onto the norm disk (direction kept), the drive is clamped; any change sets
/// [`FrameFlags::LIMITED`]. Outputs satisfy |F_i| ≤ axis limit exactly and
/// ‖F‖₂ ≤ norm limit to within one rounding.
#[inline]
pub fn hard_limit(cmd: ActuatorFrame, lim: &HardLimits) -> (ActuatorFrame, FrameFlags) {
    let finite =
        cmd.force_n[0].is_finite() && cmd.force_n[1].is_finite() && cmd.haptuator_v.is_finite();
    if !finite {
        return (
            ActuatorFrame::default(),
            FrameFlags(FrameFlags::NONFINITE_COMMAND),
        );
    }
    let mut flags = 0u8;
    let a = lim.force_axis_max_n;
    let mut f = cmd.force_n;
    for x in &mut f {
        if x.abs() > a {
            *x = a.copysign(*x);
            flags |= FrameFlags::LIMITED;
        }
    }
    let n = norm2(f[0], f[1]);
    if n > lim.force_norm_max_n {
        let s = lim.force_norm_max_n / n;
        f = [f[0] * s, f[1] * s];
        flags |= FrameFlags::LIMITED;
    }
    let mut v = cmd.haptuator_v;
    if v.abs() > lim.drive_max_v {
        v = lim.drive_max_v.copysign(v);
        flags |= FrameFlags::LIMITED;
    }
    (
        ActuatorFrame {
            force_n: f,
            haptuator_v: v,
        },
        FrameFlags(flags),
    )
}

/// State of the layer (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SafetyState {
    /// Forces off (zero output); `arm` to start.
    Disabled,
    /// Armed, waiting for a small command and a slow handle (zero output).
    Arming,
    /// Forces ramping on (gain rising from 0 to 1).
    Ramping,
    /// Forces on.
    Enabled,
    /// Tripped (latched, zero output); `reset` then `arm`.
    Fault,
    /// Emergency stop (latched, zero output); `reset` then `arm`.
    EStop,
}

impl SafetyState {
    /// True when forces may be non-zero (Ramping or Enabled).
    pub fn forces_on(self) -> bool {
        matches!(self, Self::Ramping | Self::Enabled)
    }

    /// True in the latched states (Fault, EStop).
    pub fn latched(self) -> bool {
        matches!(self, Self::Fault | Self::EStop)
    }

    /// Short label for status bars.
    pub fn label(self) -> &'static str {
        match self {
            Self::Disabled => "outputs off",
            Self::Arming => "arming",
            Self::Ramping => "ramping on",
            Self::Enabled => "armed",
            Self::Fault => "FAULT",
            Self::EStop => "EMERGENCY STOP",
        }
    }
}

/// Why the layer tripped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TripReason {
    /// Handle speed above `handle_velocity_max_m_s` (value: speed, m/s).
    HandleVelocity,
    /// More than M missed deadlines in the watchdog window
    /// (value: misses in the window).
    Watchdog,
    /// A non-finite command while armed or on.
    NonFiniteCommand,
    /// Handle position non-finite for more than the velocity span
    /// (value: consecutive bad samples).
    SensorInvalid,
    /// The rig reported an error (disconnect, device fault).
    RigError,
    /// Emergency stop.
    EStop,
}

/// A trip: reason, the layer's sample index and a reason-specific value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Trip {
    /// Reason.
    pub reason: TripReason,
    /// Index of the sample (0-based count of `apply` calls) at which it
    /// happened.
    pub sample: u64,
    /// Speed (m/s), misses, bad samples, or 0 (see [`TripReason`]).
    pub value: f64,
}

/// Counters since creation.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SafetyCounters {
    /// Samples processed.
    pub samples: u64,
    /// Output samples changed by a hard limit.
    pub limited: u64,
    /// Output samples changed by the slew limit.
    pub slew_limited: u64,
    /// Non-finite commands replaced by zero.
    pub nonfinite_commands: u64,
    /// Non-finite handle positions replaced by the last good one.
    pub nonfinite_sensors: u64,
    /// Missed deadlines reported.
    pub missed_deadlines: u64,
    /// Trips into Fault.
    pub faults: u64,
    /// Emergency stops.
    pub estops: u64,
    /// Samples output as exactly zero in a latched state (Fault, EStop).
    pub latched_zeroed: u64,
}

/// Compact status for GUIs and logs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SafetyStatus {
    /// State.
    pub state: SafetyState,
    /// Ramp gain in [0, 1] (0 in the zero-output states).
    pub gain: f64,
    /// Latest trip (kept after reset, for the record).
    pub last_trip: Option<Trip>,
    /// Latest handle-speed estimate, m/s (`None` while warming up).
    pub handle_speed_m_s: Option<f64>,
    /// Missed deadlines in the current watchdog window.
    pub missed_in_window: u32,
    /// Counters.
    pub counters: SafetyCounters,
}

/// Thread-safe emergency-stop button for a [`SafetyLayer`]: cloneable, one
/// atomic flag, polled by the layer every sample.
#[derive(Debug, Clone)]
pub struct EStopHandle(Arc<AtomicBool>);

impl EStopHandle {
    /// Press the emergency stop (takes effect at the next sample; latched
    /// until [`SafetyLayer::reset`]).
    pub fn trigger(&self) {
        self.0.store(true, Ordering::Release);
    }

    /// True while pressed and not yet reset.
    pub fn is_triggered(&self) -> bool {
        self.0.load(Ordering::Acquire)
    }
}

/// Handle-speed estimator (module docs): span differences, median of three.
#[derive(Debug, Clone)]
struct VelocityEstimator {
    ring: [[f64; 2]; RING],
    head: usize,
    filled: usize,
    span: usize,
    scale: f64,
    est: [[f64; 2]; 3],
    n_est: usize,
    last_good: [f64; 2],
    has_good: bool,
    bad_run: u32,
}

/// Median of three non-NaN values. With plain comparisons (one `minsd` or
/// `maxsd` each) instead of `f64::min`/`max`, whose NaN handling costs
/// several instructions per call; the span estimates are never NaN (finite
/// positions, a finite scale). The result can differ from the
/// `min`/`max` form only in the sign of a zero, which the speed (a norm)
/// does not see.
#[inline]
fn median3(a: f64, b: f64, c: f64) -> f64 {
    #[inline(always)]
    fn lo(a: f64, b: f64) -> f64 {
        if a < b { a } else { b }
    }
    #[inline(always)]
    fn hi(a: f64, b: f64) -> f64 {
        if a > b { a } else { b }
    }
    hi(lo(a, b), lo(hi(a, b), c))
}

impl VelocityEstimator {
    fn new(span: usize, fs: f64) -> Self {
        Self {
            ring: [[0.0; 2]; RING],
            head: 0,
            filled: 0,
            span,
            scale: fs / span as f64,
            est: [[0.0; 2]; 3],
            n_est: 0,
            last_good: [0.0; 2],
            has_good: false,
            bad_run: 0,
        }
    }

    /// Feed one position; returns (speed estimate, was the sample bad).
    #[inline]
    fn update(&mut self, p: [f64; 2]) -> (Option<f64>, bool) {
        let good = p[0].is_finite() && p[1].is_finite();
        if good && self.n_est == 3 {
            // Steady state (the ring holds more than `span` positions, three
            // estimates exist; `filled` only gates that and stays > span).
            self.bad_run = 0;
            self.last_good = p;
            self.head = (self.head + 1) % RING;
            self.ring[self.head] = p;
            let old = self.ring[(self.head + RING - self.span) % RING];
            let v = [(p[0] - old[0]) * self.scale, (p[1] - old[1]) * self.scale];
            self.est = [self.est[1], self.est[2], v];
            return (Some(self.speed()), false);
        }
        self.update_general(p)
    }

    /// [`Self::update`] while warming up or for a bad sample.
    #[cold]
    #[inline(never)]
    fn update_general(&mut self, p: [f64; 2]) -> (Option<f64>, bool) {
        let bad = !(p[0].is_finite() && p[1].is_finite());
        if bad {
            self.bad_run = self.bad_run.saturating_add(1);
            if !self.has_good {
                return (None, true);
            }
        } else {
            self.bad_run = 0;
            self.last_good = p;
            self.has_good = true;
        }
        let p = self.last_good;
        self.head = (self.head + 1) % RING;
        self.ring[self.head] = p;
        self.filled = (self.filled + 1).min(RING);
        if self.filled > self.span {
            let old = self.ring[(self.head + RING - self.span) % RING];
            let v = [(p[0] - old[0]) * self.scale, (p[1] - old[1]) * self.scale];
            self.est = [self.est[1], self.est[2], v];
            self.n_est = (self.n_est + 1).min(3);
        }
        if self.n_est < 3 {
            return (None, bad);
        }
        (Some(self.speed()), bad)
    }

    /// Speed from the three latest span estimates (median per axis, norm).
    #[inline(always)]
    fn speed(&self) -> f64 {
        let e = &self.est;
        let vx = median3(e[0][0], e[1][0], e[2][0]);
        let vy = median3(e[0][1], e[1][1], e[2][1]);
        let s = norm2(vx, vy);
        // +∞ only for position differences beyond ~1e150 m: a trip.
        if s.is_finite() { s } else { f64::MAX }
    }
}

/// Sliding-window count of missed deadlines (bit set, O(1) per sample).
#[derive(Debug, Clone)]
struct Watchdog {
    bits: Box<[u64]>,
    window: usize,
    pos: usize,
    count: u32,
}

impl Watchdog {
    fn new(window: usize) -> Self {
        Self {
            bits: vec![0u64; window.div_ceil(64)].into_boxed_slice(),
            window,
            pos: 0,
            count: 0,
        }
    }

    /// Record one sample; returns the misses among the last `window` samples.
    #[inline]
    fn record(&mut self, missed: bool) -> u32 {
        let (w, b) = (self.pos / 64, self.pos % 64);
        if let Some(word) = self.bits.get_mut(w) {
            let old = (*word >> b) & 1 == 1;
            if old {
                self.count -= 1;
            }
            if missed {
                *word |= 1 << b;
                self.count += 1;
            } else {
                *word &= !(1 << b);
            }
        }
        self.pos += 1;
        if self.pos == self.window {
            self.pos = 0;
        }
        self.count
    }

    /// [`Self::record`]`(false)` when the window holds no miss
    /// (`count` = 0, so the slot being overwritten is already clear): only
    /// the position advances.
    #[inline]
    fn advance_clear(&mut self) {
        debug_assert_eq!(self.count, 0);
        self.pos += 1;
        if self.pos == self.window {
            self.pos = 0;
        }
    }

    fn clear(&mut self) {
        self.bits.fill(0);
        self.count = 0;
    }
}

/// The safety layer (module docs). Not `Clone`: a copy would share the
/// emergency-stop flag of its [`EStopHandle`]s.
#[derive(Debug)]
pub struct SafetyLayer {
    limits: HardLimits,
    fs: f64,
    slew_step: f64,
    enable_force: f64,
    v_max: f64,
    ramp_n: u64,
    max_missed: u32,
    arm_on_start: bool,
    state: SafetyState,
    ramp_k: u64,
    gain: f64,
    prev_f: [f64; 2],
    vel: VelocityEstimator,
    speed: Option<f64>,
    wd: Watchdog,
    estop_flag: Arc<AtomicBool>,
    last_trip: Option<Trip>,
    counters: SafetyCounters,
    last_flags: FrameFlags,
}

impl SafetyLayer {
    /// A layer for a rig running at `fs` Hz with `limits` and the `[safety]`
    /// settings `cfg`. Starts Disabled.
    pub fn new(cfg: &SafetyConfig, limits: HardLimits, fs: f64) -> Result<Self, RigError> {
        let limits = HardLimits::new(
            limits.force_axis_max_n,
            limits.force_norm_max_n,
            limits.drive_max_v,
        )?;
        RigError::require_positive("sample_rate_hz", fs)?;
        if let Some((key, value, reason)) = cfg.issue(fs).into_iter().next() {
            return Err(RigError::InvalidParameter {
                name: key,
                value,
                reason,
            });
        }
        let window = cfg.watchdog_window_samples(fs);
        Ok(Self {
            limits,
            fs,
            slew_step: cfg.force_slew_max_n_per_s / fs,
            enable_force: cfg.enable_force_max_n,
            v_max: cfg.handle_velocity_max_m_s,
            ramp_n: cfg.ramp_samples(fs),
            max_missed: cfg.watchdog_max_missed(fs),
            arm_on_start: cfg.arm_on_start,
            state: SafetyState::Disabled,
            ramp_k: 0,
            gain: 0.0,
            prev_f: [0.0; 2],
            vel: VelocityEstimator::new(cfg.velocity_span_samples as usize, fs),
            speed: None,
            wd: Watchdog::new(window),
            estop_flag: Arc::new(AtomicBool::new(false)),
            last_trip: None,
            counters: SafetyCounters::default(),
            last_flags: FrameFlags::default(),
        })
    }

    /// The layer of a rig file at its own sample rate.
    pub fn from_config(cfg: &RigConfig) -> Result<Self, RigError> {
        Self::for_rate(cfg, cfg.rig.sample_rate_hz)
    }

    /// The layer of a rig file for a rig running at `fs` Hz (an audio
    /// interface runs at the device's rate).
    pub fn for_rate(cfg: &RigConfig, fs: f64) -> Result<Self, RigError> {
        Self::new(&cfg.safety, HardLimits::from_config(cfg)?, fs)
    }

    /// The layer for a rig as it identifies itself (its sample rate, force
    /// and drive limits; the norm limit is `cfg.force_norm_max_n`).
    pub fn for_rig(id: &RigIdentity, cfg: &SafetyConfig) -> Result<Self, RigError> {
        Self::new(
            cfg,
            HardLimits::new(id.force_max_n, cfg.force_norm_max_n, id.haptuator_max_v)?,
            id.sample_rate_hz,
        )
    }

    /// Per-sample safety (module docs): the controller's `cmd`, the sensor
    /// frame the controller saw (handle position), and whether the previous
    /// exchange missed its deadline. Returns the command to send. O(1), no
    /// allocation, no lock, no panic; never non-finite.
    #[inline]
    pub fn apply(
        &mut self,
        cmd: ActuatorFrame,
        sensors: &SensorFrame,
        deadline_missed: bool,
    ) -> ActuatorFrame {
        let sample = self.open_sample();
        let (speed, bad_sensor) = self.vel.update(sensors.handle_m);
        self.speed = speed;
        // The common case, forces on and nothing to count or trip: every
        // test of the general path below is false (no bad sensor sample, so
        // `bad_run` = 0; no miss now and none in the window, so the watchdog
        // slot being overwritten is already clear; finite command; speed
        // within the limit), and the limits are checked with one combined
        // test before the general limiting code (a command within the
        // limits is finite).
        if self.state == SafetyState::Enabled
            && !bad_sensor
            && !deadline_missed
            && self.wd.count == 0
            && speed.is_some_and(|s| s <= self.v_max)
        {
            // g = 1 in Enabled (every way into Enabled sets it, every way
            // out leaves Enabled): 1·x = x bit for bit, so no multiply.
            debug_assert!(self.gain == 1.0);
            let f = cmd.force_n;
            let v = cmd.haptuator_v;
            let a = self.limits.force_axis_max_n;
            if f[0].abs() <= a
                && f[1].abs() <= a
                && v.abs() <= self.limits.drive_max_v
                && norm2(f[0], f[1]) <= self.limits.force_norm_max_n
                && norm2(f[0] - self.prev_f[0], f[1] - self.prev_f[1]) <= self.slew_step
            {
                self.wd.advance_clear();
                self.prev_f = f;
                self.last_flags = FrameFlags::default();
                return ActuatorFrame {
                    force_n: f,
                    haptuator_v: v,
                };
            }
            if cmd.force_n[0].is_finite()
                && cmd.force_n[1].is_finite()
                && cmd.haptuator_v.is_finite()
            {
                self.wd.advance_clear();
                return self.limit_on_binding(f, v, 0);
            }
        }
        self.apply_general(cmd, sample, speed, bad_sensor, deadline_missed)
    }

    /// Count the sample and honour a pending emergency stop; returns the
    /// sample's index.
    #[inline(always)]
    fn open_sample(&mut self) -> u64 {
        let sample = self.counters.samples;
        self.counters.samples += 1;
        if self.estop_flag.load(Ordering::Acquire) && self.state != SafetyState::EStop {
            self.enter_estop(sample);
        }
        sample
    }

    /// [`Self::apply`] by the general paths alone (velocity estimate and
    /// limiting): the reference the common-case paths must equal bit for
    /// bit, for the equivalence harness (`tests/equivalence.rs`).
    #[doc(hidden)]
    pub fn apply_reference(
        &mut self,
        cmd: ActuatorFrame,
        sensors: &SensorFrame,
        deadline_missed: bool,
    ) -> ActuatorFrame {
        let sample = self.open_sample();
        let (speed, bad_sensor) = self.vel.update_general(sensors.handle_m);
        self.speed = speed;
        self.apply_general(cmd, sample, speed, bad_sensor, deadline_missed)
    }

    /// Forces on, finite command scaled by the gain (`f`, `v`), some limit
    /// binding (or possibly): the hard limits, then the slew limit, with
    /// flags and counters.
    #[cold]
    #[inline(never)]
    fn limit_on_binding(&mut self, f: [f64; 2], v: f64, flags: u8) -> ActuatorFrame {
        let mut flags = flags;
        let (lim, lf) = hard_limit(
            ActuatorFrame {
                force_n: f,
                haptuator_v: v,
            },
            &self.limits,
        );
        if lf.has(FrameFlags::LIMITED) {
            flags |= FrameFlags::LIMITED;
            self.counters.limited += 1;
        }
        let mut f = lim.force_n;
        let d = [f[0] - self.prev_f[0], f[1] - self.prev_f[1]];
        let dn = norm2(d[0], d[1]);
        if dn > self.slew_step {
            let s = self.slew_step / dn;
            let a = self.limits.force_axis_max_n;
            f = [
                (self.prev_f[0] + d[0] * s).clamp(-a, a),
                (self.prev_f[1] + d[1] * s).clamp(-a, a),
            ];
            flags |= FrameFlags::LIMITED;
            self.counters.slew_limited += 1;
        }
        self.prev_f = f;
        self.last_flags = FrameFlags(flags);
        ActuatorFrame {
            force_n: f,
            haptuator_v: lim.haptuator_v,
        }
    }

    /// [`Self::apply`] outside the common case (any state, counters, trips,
    /// arming and ramp).
    #[cold]
    #[inline(never)]
    fn apply_general(
        &mut self,
        cmd: ActuatorFrame,
        sample: u64,
        speed: Option<f64>,
        bad_sensor: bool,
        deadline_missed: bool,
    ) -> ActuatorFrame {
        let mut flags = 0u8;
        if bad_sensor {
            self.counters.nonfinite_sensors += 1;
        }
        if deadline_missed {
            self.counters.missed_deadlines += 1;
        }
        let missed = self.wd.record(deadline_missed);

        let finite =
            cmd.force_n[0].is_finite() && cmd.force_n[1].is_finite() && cmd.haptuator_v.is_finite();
        if !finite {
            flags |= FrameFlags::NONFINITE_COMMAND;
            self.counters.nonfinite_commands += 1;
        }

        let armed = matches!(
            self.state,
            SafetyState::Arming | SafetyState::Ramping | SafetyState::Enabled
        );
        if armed {
            if !finite {
                self.trip(TripReason::NonFiniteCommand, 0.0, sample);
            } else if self.vel.bad_run as usize > self.vel.span {
                self.trip(TripReason::SensorInvalid, self.vel.bad_run as f64, sample);
            } else if missed > self.max_missed {
                self.trip(TripReason::Watchdog, missed as f64, sample);
            } else if self.state.forces_on()
                && let Some(s) = speed
                && s > self.v_max
            {
                self.trip(TripReason::HandleVelocity, s, sample);
            }
        }

        if self.state == SafetyState::Arming
            && finite
            && norm2(cmd.force_n[0], cmd.force_n[1]) < self.enable_force
            && speed.is_some_and(|s| s <= self.v_max)
        {
            self.ramp_k = 0;
            self.state = if self.ramp_n == 0 {
                self.gain = 1.0;
                SafetyState::Enabled
            } else {
                SafetyState::Ramping
            };
        }
        if self.state == SafetyState::Ramping {
            self.ramp_k += 1;
            if self.ramp_k >= self.ramp_n {
                self.gain = 1.0;
                self.state = SafetyState::Enabled;
            } else {
                let x = std::f64::consts::PI * self.ramp_k as f64 / self.ramp_n as f64;
                // Never below the previous gain (monotone even if cos is not
                // correctly rounded).
                self.gain = self.gain.max(0.5 * (1.0 - x.cos())).min(1.0);
            }
        }

        if self.state.forces_on() && finite {
            let g = self.gain;
            return self.limit_on_binding(
                [g * cmd.force_n[0], g * cmd.force_n[1]],
                g * cmd.haptuator_v,
                flags,
            );
        }
        if !self.state.forces_on() {
            self.gain = 0.0;
        }
        if self.state.latched() {
            self.counters.latched_zeroed += 1;
        }
        self.prev_f = [0.0; 2];
        self.last_flags = FrameFlags(flags);
        ActuatorFrame::default()
    }

    #[cold]
    #[inline(never)]
    fn trip(&mut self, reason: TripReason, value: f64, sample: u64) {
        if self.state.latched() {
            return;
        }
        self.state = SafetyState::Fault;
        self.gain = 0.0;
        self.counters.faults += 1;
        self.last_trip = Some(Trip {
            reason,
            sample,
            value,
        });
    }

    #[cold]
    #[inline(never)]
    fn enter_estop(&mut self, sample: u64) {
        self.state = SafetyState::EStop;
        self.gain = 0.0;
        self.counters.estops += 1;
        self.last_trip = Some(Trip {
            reason: TripReason::EStop,
            sample,
            value: 0.0,
        });
    }

    /// Arm: Disabled → Arming (forces come on once the command is small,
    /// through the ramp). No-op when already armed or on. Refused in the
    /// latched states (call [`reset`](Self::reset) first).
    pub fn arm(&mut self) -> Result<(), RigError> {
        if self.estop_flag.load(Ordering::Acquire) && self.state != SafetyState::EStop {
            self.enter_estop(self.counters.samples);
        }
        match self.state {
            SafetyState::Disabled => {
                self.state = SafetyState::Arming;
                Ok(())
            }
            SafetyState::Arming | SafetyState::Ramping | SafetyState::Enabled => Ok(()),
            SafetyState::Fault | SafetyState::EStop => Err(RigError::NotReady(format!(
                "safety layer latched in {:?} ({:?}): reset before arming",
                self.state,
                self.last_trip.map(|t| t.reason)
            ))),
        }
    }

    /// Forces off (→ Disabled, zero output from the next sample). The
    /// latched states stay latched.
    pub fn disarm(&mut self) {
        if !self.state.latched() {
            self.state = SafetyState::Disabled;
            self.gain = 0.0;
        }
    }

    /// Emergency stop from the owning thread (latched; zero output from the
    /// next sample).
    pub fn estop(&mut self) {
        self.estop_flag.store(true, Ordering::Release);
        if self.state != SafetyState::EStop {
            self.enter_estop(self.counters.samples);
        }
    }

    /// Trip into Fault from outside (e.g. the loop saw a rig error).
    pub fn fault(&mut self, reason: TripReason) {
        let s = self.counters.samples;
        self.trip(reason, 0.0, s);
    }

    /// Clear a latched Fault or EStop (and the emergency-stop flag and the
    /// watchdog window): → Disabled. Forces come back only after
    /// [`arm`](Self::arm) and the ramp.
    pub fn reset(&mut self) {
        self.estop_flag.store(false, Ordering::Release);
        self.state = SafetyState::Disabled;
        self.gain = 0.0;
        self.ramp_k = 0;
        self.wd.clear();
    }

    /// A cloneable emergency-stop button usable from any thread.
    pub fn estop_handle(&self) -> EStopHandle {
        EStopHandle(Arc::clone(&self.estop_flag))
    }

    /// State.
    pub fn state(&self) -> SafetyState {
        self.state
    }

    /// Compact status.
    pub fn status(&self) -> SafetyStatus {
        SafetyStatus {
            state: self.state,
            gain: self.gain,
            last_trip: self.last_trip,
            handle_speed_m_s: self.speed,
            missed_in_window: self.wd.count,
            counters: self.counters,
        }
    }

    /// Flags of the last [`apply`](Self::apply):
    /// [`FrameFlags::NONFINITE_COMMAND`], [`FrameFlags::LIMITED`].
    pub fn last_flags(&self) -> FrameFlags {
        self.last_flags
    }

    /// The hard limits.
    pub fn limits(&self) -> &HardLimits {
        &self.limits
    }

    /// Sample rate, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    /// Largest force change per sample, N (slew limit / f_s).
    pub fn slew_step_n(&self) -> f64 {
        self.slew_step
    }

    /// Ramp length N, samples.
    pub fn ramp_samples(&self) -> u64 {
        self.ramp_n
    }

    /// Watchdog window W, samples.
    pub fn watchdog_window_samples(&self) -> usize {
        self.wd.window
    }

    /// Watchdog limit M: more than M misses in the window trip.
    pub fn watchdog_max_missed(&self) -> u32 {
        self.max_missed
    }

    /// Whether a closed loop should arm the layer when it starts
    /// (`arm_on_start`).
    pub fn arm_on_start(&self) -> bool {
        self.arm_on_start
    }
}
