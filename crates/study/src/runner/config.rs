//! [`RunnerConfig`]: the camera and control timing of a run and the type of
//! its raw-signal files.

use crate::rawsig::Dtype;

/// Camera and control timing of the runner.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunnerConfig {
    /// Samples between two participant `act` calls (10 → 1 kHz at 10 kHz).
    pub act_every: usize,
    /// Camera frame rate, Hz.
    pub camera_fps: f64,
    /// Camera-to-display latency, s.
    pub camera_latency_s: f64,
    /// Raw-signal sample type (`None`: no raw files).
    pub raw: Option<Dtype>,
    /// Decimation of the kept trajectory (samples per point).
    pub trajectory_every: usize,
}

impl Default for RunnerConfig {
    fn default() -> Self {
        Self {
            act_every: 10,
            camera_fps: 25.0,
            camera_latency_s: 0.04,
            raw: Some(Dtype::F32),
            trajectory_every: 100,
        }
    }
}
