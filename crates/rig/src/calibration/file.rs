//! Step 7: the calibration file (TOML).
//!
//! Contents: format name and version, creation date (UTC), software version,
//! rig identity and configuration hash with the sample rate, every setting
//! of the procedure, the check results, the identified models with their
//! fit diagnostics, the crossover choice, the compensators and the
//! verification table, and a checksum of all of it ([`super::hash`]).
//!
//! Loading validates, each failure a distinct [`CalibrationError`]:
//! TOML syntax, missing or unknown fields and a wrong format version
//! ([`CalibrationError::File`], with line and column), a checksum that does
//! not match the contents ([`CalibrationError::Corrupted`]), a file made for
//! another rig, rig configuration or sample rate
//! ([`CalibrationError::WrongRig`]), and unusable contents — an unstable
//! compensator, a non-finite or inconsistent gain
//! ([`CalibrationError::InvalidFile`]).

use super::CalibrationOutcome;
use super::check::CheckResult;
use super::config::CalibrationConfig;
use super::crossover::CrossoverChoice;
use super::design::CompensatorDesign;
use super::error::{CalibrationError, Result};
use super::hash::content_hash;
use super::identify::{HighChannelId, LowChannelId};
use super::interface::RigRecord;
use super::verify::Verification;
use kilotouch_dsp::chain::ChainCoefficients;
use kilotouch_dsp::compensator;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Value of the `format` key.
pub const FORMAT: &str = "kilotouch-calibration";
/// Current `format_version`.
pub const FORMAT_VERSION: u32 = 1;

/// A calibration file. Build one with [`CalibrationFile::new`], write it
/// with [`CalibrationFile::save`], read it with [`CalibrationFile::load_for`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`FORMAT_VERSION`] when written.
    pub format_version: u32,
    /// Creation time, RFC 3339 UTC.
    pub created: String,
    /// Software that wrote the file, e.g. `kilotouch-rig 0.1.0`.
    pub software: String,
    /// Content hash of everything else (`fnv1a64:…`).
    pub checksum: String,
    /// Rig identity and sample rate.
    pub rig: RigRecord,
    /// Settings the procedure ran with.
    pub settings: CalibrationConfig,
    /// Step 1.
    pub check: CheckResult,
    /// Step 2.
    pub low: LowChannelId,
    /// Step 3.
    pub high: HighChannelId,
    /// Step 4.
    pub crossover: CrossoverChoice,
    /// Step 5.
    pub compensators: CompensatorDesign,
    /// Step 6.
    pub verification: Verification,
}

/// `name version` of this crate.
pub fn software_version() -> String {
    format!("{} {}", env!("CARGO_PKG_NAME"), env!("CARGO_PKG_VERSION"))
}

fn invalid(origin: &str, message: impl Into<String>) -> CalibrationError {
    CalibrationError::InvalidFile {
        origin: origin.to_owned(),
        message: message.into(),
    }
}

impl CalibrationFile {
    /// The file of a finished calibration, created at `created` (RFC 3339,
    /// e.g. [`super::hash::utc_now_rfc3339`]), checksum filled in.
    pub fn new(outcome: &CalibrationOutcome, created: String) -> Result<Self> {
        let mut f = Self {
            format: FORMAT.to_owned(),
            format_version: FORMAT_VERSION,
            created,
            software: software_version(),
            checksum: String::new(),
            rig: outcome.rig.clone(),
            settings: outcome.config.clone(),
            check: outcome.check.clone(),
            low: outcome.low.clone(),
            high: outcome.high.clone(),
            crossover: outcome.crossover.clone(),
            compensators: outcome.design.clone(),
            verification: outcome.verification.clone(),
        };
        f.seal()?;
        Ok(f)
    }

    /// Checksum of the contents (the `checksum` field itself excluded).
    pub fn compute_checksum(&self) -> Result<String> {
        let mut c = self.clone();
        c.checksum.clear();
        content_hash(&c)
    }

    /// Set `checksum` to match the contents (after editing a file
    /// programmatically).
    pub fn seal(&mut self) -> Result<()> {
        self.checksum = self.compute_checksum()?;
        Ok(())
    }

    /// TOML text.
    pub fn to_toml_string(&self) -> Result<String> {
        toml::to_string(self).map_err(|e| CalibrationError::File {
            origin: "<string>".into(),
            message: format!("cannot write TOML: {e}"),
        })
    }

