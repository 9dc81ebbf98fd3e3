//! The simulated rig: [`SimRig`] runs the [`DualStagePlant`], the [`Accelerometer`] and encoder
//! quantisation, either as fast as possible ([`Pacing::Batch`]: tests,
//! calibration) or paced by a wall [`Clock`] ([`Pacing::WallClock`]: GUI).
//! Pacing derives the deadline of every block from a clock anchor and the
//! sample count — deadline = t_anchor + (seq_end − seq_anchor)/f_s — never by
//! accumulating sleeps, so after a stall the following blocks run without
//! sleeping until the simulation has caught up; a stall longer than
//! `max_lag_s` re-anchors (the lost time is reported as an overrun).

use crate::accel::Accelerometer;
use crate::config::RigConfig;
use crate::device::{
    ActuatorFrame, BlockReport, Clock, FrameFlags, Rig, RigFault, RigIdentity, RigKind, RigState,
    RigStatus, SensorFrame, StatusCounters, SystemClock, frame_as_block, open_block,
};
use crate::error::RigError;
use crate::lti::Integrator;
use crate::plant::{DualStagePlant, PlantFastOutput, PlantInput, PlantOutput};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// How a simulated rig uses time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Pacing {
    /// As fast as possible (tests, calibration, batch runs).
    Batch,
    /// Paced by the wall clock (GUI); stalls longer than `max_lag_s` are
    /// skipped rather than caught up.
    WallClock {
        /// Largest lag caught up by running without sleeping, s.
        max_lag_s: f64,
    },
}

/// The simulated dual-stage rig (module docs).
#[derive(Debug, Clone)]
pub struct SimRig<C: Clock = SystemClock> {
    identity: RigIdentity,
    fs: f64,
    plant: DualStagePlant,
    accel: Accelerometer,
    // Render the accelerometer (default); off, every reading is the
    // sensor's static output ([`SimRig::set_accelerometer_rendering`]).
    render_accel: bool,
    encoder_res: f64,
    force_max: f64,
    drive_max: f64,
    hand_prev: [f64; 2],
    hand_target: [f64; 2],
    truth: PlantFastOutput,
    seq: u64,
    state: RigState,
    pacing: Pacing,
    clock: C,
    anchor_time: Duration,
    anchor_seq: u64,
    counters: StatusCounters,
}

impl SimRig<SystemClock> {
    /// Batch (as-fast-as-possible) simulated rig from a configuration.
    pub fn new(cfg: &RigConfig) -> Result<Self, RigError> {
        Self::with_clock(cfg, Integrator::Zoh, Pacing::Batch, SystemClock::default())
    }

    /// Paced by the system clock.
    pub fn paced(cfg: &RigConfig, max_lag_s: f64) -> Result<Self, RigError> {
        Self::with_clock(
            cfg,
            Integrator::Zoh,
            Pacing::WallClock { max_lag_s },
            SystemClock::default(),
        )
    }
}

impl<C: Clock> SimRig<C> {
    /// Full constructor: integrator, pacing and clock.
    pub fn with_clock(
        cfg: &RigConfig,
        integrator: Integrator,
        pacing: Pacing,
        clock: C,
    ) -> Result<Self, RigError> {
        cfg.validate()?;
        if let Pacing::WallClock { max_lag_s } = pacing {
            RigError::require_positive("max_lag_s", max_lag_s)?;
        }
        let fs = cfg.rig.sample_rate_hz;
        let plant = DualStagePlant::new(cfg, integrator)?;
        let accel = Accelerometer::new(&cfg.accelerometer, fs)?;
        let identity = RigIdentity {
            kind: RigKind::Simulated,
            name: cfg.rig.name.clone(),
            serial: format!("sim-{}", integrator.name()),
            firmware: concat!("kilotouch-rig ", env!("CARGO_PKG_VERSION")).to_string(),
            sample_rate_hz: fs,
            force_max_n: cfg.limits.pantograph_force_max_n,
            haptuator_max_v: cfg.limits.haptuator_drive_max_v,
            accel_range_m_s2: accel.range_m_s2(),
        };
        Ok(Self {
            identity,
            fs,
            plant,
            accel,
            render_accel: true,
            encoder_res: cfg.rig.encoder_resolution_m,
            force_max: cfg.limits.pantograph_force_max_n,
            drive_max: cfg.limits.haptuator_drive_max_v,
            hand_prev: [0.0; 2],
            hand_target: [0.0; 2],
            truth: PlantFastOutput::default(),
            seq: 0,
            state: RigState::Idle,
            pacing,
            clock,
            anchor_time: Duration::ZERO,
            anchor_seq: 0,
            counters: StatusCounters::default(),
        })
    }

