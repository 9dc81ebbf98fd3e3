//! The trial side of a sitting on the engine thread: [`SittingDriver`], the
//! engine's [`BlockDriver`] while a sitting runs. It runs the study's
//! [`TrialCore`] on the engine's own closed loop (the station is the loop:
//! [`LoopStation`]), installs each trial's parts built by the worker
//! ([`TrialSlot`]), and hands back every finished trial, its raw rows and
//! the participant's telemetry through lock-free queues. It allocates,
//! frees and locks nothing: slots travel both ways, garbage is dropped on
//! the worker.
//!
//! Between trials (and while a trial is paused) the simulated loop stands
//! still; a live loop keeps exchanging blocks with the outputs at zero
//! (the safety layer disarmed), as a device must be fed. An emergency stop
//! (the engine's one stop) aborts the running trial at the next block; a
//! rig failure ends the trial unrecorded and is reported with the device's
//! error.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use kilotouch_rig::AnyTweezer;
use kilotouch_rig::Rig;
use kilotouch_rig::coupling::{ChainSource, HandMapping};
use kilotouch_rig::device::{HostInfo, PhaseCode, TaskCode, TrialInfo};
use kilotouch_rig::error::RigError;
use kilotouch_rig::haptic_loop::TrialStart;
use kilotouch_rig::safety::SafetyLayer;
use kilotouch_rig::sim::SimRig;
use kilotouch_study::export::TaskKind;
use kilotouch_study::export::{ExportError, SittingTiming};
use kilotouch_study::runner::{RAW_CHANNELS, RawSink, RunError, TrialCore, TrialOutcome};
use kilotouch_study::seeds::{Phase, TrialKey};
use kilotouch_study::task::station::{Station, StationSample};

use super::Telemetry;
use super::participant::{Tap, Who};
use crate::engine::{BlockCtx, BlockDriver, EngineLoop, FreeExploration, run_live_block};

/// One trial's parts, built by the worker off the real-time path and
/// swapped into the loop by the driver; the same box carries the old
/// parts and the trial's outcome back.
#[derive(Debug)]
pub(crate) struct TrialSlot {
    /// The trial.
    pub setup: kilotouch_study::runner::TrialSetup,
    /// A fresh simulated rig (the simulated rig only).
    pub rig: Option<Box<SimRig>>,
    /// The trial's simulated tweezer (unused, and dropped by the worker,
    /// when the loop runs a live tweezer: that one stays and is reset).
    pub tweezer: AnyTweezer,
    /// Where the trial's frame sits in a live tweezer's, m
    /// ([`kilotouch_rig::backend::LiveTweezer`]).
    pub tweezer_origin_m: [f64; 2],
    /// Its safety layer, armed.
    pub safety: Box<SafetyLayer>,
    /// The kept trajectory's buffer (capacity for the whole trial).
    pub trajectory: Vec<[f64; 2]>,
    /// The finished trial and how it ended.
    pub outcome: Option<TrialOutcome>,
    /// How it ended.
    pub end: Option<kilotouch_study::task::TrialEnd>,
    /// Raw rows the queue could not take (the worker reports them).
    pub raw_dropped: u64,
}

/// Worker → driver.
#[derive(Debug)]
pub(crate) enum ToDriver {
    /// Begin this trial.
    Begin(Box<TrialSlot>),
    /// Hold the running trial (a live loop's outputs go to zero).
    Pause,
    /// Continue it.
    Resume,
    /// End the running trial as aborted (its row is committed).
    Abort,
    /// Leave the trial unrecorded and stop driving trials.
    Detach,
}

