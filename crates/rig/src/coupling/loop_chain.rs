//! The chain the D loop runs and where it came from.
//!
//! The coupling's input is a force in newtons, so its chain is
//! *force-normalised*: K_sys = G0_L, hence C_L = 1 N/N on the Pantograph and
//! C_H = G0_L·F(s)/Ĝ_H(s) V/N on the Haptuator. The low band is rendered as
//! the force asked for; the high band is what the Pantograph alone would
//! have produced on a rigid body of the device's mass, continued by the
//! Haptuator to 1 kHz. Before a calibration the models give G0_L and Ĝ_H
//! ([`model_chain_design`]); a calibration replaces them by the identified
//! ones ([`crate::calibration::CompensatorDesign::force_chain_design`]),
//! which moves the crossover's compensation but not the rendered force
//! (`docs/theory/coupling-and-stability.md`, bilateral coupling).

use crate::calibration::CalibrationFile;
use crate::config::RigConfig;
use crate::error::RigError;
use crate::plant::{Axis, AxisModel, Channel};
use kilotouch_dsp::Tf;
use kilotouch_dsp::chain::{ChainCoefficients, ChainDesign};
use serde::{Deserialize, Serialize};

/// The analytic "as designed" chain for a rig model: G0_L = the mass-line
/// gain of the low channel (geometric mean of |G_L| over 63–200 Hz),
/// K_sys = G0_L, Ĝ_H = the paper's eq. 2 scaled to the model's high channel
/// (least squares in dB over 100–1000 Hz), LR4 at 200 Hz, F at 1 kHz.
///
/// # Errors
/// Invalid configuration.
pub fn model_chain_design(cfg: &RigConfig) -> Result<ChainDesign, RigError> {
    let m = AxisModel::new(cfg, Axis::X)?;
    let gm =
        |ch: Channel, lo: f64, hi: f64, reference: &dyn Fn(f64) -> f64| -> Result<f64, RigError> {
            let n = 200;
            let mut s = 0.0;
            for i in 0..n {
                let f = lo * (hi / lo).powf(i as f64 / (n - 1) as f64);
                s += (m.channel_response(ch, f)?.norm() / reference(f)).ln();
            }
            Ok((s / n as f64).exp())
        };
    let g0_l = gm(Channel::Low, 63.0, 200.0, &|_| 1.0)?;
    let paper = kilotouch_dsp::compensator::paper_g_h();
    let k = gm(Channel::High, 100.0, 1000.0, &|f| {
        paper.response_hz(f).norm()
    })?;
    let g_h = Tf::new(paper.num.iter().map(|c| c * k).collect(), paper.den.clone())?;
    Ok(ChainDesign {
        fs: cfg.rig.sample_rate_hz,
        k_sys: g0_l,
        g0_l,
        g_h,
        ..ChainDesign::paper()
    })
}

/// Where the loop's chain came from.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum ChainSource {
    /// The model's as-designed chain ([`model_chain_design`]): uncalibrated.
    AsDesigned,
    /// A calibration file.
    Calibration {
        /// Path as given.
        path: String,
        /// The file's own content checksum (`checksum` key).
        checksum: String,
    },
}

impl ChainSource {
    /// Short description ("as designed (uncalibrated)", "calibration FILE").
    pub fn describe(&self) -> String {
        match self {
            Self::AsDesigned => "as designed (uncalibrated)".into(),
            Self::Calibration { path, .. } => format!("calibration {path}"),
        }
    }

    /// Is this a calibration?
    pub fn is_calibrated(&self) -> bool {
        matches!(self, Self::Calibration { .. })
    }
}

/// The chain a loop runs: force-normalised coefficients and their source.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopChain {
    /// Coefficients (force in N → Pantograph N, Haptuator V).
    pub coefficients: ChainCoefficients,
    /// Where they came from.
    pub source: ChainSource,
}

impl LoopChain {
    /// The model's as-designed chain for `cfg`.
    ///
    /// # Errors
    /// Invalid configuration, design failure.
    pub fn as_designed(cfg: &RigConfig) -> Result<Self, RigError> {
        Ok(Self {
            coefficients: ChainCoefficients::design(&model_chain_design(cfg)?)?,
            source: ChainSource::AsDesigned,
        })
    }

    /// The force-normalised chain of a calibration file read from `path`
    /// (any path text; used in messages and records).
    ///
    /// # Errors
    /// A calibration at another sample rate than `fs`, an unusable design.
    pub fn from_calibration(file: &CalibrationFile, path: &str, fs: f64) -> Result<Self, RigError> {
        if file.rig.sample_rate_hz != fs {
            return Err(RigError::InvalidInput(format!(
                "calibration {path} is for {} Hz, the rig runs at {fs} Hz",
                file.rig.sample_rate_hz
            )));
        }
        let coefficients = file
            .compensators
            .force_chain_coefficients(&file.crossover)
            .map_err(|e| RigError::InvalidInput(format!("calibration {path}: {e}")))?;
        Ok(Self {
            coefficients,
            source: ChainSource::Calibration {
                path: path.to_owned(),
                checksum: file.checksum.clone(),
            },
        })
    }

    /// Read, check and load the calibration at `path` for the rig `cfg`
    /// (same configuration hash, same sample rate).
    ///
    /// # Errors
    /// Unreadable or corrupted file, another rig, another rate.
    pub fn load(path: &std::path::Path, cfg: &RigConfig) -> Result<Self, RigError> {
        let shown = path.display().to_string();
        let file =
            CalibrationFile::load(path).map_err(|e| RigError::InvalidInput(e.to_string()))?;
        let hash = crate::calibration::rig_config_hash(cfg)
            .map_err(|e| RigError::InvalidInput(e.to_string()))?;
        if file.rig.config_hash != hash {
            return Err(RigError::InvalidInput(format!(
                "calibration {shown} was made on another rig configuration ({}; this rig file is {hash}): calibrate this rig",
                file.rig.config_hash
            )));
        }
        Self::from_calibration(&file, &shown, cfg.rig.sample_rate_hz)
    }
}