    /// Move the hand (the mouse, or a recorded trajectory) to `pos` (m): it
    /// travels linearly to `pos` over the next block. Non-finite → ignored.
    pub fn set_hand(&mut self, pos: [f64; 2]) {
        if pos.iter().all(|v| v.is_finite()) {
            self.hand_target = pos;
        }
    }

    /// True plant outputs of the last sample (tip acceleration without the
    /// sensor, positions, stroke) — the "ground truth" for validation.
    /// The tip position is computed on demand from the plant's state
    /// ([`DualStagePlant::tip_m`], bit-identical to what the step would have
    /// returned), so the per-sample path skips it.
    pub fn truth(&self) -> PlantOutput {
        PlantOutput {
            accel_m_s2: self.truth.accel_m_s2,
            tip_m: self.plant.tip_m(),
            motor_m: self.truth.motor_m,
            stroke_m: self.truth.stroke_m,
        }
    }

    /// The plant (for inspection).
    pub fn plant(&self) -> &DualStagePlant {
        &self.plant
    }

    /// The accelerometer (its response, for calibration).
    pub fn accelerometer(&self) -> &Accelerometer {
        &self.accel
    }

    /// A new rig like this one as [`SimRig::with_clock`] built it — plant at
    /// rest, not started, counters zero, accelerometer rendered — with the
    /// accelerometer's noise seeded `accel_seed`: bit for bit what the
    /// constructor gives for the same configuration with that seed, without
    /// repeating the plant's modal decomposition (a study builds one rig per
    /// trial).
    pub fn rebuilt(&self, accel_seed: u64) -> Self
    where
        C: Clone,
    {
        let mut r = self.clone();
        r.plant.reset();
        r.accel.reseed(accel_seed);
        r.render_accel = true;
        r.hand_prev = [0.0; 2];
        r.hand_target = [0.0; 2];
        r.truth = PlantFastOutput::default();
        r.seq = 0;
        r.state = RigState::Idle;
        r.anchor_time = Duration::ZERO;
        r.anchor_seq = 0;
        r.counters = StatusCounters::default();
        r
    }

    /// Render the accelerometer (the default) or not: off, every reading is
    /// the sensor's static output (no noise, no motion), for simulations
    /// in which nobody feels or records the fingertip acceleration (a
    /// study's V trials at scene fidelity).
    pub fn set_accelerometer_rendering(&mut self, on: bool) {
        self.render_accel = on;
    }

    /// Samples due now according to the wall clock and not yet simulated
    /// (paced rigs; 0 for batch).
    pub fn frames_due(&self) -> u64 {
        match (self.pacing, self.state) {
            (Pacing::WallClock { .. }, RigState::Running) => {
                let elapsed = self
                    .clock
                    .now()
                    .saturating_sub(self.anchor_time)
                    .as_secs_f64();
                let pos = self.anchor_seq + (elapsed * self.fs).floor() as u64;
                pos.saturating_sub(self.seq)
            }
            _ => 0,
        }
    }

    /// Next sequence number.
    pub fn seq(&self) -> u64 {
        self.seq
    }

    fn deadline(&self, seq: u64) -> Duration {
        self.anchor_time + Duration::from_secs_f64((seq - self.anchor_seq) as f64 / self.fs)
    }

