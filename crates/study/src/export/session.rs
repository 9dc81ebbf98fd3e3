//! `session.json`: the study-level record of an output folder.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::checksum::sha256_hex;
use crate::protocol::{AssignmentTable, Condition, Protocol};
use crate::storage::error::{ExportError, Result, io_err};
use crate::storage::fsutil::{read_json, write_atomic};
use crate::storage::utc::UtcTime;
use kilotouch_rig::tweezer::TrapCalibrationRecord;

/// File name of the study record.
pub const SESSION_FILE: &str = "session.json";

/// Format tag written to `session.json`.
pub const FORMAT: &str = "kilotouch-study-output/1";

/// Software version recorded by default.
pub const SOFTWARE_VERSION: &str = env!("CARGO_PKG_VERSION");

/// Identity of the writer and the hardware, recorded with every sitting.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyMeta {
    /// Software name (default `kilotouch`).
    pub software_name: String,
    /// Software version (default [`SOFTWARE_VERSION`]).
    pub software_version: String,
    /// Rig identity (e.g. `simulated`, or the Pantograph serial number).
    pub rig: String,
    /// Calibration file in use.
    pub calibration: Option<CalibrationRef>,
    /// Content hash of the whole rig file in force
    /// (`kilotouch_rig::calibration::hash::content_hash`; `None`: not
    /// known to the writer, not checked).
    pub rig_hash: Option<String>,
    /// Whether raw signal files are written (`None`: not checked).
    pub raw_signals: Option<bool>,
    /// The trap calibration in force (κ and the detector's sensitivity
    /// applied to the tweezer; `None`: none applied).
    pub trap_calibration: Option<TrapCalibrationRecord>,
    /// The experimenter starts a new sitting with a recorded change of
    /// rig file, calibration or raw recording: the reason, journaled with
    /// the differences. `None`: a resume with different settings is
    /// refused ([`crate::export::ExportError::SettingsChanged`]).
    pub recorded_change: Option<String>,
    /// The device the sitting runs on (a live rig), recorded with the
    /// sitting in the journal and `session.json`; `None`: the simulated rig.
    pub device: Option<DeviceRecord>,
}

/// The device a sitting ran on and its measured loop delay
/// (`session.json` `sittings[].device`, the journal's `session_started`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceRecord {
    /// How it was opened, e.g. `serial:/dev/ttyACM0`.
    pub spec: String,
    /// Kind (`serial-daq`, `audio`).
    pub kind: String,
    /// Model name as the device reports it.
    pub name: String,
    /// Serial number.
    pub serial: String,
    /// Firmware version.
    pub firmware: String,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Samples per block exchanged with the device.
    pub block_samples: u32,
    /// Loop delay: from a sensor sample to the sample its command acts in,
    /// samples (block + command lead).
    pub loop_delay_samples: u32,
    /// The loop delay, ms.
    pub loop_delay_ms: f64,
    /// The delay beyond the simulated loop's one sample that the stability
    /// clearance includes, ms.
    pub extra_latency_ms: f64,
    /// Link round trip measured at connection, ms (`None`: not measured).
    pub round_trip_ms: Option<f64>,
}

impl StudyMeta {
    /// Meta with this crate's version and no calibration.
    pub fn new(rig: &str) -> Self {
        Self {
            software_name: "kilotouch".into(),
            software_version: SOFTWARE_VERSION.into(),
            rig: rig.into(),
            calibration: None,
            rig_hash: None,
            raw_signals: None,
            trap_calibration: None,
            recorded_change: None,
            device: None,
        }
    }
}

/// One participant's condition order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OrderRow {
    /// Display id (`P01`, …), the `participant` column.
    pub participant: String,
    /// 0-based participant index (used by the seed derivation).
    pub index: u32,
    /// Row of the counterbalancing square.
    pub row: usize,
    /// Conditions in session order (`session_index` 1, 2, …).
    pub sessions: Vec<Condition>,
}

impl OrderRow {
    /// The order as one string, e.g. `VDP` (the `session_order` column).
    pub fn order_string(&self) -> String {
        self.sessions.iter().map(|c| c.code()).collect()
    }

    /// 1-based session index of `condition`, if the participant runs it.
    pub fn session_index(&self, condition: Condition) -> Option<u32> {
        self.sessions
            .iter()
            .position(|&c| c == condition)
            .and_then(|i| u32::try_from(i + 1).ok())
    }
}

/// Order rows of an assignment table.
pub fn order_rows(table: &AssignmentTable) -> Vec<OrderRow> {
    table
        .participants
        .iter()
        .map(|p| OrderRow {
            participant: p.id.clone(),
            index: u32::try_from(p.participant).unwrap_or(u32::MAX),
            row: p.row,
            sessions: p.sessions.clone(),
        })
        .collect()
}

/// A calibration file identified by its SHA-256.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CalibrationRef {
    /// Path as given (informative).
    pub path: String,
    /// SHA-256 of the file's bytes, lowercase hex.
    pub sha256: String,
}