/// Driver → worker.
#[derive(Debug)]
pub(crate) enum FromDriver {
    /// The trial began at this rig sequence number.
    Started(TrialKey),
    /// The trial could not begin (why).
    Refused(Box<TrialSlot>, &'static str),
    /// The trial ended; its outcome is in the slot.
    Ended(Box<TrialSlot>),
    /// The emergency stop latched; the trial it aborted, if any (its
    /// [`FromDriver::Ended`] follows).
    EmergencyStop(Option<TrialKey>),
    /// The rig failed: the trial in progress (not ended) and the error.
    DeviceFailed(Option<Box<TrialSlot>>, String),
    /// Detached: the trial in progress, unrecorded.
    Detached(Option<Box<TrialSlot>>),
}

/// What the driver counts for the sitting's handle (lock-free).
#[derive(Debug, Default)]
pub(crate) struct SittingCounters {
    /// Samples the sitting's trials ran.
    pub samples: AtomicU64,
    /// Participant telemetry events the GUI did not drain in time.
    pub telemetry_dropped: AtomicU64,
    /// Engine blocks while the sitting ran.
    pub blocks: AtomicU64,
    /// Of them, blocks that missed their deadline.
    pub deadline_misses: AtomicU64,
    /// Latest block end past its deadline, s (bits of an f64; 0 = none).
    pub worst_lateness_bits: AtomicU64,
    /// Commands the device flagged as late during the sitting.
    pub late_commands: AtomicU64,
}

impl SittingCounters {
    /// The sitting's timing verdict so far ([`SittingTiming::judge`]).
    pub fn timing(&self, block_len: u64, max_late_fraction: f64) -> SittingTiming {
        SittingTiming::judge(
            self.samples.load(Ordering::Relaxed),
            self.blocks.load(Ordering::Relaxed),
            self.deadline_misses.load(Ordering::Relaxed),
            f64::from_bits(self.worst_lateness_bits.load(Ordering::Relaxed)),
            self.late_commands.load(Ordering::Relaxed),
            block_len,
            max_late_fraction,
        )
    }
}

/// The raw rows' queue to the worker (a full queue drops and counts: it
/// holds [`RAW_QUEUE_ROWS`] rows, seconds of data, so only a worker stalled
/// that long loses rows, and the loss is reported with the trial).
#[derive(Debug)]
pub(crate) struct RawRing {
    pub tx: rtrb::Producer<[f64; RAW_CHANNELS]>,
    pub dropped: u64,
}

/// Rows the raw queue holds: 2¹⁶ (6.5 s at 10 kHz).
pub(crate) const RAW_QUEUE_ROWS: usize = 1 << 16;

impl RawSink for RawRing {
    #[inline]
    fn push(&mut self, row: &[f64]) -> Result<(), ExportError> {
        let mut r = [0.0; RAW_CHANNELS];
        let n = row.len().min(RAW_CHANNELS);
        r[..n].copy_from_slice(&row[..n]);
        if self.tx.push(r).is_err() {
            self.dropped += 1;
        }
        Ok(())
    }
}

/// The engine's loop as the station a trial runs on (module docs).
struct LoopStation<'c, 'a> {
    ctx: &'c mut BlockCtx<'a>,
    fs: f64,
}

impl Station for LoopStation<'_, '_> {
    fn sample_rate_hz(&self) -> f64 {
        self.fs
    }

    fn mapping(&self) -> HandMapping {
        *self.ctx.lp.coupling.mapping()
    }

    fn chain_source(&self) -> ChainSource {
        self.ctx.lp.clearance().source().clone()
    }

    fn hand_is_real(&self) -> bool {
        self.ctx.lp.rig.is_live()
    }