    /// Simulate one sample: sanitise and limit the command, step the
    /// plant, read the accelerometer and the encoders. Allocation-free; the
    /// flags of the frame tell what happened (counted by [`Self::note_flags`]).
    #[inline(always)]
    fn frame(&mut self, cmd: &ActuatorFrame, hand: [f64; 2], hv: [f64; 2]) -> SensorFrame {
        // Common case: within the limits (hence finite), nothing to change.
        let (f, v, mut flags) = if cmd.force_n[0].abs() <= self.force_max
            && cmd.force_n[1].abs() <= self.force_max
            && cmd.haptuator_v.abs() <= self.drive_max
        {
            (cmd.force_n, cmd.haptuator_v, 0u8)
        } else {
            self.sanitise(cmd)
        };
        let in_stop_before = self.plant.x.end_stop_steps();
        let o = self.plant.step_fast(&PlantInput {
            force_n: f,
            drive_v: v,
            hand_m: hand,
            hand_vel_m_s: hv,
        });
        if self.plant.x.end_stop_steps() != in_stop_before {
            flags |= FrameFlags::END_STOP;
        }
        let r = if self.render_accel {
            self.accel.sample([o.accel_m_s2[0], o.accel_m_s2[1], 0.0])
        } else {
            self.accel.at_rest()
        };
        if r.clipped {
            flags |= FrameFlags::CLIPPED;
        }
        self.truth = o;
        SensorFrame {
            seq: self.seq,
            handle_m: [self.quantise(o.motor_m[0]), self.quantise(o.motor_m[1])],
            accel_m_s2: r.m_s2,
            flags: FrameFlags(flags),
        }
    }

    /// A command outside the limits or non-finite: non-finite components
    /// become 0 ([`FrameFlags::NONFINITE_COMMAND`]), others are clamped to
    /// the limits ([`FrameFlags::LIMITED`]). Returns (force, drive, flags).
    #[cold]
    #[inline(never)]
    fn sanitise(&self, cmd: &ActuatorFrame) -> ([f64; 2], f64, u8) {
        let mut flags = 0u8;
        let mut f = cmd.force_n;
        let mut v = cmd.haptuator_v;
        for x in f.iter_mut() {
            if !x.is_finite() {
                *x = 0.0;
                flags |= FrameFlags::NONFINITE_COMMAND;
            } else if x.abs() > self.force_max {
                *x = self.force_max.copysign(*x);
                flags |= FrameFlags::LIMITED;
            }
        }
        if !v.is_finite() {
            v = 0.0;
            flags |= FrameFlags::NONFINITE_COMMAND;
        } else if v.abs() > self.drive_max {
            v = self.drive_max.copysign(v);
            flags |= FrameFlags::LIMITED;
        }
        (f, v, flags)
    }

    /// Count a frame's flags and queue each kind of fault once per block
    /// (`noted` collects the kinds already queued in this block).
    #[cold]
    #[inline(never)]
    fn note_flags(&mut self, ff: FrameFlags, noted: &mut u8) {
        self.counters.note_flags(ff, self.seq, noted);
    }

    /// [`Rig::process_frame`] through the block path (paced or not running).
    #[cold]
    #[inline(never)]
    fn process_frame_slow(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        frame_as_block(self, command, sensors)
    }

    fn quantise(&self, x: f64) -> f64 {
        if self.encoder_res > 0.0 {
            crate::round_half_away(x / self.encoder_res) * self.encoder_res
        } else {
            x
        }
    }
}

impl<C: Clock> Rig for SimRig<C> {
    fn identity(&self) -> &RigIdentity {
        &self.identity
    }

    fn start(&mut self) -> Result<(), RigError> {
        self.state = RigState::Running;
        self.anchor_time = self.clock.now();
        self.anchor_seq = self.seq;
        Ok(())
    }

