//! # kilotouch-rig
//!
//! The dual-stage haptic rig of Ji, Vézien, Hayward et al. ("KiloHertz
//! bandwidth, dual-stage haptic device lets you touch Brownian motion"),
//! simulated: the lumped plant of §2.2 (eq. 1, Table 2) with exact
//! zero-order-hold discretisation, the fingertip accelerometer, the optical
//! tweezer of §4.1 (eqs. 4–6), the [`Rig`] interface that live
//! rigs will also implement, and the bilateral coupling between handle and
//! trap.
//!
//! Units are SI unless a name says otherwise. Theory and references:
//! `docs/THEORY.md`; speed and accuracy tables: `docs/perf/rig.md`.

pub mod accel;
pub mod calibration;
pub mod config;
pub mod coupling;
pub mod error;
pub mod lorentzian;
pub mod lti;
pub mod plant;
pub mod rig;
pub mod sim;
pub mod tweezer;

pub use config::{RigConfig, default_config_text};
pub use error::RigError;
pub use lti::Integrator;
pub use plant::{Axis, AxisModel, Channel, DualStagePlant};
pub use rig::{ActuatorFrame, Rig, SensorFrame, SimRig};
pub use sim::{FrfReport, simulate_frf};
pub use tweezer::{SimTweezer, Tweezer, TweezerParams};
