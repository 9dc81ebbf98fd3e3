//! The closed loop: rig + tweezer + coupling (with its chain) + safety layer,
//! the one type the Explore engine, the study's stations, `kilotouch sim
//! press` and the benchmarks drive.
//!
//! # One sample ([`HapticLoop::control`])
//!
//! ```text
//!  sensors[n−1] ──▶ trap = mapping(handle) ──▶ tweezer.step ──▶ image (+ wall damper)
//!                                                                   │
//!  rig.process ◀── safety.apply ◀── condition routing / chain (V, P, D) ◀──┘
//! ```
//!
//! The handle position read at the end of sample n − 1 sets the trap; the
//! command computed from it is applied during sample n (block size 1: one
//! sample of loop delay, [`HapticLoop::step`]). Live rigs exchange blocks
//! ([`HapticLoop::step_block`]): the commands of block b are computed, one
//! sample at a time through the same [`HapticLoop::control`], from the
//! sensor frames of block b − 1, so the loop delay is the block length.
//!
//! # Arming
//!
//! A loop is armed only with a [`Clearance`]: the stability analysis
//! ([`crate::stability`]) of its rig file and chain met the configured
//! minimum margins, or the caller overrode it explicitly (tests that study
//! unstable settings, `sim press --allow-unstable`). A live loop's delay
//! beyond the simulated one sample (block exchange, the link's command
//! lead) is analysed with [`Clearance::check_with_latency`]. The safety
//! layer then brings forces on through its ramp.

use crate::condition::Condition;
use crate::config::RigConfig;
use crate::coupling::{ChainSource, Coupling, ForceSplitter, LoopChain, Rendered};
use crate::device::{ActuatorFrame, BlockReport, Rig, SensorFrame};
use crate::error::RigError;
use crate::safety::{SafetyLayer, SafetyStatus, TripReason};
use crate::sim::SimRig;
use crate::stability::StabilityReport;
use crate::tweezer::{SimTweezer, Tweezer, TweezerParams, TweezerSample};
use kilotouch_dsp::chain::Chain;

/// Largest block a live exchange computes at once, samples.
pub const MAX_BLOCK: usize = 64;

/// Permission to arm a loop (module docs).
#[derive(Debug, Clone)]
pub struct Clearance {
    report: Option<Box<StabilityReport>>,
    source: ChainSource,
    latency_s: f64,
}

impl Clearance {
    /// Analyse `cfg` with `chain` as the simulated loop runs it (one
    /// sample of loop delay); refuse (naming the failing margin and the
    /// largest safe force scale) when a margin is below the minimum.
    /// [`Self::check_with_latency`] at 0 s.
    ///
    /// # Errors
    /// [`RigError::LoopNotSafe`]; analysis failures.
    pub fn check(cfg: &RigConfig, chain: &LoopChain) -> Result<Self, RigError> {
        Self::check_with_latency(cfg, chain, 0.0)
    }

    /// Analyse `cfg` with `chain` and an extra loop delay of `latency_s`
    /// seconds on top of the simulated loop's one sample (a live loop:
    /// block exchange and the link's command lead;
    /// [`crate::stability::analyse_with_latency`], rounded up to whole
    /// samples); refuse when a margin is below the minimum at that delay,
    /// naming the failing margin, the delay in ms and samples, and the
    /// largest safe force scale at that delay.
    ///
    /// # Errors
    /// [`RigError::LoopNotSafe`]; [`RigError::InvalidParameter`] for a
    /// latency outside [0, [`crate::stability::MAX_LATENCY_S`]]; analysis
    /// failures.
    pub fn check_with_latency(
        cfg: &RigConfig,
        chain: &LoopChain,
        latency_s: f64,
    ) -> Result<Self, RigError> {
        let report = crate::stability::analyse_with_latency(cfg, &chain.coefficients, latency_s)?;
        if let Some(why) = report.refusal() {
            return Err(RigError::LoopNotSafe(format!(
                "{why} (chain: {})",
                chain.source.describe()
            )));
        }
        Ok(Self {
            report: Some(Box::new(report)),
            source: chain.source.clone(),
            latency_s,
        })
    }

