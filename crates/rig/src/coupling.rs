//! Bilateral coupling between the haptic handle and the optical trap.
//!
//! Position (master → slave): trap = offset + s·(handle − origin), clamped
//! to the trap workspace (per axis). Force (slave → master): the reaction of
//! the optical force on the trap, κ(bead − trap), scaled to newtons at the
//! handle by `force_scale` (N per N), so that pushing the bead into an
//! obstacle is felt as a resistance. The handle force is then split into the
//! device's two inputs:
//!
//! * **P mode** (Pantograph only): a 2nd-order Butterworth low-pass at
//!   `pantograph_band_hz` (bilinear, prewarped), Haptuator drive 0.
//! * **D mode** (dual stage): the paper's chain of Fig. 6 — Linkwitz–Riley
//!   crossover, C_L = K_sys/G0_L on the low path (Pantograph force, N) and
//!   C_H = K_sys F/Ĝ_H on the high path (Haptuator drive, V) — behind the
//!   minimal [`ForceSplitter`] trait, implemented here for
//!   `kilotouch_dsp::chain::Chain`.
//!
//! Both paths run every sample, so switching modes at run time is glitch-free
//! (the newly selected path is already warm). The y axis has no Haptuator:
//! it always uses the band-limited Pantograph path. Outputs are clamped to
//! the actuator limits and a non-finite value never reaches an actuator (it
//! is replaced by 0 and counted).

use crate::config::{CouplingConfig, CouplingModeConfig, RigConfig, SafetyConfig};
use crate::error::RigError;
use crate::plant::{Axis, AxisModel, Channel};
use crate::rig::{ActuatorFrame, Rig, SensorFrame};
use crate::safety::{SafetyLayer, SafetyStatus, TripReason};
use crate::tweezer::{Tweezer, TweezerSample};
use kilotouch_dsp::Tf;
use kilotouch_dsp::chain::{Chain, ChainCoefficients, ChainDesign};
use kilotouch_dsp::design::{FilterKind, Prewarp, butter};
use kilotouch_dsp::filter::{Biquad, sections_response};
use serde::{Deserialize, Serialize};

/// Force sample (N) → (Pantograph force N, Haptuator drive V). The minimal
/// interface the coupling needs from the dsp chain.
pub trait ForceSplitter: Send {
    /// Split one sample. Must not allocate, lock or panic.
    fn split(&mut self, force_n: f64) -> (f64, f64);
    /// Clear the state.
    fn reset(&mut self);
}

impl ForceSplitter for Chain {
    #[inline]
    fn split(&mut self, force_n: f64) -> (f64, f64) {
        self.process(force_n)
    }
    fn reset(&mut self) {
        Chain::reset(self);
    }
}

/// P-mode splitter: band-limited Pantograph force, no Haptuator drive.
#[derive(Debug, Clone)]
pub struct PantographOnly {
    /// The single second-order section (a `Biquad` rather than a one-section
    /// `Sos`: the same guarded step without the loop over sections).
    lp: Biquad,
}

impl PantographOnly {
    /// 2nd-order Butterworth low-pass at `band_hz` (prewarped) at rate `fs`.
    pub fn new(band_hz: f64, fs: f64) -> Result<Self, RigError> {
        let sections = butter(2, band_hz, fs, FilterKind::Lowpass, Prewarp::AtCutoff)?;
        match sections.as_slice() {
            [c] => Ok(Self {
                lp: Biquad::new(*c)?,
            }),
            _ => Err(RigError::InvalidParameter {
                name: "pantograph_band_hz",
                value: band_hz,
                reason: format!("expected one section, got {}", sections.len()),
            }),
        }
    }

    /// Frequency response of the band limit at `f` Hz.
    pub fn response(&self, f: f64, fs: f64) -> num_complex::Complex64 {
        sections_response(std::slice::from_ref(&self.lp.coefficients()), f, fs)
    }
}

impl ForceSplitter for PantographOnly {
    #[inline]
    fn split(&mut self, force_n: f64) -> (f64, f64) {
        (self.lp.process(force_n), 0.0)
    }
    fn reset(&mut self) {
        self.lp.reset();
    }
}

/// Which splitter drives the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CouplingMode {
    /// P: Pantograph only, band-limited.
    Pantograph,
    /// D: crossover and both compensated channels.
    Dual,
}

