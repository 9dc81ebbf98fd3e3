//! The GUI side of the engine: commands in, telemetry and events out.

use super::driver::FreeExploration;
use super::runner::{EngineCore, Shared};
use super::splitter::{ChainSwap, SwapOutcome};
use super::{
    BlockDriver, Command, Condition, EngineError, EngineEvent, EngineOptions, Health,
    TelemetrySample,
};
use kilotouch_rig::coupling::{ChainSource, LoopChain};
use kilotouch_rig::device::{Clock, RigIdentity, SystemClock};
use kilotouch_rig::device::{RigSpec, TweezerSpec};
use kilotouch_rig::haptic_loop::Clearance;
use kilotouch_rig::stability::StabilityReport;
use kilotouch_rig::tweezer::Obstacle;
use kilotouch_rig::tweezer::{AppliedTrap, DetectedTweezer, TrapCalibrationRecord};
use kilotouch_rig::{AnyRig, AnyTweezer};
use kilotouch_rig::{RigConfig, TweezerParams};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::thread::JoinHandle;

/// Capacity of the command and event queues.
const QUEUE: usize = 256;

/// Build an engine core and its handle without starting a thread (tests
/// step the core themselves; [`EngineHandle::spawn`] moves it to a thread).
pub fn engine_pair<C: Clock>(
    cfg: &RigConfig,
    opts: EngineOptions,
    clock: C,
) -> Result<(EngineCore<C>, EngineHandle), EngineError> {
    engine_pair_with_rig(cfg, AnyRig::sim(cfg)?, opts, clock)
}

/// [`engine_pair`] on a given rig (simulated or live, see
/// [`AnyRig::open`]) with the rig file's simulated tweezer.
pub fn engine_pair_with_rig<C: Clock>(
    cfg: &RigConfig,
    rig: AnyRig,
    opts: EngineOptions,
    clock: C,
) -> Result<(EngineCore<C>, EngineHandle), EngineError> {
    engine_pair_with_devices(cfg, rig, None, opts, clock)
}

/// [`engine_pair`] on a given rig and tweezer (`None`: the rig file's
/// simulated tweezer at the rig's rate; a live one from
/// [`AnyTweezer::open`]).
pub fn engine_pair_with_devices<C: Clock>(
    cfg: &RigConfig,
    rig: AnyRig,
    tweezer: Option<AnyTweezer>,
    opts: EngineOptions,
    clock: C,
) -> Result<(EngineCore<C>, EngineHandle), EngineError> {
    if opts.telemetry_capacity == 0 {
        return Err(EngineError::Option {
            name: "telemetry_capacity",
            reason: "must be > 0",
        });
    }
    let (cmd_tx, cmd_rx) = rtrb::RingBuffer::new(QUEUE);
    let (tel_tx, tel_rx) = rtrb::RingBuffer::new(opts.telemetry_capacity);
    let (ev_tx, ev_rx) = rtrb::RingBuffer::new(QUEUE);
    let shared = Arc::new(Shared::default());
    let spec = rig.spec().clone();
    let tweezer_spec = match &tweezer {
        Some(t @ AnyTweezer::Link(_)) => t.as_link().map_or(TweezerSpec::Sim, |l| {
            TweezerSpec::Serial(l.link_config().clone())
        }),
        _ => TweezerSpec::Sim,
    };
    let core = EngineCore::new(
        cfg,
        rig,
        tweezer,
        opts,
        clock,
        cmd_rx,
        tel_tx,
        ev_tx,
        shared.clone(),
    )?;
    let identity = kilotouch_rig::Rig::identity(&core.closed_loop().rig).clone();
    let config = core.config().clone();
    let free = core.free_exploration();
    let latency_s = core.latency_s();
    let block_len = opts.block_len;
    let lp = core.closed_loop();
    let loop_delay = super::runner::loop_delay_samples(&lp.rig, &lp.tweezer, block_len);
    let round_trip_s = kilotouch_rig::Rig::round_trip_s(&lp.rig);
    let tweezer = lp.tweezer.as_link().map(|t| LiveTweezerInfo {
        spec: tweezer_spec.clone(),
        name: t.hello().name.clone(),
        serial: t.hello().serial.clone(),
        firmware: t.hello().firmware.clone(),
        lead_samples: kilotouch_rig::Tweezer::loop_delay_samples(t, block_len),
        round_trip_s: kilotouch_rig::Tweezer::round_trip_s(t),
        obstacles: t.obstacles().to_vec(),
    });
    let chain = core.initial_chain().clone();
    let clearance = core.closed_loop().clearance();
    let chain_source = clearance.source().clone();
    let stability = clearance.report().cloned();
    let applied = Some((chain, clearance.clone()));
    let handle = EngineHandle {
        commands: cmd_tx,
        telemetry: tel_rx,
        events: ev_rx,
        shared,
        thread: None,
        health: None,
        identity,
        config,
        spec,
        last_error: None,
        condition: core.condition(),
        last_swap: None,
        chain_source,
        stability,
        free,
        latency_s,
        block_len,
        loop_delay,
        round_trip_s,
        tweezer,
        applied,
    };
    Ok((core, handle))
}