    /// Arm without the analysis. For tests and tools that study unsafe
    /// settings on the simulated rig on purpose; never for a live rig.
    pub fn overridden(source: ChainSource) -> Self {
        Self {
            report: None,
            source,
            latency_s: 0.0,
        }
    }

    /// The extra loop delay the analysis was run for, s (0 for
    /// [`Self::check`] and [`Self::overridden`]).
    pub fn latency_s(&self) -> f64 {
        self.latency_s
    }

    /// The analysis, when one was run.
    pub fn report(&self) -> Option<&StabilityReport> {
        self.report.as_deref()
    }

    /// The chain's source.
    pub fn source(&self) -> &ChainSource {
        &self.source
    }
}

/// One sample of the loop.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopSample {
    /// The sensor frame read at the end of the sample (handle position m,
    /// fingertip acceleration m/s²).
    pub sensors: SensorFrame,
    /// The tweezer's output of the sample.
    pub tweezer: TweezerSample,
    /// The coupling's rendering (image, damper, command before safety).
    pub rendered: Rendered,
    /// The command sent to the rig (after the safety layer).
    pub command: ActuatorFrame,
}

/// The closed loop (module docs).
#[derive(Debug)]
pub struct HapticLoop<R: Rig, T: Tweezer, S: ForceSplitter = Chain> {
    /// The rig.
    pub rig: R,
    /// The tweezer.
    pub tweezer: T,
    /// The coupling.
    pub coupling: Coupling<S>,
    /// The safety layer every command passes through.
    pub safety: SafetyLayer,
    clearance: Clearance,
    sensors: SensorFrame,
    missed: bool,
    last: LoopSample,
    block_in: [SensorFrame; MAX_BLOCK],
    block: [LoopSample; MAX_BLOCK],
    block_cmd: [ActuatorFrame; MAX_BLOCK],
    block_out: [SensorFrame; MAX_BLOCK],
    block_trap: [[f64; 2]; MAX_BLOCK],
    block_tw: [TweezerSample; MAX_BLOCK],
    block_len: usize,
}

/// Where the handle is when a trial begins ([`HapticLoop::begin_trial`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrialStart {
    /// A fresh simulated rig: the handle rests at its origin.
    Fresh,
    /// A live rig: the handle is wherever the participant left it; the hand
    /// mapping is re-centred there, so the trap starts at rest.
    AtHandle,
}

/// The simulated loop.
pub type SimLoop = HapticLoop<SimRig, SimTweezer, Chain>;

impl SimLoop {
    /// The simulated loop of a rig file (batch-paced [`SimRig`], the rig
    /// file's tweezer and `[safety]`) running `chain`, armed by `clearance`.
    ///
    /// # Errors
    /// Invalid configuration.
    pub fn simulated(
        cfg: &RigConfig,
        chain: &LoopChain,
        clearance: Clearance,
    ) -> Result<Self, RigError> {
        let fs = cfg.rig.sample_rate_hz;
        Self::new(
            SimRig::new(cfg)?,
            SimTweezer::new(TweezerParams::from_config(&cfg.tweezer), fs)?,
            Coupling::with_chain(cfg, &chain.coefficients)?,
            SafetyLayer::from_config(cfg)?,
            clearance,
        )
    }
}

impl<R: Rig, T: Tweezer, S: ForceSplitter> HapticLoop<R, T, S> {
    /// Assemble: starts the rig, puts the bead in the trap at the rest
    /// position and arms the safety layer when its `arm_on_start` is set.
    ///
    /// # Errors
    /// The rig refuses to start.
    pub fn new(
        mut rig: R,
        mut tweezer: T,
        coupling: Coupling<S>,
        mut safety: SafetyLayer,
        clearance: Clearance,
    ) -> Result<Self, RigError> {
        rig.start()?;
        tweezer.reset(coupling.mapping().rest_trap_m());
        if safety.arm_on_start() {
            safety.arm()?;
        }
        Ok(Self {
            rig,
            tweezer,
            coupling,
            safety,
            clearance,
            sensors: SensorFrame::default(),
            missed: false,
            last: LoopSample::default(),
            block_in: [SensorFrame::default(); MAX_BLOCK],
            block: [LoopSample::default(); MAX_BLOCK],
            block_cmd: [ActuatorFrame::default(); MAX_BLOCK],
            block_out: [SensorFrame::default(); MAX_BLOCK],
            block_trap: [[0.0; 2]; MAX_BLOCK],
            block_tw: [TweezerSample::default(); MAX_BLOCK],
            block_len: 0,
        })
    }

