//! The dual-stage plant: lumped model of paper §2.2, eq. 1 (Table 2).
//!
//! Along x the bodies are the terminal assembly `h` (mass m_h), the
//! Haptuator's moving magnet `v` (m_v), the motor windings `1` (m_1) and the
//! links `2` (m_2): M Ẍ + C Ẋ + K X = F with X = [x_h, x_v, x_1, x_2],
//! F = [f_v, −f_v, f, 0] and the chain 1 —(k_1,b_1)— 2 —(k_2,b_2)— h
//! —(k_v,b_v)— v. The finger (k_f, b_f) ties h to the hand, whose position
//! (and velocity) is an input: it adds k_f x_hand + b_f ẋ_hand to h's force.
//! (The paper prints m_l twice on the mass diagonal; the fourth mass is m_2.)
//!
//! Two optional side branches extend eq. 1 (see `docs/theory/plant.md` for
//! why the chain alone cannot show two antiresonances in the force channel):
//! a mass `e` on node 1 (motor shaft torsion, the sharp pair near 800 Hz)
//! and a mass `l` on node 2 (link bending, the damped antiresonance just
//! above 200 Hz). An absent branch leaves a "phantom" degree of freedom
//! with zero dynamics that is never excited (fixed-size matrices).
//!
//! The Haptuator drive u_v (V) reaches the Laplace force through a
//! first-order drive stage, ḟ_v = ω_d (g_v u_v − f_v). The magnet's stroke
//! r = x_v − x_h is limited by one-sided end stops: beyond ±s a spring–damper
//! (k_s, b_s) acts on r. The y axis has the same structure without the
//! Haptuator (bodies h, 1, 2 and the branches).
//!
//! State order: positions (one per DOF), velocities, then f_v (x axis only).
//! Inputs: [f (N), u_v (V), x_hand (m), ẋ_hand (m/s), 1] — the constant
//! input carries the end-stop offsets. Outputs: [ẍ_h (m/s²), x_h (m),
//! x_1 (m), r (m)].
//!
//! Discretisation: exact ZOH per end-stop regime (free, +stop, −stop; each
//! an affine LTI, switched on the state at the start of a step) is the
//! default; RK4 and semi-implicit Euler evaluate the piecewise-linear
//! vector field stage by stage. The per-step update allocates nothing.
//!
//! Files: [`model`] builds the continuous model of an axis from a rig file
//! (eq. 1 and the side branches); [`axis_sim`] discretises and steps it,
//! choosing once between the dense update (the readable reference: ZOH,
//! RK4 or semi-implicit Euler on fixed-size matrices) and the modal fast
//! path; [`modal`] holds the modal decomposition of the ZOH maps and
//! [`kernel`] the packed two-lane kernel that steps it.

pub mod axis_sim;
pub mod kernel;
pub mod modal;
pub mod model;
pub mod sections;

pub use axis_sim::AxisSim;
pub use model::AxisModel;

use crate::config::RigConfig;
use crate::error::RigError;
use crate::lti::Integrator;
use serde::{Deserialize, Serialize};

/// Number of plant inputs.
pub const NU: usize = 5;
/// Number of plant outputs.
pub const NY: usize = 4;
/// Input index: Pantograph force, N.
pub const IN_FORCE: usize = 0;
/// Input index: Haptuator drive, V.
pub const IN_DRIVE: usize = 1;
/// Input index: hand position, m.
pub const IN_HAND_POS: usize = 2;
/// Input index: hand velocity, m/s.
pub const IN_HAND_VEL: usize = 3;
/// Input index: constant 1 (end-stop offsets).
pub const IN_ONE: usize = 4;
/// Output index: tip acceleration ẍ_h, m/s².
pub const OUT_ACCEL: usize = 0;
/// Output index: tip position x_h, m.
pub const OUT_TIP: usize = 1;
/// Output index: motor position x_1 (what the encoders see), m.
pub const OUT_MOTOR: usize = 2;
/// Output index: magnet stroke r = x_v − x_h, m.
pub const OUT_STROKE: usize = 3;
/// State dimension of the x axis: 6 DOF × 2 + drive state.
pub const NX: usize = 13;
/// State dimension of the y axis: 5 DOF × 2.
pub const NYAX: usize = 10;
/// Plant axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    /// x: with the Haptuator.
    X,
    /// y: Pantograph only.
    Y,
}
/// Drive channel of the dual-stage device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Pantograph force (N) → tip acceleration (m/s²).
    Low,
    /// Haptuator drive (V) → tip acceleration (m/s²).
    High,
}
impl std::str::FromStr for Channel {
    type Err = RigError;
    fn from_str(s: &str) -> Result<Self, RigError> {
        match s {
            "low" => Ok(Channel::Low),
            "high" => Ok(Channel::High),
            _ => Err(RigError::InvalidInput(format!(
                "unknown channel `{s}` (expected low|high)"
            ))),
        }
    }
}
/// End-stop regime of the Haptuator magnet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Regime {
    /// |r| ≤ stroke.
    Free,
    /// r > stroke.
    Plus,
    /// r < −stroke.
    Minus,
}
/// Indices of one axis's degrees of freedom (`None` if absent).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DofMap {
    /// Terminal assembly.
    pub h: usize,
    /// Haptuator magnet (x axis only).
    pub v: Option<usize>,
    /// Motor windings.
    pub m1: usize,
    /// Links.
    pub m2: usize,
    /// Motor-side branch (phantom if absent).
    pub e: usize,
    /// Link-side branch (phantom if absent).
    pub l: usize,
    /// Number of DOF.
    pub n_dof: usize,
    /// Index of the drive state f_v, if any.
    pub drive: Option<usize>,
}
/// Outputs of one axis after a step.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AxisOutput {
    /// Tip acceleration, m/s².
    pub accel: f64,
    /// Tip position, m.
    pub tip: f64,
    /// Motor position, m.
    pub motor: f64,
    /// Magnet stroke, m (0 on y).
    pub stroke: f64,
}
/// Inputs of the two-axis plant for one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlantInput {
    /// Pantograph force command (x, y), N.
    pub force_n: [f64; 2],
    /// Haptuator drive (x axis), V.
    pub drive_v: f64,
    /// Hand position (x, y), m.
    pub hand_m: [f64; 2],
    /// Hand velocity (x, y), m/s.
    pub hand_vel_m_s: [f64; 2],
}
/// Outputs of the two-axis plant after one sample.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlantOutput {
    /// Tip acceleration (x, y), m/s².
    pub accel_m_s2: [f64; 2],
    /// Tip position (x, y), m.
    pub tip_m: [f64; 2],
    /// Motor-side (encoder) position (x, y), m.
    pub motor_m: [f64; 2],
    /// Haptuator magnet stroke, m.
    pub stroke_m: f64,
}
/// Outputs of the two-axis plant that a control loop needs each sample
/// ([`DualStagePlant::step_fast`]): [`PlantOutput`] without the tip
/// position (ground truth, [`DualStagePlant::tip_m`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PlantFastOutput {
    /// Tip acceleration (x, y), m/s².
    pub accel_m_s2: [f64; 2],
    /// Motor-side (encoder) position (x, y), m.
    pub motor_m: [f64; 2],
    /// Haptuator magnet stroke, m.
    pub stroke_m: f64,
}
/// The two-axis dual-stage plant (x with Haptuator, y without).
#[derive(Debug, Clone)]
pub struct DualStagePlant {
    /// x axis simulator.
    pub x: AxisSim<NX>,
    /// y axis simulator.
    pub y: AxisSim<NYAX>,
}
impl DualStagePlant {
    /// Build both axes from a configuration at its sample rate.
    pub fn new(cfg: &RigConfig, integrator: Integrator) -> Result<Self, RigError> {
        Self::with_rate(cfg, integrator, cfg.rig.sample_rate_hz)
    }