/// The live tweezer an engine runs with, as it answered at connection.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveTweezerInfo {
    /// The specification it was opened from.
    pub spec: TweezerSpec,
    /// Its name (HELLO).
    pub name: String,
    /// Its serial number (HELLO).
    pub serial: String,
    /// Its firmware (HELLO).
    pub firmware: String,
    /// The link's command lead, samples (its share of the loop delay).
    pub lead_samples: u32,
    /// The link's round trip measured at connection, s.
    pub round_trip_s: Option<f64>,
    /// The obstacles it reports, in its own frame.
    pub obstacles: Vec<kilotouch_rig::tweezer::Obstacle>,
}

/// The GUI's end of a running engine (module docs of [`crate::engine`]).
/// Dropping it stops the engine thread.
#[derive(Debug)]
pub struct EngineHandle {
    commands: rtrb::Producer<Command>,
    telemetry: rtrb::Consumer<TelemetrySample>,
    events: rtrb::Consumer<EngineEvent>,
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    health: Option<Health>,
    identity: RigIdentity,
    config: RigConfig,
    spec: RigSpec,
    last_error: Option<String>,
    condition: Condition,
    last_swap: Option<SwapOutcome>,
    chain_source: ChainSource,
    stability: Option<StabilityReport>,
    free: FreeExploration,
    latency_s: f64,
    block_len: usize,
    loop_delay: u32,
    round_trip_s: Option<f64>,
    /// The live tweezer (None: the simulated one).
    tweezer: Option<LiveTweezerInfo>,
    /// The chain the engine runs and the clearance it was armed with.
    applied: Option<(LoopChain, Clearance)>,
}

/// Presses the engine's emergency stop from anywhere (a cloneable handle on
/// the same atomic counter as [`EngineHandle::emergency_stop`]).
#[derive(Debug, Clone)]
pub struct EstopTrigger(Arc<Shared>);

impl EstopTrigger {
    /// Emergency stop: never blocks, never fails.
    pub fn fire(&self) {
        self.0.estop_count.fetch_add(1, Ordering::AcqRel);
    }
}

impl EngineHandle {
    /// Start the engine on its own thread, paced by the system clock.
    pub fn spawn(cfg: &RigConfig, opts: EngineOptions) -> Result<Self, EngineError> {
        Self::spawn_with_clock(cfg, opts, SystemClock::default())
    }

    /// Start the engine on the rig `spec` names (`sim`, `serial:PATH…`,
    /// `audio[:DEVICE]`), paced by the system clock (the simulated rig) or
    /// by the device (live rigs). Opening a serial rig handshakes first: this
    /// call blocks up to the handshake timeout (2 s) when a device does not
    /// answer.
    pub fn spawn_spec(
        cfg: &RigConfig,
        spec: &RigSpec,
        opts: EngineOptions,
    ) -> Result<Self, EngineError> {
        Self::spawn_devices(cfg, spec, &TweezerSpec::Sim, opts)
    }

    /// [`Self::spawn_spec`] with the tweezer `tweezer` names (`sim`: the
    /// rig file's simulated tweezer; `serial:PATH…`: a live tweezer or its
    /// emulator, which must stream at the rig's rate). Both links' command
    /// leads enter the stability clearance.
    pub fn spawn_devices(
        cfg: &RigConfig,
        spec: &RigSpec,
        tweezer: &TweezerSpec,
        opts: EngineOptions,
    ) -> Result<Self, EngineError> {
        let rig = AnyRig::open(spec, cfg)?;
        let tw = match tweezer {
            TweezerSpec::Sim => None,
            live => Some(AnyTweezer::open(
                live,
                cfg,
                kilotouch_rig::Rig::identity(&rig).sample_rate_hz,
            )?),
        };
        let (core, handle) = engine_pair_with_devices(cfg, rig, tw, opts, SystemClock::default())?;
        handle.run(core)
    }

