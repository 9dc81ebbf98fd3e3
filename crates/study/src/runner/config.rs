//! [`RunnerConfig`]: the control timing of a run and the type of its
//! raw-signal files (the camera is the rig file's `[camera]`).

use crate::rawsig::Dtype;

/// Control timing and recording of the runner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunnerConfig {
    /// Samples between two participant `act` calls (10 → 1 kHz at 10 kHz).
    pub act_every: usize,
    /// Raw-signal sample type (`None`: no raw files).
    pub raw: Option<Dtype>,
    /// Decimation of the kept trajectory (samples per point).
    pub trajectory_every: usize,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            act_every: 10,
            raw: Some(Dtype::F32),
            trajectory_every: 100,
        }
    }
}
