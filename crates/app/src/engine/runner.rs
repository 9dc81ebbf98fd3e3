//! The engine's loop body: one block per call (see the module docs of
//! [`crate::engine`]). No allocation, freeing or locking after construction.

use super::driver::{BlockCtx, BlockDriver, EngineLoop, FreeExploration, Publisher};
use super::pacing::{BlockTiming, Pacer};
use super::splitter::{SwapPort, SwappableChain};
use super::{
    Command, Condition, EngineError, EngineEvent, EngineOptions, Garbage, Health, TelemetrySample,
    flags,
};
use kilotouch_dsp::chain::Chain;
use kilotouch_rig::coupling::{Coupling, LoopChain};
use kilotouch_rig::device::Clock;
use kilotouch_rig::device::RigSpec;
use kilotouch_rig::error::RigError;
use kilotouch_rig::haptic_loop::{Clearance, HapticLoop, MAX_BLOCK};
use kilotouch_rig::safety::{SafetyLayer, SafetyState, TripReason};
use kilotouch_rig::{AnyRig, AnyTweezer};
use kilotouch_rig::{Rig, RigConfig, Tweezer};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

/// State shared lock-free between the handle and the engine.
#[derive(Debug, Default)]
pub(crate) struct Shared {
    /// Emergency stops requested so far (the GUI increments; never blocks).
    pub estop_count: AtomicU64,
    /// Ask the engine thread to end.
    pub shutdown: AtomicBool,
    /// The Lab Streaming Layer tap's switches and counters.
    #[cfg(feature = "lsl")]
    pub lsl: Arc<crate::lsl::LslShared>,
}

/// The loop delay of `rig` and `tweezer` for blocks of `block_len`
/// samples, samples: the simulated loop's one sample, or when either device
/// is live and the loop exchanges blocks, the rig's block and command lead
/// ([`Rig::loop_delay_samples`]; the block on the simulated rig) plus the
/// tweezer link's command lead ([`Tweezer::loop_delay_samples`]).
pub fn loop_delay_samples(rig: &AnyRig, tweezer: &AnyTweezer, block_len: usize) -> u32 {
    let rig_delay = if rig.is_live() {
        rig.loop_delay_samples(block_len)
    } else if tweezer.is_live() {
        u32::try_from(block_len.max(1)).unwrap_or(u32::MAX)
    } else {
        1
    };
    rig_delay.saturating_add(tweezer.loop_delay_samples(block_len))
}

/// [`loop_delay_samples`] beyond the one sample of the simulated loop at
/// `fs` Hz, s: what the stability analysis adds.
pub fn extra_latency_s(rig: &AnyRig, tweezer: &AnyTweezer, block_len: usize, fs: f64) -> f64 {
    f64::from(loop_delay_samples(rig, tweezer, block_len).saturating_sub(1)) / fs
}

/// Idle period while the rig is stopped, s.
const IDLE_SLEEP_S: f64 = 5e-3;

/// The engine's state and loop body; [`EngineCore::run_block`] runs one
/// block. Run it on a thread ([`super::EngineHandle::spawn`]) or step it
/// directly in tests.
#[derive(Debug)]
pub struct EngineCore<C: Clock> {
    lp: EngineLoop,
    swap_port: SwapPort,
    pacer: Pacer<C>,
    driver: Box<dyn BlockDriver>,
    commands: rtrb::Consumer<Command>,
    out: Publisher,
    events: rtrb::Producer<EngineEvent>,
    shared: Arc<Shared>,
    opts: EngineOptions,
    fs: f64,
    condition: Condition,
    running: bool,
    faulted: bool,
    stopped: bool,
    gui_hand: [f64; 2],
    estop_seen: u64,
    events_dropped: u64,
    blocks: u64,
    window_start: Duration,
    window_busy_s: f64,
    window_worst_s: f64,
    idle_ticks: u64,
    /// Configuration the loop was built from (sample rate = the rig's).
    cfg: RigConfig,
    /// Live rig: block exchange (module docs of [`crate::engine`]).
    live: bool,
    /// Live: time spent waiting for the device in this block, s (not load).
    wait_s: f64,
    /// Hand smoothing of free exploration, per sample.
    hand_alpha: f64,
    /// The chain the loop was armed with at construction.
    chain: LoopChain,
    /// The loop's delay beyond one sample, s (the clearance includes it).
    latency_s: f64,
    /// The engine thread runs `SCHED_FIFO`.
    realtime: bool,
    /// How the last block kept its deadline (drivers see it in the next).
    prev_block: BlockTiming,
}

