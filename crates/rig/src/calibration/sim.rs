//! The simulated rig as a [`CalibrationRig`]: the dual-stage plant
//! ([`crate::plant::DualStagePlant`], x axis driven, hand held still) and the
//! fingertip accelerometer ([`crate::accel::Accelerometer`], x axis read).

use super::error::{CalibrationError, Result};
use super::hash::content_hash;
use super::interface::{ActuatorLimits, CalibrationRig, CheckReport, RigIdentity, RunStats};
use crate::accel::Accelerometer;
use crate::config::RigConfig;
use crate::lti::Integrator;
use crate::plant::{DualStagePlant, PlantInput};
use kilotouch_dsp::C64;

/// The simulated rig, seen by the calibration.
#[derive(Debug, Clone)]
pub struct SimCalibrationRig {
    cfg: RigConfig,
    plant: DualStagePlant,
    accel: Accelerometer,
    tip: Vec<f64>,
}

fn rig_err(e: crate::error::RigError) -> CalibrationError {
    CalibrationError::Rig(e.to_string())
}

impl SimCalibrationRig {
    /// Build from a rig configuration; `seed` overrides the accelerometer's
    /// noise seed.
    pub fn new(cfg: &RigConfig, seed: Option<u64>) -> Result<Self> {
        let mut cfg = cfg.clone();
        if let Some(s) = seed {
            cfg.accelerometer.seed = s;
        }
        cfg.validate().map_err(rig_err)?;
        let fs = cfg.rig.sample_rate_hz;
        Ok(Self {
            plant: DualStagePlant::new(&cfg, Integrator::Zoh).map_err(rig_err)?,
            accel: Accelerometer::new(&cfg.accelerometer, fs).map_err(rig_err)?,
            tip: Vec::new(),
            cfg,
        })
    }

    /// The rig configuration in use.
    pub fn config(&self) -> &RigConfig {
        &self.cfg
    }

    /// True tip acceleration along x (m/s², before the sensor) of the last
    /// run.
    pub fn last_tip(&self) -> &[f64] {
        &self.tip
    }
}

impl CalibrationRig for SimCalibrationRig {
    fn sample_rate(&self) -> f64 {
        self.cfg.rig.sample_rate_hz
    }

    fn identity(&self) -> RigIdentity {
        RigIdentity {
            name: "sim".into(),
            serial: self.cfg.rig.name.clone(),
            config_hash: content_hash(&self.cfg).unwrap_or_else(|_| "fnv1a64:unhashable".into()),
        }
    }

    fn check(&mut self) -> Result<CheckReport> {
        Ok(CheckReport {
            sensor_alive: true,
            sensor_in_range: true,
            responding: true,
            safety_armed: self.cfg.limits.pantograph_force_max_n > 0.0
                && self.cfg.limits.haptuator_drive_max_v > 0.0,
            messages: vec![],
        })
    }

    fn run(
        &mut self,
        low_drive: &[f64],
        high_drive: &[f64],
        accel: &mut [f64],
    ) -> Result<RunStats> {
        let n = accel.len();
        if low_drive.len() != n || high_drive.len() != n {
            return Err(CalibrationError::Rig(format!(
                "drive lengths {} and {} differ from the record length {n}",
                low_drive.len(),
                high_drive.len()
            )));
        }
        let lim = &self.cfg.limits;
        let mut stats = RunStats {
            samples: n,
            ..RunStats::default()
        };
        let stops_before = self.plant.x.end_stop_steps();
        let clamp = |u: f64, l: f64, c: &mut usize| {
            let u = if u.is_finite() { u } else { 0.0 };
            if u.abs() > l {
                *c += 1;
                l.copysign(u)
            } else {
                u
            }
        };
        self.tip.clear();
        self.tip.reserve(n);
        for i in 0..n {
            let input = PlantInput {
                force_n: [
                    clamp(
                        low_drive[i],
                        lim.pantograph_force_max_n,
                        &mut stats.drive_clipped,
                    ),
                    0.0,
                ],
                drive_v: clamp(
                    high_drive[i],
                    lim.haptuator_drive_max_v,
                    &mut stats.drive_clipped,
                ),
                ..PlantInput::default()
            };
            let out = self.plant.step(&input);
            self.tip.push(out.accel_m_s2[0]);
            let r = self
                .accel
                .sample([out.accel_m_s2[0], out.accel_m_s2[1], 0.0]);
            if r.clipped {
                stats.accel_clipped += 1;
            }
            accel[i] = r.m_s2[0];
        }
        stats.end_stop_hits = Some((self.plant.x.end_stop_steps() - stops_before) as usize);
        Ok(stats)
    }

    fn limits(&self) -> ActuatorLimits {
        ActuatorLimits {
            max_force_n: self.cfg.limits.pantograph_force_max_n,
            max_high_drive: self.cfg.limits.haptuator_drive_max_v,
            accel_range_m_s2: Some(self.accel.range_m_s2()),
        }
    }

    fn sensor_response(&self, f_hz: f64) -> Option<C64> {
        Some(self.accel.response(0, f_hz))
    }
}