impl From<CouplingModeConfig> for CouplingMode {
    fn from(m: CouplingModeConfig) -> Self {
        match m {
            CouplingModeConfig::Pantograph => Self::Pantograph,
            CouplingModeConfig::Dual => Self::Dual,
        }
    }
}

/// Counters of the coupling's safety nets.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CouplingCounters {
    /// Output samples clamped to an actuator limit.
    pub clamped: u64,
    /// Non-finite values replaced by 0 before an actuator.
    pub nonfinite: u64,
    /// Handle positions outside the trap workspace (trap clamped).
    pub workspace_clamped: u64,
}

/// The analytic "as designed" chain for a rig model: K_sys = G0_L (the
/// mass-line gain of the low channel, geometric mean of |G_L| over
/// 63–200 Hz), Ĝ_H = the paper's eq. 2 scaled to the model's high channel
/// (least squares in dB over 100–1000 Hz), LR4 at 200 Hz, F at 1 kHz.
/// Calibration replaces this with identified values.
pub fn model_chain_design(cfg: &RigConfig) -> Result<ChainDesign, RigError> {
    let m = AxisModel::new(cfg, Axis::X)?;
    let gm =
        |ch: Channel, lo: f64, hi: f64, reference: &dyn Fn(f64) -> f64| -> Result<f64, RigError> {
            let n = 200;
            let mut s = 0.0;
            for i in 0..n {
                let f = lo * (hi / lo).powf(i as f64 / (n - 1) as f64);
                s += (m.channel_response(ch, f)?.norm() / reference(f)).ln();
            }
            Ok((s / n as f64).exp())
        };
    let g0_l = gm(Channel::Low, 63.0, 200.0, &|_| 1.0)?;
    let paper = kilotouch_dsp::compensator::paper_g_h();
    let k = gm(Channel::High, 100.0, 1000.0, &|f| {
        paper.response_hz(f).norm()
    })?;
    let g_h = Tf::new(paper.num.iter().map(|c| c * k).collect(), paper.den.clone())?;
    Ok(ChainDesign {
        fs: cfg.rig.sample_rate_hz,
        k_sys: g0_l,
        g0_l,
        g_h,
        ..ChainDesign::paper()
    })
}

/// Handle ↔ trap coupling (module docs), generic over the D-mode splitter.
#[derive(Debug, Clone)]
pub struct Coupling<S: ForceSplitter = Chain> {
    cfg: CouplingConfig,
    force_max: f64,
    drive_max: f64,
    mode: CouplingMode,
    p_x: PantographOnly,
    p_y: PantographOnly,
    dual: S,
    last_trap: [f64; 2],
    counters: CouplingCounters,
}

impl Coupling<Chain> {
    /// Coupling with the model's as-designed chain ([`model_chain_design`]).
    pub fn from_config(cfg: &RigConfig) -> Result<Self, RigError> {
        let coeffs = ChainCoefficients::design(&model_chain_design(cfg)?)?;
        Self::with_splitter(cfg, Chain::new(&coeffs))
    }
}

impl<S: ForceSplitter> Coupling<S> {
    /// Coupling with an explicit D-mode splitter (e.g. a calibrated chain).
    pub fn with_splitter(cfg: &RigConfig, dual: S) -> Result<Self, RigError> {
        cfg.validate()?;
        let fs = cfg.rig.sample_rate_hz;
        let c = &cfg.coupling;
        let trap0 = [
            c.trap_offset_m[0].clamp(c.trap_min_m[0], c.trap_max_m[0]),
            c.trap_offset_m[1].clamp(c.trap_min_m[1], c.trap_max_m[1]),
        ];
        Ok(Self {
            cfg: c.clone(),
            force_max: cfg.limits.pantograph_force_max_n,
            drive_max: cfg.limits.haptuator_drive_max_v,
            mode: c.mode.into(),
            p_x: PantographOnly::new(c.pantograph_band_hz, fs)?,
            p_y: PantographOnly::new(c.pantograph_band_hz, fs)?,
            dual,
            last_trap: trap0,
            counters: CouplingCounters::default(),
        })
    }

    /// Current mode.
    pub fn mode(&self) -> CouplingMode {
        self.mode
    }