impl<C: Clock> EngineCore<C> {
    /// Build the loop for `cfg` (called by [`super::engine_pair`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        cfg: &RigConfig,
        rig: AnyRig,
        tweezer: Option<AnyTweezer>,
        opts: EngineOptions,
        clock: C,
        commands: rtrb::Consumer<Command>,
        telemetry: rtrb::Producer<TelemetrySample>,
        events: rtrb::Producer<EngineEvent>,
        shared: Arc<Shared>,
    ) -> Result<Self, EngineError> {
        if !(1..=MAX_BLOCK).contains(&opts.block_len) {
            return Err(EngineError::Option {
                name: "block_len",
                reason: "must be 1–64 samples",
            });
        }
        for (name, v) in [
            ("tolerance_s", opts.tolerance_s),
            ("max_lag_s", opts.max_lag_s),
            ("ramp_s", opts.ramp_s),
            ("hand_smoothing_s", opts.hand_smoothing_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(EngineError::Option {
                    name,
                    reason: "must be finite and ≥ 0",
                });
            }
        }
        // The loop runs at the rig's rate (a live device announces its own).
        let mut cfg = cfg.clone();
        cfg.rig.sample_rate_hz = rig.identity().sample_rate_hz;
        cfg.safety.ramp_time_s = opts.ramp_s;
        let cfg = &cfg;
        let fs = cfg.rig.sample_rate_hz;
        let tweezer = match tweezer {
            Some(t) => t,
            None => AnyTweezer::sim(cfg, fs)?,
        };
        let rate = kilotouch_rig::Tweezer::sample_rate_hz(&tweezer);
        if rate != fs {
            return Err(EngineError::Rig(RigError::Device(format!(
                "the tweezer runs at {rate} Hz, the rig at {fs} Hz: both must stream at the same rate"
            ))));
        }
        let live = rig.is_live() || tweezer.is_live();
        // The loop is armed only if its margins meet the rig file's minimum
        // with the loop's own delay: one sample on the simulated loop, the
        // block and the links' command leads on a live one.
        let latency_s = extra_latency_s(&rig, &tweezer, opts.block_len, fs);
        let chain = LoopChain::as_designed(cfg)?;
        let clearance = Clearance::check_with_latency(cfg, &chain, latency_s)?;
        let (splitter, swap_port) = SwappableChain::new(Chain::new(&chain.coefficients));
        let coupling = Coupling::with_splitter(cfg, splitter)?;
        let condition = coupling.condition();
        let safety = SafetyLayer::for_rig(rig.identity(), &cfg.safety)?;
        let lp = HapticLoop::new(rig, tweezer, coupling, safety, clearance)?;
        let trap0 = lp.coupling.mapping().rest_trap_m();
        let hand_alpha = if opts.hand_smoothing_s > 0.0 {
            1.0 - (-1.0 / (fs * opts.hand_smoothing_s)).exp()
        } else {
            1.0
        };
        let period = opts.block_len as f64 / fs;
        let mut pacer = Pacer::new(clock, period, opts.tolerance_s, opts.max_lag_s, opts.paced);
        if live {
            pacer.set_device_paced();
        }
        let window_start = pacer.clock().now();
        let mut core = Self {
            lp,
            swap_port,
            pacer,
            driver: Box::new(FreeExploration::new(hand_alpha)),
            commands,
            out: Publisher::new(telemetry, trap0),
            events,
            shared,
            opts,
            fs,
            condition,
            running: true,
            faulted: false,
            stopped: false,
            gui_hand: [0.0; 2],
            estop_seen: 0,
            events_dropped: 0,
            blocks: 0,
            window_start,
            window_busy_s: 0.0,
            window_worst_s: f64::NEG_INFINITY,
            idle_ticks: 0,
            cfg: cfg.clone(),
            live,
            wait_s: 0.0,
            hand_alpha,
            latency_s,
            chain,
            realtime: false,
            prev_block: BlockTiming::default(),
        };
        #[cfg(feature = "lsl")]
        {
            core.out.lsl = Some(crate::lsl::LslTap::new(core.shared.lsl.clone()));
        }
        if !opts.start {
            core.stop_rig();
        }
        Ok(core)
    }

    /// The closed loop (inspection in tests).
    pub fn closed_loop(&self) -> &EngineLoop {
        &self.lp
    }

    /// Current condition.
    pub fn condition(&self) -> Condition {
        self.condition
    }

    /// Exchanging frames?
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// Call first on the engine's own thread: it runs real-time while
    /// paced ([`EngineOptions::realtime`]).
    pub fn thread_started(&mut self) {
        self.schedule();
    }

    /// Real-time while the thread sleeps or blocks between blocks (paced
    /// by the wall clock or a live device), normal while it runs without
    /// pause.
    fn schedule(&mut self) {
        let want = self.opts.realtime && (self.live || self.pacer.sleeps());
        if want && !self.realtime {
            self.realtime = kilotouch_rig::realtime::promote_current_thread().is_realtime();
        } else if !want && self.realtime {
            kilotouch_rig::realtime::demote_current_thread();
            self.realtime = false;
        }
    }

    /// The chain the loop was armed with at construction (the rig file's
    /// as-designed chain).
    pub fn initial_chain(&self) -> &LoopChain {
        &self.chain
    }

    /// The driver free exploration uses (the engine's hand smoothing).
    pub fn free_exploration(&self) -> FreeExploration {
        FreeExploration::new(self.hand_alpha)
    }

    /// The loop's delay beyond the simulated loop's one sample, s: the
    /// block and the link's command lead of a live rig (0 on the simulated
    /// rig). The clearance the loop was armed with includes it.
    pub fn latency_s(&self) -> f64 {
        self.latency_s
    }

    /// A live rig (block exchange, the hand is the real handle)?
    pub fn is_live(&self) -> bool {
        self.live
    }

    /// The configuration the loop runs (its sample rate is the rig's).
    pub fn config(&self) -> &RigConfig {
        &self.cfg
    }

    /// Rig sample rate, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    /// Has a shutdown been requested?
    pub fn is_shut_down(&self) -> bool {
        self.stopped
    }

    fn push_event(&mut self, e: EngineEvent) {
        // Garbage must never be dropped here (that would free on this
        // thread): commands producing garbage wait until there is room.
        if let Err(rtrb::PushError::Full(e)) = self.events.push(e) {
            self.events_dropped += 1;
            if let EngineEvent::Garbage(_) = e {
                // Unreachable by construction; leak rather than free here.
                std::mem::forget(e);
            }
        }
    }

    /// Push a droppable event only if room remains for garbage.
    fn push_notice(&mut self, e: EngineEvent) {
        if self.events.slots() > 4 {
            self.push_event(e);
        } else {
            self.events_dropped += 1;
        }
    }

    fn check_estop(&mut self) {
        let c = self.shared.estop_count.load(Ordering::Acquire);
        if c != self.estop_seen {
            self.estop_seen = c;
            self.lp.safety.estop();
        }
    }

    fn stop_rig(&mut self) {
        let _ = self.lp.rig.stop();
        self.lp.tweezer.stop();
        self.lp.safety.disarm();
        self.running = false;
    }

    /// Start the rig, then a live tweezer (its link reopened if it was
    /// lost). Blocks for the devices' answers: only while the loop is
    /// stopped.
    fn start_devices(&mut self) -> Result<(), RigError> {
        self.lp.rig.start()?;
        if let Err(e) = self.lp.tweezer.start() {
            let _ = self.lp.rig.stop();
            return Err(RigError::Disconnected(format!(
                "the tweezer did not start: {e}"
            )));
        }
        Ok(())
    }

    fn handle_commands(&mut self) {
        loop {
            let needs_room = match self.commands.peek() {
                Ok(Command::SetTweezer(_)) | Ok(Command::SetDriver(_)) => 2,
                Ok(Command::ApplyChain(_)) if self.driver.owns_loop() => 2,
                Ok(Command::ApplyChain(_)) => {
                    if self.swap_port.to_chain.is_full() {
                        return;
                    }
                    0
                }
                Ok(_) => 0,
                Err(_) => return,
            };
            if self.events.slots() < needs_room {
                return;
            }
            let Ok(cmd) = self.commands.pop() else {
                return;
            };
            self.apply(cmd);
        }
    }

    fn apply(&mut self, cmd: Command) {
        if self.driver.owns_loop()
            && matches!(
                cmd,
                Command::SetCondition(_)
                    | Command::SetTweezer(_)
                    | Command::SetTrapCalibration(_)
                    | Command::ApplyChain(_)
                    | Command::ResetBead
            )
        {
            self.push_notice(EngineEvent::Refused(
                "a study sitting is running: the condition, the scene and the calibrations \
                 are the sitting's until it ends",
            ));
            if let Command::SetTweezer(t) = cmd {
                self.push_event(EngineEvent::Garbage(Garbage::Tweezer(t)));
            } else if let Command::ApplyChain(c) = cmd {
                self.push_event(EngineEvent::Garbage(Garbage::Chain(c)));
            }
            return;
        }
        match cmd {
            Command::SetHand(h) => {
                if h.iter().all(|v| v.is_finite()) {
                    self.gui_hand = h;
                }
            }
            Command::SetCondition(c) => {
                self.condition = c;
                self.lp.coupling.set_condition(c);
            }
            Command::SetTweezer(mut t) => {
                let calibration = self.lp.tweezer.calibration();
                if let AnyTweezer::Sim(cur) = &mut self.lp.tweezer {
                    let bead = cur.bead();
                    t.reset(self.out.last_trap);
                    t.set_bead(bead);
                    // Validated when it was applied.
                    let _ = t.set_calibration(calibration);
                    std::mem::swap(&mut t, cur);
                } else {
                    self.push_notice(EngineEvent::Refused(
                        "the obstacles of a live tweezer are its own: they cannot be replaced \
                         from the Explore page",
                    ));
                }
                self.push_event(EngineEvent::Garbage(Garbage::Tweezer(t)));
            }
            Command::SetTrapCalibration(c) => {
                // Validated by the handle; an invalid one keeps the old.
                let _ = self.lp.tweezer.set_calibration(c);
            }
            Command::ApplyChain(swap) => {
                // Room checked in handle_commands.
                if let Err(rtrb::PushError::Full(b)) = self.swap_port.to_chain.push(swap) {
                    std::mem::forget(b);
                }
            }
            Command::ResetEmergencyStop { ack } => {
                if ack == self.shared.estop_count.load(Ordering::Acquire)
                    && self.lp.safety.state() == SafetyState::EStop
                {
                    self.estop_seen = ack;
                    // Forces come back through arming and the ramp.
                    self.lp.safety.reset();
                    if self.running {
                        let _ = self.lp.safety.arm();
                    }
                }
            }
            Command::ResetBead => self.lp.tweezer.reset(self.out.last_trap),
            Command::Start => {
                if !self.running {
                    match self.start_devices() {
                        Ok(()) => self.resume(),
                        Err(e) => self.push_notice(EngineEvent::RigError(e)),
                    }
                }
            }
            Command::Reconnect(spec) => self.reconnect(spec.as_deref()),
            Command::Stop => self.stop_rig(),
            Command::SetDriver(mut d) => {
                std::mem::swap(&mut d, &mut self.driver);
                d.detach(&mut self.lp);
                self.push_event(EngineEvent::Garbage(Garbage::Driver(d)));
            }
            Command::SetPaced(on) => {
                if !self.live {
                    self.pacer.set_paced(on);
                    self.schedule();
                }
            }
            Command::Shutdown => self.stopped = true,
        }
    }

    /// Back to running after `start` succeeded: a trip caused by the rig
    /// error is cleared and the layer re-arms (forces return only once the
    /// command is small, through the ramp). A latched emergency stop stays
    /// latched until the user resets it.
    fn resume(&mut self) {
        if self.faulted && self.lp.safety.state() == SafetyState::Fault {
            self.lp.safety.reset();
        }
        let _ = self.lp.safety.arm();
        self.running = true;
        self.faulted = false;
        self.pacer.reanchor();
    }

    /// Reopen the device (or open `spec` instead) and resume. Runs on the
    /// engine thread with the loop stopped: it may block for the device's
    /// handshake and allocates (a new device, the safety layer for its
    /// limits), which is acceptable outside the running loop.
    fn reconnect(&mut self, spec: Option<&RigSpec>) {
        self.stop_rig();
        let cfg = self.cfg.clone();
        if let Err(e) = self.lp.rig.reconnect(spec, &cfg) {
            self.faulted = true;
            self.push_notice(EngineEvent::RigError(e));
            return;
        }
        let id = self.lp.rig.identity().clone();
        if id.sample_rate_hz != self.fs {
            let _ = self.lp.rig.stop();
            self.faulted = true;
            self.push_notice(EngineEvent::RigError(RigError::InvalidInput(format!(
                "the rig now runs at {} Hz, the engine at {} Hz: disconnect and connect instead",
                id.sample_rate_hz, self.fs
            ))));
            return;
        }
        // The new device's loop delay (its link's round trip sizes the
        // command lead) must be within what the stability clearance was
        // made for; a longer one needs a new connection, which checks the
        // margins again.
        let latency = extra_latency_s(&self.lp.rig, &self.lp.tweezer, self.opts.block_len, self.fs);
        if latency > self.latency_s + 0.5 / self.fs {
            let _ = self.lp.rig.stop();
            self.faulted = true;
            self.push_notice(EngineEvent::RigError(RigError::LoopNotSafe(format!(
                "the reconnected device's loop adds {:.2} ms of delay, the stability check was made \
                 for {:.2} ms: disconnect and connect again so the margins are checked with it",
                latency * 1e3,
                self.latency_s * 1e3
            ))));
            return;
        }
        match SafetyLayer::for_rig(&id, &self.cfg.safety) {
            Ok(mut layer) => {
                if layer.arm_on_start() {
                    let _ = layer.arm();
                }
                // The old layer's state is dropped here, on the engine
                // thread, while the loop is stopped (no real-time deadline).
                self.lp.safety = layer;
            }
            Err(e) => {
                self.faulted = true;
                self.push_notice(EngineEvent::RigError(e));
                return;
            }
        }
        match self.start_devices() {
            Ok(()) => {
                self.faulted = true; // clears the rig-error trip in resume()
                self.resume();
                self.push_notice(EngineEvent::Reconnected(Box::new(id)));
            }
            Err(e) => {
                self.faulted = true;
                self.push_notice(EngineEvent::RigError(e));
            }
        }
    }

    /// The rig failed: outputs zero (the rig's own stop path commands zero
    /// where the device still listens), loop stopped, error reported.
    fn rig_failed(&mut self, e: RigError) {
        if !self.lp.safety.state().latched() {
            self.lp.safety.fault(TripReason::RigError);
        }
        self.stop_rig();
        self.faulted = true;
        self.push_notice(EngineEvent::RigError(e));
    }

    fn health(&self, loop_rate_hz: f64, load: f64, worst: f64) -> Health {
        let st = self.lp.safety.status();
        Health {
            seq: self.lp.rig.next_seq(),
            loop_rate_hz,
            load,
            deadline_misses: self.pacer.misses,
            overruns: self.pacer.overruns,
            worst_lateness_s: worst,
            worst_lateness_total_s: self.pacer.worst_lateness_s,
            blocks: self.blocks,
            samples: self.out.samples,
            telemetry_dropped: self.out.dropped,
            events_dropped: self.events_dropped,
            safety: st.state,
            last_trip: st.last_trip,
            condition: self.condition,
            running: self.running,
            rig: self.lp.rig.status(),
            coupling: self.lp.coupling.counters(),
            estop_zeroed_frames: st.counters.latched_zeroed,
            trapped: self.out.trapped,
            trap_calibration: self.lp.tweezer.calibration(),
            realtime: self.realtime,
        }
    }

    fn emit_health(&mut self) {
        let now = self.pacer.clock().now();
        let wall = now.saturating_sub(self.window_start).as_secs_f64();
        let (rate, load) = if wall > 0.0 {
            (
                self.out.window_samples as f64 / wall,
                self.window_busy_s / wall,
            )
        } else {
            (0.0, 0.0)
        };
        let worst = if self.window_worst_s.is_finite() {
            self.window_worst_s
        } else {
            0.0
        };
        let h = self.health(rate, load, worst);
        self.push_notice(EngineEvent::Health(h));
        self.window_start = now;
        self.out.window_samples = 0;
        self.window_busy_s = 0.0;
        self.window_worst_s = f64::NEG_INFINITY;
    }

    fn forward_swaps_and_faults(&mut self) {
        while self.events.slots() >= 2 {
            let Ok(done) = self.swap_port.from_chain.pop() else {
                break;
            };
            self.push_event(EngineEvent::ChainSwapped(done.outcome));
            self.push_event(EngineEvent::Garbage(Garbage::Chain(done.garbage)));
        }
        while let Some(f) = self.lp.rig.pop_fault() {
            self.push_notice(EngineEvent::RigFault(f));
        }
    }

    /// The driver runs one block (module docs of [`crate::engine`]).
    fn run_driver(&mut self, n: usize) {
        let latched = self.lp.safety.state().latched();
        #[cfg(feature = "lsl")]
        if self.out.estop_flag == 0 && self.lp.safety.state() == SafetyState::EStop {
            self.out.marker(crate::lsl::Marker::EmergencyStop);
        }
        self.out.estop_flag = if self.lp.safety.state() == SafetyState::EStop {
            flags::ESTOP
        } else {
            0
        };
        let mut ctx = BlockCtx {
            lp: &mut self.lp,
            n: n.min(MAX_BLOCK),
            live: self.live,
            gui_hand: self.gui_hand,
            latched,
            out: &mut self.out,
            clock: self.pacer.clock(),
            wait_s: 0.0,
            prev_block: self.prev_block,
        };
        let res = self.driver.run_block(&mut ctx);
        // Load counts computation only, not the wait for a live device.
        self.wait_s = ctx.wait_s;
        match res {
            Ok(0) if !self.live && !self.pacer.sleeps() => {
                // Nothing to run (a sitting between trials) and nothing to
                // pace: yield instead of spinning.
                let now = self.pacer.clock().now();
                self.pacer
                    .clock()
                    .sleep_until(now + Duration::from_secs_f64(IDLE_SLEEP_S / 10.0));
                self.pacer.reanchor();
            }
            Ok(_) => {}
            Err(e) => self.rig_failed(e),
        }
    }

    /// Run one block: commands, emergency stop, `block_len` samples,
    /// telemetry, pacing. Returns `false` once shut down.
    pub fn run_block(&mut self) -> bool {
        if self.stopped || self.shared.shutdown.load(Ordering::Acquire) {
            self.stop_rig();
            self.stopped = true;
            return false;
        }
        self.check_estop();
        self.handle_commands();
        self.check_estop();
        if !self.running {
            let now = self.pacer.clock().now();
            self.pacer
                .clock()
                .sleep_until(now + Duration::from_secs_f64(IDLE_SLEEP_S));
            self.idle_ticks += 1;
            let every = ((self.opts.health_interval_blocks as f64 * self.opts.block_len as f64
                / self.fs
                / IDLE_SLEEP_S)
                .round() as u64)
                .max(1);
            if self.idle_ticks.is_multiple_of(every) {
                self.emit_health();
            }
            return !self.stopped;
        }
        self.pacer.begin_block();
        self.run_driver(self.opts.block_len);
        self.forward_swaps_and_faults();
        let timing = self.pacer.end_block();
        self.prev_block = timing;
        self.blocks += 1;
        // Load counts computation only, not the wait for a live device.
        self.window_busy_s += (timing.busy_s - self.wait_s).max(0.0);
        self.wait_s = 0.0;
        self.window_worst_s = self.window_worst_s.max(timing.lateness_s);
        if self
            .blocks
            .is_multiple_of(self.opts.health_interval_blocks.max(1))
        {
            self.emit_health();
        }
        !self.stopped
    }
}