    #[inline]
    fn step_block(
        &mut self,
        hands: &[[f64; 2]],
        out: &mut [StationSample],
    ) -> Result<(), RunError> {
        let ctx = &mut *self.ctx;
        if ctx.live {
            if !ctx.lp.rig.is_live()
                && let Some(h) = hands.last()
            {
                // A live tweezer on the simulated rig: block exchange, the
                // simulated hand set once per block.
                ctx.lp.rig.set_hand(*h);
            }
            ctx.exchange(hands.len())?;
            for (o, l) in out.iter_mut().zip(ctx.lp.block()) {
                ctx.out.publish(l, l.sensors.handle_m);
                *o = StationSample::from_loop(l);
            }
            return Ok(());
        }
        for (o, h) in out.iter_mut().zip(hands) {
            ctx.lp.rig.set_hand(*h);
            ctx.lp.advance()?;
            let l = ctx.lp.last();
            ctx.out.publish(l, *h);
            *o = StationSample::from_loop(l);
        }
        Ok(())
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Running,
    Paused,
}

/// The engine's driver during a sitting (module docs).
#[derive(Debug)]
pub(crate) struct SittingDriver {
    core: TrialCore,
    who: Tap<Who>,
    state: State,
    slot: Option<Box<TrialSlot>>,
    inbox: rtrb::Consumer<ToDriver>,
    outbox: rtrb::Producer<FromDriver>,
    raw: RawRing,
    raw_on: bool,
    telemetry: rtrb::Producer<Telemetry>,
    telemetry_every: u64,
    since_telemetry: u64,
    counters: Arc<SittingCounters>,
    latched_seen: bool,
    detached: bool,
    fs: f64,
    last_view: Option<u64>,
    /// The rig file's hand mapping (restored when the sitting ends: a live
    /// trial re-centres it on the handle).
    mapping: HandMapping,
    /// What the driver does once detached (the sitting ended but the engine
    /// still runs it): free exploration.
    free: FreeExploration,
    /// The device's late-command count when the sitting began (None: not
    /// read yet).
    late_commands_at_start: Option<u64>,
    /// Latest block lateness so far, s.
    worst_lateness_s: f64,
}

/// What a [`SittingDriver`] is built from.
pub(crate) struct DriverParts {
    pub core: TrialCore,
    pub who: Tap<Who>,
    pub inbox: rtrb::Consumer<ToDriver>,
    pub outbox: rtrb::Producer<FromDriver>,
    pub raw: rtrb::Producer<[f64; RAW_CHANNELS]>,
    pub raw_on: bool,
    pub telemetry: rtrb::Producer<Telemetry>,
    pub telemetry_every: u64,
    pub counters: Arc<SittingCounters>,
    pub fs: f64,
    pub mapping: HandMapping,
    pub free: FreeExploration,
}

impl SittingDriver {
    pub(crate) fn new(p: DriverParts) -> Self {
        Self {
            core: p.core,
            who: p.who,
            state: State::Idle,
            slot: None,
            inbox: p.inbox,
            outbox: p.outbox,
            raw: RawRing {
                tx: p.raw,
                dropped: 0,
            },
            raw_on: p.raw_on,
            telemetry: p.telemetry,
            telemetry_every: p.telemetry_every.max(1),
            since_telemetry: 0,
            counters: p.counters,
            latched_seen: false,
            detached: false,
            fs: p.fs,
            last_view: None,
            mapping: p.mapping,
            free: p.free,
            late_commands_at_start: None,
            worst_lateness_s: 0.0,
        }
    }

    /// Count the previous block for the sitting's timing verdict.
    #[inline]
    fn count_timing(&mut self, ctx: &BlockCtx<'_>) {
        let c = &self.counters;
        c.blocks.fetch_add(1, Ordering::Relaxed);
        if ctx.prev_block.missed {
            c.deadline_misses.fetch_add(1, Ordering::Relaxed);
        }
        if ctx.prev_block.lateness_s > self.worst_lateness_s {
            self.worst_lateness_s = ctx.prev_block.lateness_s;
            c.worst_lateness_bits
                .store(self.worst_lateness_s.to_bits(), Ordering::Relaxed);
        }
        let late = ctx.lp.rig.status().late_commands;
        let start = *self.late_commands_at_start.get_or_insert(late);
        c.late_commands
            .store(late.saturating_sub(start), Ordering::Relaxed);
    }

    /// Sends to the worker; the worker drains its queue every few
    /// milliseconds and the queue holds more messages than a sitting has
    /// in flight, so a full queue is a bug: the message is kept from being
    /// freed here (leaked) rather than dropped on the real-time thread.
    fn tell(&mut self, m: FromDriver) {
        if let Err(rtrb::PushError::Full(m)) = self.outbox.push(m) {
            std::mem::forget(m);
        }
    }

