//! The simulated backend: the simulated rig ([`SimRig`]) and the model's
//! analytic responses behind `kilotouch sim frf` ([`frf`]).

pub mod frf;
pub mod rig;

pub use frf::{FrfPoint, FrfReport, simulate_frf};
pub use rig::{Pacing, SimRig};
