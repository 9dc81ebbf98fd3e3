//! Any [`Rig`] — the simulated [`SimRig`] or a live backend — as a
//! [`CalibrationRig`]: drives on the x axis (Pantograph force x, Haptuator
//! drive), the hand held still, the x axis of the fingertip accelerometer
//! recorded; and the entry point of `kilotouch calibrate --rig sim`.

use super::error::{CalibrationError, Result};
use super::hash::content_hash;
use super::interface::check_run_lengths;
use super::interface::{ActuatorLimits, CalibrationRig, CheckReport, RigRecord, RunStats};
use super::progress::Progress;
use super::{CalibrationConfig, CalibrationOutcome, calibrate};
use crate::accel::Accelerometer;
use crate::config::RigConfig;
use crate::device::{ActuatorFrame, FrameFlags, Rig, RigFault, RigState, SensorFrame};
use crate::sim::SimRig;
use kilotouch_dsp::C64;
use std::path::Path;
use std::sync::atomic::AtomicBool;

/// Frames per `process_block` call.
pub const BLOCK: usize = 256;

/// A [`Rig`] seen by the calibration (module documentation).
#[derive(Debug)]
pub struct RigAdapter<R: Rig> {
    rig: R,
    config_hash: String,
    sensor: Option<Accelerometer>,
    commands: Vec<ActuatorFrame>,
    frames: Vec<SensorFrame>,
}

/// Hash of a rig configuration for [`RigRecord::config_hash`]: the
/// content hash ([`super::hash`]) of the sections that describe the device
/// a calibration measures (`[rig]`, `[plant]`, `[haptuator]`,
/// `[accelerometer]` without its noise seed, `[limits]`). The tweezer, the
/// coupling, the safety layer, the stability requirements and the camera
/// are set to their defaults first: a calibration stays valid when the
/// trap, the force scale, a safety setting or the camera changes.
pub fn rig_config_hash(cfg: &RigConfig) -> Result<String> {
    let mut c = cfg.clone();
    let d = RigConfig::default();
    c.accelerometer.seed = 0;
    c.tweezer = d.tweezer;
    c.coupling = d.coupling;
    c.safety = crate::config::SafetyConfig::default();
    c.stability = crate::config::StabilityConfig::default();
    c.camera = crate::config::CameraConfig::default();
    content_hash(&c)
}

impl<R: Rig> RigAdapter<R> {
    /// Wrap `rig`; `config_hash` identifies its configuration (e.g.
    /// [`rig_config_hash`]); `sensor` is the model of its accelerometer
    /// whose x-axis response is divided out (`None`: unknown).
    pub fn new(rig: R, config_hash: String, sensor: Option<Accelerometer>) -> Self {
        Self {
            rig,
            config_hash,
            sensor,
            commands: vec![ActuatorFrame::default(); BLOCK],
            frames: vec![SensorFrame::default(); BLOCK],
        }
    }

    /// The rig.
    pub fn rig(&self) -> &R {
        &self.rig
    }

    /// The rig, mutably.
    pub fn rig_mut(&mut self) -> &mut R {
        &mut self.rig
    }

    /// Give the rig back.
    pub fn into_inner(self) -> R {
        self.rig
    }

    fn ensure_running(&mut self) -> Result<()> {
        match self.rig.status().state {
            RigState::Running => Ok(()),
            RigState::Disconnected => Err(CalibrationError::Rig("the rig is disconnected".into())),
            _ => self.rig.start().map_err(CalibrationError::from),
        }
    }

    fn drain_faults(&mut self) -> Vec<RigFault> {
        std::iter::from_fn(|| self.rig.pop_fault()).collect()
    }
}

impl RigAdapter<SimRig> {
    /// The simulated rig of `cfg` (batch pacing), the accelerometer noise
    /// seeded with `seed` when given.
    pub fn sim(cfg: &RigConfig, seed: Option<u64>) -> Result<Self> {
        let mut cfg = cfg.clone();
        if let Some(s) = seed {
            cfg.accelerometer.seed = s;
        }
        let rig = SimRig::new(&cfg)?;
        let sensor = Some(rig.accelerometer().clone());
        Ok(Self::new(rig, rig_config_hash(&cfg)?, sensor))
    }
}

impl<R: Rig> CalibrationRig for RigAdapter<R> {
    fn sample_rate(&self) -> f64 {
        self.rig.sample_rate_hz()
    }

    fn record(&self) -> RigRecord {
        RigRecord::of(self.rig.identity(), self.config_hash.clone())
    }

