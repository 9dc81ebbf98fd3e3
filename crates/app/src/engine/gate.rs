//! The output gate between the coupling and the rig: emergency stop (latched,
//! outputs exactly zero), haptics on/off (condition V) and a linear ramp-on.
//!
//! [`OutputGate::emergency_stop`] is the single place where the emergency
//! stop acts on the actuators; when the rig crate's safety layer lands, this
//! function is where the engine routes its stop request.
//!
//! [`GatedRig`] wraps any [`Rig`] so that every actuator frame passes the
//! gate just before the device, whatever computed it (here the rig crate's
//! [`kilotouch_rig::coupling::ClosedLoop`]).

use kilotouch_rig::error::RigError;
use kilotouch_rig::rig::{BlockReport, RigFault, RigIdentity, RigStatus};
use kilotouch_rig::{ActuatorFrame, Rig, SensorFrame};

/// Largest number of frames the gate copies per inner `process_block` call
/// (longer blocks are split; the copy lives on the stack).
pub const GATE_CHUNK: usize = 64;

/// Emergency stop latch, haptics enable and ramp (module docs).
#[derive(Debug, Clone)]
pub struct OutputGate {
    estopped: bool,
    enabled: bool,
    gain: f64,
    step: f64,
    zeroed_frames: u64,
}

impl OutputGate {
    /// A gate with outputs disabled, ramping over `ramp_samples` samples
    /// (0 = switch at once) when enabled.
    pub fn new(ramp_samples: u32) -> Self {
        Self {
            estopped: false,
            enabled: false,
            gain: 0.0,
            step: if ramp_samples == 0 {
                1.0
            } else {
                1.0 / f64::from(ramp_samples)
            },
            zeroed_frames: 0,
        }
    }

    /// THE emergency stop: from the next frame on every output is exactly
    /// zero, until [`OutputGate::reset_emergency_stop`]. Latched.
    pub fn emergency_stop(&mut self) {
        self.estopped = true;
        self.gain = 0.0;
    }

    /// Release the latch; outputs ramp back on from zero (no step).
    pub fn reset_emergency_stop(&mut self) {
        self.estopped = false;
        self.gain = 0.0;
    }

    /// Drop the gain to zero at once (rig stopped); outputs ramp on again.
    pub fn cut(&mut self) {
        self.gain = 0.0;
    }

    /// Is the emergency stop latched?
    pub fn is_estopped(&self) -> bool {
        self.estopped
    }

    /// Enable or disable the haptic outputs (ramped both ways).
    pub fn set_enabled(&mut self, on: bool) {
        self.enabled = on;
    }

    /// Are the outputs enabled (ignoring the emergency stop)?
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Current gain in [0, 1].
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// Frames forced to zero by the emergency stop so far.
    pub fn zeroed_frames(&self) -> u64 {
        self.zeroed_frames
    }

    /// Gate one frame. Never allocates, locks or panics; the result is
    /// finite and exactly zero while stopped or at zero gain.
    #[inline]
    pub fn apply(&mut self, cmd: ActuatorFrame) -> ActuatorFrame {
        if self.estopped {
            self.zeroed_frames += 1;
            return ActuatorFrame::default();
        }
        let target = if self.enabled { 1.0 } else { 0.0 };
        if self.gain < target {
            self.gain = (self.gain + self.step).min(target);
        } else if self.gain > target {
            self.gain = (self.gain - self.step).max(target);
        }
        if self.gain == 0.0 {
            return ActuatorFrame::default();
        }
        let g = self.gain;
        let fin = |v: f64| if v.is_finite() { v * g } else { 0.0 };
        ActuatorFrame {
            force_n: [fin(cmd.force_n[0]), fin(cmd.force_n[1])],
            haptuator_v: fin(cmd.haptuator_v),
        }
    }
}

/// A rig whose actuator frames pass an [`OutputGate`] (module docs).
#[derive(Debug)]
pub struct GatedRig<R: Rig> {
    /// The device.
    pub inner: R,
    /// The gate.
    pub gate: OutputGate,
    last: ActuatorFrame,
    outputs: [ActuatorFrame; GATE_CHUNK],
    n_outputs: usize,
}

impl<R: Rig> GatedRig<R> {
    /// Wrap `inner`.
    pub fn new(inner: R, gate: OutputGate) -> Self {
        Self {
            inner,
            gate,
            last: ActuatorFrame::default(),
            outputs: [ActuatorFrame::default(); GATE_CHUNK],
            n_outputs: 0,
        }
    }