    /// Build both axes at an explicit sample rate (Hz).
    pub fn with_rate(cfg: &RigConfig, integrator: Integrator, fs: f64) -> Result<Self, RigError> {
        RigError::require_positive("fs", fs)?;
        let mx = AxisModel::new(cfg, Axis::X)?;
        let my = AxisModel::new(cfg, Axis::Y)?;
        Ok(Self {
            x: AxisSim::new(&mx, integrator, 1.0 / fs)?,
            y: AxisSim::new(&my, integrator, 1.0 / fs)?,
        })
    }

    /// Zero both axes.
    pub fn reset(&mut self) {
        self.x.reset();
        self.y.reset();
    }

    /// Advance one sample.
    #[inline]
    pub fn step(&mut self, i: &PlantInput) -> PlantOutput {
        let ox = self
            .x
            .step_inputs([i.force_n[0], i.drive_v, i.hand_m[0], i.hand_vel_m_s[0], 1.0]);
        let oy = self
            .y
            .step_inputs([i.force_n[1], 0.0, i.hand_m[1], i.hand_vel_m_s[1], 1.0]);
        PlantOutput {
            accel_m_s2: [ox.accel, oy.accel],
            tip_m: [ox.tip, oy.tip],
            motor_m: [ox.motor, oy.motor],
            stroke_m: ox.stroke,
        }
    }

    /// [`Self::step`] without the tip position: same state, counters and
    /// (bit-identical) other outputs; the tip of the new state is
    /// [`Self::tip_m`]. Saves the tip's dot products on the modal path.
    #[inline]
    pub fn step_fast(&mut self, i: &PlantInput) -> PlantFastOutput {
        let ox =
            self.x
                .step_inputs_fast([i.force_n[0], i.drive_v, i.hand_m[0], i.hand_vel_m_s[0], 1.0]);
        let oy = self
            .y
            .step_inputs_fast([i.force_n[1], 0.0, i.hand_m[1], i.hand_vel_m_s[1], 1.0]);
        PlantFastOutput {
            accel_m_s2: [ox.accel, oy.accel],
            motor_m: [ox.motor, oy.motor],
            stroke_m: ox.stroke,
        }
    }

    /// Tip position (x, y) of the current state, m (what [`Self::step`]
    /// returned as `tip_m` for the last step, bit for bit).
    pub fn tip_m(&self) -> [f64; 2] {
        [self.x.tip_m(), self.y.tip_m()]
    }
}

#[cfg(test)]
mod tests {
    use super::axis_sim::StepPath;
    use super::*;

    /// The default rig takes the fast input paths: force and drive as unit
    /// columns on x (all three regimes), no drive column on y. (That the
    /// fast paths equal the reference is `tests/equivalence.rs`.)
    #[test]
    fn the_default_rig_takes_the_fast_paths() {
        let a = DualStagePlant::new(&RigConfig::default(), Integrator::Zoh).unwrap();
        assert!(a.x.is_modal() && a.y.is_modal());
        assert!(a.x.drive_unit && !a.x.drive_free && !a.x.fast_d);
        assert!(a.y.drive_free && !a.y.fast_d);
        assert_eq!(a.x.path, StepPath::ModalDriveUnit);
        assert_eq!(a.y.path, StepPath::ModalNoDrive);
    }
}