    /// Install the trial of `slot` on the loop and start it.
    fn begin(&mut self, ctx: &mut BlockCtx<'_>, mut slot: Box<TrialSlot>) {
        if ctx.latched {
            self.tell(FromDriver::Refused(
                slot,
                "the emergency stop is latched: reset it before the next trial",
            ));
            return;
        }
        if self.state != State::Idle || self.detached {
            self.tell(FromDriver::Refused(slot, "a trial is already running"));
            return;
        }
        let lp = &mut *ctx.lp;
        if let Some(rig) = &mut slot.rig {
            if !lp.rig.swap_sim(rig) {
                self.tell(FromDriver::Refused(slot, "a simulated trial on a live rig"));
                return;
            }
            if lp.rig.start().is_err() {
                self.tell(FromDriver::Refused(slot, "the simulated rig did not start"));
                return;
            }
        }
        // The applied trap calibration carries over (validated when applied).
        let _ = slot.tweezer.set_calibration(lp.tweezer.calibration());
        lp.tweezer.set_frame_origin(slot.tweezer_origin_m);
        let tweezer = (!lp.tweezer.is_live()).then_some(&mut slot.tweezer);
        let start = if lp.rig.is_live() {
            TrialStart::AtHandle
        } else {
            TrialStart::Fresh
        };
        let condition = slot.setup.feedback.condition;
        lp.begin_trial(tweezer, condition, &mut slot.safety, start);
        slot.setup.brief.mapping = *lp.coupling.mapping();
        let trajectory = std::mem::take(&mut slot.trajectory);
        if self
            .core
            .start(&slot.setup, 1, &mut self.who, trajectory)
            .is_err()
        {
            lp.safety.disarm();
            self.tell(FromDriver::Refused(slot, "the trial could not start"));
            return;
        }
        let first_seq = lp.rig.next_seq();
        if ctx.live {
            let _ = lp
                .rig
                .send_info(&HostInfo::TrialBegin(trial_info(&slot, first_seq)));
        }
        self.raw.dropped = 0;
        self.since_telemetry = 0;
        self.last_view = None;
        self.state = State::Running;
        let key = slot.setup.key;
        self.slot = Some(slot);
        #[cfg(feature = "lsl")]
        ctx.out.marker(crate::lsl::Marker::TrialStart(key));
        self.tell(FromDriver::Started(key));
    }

    /// The running trial ended: its outcome goes back in its slot.
    fn finish(&mut self, ctx: &mut BlockCtx<'_>) {
        self.state = State::Idle;
        if ctx.live {
            ctx.lp.safety.disarm();
            let _ = ctx.lp.rig.send_info(&HostInfo::TrialEnd);
        }
        if let Some(mut slot) = self.slot.take() {
            #[cfg(feature = "lsl")]
            ctx.out.marker(crate::lsl::Marker::TrialEnd(slot.setup.key));
            slot.end = self.core.end();
            slot.outcome = self.core.take_outcome().ok();
            slot.raw_dropped = self.raw.dropped;
            self.tell(FromDriver::Ended(slot));
        }
    }

    fn commands(&mut self, ctx: &mut BlockCtx<'_>) {
        while let Ok(m) = self.inbox.pop() {
            match m {
                ToDriver::Begin(slot) => self.begin(ctx, slot),
                ToDriver::Pause => {
                    if self.state == State::Running {
                        self.state = State::Paused;
                        #[cfg(feature = "lsl")]
                        ctx.out.marker(crate::lsl::Marker::Pause);
                        if ctx.live {
                            ctx.lp.safety.disarm();
                        }
                    }
                }
                ToDriver::Resume => {
                    if self.state == State::Paused {
                        self.state = State::Running;
                        #[cfg(feature = "lsl")]
                        ctx.out.marker(crate::lsl::Marker::Resume);
                        if ctx.live {
                            let _ = ctx.lp.safety.arm();
                        }
                    }
                }
                ToDriver::Abort => {
                    if self.state != State::Idle {
                        self.core.abort();
                        self.finish(ctx);
                    }
                }
                ToDriver::Detach => {
                    self.state = State::Idle;
                    self.detached = true;
                    let slot = self.slot.take();
                    self.tell(FromDriver::Detached(slot));
                    self.detach(ctx.lp);
                }
            }
        }
    }

