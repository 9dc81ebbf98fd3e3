//! What runs in a block: the [`BlockDriver`] interface, the default driver
//! ([`FreeExploration`]) and the [`Publisher`] every driver hands its
//! samples to (telemetry and flags). See the module docs of
//! [`crate::engine`].

use super::{TelemetrySample, flags};
use kilotouch_rig::LoopSample;
use kilotouch_rig::device::Clock;
use kilotouch_rig::error::RigError;
use kilotouch_rig::haptic_loop::MAX_BLOCK;

/// The closed loop the engine runs (simulated or live rig, simulated or
/// live tweezer, the swappable chain).
pub type EngineLoop = kilotouch_rig::haptic_loop::HapticLoop<
    kilotouch_rig::AnyRig,
    kilotouch_rig::AnyTweezer,
    super::splitter::SwappableChain,
>;

/// One block as the engine hands it to its driver.
pub struct BlockCtx<'a> {
    /// The closed loop (rig, tweezer, coupling, safety layer).
    pub lp: &'a mut EngineLoop,
    /// Samples in this block (1–[`MAX_BLOCK`]).
    pub n: usize,
    /// A live rig or a live tweezer: the loop exchanges blocks
    /// ([`EngineLoop::step_block`]) and must keep exchanging them (the
    /// device paces the loop).
    pub live: bool,
    /// The GUI's latest hand request (m; the mouse on the simulated rig).
    pub gui_hand: [f64; 2],
    /// The safety layer is latched (emergency stop or fault): outputs are
    /// zero until the experimenter resets it.
    pub latched: bool,
    /// Where every sample the driver runs goes.
    pub out: &'a mut Publisher,
    /// The engine's clock (to time the wait for a live device).
    pub clock: &'a dyn Clock,
    /// Time spent waiting for a live device in this block, s (not load).
    pub wait_s: f64,
    /// How the previous block kept its deadline (a sitting counts its late
    /// blocks for its timing verdict).
    pub prev_block: super::pacing::BlockTiming,
}

impl std::fmt::Debug for BlockCtx<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockCtx")
            .field("n", &self.n)
            .field("live", &self.live)
            .field("latched", &self.latched)
            .finish_non_exhaustive()
    }
}

impl BlockCtx<'_> {
    /// Exchange one block of `n` samples with a live rig
    /// ([`EngineLoop::step_block`]), timing the exchange as waiting.
    ///
    /// # Errors
    /// The rig's error (the safety layer has tripped).
    #[inline]
    pub fn exchange(&mut self, n: usize) -> Result<(), RigError> {
        let t0 = self.clock.now();
        let r = self.lp.step_block(n.min(MAX_BLOCK));
        self.wait_s += self.clock.now().saturating_sub(t0).as_secs_f64();
        r.map(|_| ())
    }
}