    /// The clearance the loop was armed with.
    pub fn clearance(&self) -> &Clearance {
        &self.clearance
    }

    /// Replace the clearance (a new chain was swapped in after its own check).
    pub fn set_clearance(&mut self, c: Clearance) {
        self.clearance = c;
    }

    /// Latest sensor frame.
    pub fn sensors(&self) -> &SensorFrame {
        &self.sensors
    }

    /// The last sample of [`Self::step`].
    pub fn last(&self) -> &LoopSample {
        &self.last
    }

    /// Safety state, trip and counters.
    pub fn safety_status(&self) -> SafetyStatus {
        self.safety.status()
    }

    /// Current condition.
    pub fn condition(&self) -> Condition {
        self.coupling.condition()
    }

    /// Emergency stop: zero output from the next sample, latched until
    /// `safety.reset()` and `safety.arm()`.
    pub fn estop(&mut self) {
        self.safety.estop();
    }

    /// Start a trial: new rig and tweezer (fresh seeds), the bead in the
    /// trap at rest, filters cleared, `condition` at once, a fresh safety
    /// layer armed.
    ///
    /// # Errors
    /// The rig refuses to start; the safety layer refuses to arm.
    pub fn restart(
        &mut self,
        mut rig: R,
        mut tweezer: T,
        condition: Condition,
        mut safety: SafetyLayer,
    ) -> Result<(), RigError> {
        rig.start()?;
        safety.arm()?;
        self.rig = rig;
        self.begin_trial(
            Some(&mut tweezer),
            condition,
            &mut safety,
            TrialStart::Fresh,
        );
        Ok(())
    }

    /// Start a trial on the loop as it runs, without allocating or freeing
    /// (the engine): the trial's tweezer (`Some`: a fresh simulated one;
    /// `None`: the loop keeps its own, a live tweezer, which is reset) and
    /// its (armed) safety layer are swapped in — the old ones are left in
    /// the arguments, to be dropped off the real-time path — the condition
    /// switches at once, the filters are cleared and the bead sits in the
    /// trap at rest. `start` says where the handle is ([`TrialStart`]). The
    /// rig is not touched: a simulated rig is swapped by the caller
    /// beforehand ([`crate::AnyRig::swap_sim`]).
    pub fn begin_trial(
        &mut self,
        tweezer: Option<&mut T>,
        condition: Condition,
        safety: &mut SafetyLayer,
        start: TrialStart,
    ) {
        self.coupling.set_condition_now(condition);
        self.coupling.reset();
        match start {
            TrialStart::Fresh => {
                self.sensors = SensorFrame::default();
                self.block_in = [SensorFrame::default(); MAX_BLOCK];
            }
            TrialStart::AtHandle => self.coupling.set_handle_origin(self.sensors.handle_m),
        }
        let trap = self.coupling.trap_target(self.sensors.handle_m);
        match tweezer {
            Some(t) => {
                t.reset(trap);
                std::mem::swap(&mut self.tweezer, t);
            }
            None => self.tweezer.reset(trap),
        }
        std::mem::swap(&mut self.safety, safety);
        self.missed = false;
        self.block_len = 0;
    }

    /// The controller part of one sample: `sensors` (the frame the
    /// controller sees), whether the previous exchange missed its deadline.
    /// Returns the command to send (after the safety layer), the rendering
    /// and the tweezer sample. Allocates nothing, locks nothing, never
    /// panics; the command is finite.
    #[inline]
    pub fn control(
        &mut self,
        sensors: &SensorFrame,
        missed: bool,
    ) -> (ActuatorFrame, Rendered, TweezerSample) {
        let (rendered, s) = self.coupling.step(sensors, &mut self.tweezer);
        let cmd = self.safety.apply(rendered.command, sensors, missed);
        (cmd, rendered, s)
    }