    /// Switch mode (takes effect at the next sample; no transient since
    /// both paths are always running).
    pub fn set_mode(&mut self, mode: CouplingMode) {
        self.mode = mode;
    }

    /// Safety-net counters.
    pub fn counters(&self) -> CouplingCounters {
        self.counters
    }

    /// The D-mode splitter.
    pub fn splitter(&self) -> &S {
        &self.dual
    }

    /// Clear filter states.
    pub fn reset(&mut self) {
        self.p_x.reset();
        self.p_y.reset();
        self.dual.reset();
    }

    /// Trap position (m) for a handle position (m): scale, offset, clamp to
    /// the workspace. A non-finite handle keeps the previous trap position.
    #[inline]
    pub fn trap_target(&mut self, handle_m: [f64; 2]) -> [f64; 2] {
        let c = &self.cfg;
        let v = [
            c.trap_offset_m[0] + c.position_scale * (handle_m[0] - c.handle_origin_m[0]),
            c.trap_offset_m[1] + c.position_scale * (handle_m[1] - c.handle_origin_m[1]),
        ];
        // Common case: inside the workspace (hence finite), nothing to
        // clamp or count (`clamp` would return `v` unchanged).
        if v[0] >= c.trap_min_m[0]
            && v[0] <= c.trap_max_m[0]
            && v[1] >= c.trap_min_m[1]
            && v[1] <= c.trap_max_m[1]
        {
            self.last_trap = v;
            return v;
        }
        self.trap_target_clamped(handle_m)
    }

    /// [`Self::trap_target`] outside the workspace or non-finite.
    #[cold]
    #[inline(never)]
    fn trap_target_clamped(&mut self, handle_m: [f64; 2]) -> [f64; 2] {
        let c = &self.cfg;
        let mut t = self.last_trap;
        let mut clamped = false;
        for i in 0..2 {
            let v = c.trap_offset_m[i] + c.position_scale * (handle_m[i] - c.handle_origin_m[i]);
            if v.is_finite() {
                let cl = v.clamp(c.trap_min_m[i], c.trap_max_m[i]);
                clamped |= cl != v;
                t[i] = cl;
            } else {
                self.counters.nonfinite += 1;
            }
        }
        if clamped {
            self.counters.workspace_clamped += 1;
        }
        self.last_trap = t;
        t
    }

    /// Force to render at the handle (N): force_scale·κ(bead − trap), i.e.
    /// minus the optical force on the bead, scaled. Zero when the bead is lost.
    #[inline]
    pub fn handle_force(&self, s: &TweezerSample) -> [f64; 2] {
        [
            -self.cfg.force_scale * s.force_n[0],
            -self.cfg.force_scale * s.force_n[1],
        ]
    }

    fn safe(&mut self, v: f64, max: f64) -> f64 {
        if !v.is_finite() {
            self.counters.nonfinite += 1;
            0.0
        } else if v.abs() > max {
            self.counters.clamped += 1;
            v.signum() * max
        } else {
            v
        }
    }

    /// Split a handle force (N) into actuator commands for the current mode,
    /// clamped to the limits, never non-finite.
    #[inline]
    pub fn actuate(&mut self, force_n: [f64; 2]) -> ActuatorFrame {
        let fx = if force_n[0].is_finite() {
            force_n[0]
        } else {
            0.0
        };
        let fy = if force_n[1].is_finite() {
            force_n[1]
        } else {
            0.0
        };
        let (px, _) = self.p_x.split(fx);
        let (dl, dh) = self.dual.split(fx);
        let (py, _) = self.p_y.split(fy);
        let (lx, hx) = match self.mode {
            CouplingMode::Pantograph => (px, 0.0),
            CouplingMode::Dual => (dl, dh),
        };
        // Common case: all within the limits (hence finite): `safe` would
        // return each unchanged.
        if lx.abs() <= self.force_max && py.abs() <= self.force_max && hx.abs() <= self.drive_max {
            return ActuatorFrame {
                force_n: [lx, py],
                haptuator_v: hx,
            };
        }
        self.safe_frame(lx, py, hx)
    }