/// Decides what happens in each block (module docs of [`crate::engine`]).
/// Implementations run on the engine thread: they must not allocate, free,
/// lock or block, and never panic.
pub trait BlockDriver: Send + std::fmt::Debug {
    /// Run one block: advance the loop by up to `ctx.n` samples (0: the
    /// simulated loop stands still this block; a live loop must be advanced
    /// by `ctx.n`), publishing each sample through `ctx.out`. Returns the
    /// samples run.
    ///
    /// # Errors
    /// A rig error (the loop's safety layer has tripped): the engine zeroes
    /// the outputs, stops the rig and reports it.
    fn run_block(&mut self, ctx: &mut BlockCtx<'_>) -> Result<usize, RigError>;

    /// The driver is being replaced: undo what it changed on the loop (the
    /// engine calls it on its thread; no allocation).
    fn detach(&mut self, lp: &mut EngineLoop) {
        let _ = lp;
    }

    /// Does the driver own the loop's condition, scene and chain (a study
    /// sitting)? The engine then refuses the GUI's commands that would
    /// change them under a running study. Default `false`.
    fn owns_loop(&self) -> bool {
        false
    }
}

/// The default driver: the hand follows the GUI (the mouse, through a
/// first-order smoothing filter) on the simulated rig, which the loop
/// steps one frame at a time; on a live rig the hand is the real handle
/// and the loop exchanges one block per round trip.
#[derive(Debug, Clone, Copy)]
pub struct FreeExploration {
    hand: [f64; 2],
    alpha: f64,
}

impl FreeExploration {
    /// Free exploration with hand smoothing coefficient `alpha` per sample
    /// (1: no smoothing; 1 − e^(−1/(f_s·τ)) for a time constant τ).
    pub fn new(alpha: f64) -> Self {
        Self {
            hand: [0.0; 2],
            alpha: if alpha.is_finite() {
                alpha.clamp(0.0, 1.0)
            } else {
                1.0
            },
        }
    }
}

impl BlockDriver for FreeExploration {
    fn run_block(&mut self, ctx: &mut BlockCtx<'_>) -> Result<usize, RigError> {
        if ctx.live {
            if !ctx.lp.rig.is_live() {
                // A live tweezer on the simulated rig: the hand moves once
                // per block (the block is the loop's exchange unit).
                let target = ctx.gui_hand;
                let a = 1.0 - (1.0 - self.alpha).powi(ctx.n as i32);
                self.hand[0] += a * (target[0] - self.hand[0]);
                self.hand[1] += a * (target[1] - self.hand[1]);
                ctx.lp.rig.set_hand(self.hand);
            }
            let n = run_live_block(ctx)?;
            if let Some(last) = ctx.lp.block().last() {
                self.hand = last.sensors.handle_m;
            }
            return Ok(n);
        }
        let target = ctx.gui_hand;
        for _ in 0..ctx.n {
            self.hand[0] += self.alpha * (target[0] - self.hand[0]);
            self.hand[1] += self.alpha * (target[1] - self.hand[1]);
            ctx.lp.rig.set_hand(self.hand);
            ctx.lp.advance()?;
            ctx.out.publish(ctx.lp.last(), self.hand);
        }
        Ok(ctx.n)
    }
}

/// One block of a live loop ([`EngineLoop::step_block`]: the commands of
/// block b computed sample by sample from the sensor frames of block
/// b − 1), every sample published with the handle as the hand.
///
/// # Errors
/// The rig's error (the safety layer has tripped).
pub fn run_live_block(ctx: &mut BlockCtx<'_>) -> Result<usize, RigError> {
    ctx.exchange(ctx.n)?;
    for l in ctx.lp.block() {
        ctx.out.publish(l, l.sensors.handle_m);
    }
    Ok(ctx.lp.block().len())
}

/// Publishes the loop's samples: the telemetry queue to the GUI (a full
/// queue drops the sample and counts it), the sample's flags, and what the
/// engine's health reports of the bead.
#[derive(Debug)]
pub struct Publisher {
    telemetry: rtrb::Producer<TelemetrySample>,
    /// Samples dropped because the GUI did not drain the queue.
    pub dropped: u64,
    /// Samples published since the last health window.
    pub window_samples: u64,
    /// Samples published since the engine started.
    pub samples: u64,
    /// Trap position of the last sample, m.
    pub last_trap: [f64; 2],
    /// The bead was in the trap at the last sample.
    pub trapped: bool,
    /// [`flags::ESTOP`] while the emergency stop is latched, else 0.
    pub estop_flag: u16,
    /// The Lab Streaming Layer tap (pushes only while publishing is on).
    #[cfg(feature = "lsl")]
    pub lsl: Option<crate::lsl::LslTap>,
}

impl Publisher {
    /// A publisher into `telemetry`, the trap resting at `rest_trap_m`.
    pub fn new(telemetry: rtrb::Producer<TelemetrySample>, rest_trap_m: [f64; 2]) -> Self {
        Self {
            telemetry,
            dropped: 0,
            window_samples: 0,
            samples: 0,
            last_trap: rest_trap_m,
            trapped: true,
            estop_flag: 0,
            #[cfg(feature = "lsl")]
            lsl: None,
        }
    }

    /// An event for the Lab Streaming Layer marker stream (nothing while
    /// publishing is off).
    #[cfg(feature = "lsl")]
    #[inline]
    pub fn marker(&mut self, m: crate::lsl::Marker) {
        if let Some(t) = &mut self.lsl {
            t.marker(m);
        }
    }

    /// Telemetry of one sample with the hand at `hand` (m).
    #[inline]
    pub fn publish(&mut self, l: &LoopSample, hand: [f64; 2]) {
        let s = &l.tweezer;
        self.last_trap = s.trap_m;
        self.trapped = s.trapped;
        let e = s.events;
        let mut fl = self.estop_flag;
        for (on, bit) in [
            (s.in_contact, flags::IN_CONTACT),
            (s.trapped, flags::TRAPPED),
            (e.contact_start, flags::CONTACT_START),
            (e.contact_end, flags::CONTACT_END),
            (e.escaped, flags::ESCAPED),
            (e.recaptured, flags::RECAPTURED),
            (l.sensors.flags.0 != 0, flags::RIG_FLAG),
        ] {
            if on {
                fl |= bit;
            }
        }
        let r = &l.rendered;
        let t = TelemetrySample {
            seq: l.sensors.seq,
            hand_m: hand,
            handle_m: l.sensors.handle_m,
            handle_force_n: [r.image_n[0] + r.damping_n[0], r.image_n[1] + r.damping_n[1]],
            output: l.command,
            accel_m_s2: l.sensors.accel_m_s2,
            trap_m: s.trap_m,
            bead_m: s.bead_m,
            bead_force_n: s.force_n,
            gap_m: s.gap_m,
            flags: fl,
        };
        if self.telemetry.push(t).is_err() {
            self.dropped += 1;
        }
        self.window_samples += 1;
        self.samples += 1;
        #[cfg(feature = "lsl")]
        if let Some(tap) = &mut self.lsl {
            tap.sample(l);
        }
    }
}