    /// The participant's telemetry, every `telemetry_every` samples.
    fn publish_telemetry(&mut self, samples: usize) {
        self.since_telemetry += samples as u64;
        if self.since_telemetry < self.telemetry_every {
            return;
        }
        self.since_telemetry = 0;
        if let Some(key) = self.core.key() {
            let t = self.who.telemetry(key);
            if self.telemetry.push(t).is_err() {
                self.counters
                    .telemetry_dropped
                    .fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Live rigs: the frame the participant's screen shows goes to the
    /// device (a device with a participant at its handle needs it).
    fn send_view(&mut self, ctx: &mut BlockCtx<'_>) {
        let Some(f) = self.core.shown_frame() else {
            return;
        };
        if self.last_view == Some(f.seq) {
            return;
        }
        self.last_view = Some(f.seq);
        let _ = ctx.lp.rig.send_info(&HostInfo::View(f));
    }

    fn run_trial(&mut self, ctx: &mut BlockCtx<'_>) -> Result<usize, RigError> {
        if let Who::Mouse(m) = &mut self.who.inner
            && ctx.gui_hand.iter().all(|v| v.is_finite())
        {
            m.hand_m = ctx.gui_hand;
        }
        let before = self.core.samples();
        let fs = self.fs;
        let raw_on = self.raw_on;
        let n = ctx.n;
        let r = {
            let mut station = LoopStation { ctx: &mut *ctx, fs };
            if raw_on {
                self.core.run(&mut station, &mut self.who, &mut self.raw, n)
            } else {
                let mut none = kilotouch_study::runner::NoRaw;
                self.core.run(&mut station, &mut self.who, &mut none, n)
            }
        };
        let ran = usize::try_from(self.core.samples() - before).unwrap_or(0);
        self.counters
            .samples
            .fetch_add(ran as u64, Ordering::Relaxed);
        match r {
            Ok(end) => {
                self.publish_telemetry(ran);
                if ctx.live {
                    self.send_view(ctx);
                }
                if end.is_some() {
                    self.finish(ctx);
                }
                Ok(if ctx.live { ctx.n } else { ran })
            }
            Err(e) => {
                let e = match e {
                    RunError::Rig(e) => e,
                    other => RigError::NotReady(other.to_string()),
                };
                self.state = State::Idle;
                let slot = self.slot.take();
                self.tell(FromDriver::DeviceFailed(slot, e.to_string()));
                Err(e)
            }
        }
    }
}

/// What a device with a participant at its handle is told of a trial.
fn trial_info(slot: &TrialSlot, first_seq: u64) -> TrialInfo {
    let b = &slot.setup.brief;
    let k = slot.setup.key;
    TrialInfo {
        participant: k.participant,
        condition: k.condition,
        phase: match k.phase {
            Phase::Practice => PhaseCode::Practice,
            Phase::Test => PhaseCode::Test,
        },
        index: k.trial,
        task: match b.task {
            TaskKind::Circling => TaskCode::Circling,
            TaskKind::BlindNavigation => TaskCode::BlindNavigation,
        },
        mapping: b.mapping,
        start_trap_m: b.start_trap_m,
        heading: b.heading,
        retreat_distance_m: b.retreat_distance_m,
        first_seq,
    }
}

impl BlockDriver for SittingDriver {
    fn run_block(&mut self, ctx: &mut BlockCtx<'_>) -> Result<usize, RigError> {
        self.commands(ctx);
        if self.detached {
            return self.free.run_block(ctx);
        }
        self.count_timing(ctx);
        if ctx.latched && !self.latched_seen {
            self.latched_seen = true;
            let key = (self.state != State::Idle)
                .then(|| self.core.key())
                .flatten();
            self.tell(FromDriver::EmergencyStop(key));
            if self.state != State::Idle {
                self.core.abort();
                self.finish(ctx);
            }
        } else if !ctx.latched {
            self.latched_seen = false;
        }
        match self.state {
            State::Running => self.run_trial(ctx),
            // A live loop is fed with the outputs at zero; the simulated
            // loop stands still.
            State::Idle | State::Paused if ctx.live => run_live_block(ctx),
            State::Idle | State::Paused => Ok(0),
        }
    }

    fn owns_loop(&self) -> bool {
        !self.detached
    }

    fn detach(&mut self, lp: &mut EngineLoop) {
        // Explore after a sitting: the rig file's mapping, forces back on
        // through the arming ramp.
        let origin = self.mapping.handle_origin_m;
        lp.coupling.set_handle_origin(origin);
        if !lp.safety.state().latched() {
            let _ = lp.safety.arm();
        }
    }
}