    fn stop(&mut self) -> Result<(), RigError> {
        self.state = RigState::Idle;
        Ok(())
    }

    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError> {
        let mut report = open_block(self.state, commands, sensors, self.seq)?;
        let n = report.frames;
        if n == 0 {
            return Ok(report);
        }
        // Long stall: skip the lost wall time instead of catching it up.
        if let Pacing::WallClock { max_lag_s } = self.pacing {
            let now = self.clock.now();
            let due = self.deadline(self.seq);
            if now > due && (now - due).as_secs_f64() > max_lag_s {
                let skipped = ((now - due).as_secs_f64() * self.fs).floor() as u64;
                self.anchor_time = now;
                self.anchor_seq = self.seq;
                report.skipped_samples = skipped;
                self.counters.counts.skipped_samples += skipped;
                self.counters.push(RigFault::Overrun {
                    seq: self.seq,
                    skipped,
                });
            }
        }
        // The hand moves linearly from its previous target to the new one
        // over the block: velocity Δ·f_s/n, position after frame i at
        // prev + (i + 1)/n·Δ.
        let dh = [
            self.hand_target[0] - self.hand_prev[0],
            self.hand_target[1] - self.hand_prev[1],
        ];
        let rate = self.fs / n as f64;
        let hv = [dh[0] * rate, dh[1] * rate];
        let inv_n = 1.0 / n as f64;
        let mut noted = 0u8;
        for (i, (cmd, out)) in commands.iter().zip(sensors.iter_mut()).enumerate() {
            let a = (i + 1) as f64 * inv_n;
            let hand = [self.hand_prev[0] + a * dh[0], self.hand_prev[1] + a * dh[1]];
            *out = self.frame(cmd, hand, hv);
            if out.flags.0 != 0 {
                self.note_flags(out.flags, &mut noted);
            }
            self.seq += 1;
        }
        self.hand_prev = self.hand_target;
        self.counters.counts.frames += n as u64;
        if let Pacing::WallClock { .. } = self.pacing {
            let deadline = self.deadline(self.seq);
            let now = self.clock.now();
            if now < deadline {
                self.clock.sleep_until(deadline);
            } else {
                report.lag_s = (now - deadline).as_secs_f64();
            }
        }
        Ok(report)
    }

    /// The block of one frame without the block machinery in the batch,
    /// running case (bit-identical to `process_block` with one frame: the
    /// hand moves by Δ = target − prev at velocity Δ·f_s); everything else
    /// (paced, not started) goes through `process_block`.
    #[inline]
    fn process_frame(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        if self.state != RigState::Running || !matches!(self.pacing, Pacing::Batch) {
            return self.process_frame_slow(command, sensors);
        }
        let first_seq = self.seq;
        let dh = [
            self.hand_target[0] - self.hand_prev[0],
            self.hand_target[1] - self.hand_prev[1],
        ];
        let hand = [self.hand_prev[0] + dh[0], self.hand_prev[1] + dh[1]];
        let hv = [dh[0] * self.fs, dh[1] * self.fs];
        let out = self.frame(command, hand, hv);
        if out.flags.0 != 0 {
            self.note_flags(out.flags, &mut 0);
        }
        *sensors = out;
        self.seq += 1;
        self.hand_prev = self.hand_target;
        self.counters.counts.frames += 1;
        Ok(BlockReport {
            first_seq,
            frames: 1,
            ..Default::default()
        })
    }

    fn status(&self) -> RigStatus {
        self.counters.status(self.state)
    }

    fn pop_fault(&mut self) -> Option<RigFault> {
        self.counters.pop_fault()
    }

    /// 1: the simulated rig is stepped one frame at a time
    /// ([`HapticLoop::step`](crate::HapticLoop::step)), the command computed
    /// from sample n − 1 acting during sample n, whatever the block length
    /// its driver schedules.
    fn loop_delay_samples(&self, _block_len: usize) -> u32 {
        1
    }
}

#[cfg(test)]
mod process_frame_tests {
    use super::*;
    use crate::device::ManualClock;

    /// A paced rig takes the block path (deadline, lag, skipped samples).
    #[test]
    fn paced_frame_path_reports_like_a_block() {
        let cfg = RigConfig::default();
        let clock = ManualClock::default();
        let mut a = SimRig::with_clock(
            &cfg,
            Integrator::Zoh,
            Pacing::WallClock { max_lag_s: 0.01 },
            clock.clone(),
        )
        .unwrap();
        a.start().unwrap();
        let mut s = SensorFrame::default();
        let r = a.process_frame(&ActuatorFrame::default(), &mut s).unwrap();
        assert_eq!((r.frames, r.skipped_samples), (1, 0));
        assert_eq!(clock.now(), Duration::from_secs_f64(1e-4));
        clock.advance(Duration::from_millis(50));
        let r = a.process_frame(&ActuatorFrame::default(), &mut s).unwrap();
        assert!(r.skipped_samples > 400, "{r:?}");
        assert_eq!(s.seq, 1);
    }
}