    /// Write to `path`.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        std::fs::write(path, self.to_toml_string()?).map_err(|source| CalibrationError::Io {
            action: "write",
            path: path.display().to_string(),
            source,
        })
    }

    /// Parse and validate (format, checksum, contents) without checking the
    /// rig; `origin` names the text in error messages.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self> {
        let f: Self = toml::from_str(text).map_err(|e| CalibrationError::File {
            origin: origin.to_owned(),
            message: e.to_string().trim_end().to_owned(),
        })?;
        if f.format != FORMAT {
            return Err(CalibrationError::File {
                origin: origin.to_owned(),
                message: format!("`format` is {:?}, expected {FORMAT:?}", f.format),
            });
        }
        if f.format_version != FORMAT_VERSION {
            return Err(CalibrationError::File {
                origin: origin.to_owned(),
                message: format!(
                    "`format_version` {} is not supported (this software reads {FORMAT_VERSION})",
                    f.format_version
                ),
            });
        }
        let computed = f.compute_checksum()?;
        if computed != f.checksum {
            return Err(CalibrationError::Corrupted {
                origin: origin.to_owned(),
                found: f.checksum.clone(),
                computed,
            });
        }
        f.validate_contents(origin)?;
        Ok(f)
    }

    /// Read and validate `path` without checking the rig.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = crate::input::read_text_capped(path, crate::input::MAX_CONFIG_BYTES).map_err(
            |source| CalibrationError::Io {
                action: "read",
                path: path.display().to_string(),
                source,
            },
        )?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// Read and validate `path` for the rig `rig`.
    pub fn load_for(path: impl AsRef<Path>, rig: &RigRecord) -> Result<Self> {
        let f = Self::load(path.as_ref())?;
        f.check_rig(rig, &path.as_ref().display().to_string())?;
        Ok(f)
    }

    /// Error unless this file was made for `rig`.
    pub fn check_rig(&self, rig: &RigRecord, origin: &str) -> Result<()> {
        if self.rig != *rig {
            return Err(CalibrationError::WrongRig {
                origin: origin.to_owned(),
                expected: rig.to_string(),
                found: self.rig.to_string(),
            });
        }
        Ok(())
    }

    /// The compensated chain stored in the file.
    pub fn chain_coefficients(&self) -> Result<ChainCoefficients> {
        self.compensators.chain_coefficients()
    }

    fn validate_contents(&self, origin: &str) -> Result<()> {
        let d = &self.compensators;
        let fs = self.rig.sample_rate_hz;
        if !(fs.is_finite() && fs > 0.0) || d.fs != fs {
            return Err(invalid(
                origin,
                format!("sample rate {fs} Hz (compensators at {} Hz)", d.fs),
            ));
        }
        for (name, v) in [("g0_l", d.g0_l), ("k_sys", d.k_sys), ("c_l", d.c_l)] {
            if !(v.is_finite() && v != 0.0) {
                return Err(invalid(
                    origin,
                    format!("`compensators.{name}` = {v} is unusable"),
                ));
            }
        }
        if d.crossover_hz != self.crossover.fc_hz || d.crossover_order != self.crossover.order {
            return Err(invalid(origin, "compensators and crossover disagree"));
        }
        if d.g_h != self.high.model || d.g0_l != self.crossover.g0_l {
            return Err(invalid(
                origin,
                "compensators do not use the identified models",
            ));
        }
        let c_l = compensator::low_gain(d.k_sys, d.g0_l)
            .map_err(|e| invalid(origin, format!("C_L: {e}")))?;
        if (c_l - d.c_l).abs() > 1e-9 * c_l.abs() {
            return Err(invalid(
                origin,
                format!("C_L = {} but K_sys/G0_L = {c_l}", d.c_l),
            ));
        }
        let c_h = compensator::high(d.k_sys, &d.g_h, d.band_limit_hz, d.band_limit_zeta)
            .map_err(|e| invalid(origin, format!("unstable or unusable compensator C_H: {e}")))?;
        let close = |a: &[f64], b: &[f64]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()))
        };
        if !(close(&c_h.num, &d.c_h.num) && close(&c_h.den, &d.c_h.den)) {
            return Err(invalid(origin, "C_H does not equal K_sys·F/Ĝ_H"));
        }
        self.chain_coefficients()
            .map_err(|e| invalid(origin, format!("unstable compensated chain: {e}")))?;
        Ok(())
    }
}
