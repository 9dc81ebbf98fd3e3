//! Step 7: the calibration file (TOML).
//!
//! Contents: format name and version, creation date (UTC), software version,
//! rig identity and configuration hash with the sample rate, every setting
//! of the procedure, the check results, the identified models with their
//! fit diagnostics, the crossover choice, the compensators and the
//! verification table, and a checksum of all of it ([`super::hash`]).
//!
//! The crossover (frequency `crossover_hz` and order) is stored once, in
//! `[crossover]`. Files of `format_version` 1 also held copies of both in
//! `[compensators]` (`crossover_hz`, `crossover_order`) and named the
//! frequency `fc_hz`; they still load ([`CalibrationFile::from_toml_str`]).
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
pub const FORMAT_VERSION: u32 = 2;
/// The `format_version` whose `[compensators]` table also held the
/// crossover (`crossover_hz`, `crossover_order`), copies of `[crossover]`'s
/// `fc_hz` and `order`.
const FORMAT_VERSION_CROSSOVER_TWICE: i64 = 1;

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

/// Error unless the checksum `found` in a file is the `computed` one.
fn check_checksum(found: &str, computed: &str, origin: &str) -> Result<()> {
    if computed != found {
        return Err(CalibrationError::Corrupted {
            origin: origin.to_owned(),
            found: found.to_owned(),
            computed: computed.to_owned(),
        });
    }
    Ok(())
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
    ///
    /// A file of `format_version` 1 ([`FORMAT_VERSION_CROSSOVER_TWICE`]) is
    /// checked against the checksum it was written with, its two copies of
    /// the crossover must agree (an error names both otherwise), and it is
    /// returned in the current layout, resealed: its `checksum` is that of
    /// the current layout, the one saving it again writes.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self> {
        let syntax = |e: toml::de::Error| CalibrationError::File {
            origin: origin.to_owned(),
            message: e.to_string().trim_end().to_owned(),
        };
        let table: toml::Table = toml::from_str(text).map_err(syntax)?;
        let f = if table
            .get("format_version")
            .and_then(toml::Value::as_integer)
            == Some(FORMAT_VERSION_CROSSOVER_TWICE)
        {
            Self::from_crossover_twice(table, origin)?
        } else {
            // Parsed again from the text for errors with line and column.
            let f: Self = toml::from_str(text).map_err(syntax)?;
            f.check_format(origin)?;
            check_checksum(&f.checksum, &f.compute_checksum()?, origin)?;
            f
        };
        f.validate_contents(origin)?;
        Ok(f)
    }

    /// `format` is [`FORMAT`] and `format_version` [`FORMAT_VERSION`].
    fn check_format(&self, origin: &str) -> Result<()> {
        let message = if self.format != FORMAT {
            format!("`format` is {:?}, expected {FORMAT:?}", self.format)
        } else if self.format_version != FORMAT_VERSION {
            format!(
                "`format_version` {} is not supported (this software reads {FORMAT_VERSION} \
                 and {FORMAT_VERSION_CROSSOVER_TWICE})",
                self.format_version
            )
        } else {
            return Ok(());
        };
        Err(CalibrationError::File {
            origin: origin.to_owned(),
            message,
        })
    }

    /// A parsed file of `format_version` 1 in the current layout (see
    /// [`Self::from_toml_str`]).
    fn from_crossover_twice(mut table: toml::Table, origin: &str) -> Result<Self> {
        let mut unsealed = table.clone();
        unsealed.insert("checksum".into(), toml::Value::String(String::new()));
        let computed = content_hash(&unsealed)?;
        let copies = table
            .get_mut("compensators")
            .and_then(toml::Value::as_table_mut)
            .map(|c| (c.remove("crossover_hz"), c.remove("crossover_order")));
        let mut f: Self = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| CalibrationError::File {
                origin: origin.to_owned(),
                message: e.to_string().trim_end().to_owned(),
            })?;
        f.format_version = FORMAT_VERSION;
        f.check_format(origin)?;
        check_checksum(&f.checksum, &computed, origin)?;
        let (hz, order) = copies.unwrap_or_default();
        let hz = hz.as_ref().and_then(toml::Value::as_float);
        let order = order.as_ref().and_then(toml::Value::as_integer);
        let xo = &f.crossover;
        if hz != Some(xo.crossover_hz) || order != i64::try_from(xo.order).ok() {
            let show = |v: Option<String>| v.unwrap_or_else(|| "missing".into());
            return Err(invalid(
                origin,
                format!(
                    "this format_version {FORMAT_VERSION_CROSSOVER_TWICE} file stores the crossover \
                     twice and the copies disagree: `crossover.fc_hz` = {} Hz, \
                     `compensators.crossover_hz` = {} Hz; `crossover.order` = {}, \
                     `compensators.crossover_order` = {}",
                    xo.crossover_hz,
                    show(hz.map(|v| v.to_string())),
                    xo.order,
                    show(order.map(|v| v.to_string())),
                ),
            ));
        }
        f.seal()?;
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
        self.compensators.chain_coefficients(&self.crossover)
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