    /// [`Self::actuate`]'s clamps when some output is out of range or
    /// non-finite (counted).
    #[cold]
    #[inline(never)]
    fn safe_frame(&mut self, lx: f64, py: f64, hx: f64) -> ActuatorFrame {
        ActuatorFrame {
            force_n: [self.safe(lx, self.force_max), self.safe(py, self.force_max)],
            haptuator_v: self.safe(hx, self.drive_max),
        }
    }

    /// One coupling sample: handle → trap → tweezer → force → actuators.
    #[inline]
    pub fn step<T: Tweezer>(
        &mut self,
        sensors: &SensorFrame,
        tweezer: &mut T,
    ) -> (ActuatorFrame, TweezerSample) {
        let trap = self.trap_target(sensors.handle_m);
        let s = tweezer.step(trap);
        let f = self.handle_force(&s);
        (self.actuate(f), s)
    }
}

/// A rig, a tweezer and the coupling, run sample by sample (block size 1:
/// the force computed from the sensors of sample n is applied at n + 1).
/// Every command passes through the [`SafetyLayer`] (`crate::safety`): hard
/// and slew limits, ramp-on, handle-speed trip, watchdog (a block that lost
/// frames, skipped samples or ended more than one sample period late counts
/// as a missed deadline), emergency stop ([`ClosedLoop::estop`] or an
/// [`EStopHandle`](crate::safety::EStopHandle) from any thread).
#[derive(Debug)]
pub struct ClosedLoop<R: Rig, T: Tweezer, S: ForceSplitter = Chain> {
    /// The rig.
    pub rig: R,
    /// The tweezer.
    pub tweezer: T,
    /// The coupling.
    pub coupling: Coupling<S>,
    /// The safety layer every command passes through.
    pub safety: SafetyLayer,
    sensors: SensorFrame,
    missed: bool,
}

impl<R: Rig, T: Tweezer, S: ForceSplitter> ClosedLoop<R, T, S> {
    /// Assemble with the default `[safety]` settings and the rig's own
    /// limits and rate ([`SafetyLayer::for_rig`]); starts the rig and arms
    /// the layer (forces come on once the command is small, through the
    /// ramp).
    pub fn new(rig: R, tweezer: T, coupling: Coupling<S>) -> Result<Self, RigError> {
        let safety = SafetyLayer::for_rig(rig.identity(), &SafetyConfig::default())?;
        Self::with_safety(rig, tweezer, coupling, safety)
    }

    /// Assemble with an explicit safety layer (e.g.
    /// [`SafetyLayer::from_config`] for a rig file's `[safety]`); starts the
    /// rig and arms the layer when its `arm_on_start` is set.
    pub fn with_safety(
        mut rig: R,
        tweezer: T,
        coupling: Coupling<S>,
        mut safety: SafetyLayer,
    ) -> Result<Self, RigError> {
        rig.start()?;
        if safety.arm_on_start() {
            safety.arm()?;
        }
        Ok(Self {
            rig,
            tweezer,
            coupling,
            safety,
            sensors: SensorFrame::default(),
            missed: false,
        })
    }

    /// Latest sensor frame.
    pub fn sensors(&self) -> &SensorFrame {
        &self.sensors
    }

    /// Safety state, trip and counters.
    pub fn safety_status(&self) -> SafetyStatus {
        self.safety.status()
    }

    /// Emergency stop: zero output from the next sample, latched until
    /// `safety.reset()` and `safety.arm()`.
    pub fn estop(&mut self) {
        self.safety.estop();
    }

    /// Advance one sample; returns the command sent and the tweezer sample.
    #[inline]
    pub fn step(&mut self) -> Result<(ActuatorFrame, TweezerSample), RigError> {
        let (cmd, s) = self.coupling.step(&self.sensors, &mut self.tweezer);
        let cmd = self.safety.apply(cmd, &self.sensors, self.missed);
        let report = match self.rig.process_frame(&cmd, &mut self.sensors) {
            Ok(r) => r,
            Err(e) => {
                self.safety.fault(TripReason::RigError);
                return Err(e);
            }
        };
        // `lag_s > 0` first: the same test (f_s > 0 is finite), but a
        // constant zero lag (batch rigs) then folds away.
        self.missed = report.lost_frames > 0
            || report.skipped_samples > 0
            || (report.lag_s > 0.0 && report.lag_s * self.safety.sample_rate_hz() > 1.0);
        Ok((cmd, s))
    }
}