    fn check(&mut self) -> Result<CheckReport> {
        self.ensure_running()?;
        let n = 64.min(BLOCK);
        self.commands[..n].fill(ActuatorFrame::default());
        let res = self
            .rig
            .process_block(&self.commands[..n], &mut self.frames[..n]);
        let mut messages: Vec<String> = self
            .drain_faults()
            .iter()
            .map(|f| format!("rig fault: {f:?}"))
            .collect();
        let responding = match &res {
            Ok(r) => r.frames == n,
            Err(e) => {
                messages.push(format!("no response: {e}"));
                false
            }
        };
        let frames = &self.frames[..n];
        let sensor_alive = responding
            && frames
                .iter()
                .all(|f| !f.flags.has(FrameFlags::LOST) && f.accel_m_s2[0].is_finite());
        let sensor_in_range =
            responding && frames.iter().all(|f| !f.flags.has(FrameFlags::CLIPPED));
        let id = self.rig.identity();
        let safety_armed = [id.force_max_n, id.haptuator_max_v]
            .iter()
            .all(|v| v.is_finite() && *v > 0.0);
        if !safety_armed {
            messages.push(format!(
                "actuator limits not set: force {} N, drive {} V",
                id.force_max_n, id.haptuator_max_v
            ));
        }
        Ok(CheckReport {
            sensor_alive,
            sensor_in_range,
            responding,
            safety_armed,
            messages,
        })
    }

    fn run(
        &mut self,
        low_drive: &[f64],
        high_drive: &[f64],
        accel: &mut [f64],
    ) -> Result<RunStats> {
        let n = check_run_lengths(low_drive, high_drive, accel)?;
        self.ensure_running()?;
        let mut stats = RunStats {
            samples: n,
            end_stop_hits: Some(0),
            ..RunStats::default()
        };
        let (mut hits, mut lost) = (0usize, 0usize);
        let mut start = 0;
        while start < n {
            let m = BLOCK.min(n - start);
            for ((c, &l), &h) in self.commands[..m]
                .iter_mut()
                .zip(&low_drive[start..start + m])
                .zip(&high_drive[start..start + m])
            {
                *c = ActuatorFrame {
                    force_n: [l, 0.0],
                    haptuator_v: h,
                };
            }
            self.rig
                .process_block(&self.commands[..m], &mut self.frames[..m])?;
            for (a, f) in accel[start..start + m].iter_mut().zip(&self.frames[..m]) {
                *a = f.accel_m_s2[0];
                let fl = f.flags;
                lost += usize::from(fl.has(FrameFlags::LOST));
                stats.accel_clipped += usize::from(fl.has(FrameFlags::CLIPPED));
                stats.drive_clipped += usize::from(fl.has(FrameFlags::LIMITED));
                hits += usize::from(fl.has(FrameFlags::END_STOP));
            }
            start += m;
        }
        self.drain_faults();
        if lost > 0 {
            return Err(CalibrationError::Rig(format!(
                "{lost} of {n} frames were lost during the run; the record is unusable"
            )));
        }
        stats.end_stop_hits = Some(hits);
        Ok(stats)
    }

    fn limits(&self) -> ActuatorLimits {
        let id = self.rig.identity();
        ActuatorLimits {
            max_force_n: id.force_max_n,
            max_high_drive: id.haptuator_max_v,
            accel_range_m_s2: (id.accel_range_m_s2.is_finite() && id.accel_range_m_s2 > 0.0)
                .then_some(id.accel_range_m_s2),
        }
    }

    fn sensor_response(&self, f_hz: f64) -> Option<C64> {
        self.sensor.as_ref().map(|a| a.response(0, f_hz))
    }
}

/// Entry point of `kilotouch calibrate --rig sim [--rig-config FILE]
/// [--seed N] [--out FILE.toml]`: load the rig file (the embedded default
/// when `rig_config` is `None`), build the simulated rig with the
/// accelerometer noise seeded by `seed`, run the procedure with `cfg`,
/// write the calibration file to `out` when given. The CLI prints
/// [`CalibrationOutcome::report`] as JSON (`--json`) or as
/// [`super::CalibrationReport::table`].
pub fn calibrate_sim(
    rig_config: Option<&Path>,
    seed: Option<u64>,
    cfg: &CalibrationConfig,
    out: Option<&Path>,
    progress: &mut dyn Progress,
    cancel: &AtomicBool,
) -> Result<CalibrationOutcome> {
    let rc = match rig_config {
        Some(p) => RigConfig::load(p)?,
        None => RigConfig::default(),
    };
    let mut rig = RigAdapter::sim(&rc, seed)?;
    calibrate(&mut rig, cfg, out, progress, cancel)
}