    /// Advance one sample with a one-frame exchange (simulated rigs).
    ///
    /// # Errors
    /// A rig error (the safety layer trips first).
    #[inline]
    pub fn step(&mut self) -> Result<LoopSample, RigError> {
        self.advance()?;
        Ok(self.last)
    }

    /// [`Self::step`] without returning the sample (read it with
    /// [`Self::last`]): saves copying it out on hot paths.
    ///
    /// # Errors
    /// A rig error (the safety layer trips first).
    #[inline]
    pub fn advance(&mut self) -> Result<(), RigError> {
        let input = self.sensors;
        let (cmd, rendered, tw) = self.control(&input, self.missed);
        if let Some(k) = self.tweezer.link_error() {
            return Err(self.tweezer_failed(k));
        }
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
        self.last = LoopSample {
            sensors: self.sensors,
            tweezer: tw,
            rendered,
            command: cmd,
        };
        Ok(())
    }

    /// Advance `n` ≤ [`MAX_BLOCK`] samples with one block exchange (live
    /// rigs, module docs). The samples are in [`Self::block`].
    ///
    /// # Errors
    /// A rig error (the safety layer trips first).
    pub fn step_block(&mut self, n: usize) -> Result<BlockReport, RigError> {
        let n = n.min(MAX_BLOCK);
        // Trap set-points of the whole block first, then one tweezer
        // exchange, then the rendering: a live tweezer answers a block at
        // once; a simulated one steps sample by sample, so the result is
        // the same as `control` per sample.
        for i in 0..n {
            self.block_trap[i] = self.coupling.trap_target(self.block_in[i].handle_m);
        }
        self.tweezer
            .step_block(&self.block_trap[..n], &mut self.block_tw[..n]);
        if let Some(k) = self.tweezer.link_error() {
            return Err(self.tweezer_failed(k));
        }
        for i in 0..n {
            let sens = self.block_in[i];
            let tw = self.block_tw[i];
            let rendered = self.coupling.render(sens.handle_m, &tw);
            let cmd = self
                .safety
                .apply(rendered.command, &sens, self.missed && i == 0);
            self.block_cmd[i] = cmd;
            self.block[i] = LoopSample {
                sensors: SensorFrame::default(),
                tweezer: tw,
                rendered,
                command: cmd,
            };
        }
        let res = self
            .rig
            .process_block(&self.block_cmd[..n], &mut self.block_out[..n]);
        match res {
            Ok(r) => {
                let fs = self.safety.sample_rate_hz();
                self.missed = r.lost_frames > 0 || r.skipped_samples > 0 || r.lag_s * fs > n as f64;
                for i in 0..n {
                    self.block[i].sensors = self.block_out[i];
                }
                self.block_in[..n].copy_from_slice(&self.block_out[..n]);
                if let Some(s) = self.block_out[..n].last() {
                    self.sensors = *s;
                }
                if let Some(s) = self.block[..n].last() {
                    self.last = *s;
                }
                self.block_len = n;
                Ok(r)
            }
            Err(e) => {
                self.safety.fault(TripReason::RigError);
                self.block_len = 0;
                Err(e)
            }
        }
    }

    /// The tweezer link failed: the safety layer trips (outputs to zero)
    /// and the error names the tweezer, not an escape.
    #[cold]
    #[inline(never)]
    fn tweezer_failed(&mut self, k: crate::device::LinkErrorKind) -> RigError {
        self.safety.fault(TripReason::RigError);
        self.block_len = 0;
        RigError::Disconnected(match k {
            crate::device::LinkErrorKind::Disconnected => {
                "the tweezer link was lost (no answer from the tweezer, or its port closed); \
                 outputs are held at zero"
                    .into()
            }
            crate::device::LinkErrorKind::Watchdog => {
                "the tweezer's watchdog tripped (it waited too long for trap set-points); \
                 outputs are held at zero"
                    .into()
            }
            crate::device::LinkErrorKind::EmergencyStop => {
                "the tweezer's emergency stop was engaged; outputs are held at zero".into()
            }
        })
    }

    /// The samples of the last [`Self::step_block`].
    pub fn block(&self) -> &[LoopSample] {
        &self.block[..self.block_len]
    }
}