    /// Start the engine on its own thread with a given clock.
    pub fn spawn_with_clock<C: Clock + 'static>(
        cfg: &RigConfig,
        opts: EngineOptions,
        clock: C,
    ) -> Result<Self, EngineError> {
        let (core, handle) = engine_pair(cfg, opts, clock)?;
        handle.run(core)
    }

    /// Run `core` on the engine thread ("kilotouch-engine", the real-time
    /// stack size) until it stops; `self` is its handle.
    fn run<C: Clock + 'static>(mut self, mut core: EngineCore<C>) -> Result<Self, EngineError> {
        let t = std::thread::Builder::new()
            .name("kilotouch-engine".into())
            .stack_size(kilotouch_rig::realtime::THREAD_STACK_BYTES)
            .spawn(move || {
                core.thread_started();
                while core.run_block() {}
            })?;
        self.thread = Some(t);
        Ok(self)
    }

    /// Identity of the rig.
    pub fn identity(&self) -> &RigIdentity {
        &self.identity
    }

    /// The rig configuration the engine was built from.
    pub fn config(&self) -> &RigConfig {
        &self.config
    }

    /// The rig specification the engine was started with (after a
    /// reconnect to another device: that one).
    pub fn spec(&self) -> &RigSpec {
        &self.spec
    }

    /// A live rig? (The hand is then the real handle: [`Self::set_hand`]
    /// has no effect.)
    pub fn is_live(&self) -> bool {
        kilotouch_rig::backend::is_live_kind(self.identity.kind)
    }

    /// The last rig error reported (cleared by a successful reconnect).
    pub fn last_error(&self) -> Option<&str> {
        self.last_error.as_deref()
    }

    /// Reopen the rig after a disconnect and resume (`None`: the same
    /// device; `Some(spec)`: that device instead). `false` if the queue was
    /// full. The outcome arrives as [`EngineEvent::Reconnected`] or
    /// [`EngineEvent::RigError`].
    pub fn reconnect(&mut self, spec: Option<RigSpec>) -> bool {
        if let Some(s) = &spec {
            self.spec = s.clone();
        }
        self.send(Command::Reconnect(spec.map(Box::new))).is_ok()
    }

    /// Publish the engine's samples and events to Lab Streaming Layer
    /// outlets at about `rate_hz` (decimated from the engine's rate) until
    /// the returned publisher is stopped or dropped ([`crate::lsl`]).
    ///
    /// # Errors
    /// [`crate::lsl::LslError`]: the rate, a publisher already running, liblsl.
    #[cfg(feature = "lsl")]
    pub fn start_lsl(
        &self,
        rate_hz: f64,
        id: crate::lsl::LslIdentity,
    ) -> Result<crate::lsl::LslPublisher, crate::lsl::LslError> {
        crate::lsl::LslPublisher::start(self.shared.lsl.clone(), self.sample_rate_hz(), rate_hz, id)
    }

    /// Sample rate, Hz.
    pub fn sample_rate_hz(&self) -> f64 {
        self.identity.sample_rate_hz
    }

    /// Latest health report, if any arrived.
    pub fn health(&self) -> Option<&Health> {
        self.health.as_ref()
    }

    /// The condition last requested.
    pub fn condition(&self) -> Condition {
        self.condition
    }

    /// Outcome of the last chain swap, if any.
    pub fn last_swap(&self) -> Option<SwapOutcome> {
        self.last_swap
    }

    /// Is the engine thread alive? (`true` for a core stepped by hand.)
    pub fn is_alive(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| !t.is_finished())
    }

    /// Send a command; gives it back if the queue is full.
    pub fn send(&mut self, cmd: Command) -> Result<(), Box<Command>> {
        if let Command::SetCondition(c) = cmd {
            self.condition = c;
        }
        self.commands
            .push(cmd)
            .map_err(|rtrb::PushError::Full(c)| Box::new(c))
    }

    /// Move the hand (m). `false` if the queue was full (the next call
    /// carries a newer position anyway).
    pub fn set_hand(&mut self, hand_m: [f64; 2]) -> bool {
        self.send(Command::SetHand(hand_m)).is_ok()
    }

    /// Switch V / P / D.
    pub fn set_condition(&mut self, c: Condition) -> bool {
        self.send(Command::SetCondition(c)).is_ok()
    }

    /// Emergency stop: never blocks, never fails (an atomic counter the
    /// engine checks at every block, outside the command queue).
    pub fn emergency_stop(&self) {
        self.shared.estop_count.fetch_add(1, Ordering::AcqRel);
    }

    /// Emergency stops requested so far.
    pub fn estop_count(&self) -> u64 {
        self.shared.estop_count.load(Ordering::Acquire)
    }

    /// Release the emergency stop (only if no stop was requested after
    /// this call). `false` if the queue was full.
    pub fn reset_emergency_stop(&mut self) -> bool {
        let ack = self.estop_count();
        self.send(Command::ResetEmergencyStop { ack }).is_ok()
    }

    /// The live tweezer (None: the rig file's simulated one).
    pub fn live_tweezer(&self) -> Option<&LiveTweezerInfo> {
        self.tweezer.as_ref()
    }

    /// Replace the obstacles (builds a new tweezer here; the engine swaps it in).
    pub fn set_obstacles(&mut self, obstacles: &[Obstacle]) -> Result<(), EngineError> {
        let mut p = TweezerParams::from_config(&self.config.tweezer);
        p.obstacles = obstacles.to_vec();
        let t = DetectedTweezer::new(p, &self.config.tweezer.detector, self.sample_rate_hz())?;
        self.send(Command::SetTweezer(Box::new(t)))
            .map_err(|_| EngineError::Option {
                name: "queue",
                reason: "command queue full, try again",
            })
    }

    /// Why this engine must not use the trap calibration `t`, in a
    /// researcher's words: a fit that fails the checks
    /// ([`TrapCalibrationRecord::check`]), a record of another tweezer
    /// than the one the engine's loop drives (`sim` or the live link's
    /// `serial:PATH`), or a κ that renders beyond the margins the loop was
    /// cleared for ([`kilotouch_rig::tweezer::check_loop_gain`]). The Rig
    /// page and `kilotouch study run --trap-calibration` both ask this
    /// before [`Self::apply_trap_calibration`].
    pub fn check_trap_calibration(&self, t: &TrapCalibrationRecord) -> Result<(), String> {
        t.check()?;
        let (tweezer, what) = match self.live_tweezer() {
            Some(l) => (
                l.spec.describe(),
                format!("the live tweezer on {}", l.spec.describe()),
            ),
            None => (
                "sim".to_owned(),
                "the rig file's simulated tweezer".to_owned(),
            ),
        };
        if t.source != tweezer {
            return Err(format!(
                "it was recorded from {}, and the engine's loop drives {what}",
                t.source
            ));
        }
        match self.stability() {
            Some(r) => kilotouch_rig::tweezer::check_loop_gain(r, t.applied().stiffness_n_per_m),
            None => Err("the loop was armed without its stability analysis".into()),
        }
    }

    /// Report the tweezer through this trap calibration (κ, R_d) from the
    /// next block on, or through the simulated bead and stiffness (`None`).
    /// An invalid calibration is refused.
    pub fn apply_trap_calibration(&mut self, c: Option<AppliedTrap>) -> Result<(), EngineError> {
        if let Some(c) = &c {
            c.validate()?;
        }
        self.send(Command::SetTrapCalibration(c))
            .map_err(|_| EngineError::Option {
                name: "queue",
                reason: "command queue full, try again",
            })
    }

    /// Swap in a new (force-normalised) chain, e.g. a calibration's. The
    /// loop must have been cleared with it: `clearance` is the analysis of
    /// this rig file with this chain ([`Clearance::check`]). A clearance
    /// analysed for less loop delay than this engine's rig adds
    /// ([`Self::latency_s`]: a live rig's block and command lead) is
    /// analysed again with the engine's delay first, and the chain is
    /// refused when its margins do not hold at that delay.
    ///
    /// # Errors
    /// [`RigError::LoopNotSafe`] naming the failing margin and the delay;
    /// a clearance of another chain; a full command queue.
    pub fn apply_chain(
        &mut self,
        chain: &LoopChain,
        clearance: &Clearance,
    ) -> Result<(), EngineError> {
        if clearance.source() != &chain.source {
            return Err(EngineError::Option {
                name: "clearance",
                reason: "the clearance is for another chain",
            });
        }
        let rechecked;
        let clearance = if clearance.report().is_some() && clearance.latency_s() < self.latency_s {
            rechecked = Clearance::check_with_latency(&self.config, chain, self.latency_s)?;
            &rechecked
        } else {
            clearance
        };
        self.send(Command::ApplyChain(ChainSwap::new(
            chain.coefficients.clone(),
        )))
        .map_err(|_| EngineError::Option {
            name: "queue",
            reason: "command queue full, try again",
        })?;
        self.chain_source = chain.source.clone();
        self.stability = clearance.report().cloned();
        self.applied = Some((chain.clone(), clearance.clone()));
        Ok(())
    }

    /// Where the chain the engine runs came from.
    pub fn chain_source(&self) -> &ChainSource {
        &self.chain_source
    }

    /// The stability analysis the running chain was cleared with.
    pub fn stability(&self) -> Option<&StabilityReport> {
        self.stability.as_ref()
    }

    /// Replace the block driver (e.g. a study sitting); the old one is
    /// detached on the engine thread and dropped here.
    pub fn set_driver(&mut self, d: Box<dyn BlockDriver>) -> bool {
        self.send(Command::SetDriver(d)).is_ok()
    }

    /// Back to free exploration (after a sitting).
    pub fn free_exploration(&mut self) -> bool {
        self.set_driver(Box::new(self.free))
    }

    /// The free-exploration driver of this engine (its hand smoothing).
    pub fn free_exploration_driver(&self) -> FreeExploration {
        self.free
    }

    /// A handle that presses this engine's emergency stop.
    pub fn estop_trigger(&self) -> EstopTrigger {
        EstopTrigger(self.shared.clone())
    }

    /// Samples per block.
    pub fn block_len(&self) -> usize {
        self.block_len
    }

    /// The loop delay, samples: from a sensor sample to the sample its
    /// command acts in (1 on the simulated rig; block + command lead on a
    /// live rig).
    pub fn loop_delay_samples(&self) -> u32 {
        self.loop_delay
    }

    /// The link round trip a live rig measured when it connected, s.
    pub fn round_trip_s(&self) -> Option<f64> {
        self.round_trip_s
    }

    /// The chain the engine runs and the clearance it was armed with.
    pub fn chain_and_clearance(&self) -> Option<(LoopChain, Clearance)> {
        self.applied.clone()
    }

    /// Sleep to the wall clock (`true`, the default) or run as fast as
    /// possible (`false`; the simulated rig only).
    pub fn set_paced(&mut self, on: bool) -> bool {
        self.send(Command::SetPaced(on)).is_ok()
    }

    /// The loop's delay beyond the simulated loop's one sample, s (the
    /// block and the command lead of a live rig; 0 on the simulated rig):
    /// what the stability clearance of the running chain includes.
    pub fn latency_s(&self) -> f64 {
        self.latency_s
    }

    /// Read every telemetry sample waiting; returns how many.
    pub fn drain_telemetry(&mut self, mut f: impl FnMut(&TelemetrySample)) -> usize {
        let mut n = 0;
        while let Ok(s) = self.telemetry.pop() {
            f(&s);
            n += 1;
        }
        n
    }

    /// Handle waiting events: keeps the latest health, drops garbage, and
    /// returns what the user should see (faults, errors, swaps).
    pub fn poll_events(&mut self) -> Vec<EngineEvent> {
        let mut out = Vec::new();
        while let Ok(e) = self.events.pop() {
            match e {
                EngineEvent::Health(h) => self.health = Some(h),
                EngineEvent::Garbage(g) => drop(g),
                EngineEvent::ChainSwapped(o) => {
                    self.last_swap = Some(o);
                    out.push(e);
                }
                EngineEvent::RigError(err) => {
                    self.last_error = Some(err.to_string());
                    out.push(EngineEvent::RigError(err));
                }
                EngineEvent::Reconnected(id) => {
                    self.identity = (*id).clone();
                    self.last_error = None;
                    out.push(EngineEvent::Reconnected(id));
                }
                other => out.push(other),
            }
        }
        out
    }

    /// Stop the thread and wait for it.
    pub fn shutdown(mut self) {
        self.stop_thread();
    }

    fn stop_thread(&mut self) {
        self.shared.shutdown.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for EngineHandle {
    fn drop(&mut self) {
        self.stop_thread();
    }
}