    /// The last frame actually sent to the device.
    pub fn last_output(&self) -> ActuatorFrame {
        self.last
    }

    /// The frames actually sent by the last inner `process_block` call (the
    /// last chunk of at most [`GATE_CHUNK`] frames), in order.
    pub fn last_outputs(&self) -> &[ActuatorFrame] {
        &self.outputs[..self.n_outputs]
    }
}

impl<R: Rig> Rig for GatedRig<R> {
    fn identity(&self) -> &RigIdentity {
        self.inner.identity()
    }

    fn start(&mut self) -> Result<(), RigError> {
        self.inner.start()
    }

    fn stop(&mut self) -> Result<(), RigError> {
        self.last = ActuatorFrame::default();
        self.n_outputs = 0;
        self.inner.stop()
    }

    fn process_block(
        &mut self,
        commands: &[ActuatorFrame],
        sensors: &mut [SensorFrame],
    ) -> Result<BlockReport, RigError> {
        if commands.len() != sensors.len() {
            return Err(RigError::InvalidInput(
                "commands and sensor frames differ in length".into(),
            ));
        }
        let mut total = BlockReport::default();
        let mut first = true;
        for (cmds, sens) in commands
            .chunks(GATE_CHUNK)
            .zip(sensors.chunks_mut(GATE_CHUNK))
        {
            for (b, c) in self.outputs.iter_mut().zip(cmds) {
                *b = self.gate.apply(*c);
            }
            let n = cmds.len();
            self.n_outputs = n;
            if n > 0 {
                self.last = self.outputs[n - 1];
            }
            let r = self.inner.process_block(&self.outputs[..n], sens)?;
            if first {
                total.first_seq = r.first_seq;
                first = false;
            }
            total.frames += r.frames;
            total.lost_frames += r.lost_frames;
            total.skipped_samples += r.skipped_samples;
            total.lag_s = total.lag_s.max(r.lag_s);
        }
        Ok(total)
    }

    /// One frame: gated like a one-frame block, sent through the device's
    /// frame path ([`Rig::process_frame`]).
    #[inline]
    fn process_frame(
        &mut self,
        command: &ActuatorFrame,
        sensors: &mut SensorFrame,
    ) -> Result<BlockReport, RigError> {
        let out = self.gate.apply(*command);
        self.outputs[0] = out;
        self.n_outputs = 1;
        self.last = out;
        self.inner.process_frame(&out, sensors)
    }

    fn status(&self) -> RigStatus {
        self.inner.status()
    }

    fn pop_fault(&mut self) -> Option<RigFault> {
        self.inner.pop_fault()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cmd(v: f64) -> ActuatorFrame {
        ActuatorFrame {
            force_n: [v, -v],
            haptuator_v: v,
        }
    }

    #[test]
    fn ramp_is_linear_and_estop_is_exactly_zero_and_latched() {
        let mut g = OutputGate::new(4);
        assert_eq!(g.apply(cmd(1.0)), ActuatorFrame::default(), "disabled");
        g.set_enabled(true);
        let gains: Vec<f64> = (0..6).map(|_| g.apply(cmd(1.0)).force_n[0]).collect();
        assert_eq!(gains, vec![0.25, 0.5, 0.75, 1.0, 1.0, 1.0]);
        g.emergency_stop();
        for _ in 0..10 {
            let o = g.apply(cmd(-3.0));
            assert_eq!(o.force_n[0].to_bits(), 0.0f64.to_bits(), "+0.0, not -0.0");
            assert_eq!(o.force_n[1].to_bits(), 0.0f64.to_bits());
            assert_eq!(o.haptuator_v.to_bits(), 0.0f64.to_bits());
        }
        // Still latched after re-enabling: only the explicit reset releases it.
        g.set_enabled(true);
        assert_eq!(g.apply(cmd(1.0)), ActuatorFrame::default());
        g.reset_emergency_stop();
        assert_eq!(g.apply(cmd(1.0)).force_n[0], 0.25, "ramps on again");
        assert_eq!(g.zeroed_frames(), 11);
    }

    #[test]
    fn non_finite_never_passes() {
        let mut g = OutputGate::new(0);
        g.set_enabled(true);
        let o = g.apply(ActuatorFrame {
            force_n: [f64::NAN, f64::INFINITY],
            haptuator_v: f64::NEG_INFINITY,
        });
        assert_eq!(o, ActuatorFrame::default());
    }
}