impl CalibrationRef {
    /// Hashes the file at `path`.
    ///
    /// # Errors
    /// The file cannot be read.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text =
            kilotouch_rig::input::read_text_capped(path, kilotouch_rig::input::MAX_CONFIG_BYTES)
                .map_err(io_err(path, "read calibration file"))?;
        let bytes = text.as_bytes();
        Ok(Self {
            path: path.display().to_string(),
            sha256: sha256_hex(bytes),
        })
    }
}

/// Software identity.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Software {
    /// Program name.
    pub name: String,
    /// Version.
    pub version: String,
}

/// One sitting (journal session), from the journal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sitting {
    /// Journal sequence number of its `session_started` record.
    pub journal_seq: u64,
    /// Start time.
    pub started_utc: UtcTime,
    /// Time of its `session_done` record, if it closed normally.
    pub done_utc: Option<UtcTime>,
    /// Software version.
    pub software_version: String,
    /// Rig identity.
    pub rig: String,
    /// Calibration in use.
    pub calibration: Option<CalibrationRef>,
    /// Whether it resumed existing data.
    pub resumed: bool,
    /// The live device it ran on (absent: the simulated rig).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<DeviceRecord>,
}

/// Progress counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Progress {
    /// Trials of the plan (practice + test).
    pub planned: u64,
    /// Rows in `trials.csv`.
    pub completed: u64,
}

/// Seeds and how trial seeds derive from them.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SeedInfo {
    /// Study seed.
    pub study: u64,
    /// Name of the derivation (see `docs/STUDY.md`).
    pub trial_derivation: String,
}

/// Content of `session.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    /// [`FORMAT`].
    pub format: String,
    /// Writer software at creation.
    pub software: Software,
    /// The protocol.
    pub protocol: Protocol,
    /// Its canonical TOML (hashed).
    pub protocol_toml: String,
    /// SHA-256 of `protocol_toml`.
    pub protocol_sha256: String,
    /// Seeds.
    pub seeds: SeedInfo,
    /// Participant → order.
    pub order_table: Vec<OrderRow>,
    /// Balance of the order table (human summary).
    pub order_balance: String,
    /// Rig identity at creation.
    pub rig: String,
    /// Calibration in force (at creation, or after the last recorded
    /// change).
    pub calibration: Option<CalibrationRef>,
    /// Content hash of the rig file in force (absent in folders written
    /// before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rig_hash: Option<String>,
    /// Whether raw signal files are written (absent in folders written
    /// before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw_signals: Option<bool>,
    /// The trap calibration in force (at creation, or from the last sitting
    /// that applied one; absent: none applied).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trap_calibration: Option<TrapCalibrationRecord>,
    /// Creation time of the folder.
    pub created_utc: UtcTime,
    /// Time of the last rewrite of this file.
    pub updated_utc: UtcTime,
    /// Sittings, from the journal.
    pub sittings: Vec<Sitting>,
    /// Progress at `updated_utc`.
    pub progress: Progress,
    /// How a simulated study was run (absent for studies with people).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulation: Option<SimulationInfo>,
}

/// How a simulated study's trials were run (`session.json` `simulation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SimulationInfo {
    /// How much of the model each trial ran ([`crate::fidelity`]).
    pub fidelity: crate::fidelity::Fidelity,
    /// The participant slice of a shard folder ([`crate::shard`]); absent
    /// for a whole (or merged) study.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<crate::shard::Shard>,
}

/// Name of the trial-seed derivation recorded in `session.json`.
pub const TRIAL_DERIVATION: &str = "kt-trial-v1: seed = SplitMix64 chain over (study, participant index, \
     condition letter, phase 0/1, trial); rng = ChaCha20(key = study LE | \"kt-trial\" | participant u32 | \
     condition | phase | 0 0 | trial u32 | 0 0 0 0, stream id)";

/// Canonical TOML of a protocol and its SHA-256.
///
/// # Errors
/// [`ExportError::ProtocolToml`] when the protocol cannot be serialised.
pub fn protocol_identity(protocol: &Protocol) -> Result<(String, String)> {
    let toml = protocol
        .to_toml_string()
        .map_err(|e| ExportError::ProtocolToml(e.to_string()))?;
    let sha = sha256_hex(toml.as_bytes());
    Ok((toml, sha))
}

/// Reads `session.json`.
///
/// # Errors
/// I/O or JSON errors.
pub fn read_session(path: &Path) -> Result<SessionInfo> {
    read_json(path)
}

/// Replaces `session.json` atomically with `info` (pretty JSON and a final
/// newline).
///
/// # Errors
/// JSON and I/O errors.
pub(crate) fn write_session(path: &Path, info: &SessionInfo) -> Result<()> {
    let mut json = serde_json::to_vec_pretty(info).map_err(|source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    json.push(b'\n');
    write_atomic(path, &json)
}
