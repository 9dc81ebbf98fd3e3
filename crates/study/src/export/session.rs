//! `session.json`: the study-level record of an output folder.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::checksum::sha256_hex;
use crate::protocol::{AssignmentTable, Condition, Protocol};
use crate::storage::error::{ExportError, Result, io_err};
use crate::storage::fsutil::write_atomic;
use crate::storage::utc::UtcTime;
use kilotouch_rig::config::CameraConfig;
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
    /// The camera the participant watched (the rig file's `[camera]`;
    /// `None`: not known to the writer).
    pub camera: Option<CameraConfig>,
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
    /// The live tweezer in the loop (absent: the simulated tweezer). Its
    /// command lead is part of [`Self::loop_delay_samples`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tweezer: Option<TweezerDeviceRecord>,
}

/// The live tweezer of a sitting, as it answered at connection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TweezerDeviceRecord {
    /// How it was opened, e.g. `serial:/dev/ttyACM1`.
    pub spec: String,
    /// Model name as the device reports it.
    pub name: String,
    /// Serial number.
    pub serial: String,
    /// Firmware version.
    pub firmware: String,
    /// The tweezer link's command lead, samples.
    pub lead_samples: u32,
    /// The command lead, ms.
    pub lead_ms: f64,
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
            camera: None,
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
    /// Its timing verdict (absent: a batch simulation, which runs no
    /// clock, or a sitting that did not close).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timing: Option<SittingTiming>,
}

/// How well a sitting kept time: the real-time engine's blocks that missed
/// their deadline and the commands a device received late, against the
/// rig file's `sitting_max_late_fraction`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SittingTiming {
    /// Samples the sitting's trials ran.
    pub samples: u64,
    /// Engine blocks while the sitting ran.
    pub blocks: u64,
    /// Of them, blocks that ended past their deadline's tolerance.
    pub deadline_misses: u64,
    /// Latest block end past its deadline, ms.
    pub worst_lateness_ms: f64,
    /// Commands the device flagged as received late.
    pub late_commands: u64,
    /// Share of the samples that ran late: (misses × block + late
    /// commands) / samples, 0–1.
    pub late_fraction: f64,
    /// The threshold, 0–1 (the rig file's `sitting_max_late_fraction`).
    pub max_late_fraction: f64,
    /// `on_time` or `late`.
    pub verdict: String,
}

impl SittingTiming {
    /// The verdict of a sitting's counts (`block_len` samples per block).
    pub fn judge(
        samples: u64,
        blocks: u64,
        deadline_misses: u64,
        worst_lateness_s: f64,
        late_commands: u64,
        block_len: u64,
        max_late_fraction: f64,
    ) -> Self {
        let late = deadline_misses
            .saturating_mul(block_len)
            .saturating_add(late_commands);
        let late_fraction = if samples > 0 {
            (late as f64 / samples as f64).min(1.0)
        } else {
            0.0
        };
        Self {
            samples,
            blocks,
            deadline_misses,
            worst_lateness_ms: if worst_lateness_s.is_finite() {
                (worst_lateness_s * 1e3).max(0.0)
            } else {
                0.0
            },
            late_commands,
            late_fraction,
            max_late_fraction,
            verdict: if late_fraction > max_late_fraction {
                "late"
            } else {
                "on_time"
            }
            .into(),
        }
    }

    /// Did the sitting run late?
    pub fn is_late(&self) -> bool {
        self.verdict == "late"
    }

    /// One line for people: "on time: 0.00 % of samples late (limit
    /// 0.10 %), 3 missed blocks, worst 2.4 ms".
    pub fn describe(&self) -> String {
        format!(
            "{}: {:.2} % of samples late (limit {:.2} %), {} missed block(s), worst {:.1} ms late, \
             {} late command(s)",
            if self.is_late() { "LATE" } else { "on time" },
            100.0 * self.late_fraction,
            100.0 * self.max_late_fraction,
            self.deadline_misses,
            self.worst_lateness_ms,
            self.late_commands
        )
    }
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
    /// The camera the participant watches: frame rate, latency, exposure
    /// (the rig file's `[camera]`; absent in folders written before it was
    /// recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraConfig>,
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

/// Key of the per-field checksums in `session.json`.
pub const INTEGRITY_KEY: &str = "integrity";

/// What the checksums of [`INTEGRITY_KEY`] are.
pub const INTEGRITY_ALGORITHM: &str =
    "sha256 of each top-level field's value, as compact JSON of the value parsed from this file";

/// Reads `session.json` and checks it: every field against the checksum
/// written with it ([`INTEGRITY_KEY`]; folders written before checksums
/// were recorded have none), then what is derived from the protocol text
/// ([`check_derived`]).
///
/// # Errors
/// I/O or JSON errors; [`ExportError::SessionTampered`] naming the field.
pub fn read_session(path: &Path) -> Result<SessionInfo> {
    parse_session(path, &crate::storage::fsutil::read_no_follow(path)?)
}

/// [`read_session`] of the bytes of a `session.json` (`path` names it in
/// messages).
///
/// # Errors
/// As [`read_session`].
pub fn parse_session(path: &Path, bytes: &[u8]) -> Result<SessionInfo> {
    let json_err = |source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    };
    let mut doc: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(bytes).map_err(json_err)?;
    let stored = doc.remove(INTEGRITY_KEY);
    let sums = stored.as_ref().map(|_| field_checksums(&doc));
    let info: SessionInfo =
        serde_json::from_value(serde_json::Value::Object(doc)).map_err(json_err)?;
    // The derived fields first: they name the edited value exactly
    // (`seeds.study`, `protocol.trials_per_session`); the checksums then
    // cover every other field.
    check_derived(path, &info)?;
    if let (Some(stored), Some(now)) = (stored, sums) {
        check_integrity(path, &now, &stored)?;
    }
    Ok(info)
}

/// SHA-256 of each top-level field of `doc` (compact JSON of its value).
fn field_checksums(
    doc: &serde_json::Map<String, serde_json::Value>,
) -> serde_json::Map<String, serde_json::Value> {
    doc.iter()
        .map(|(k, v)| {
            let text = serde_json::to_string(v).unwrap_or_default();
            (
                k.clone(),
                serde_json::Value::String(sha256_hex(text.as_bytes())),
            )
        })
        .collect()
}

/// Checks the checksums of the fields read (`now`, [`field_checksums`])
/// against the stored ones.
fn check_integrity(
    path: &Path,
    now: &serde_json::Map<String, serde_json::Value>,
    stored: &serde_json::Value,
) -> Result<()> {
    let tampered = |field: &str, detail: &str| ExportError::SessionTampered {
        path: path.to_path_buf(),
        field: field.to_owned(),
        detail: detail.to_owned(),
    };
    let Some(sums) = stored.get("fields").and_then(serde_json::Value::as_object) else {
        return Err(tampered(
            INTEGRITY_KEY,
            "its `fields` checksums are missing",
        ));
    };
    for (field, sum) in now {
        match sums.get(field) {
            None => return Err(tampered(field, "the field was added (it has no checksum)")),
            Some(s) if s != sum => {
                return Err(tampered(
                    field,
                    "its value does not match the checksum written with it",
                ));
            }
            Some(_) => {}
        }
    }
    if let Some(field) = sums.keys().find(|k| !now.contains_key(*k)) {
        return Err(tampered(field, "the field was removed"));
    }
    Ok(())
}

/// The fields of `session.json` that follow from its protocol text must
/// follow from it: `protocol_toml` hashes to `protocol_sha256`, parses to
/// `protocol`, and gives `seeds.study` and `order_table`.
///
/// # Errors
/// [`ExportError::SessionTampered`] naming the first field that does not.
pub fn check_derived(path: &Path, info: &SessionInfo) -> Result<()> {
    let tampered = |field: String, detail: String| ExportError::SessionTampered {
        path: path.to_path_buf(),
        field,
        detail,
    };
    let sha = sha256_hex(info.protocol_toml.as_bytes());
    if sha != info.protocol_sha256 {
        return Err(tampered(
            "protocol_toml".into(),
            format!(
                "its SHA-256 is {sha}, but protocol_sha256 records {}",
                info.protocol_sha256
            ),
        ));
    }
    // Deserialised only: a folder keeps the protocol it was created with
    // even where a later version validates protocols more strictly.
    let parsed: Protocol = toml::from_str(&info.protocol_toml)
        .map_err(|e| tampered("protocol_toml".into(), e.message().to_owned()))?;
    if parsed != info.protocol {
        let a = serde_json::to_value(&parsed).unwrap_or_default();
        let b = serde_json::to_value(&info.protocol).unwrap_or_default();
        let at = first_difference(&a, &b, "protocol".into());
        return Err(tampered(
            at,
            "differs from what protocol_toml (covered by protocol_sha256) gives".into(),
        ));
    }
    if info.seeds.study != info.protocol.seeds.study {
        return Err(tampered(
            "seeds.study".into(),
            format!(
                "is {}, but the protocol's seed is {}",
                info.seeds.study, info.protocol.seeds.study
            ),
        ));
    }
    if let Ok(table) = info.protocol.assignment()
        && order_rows(&table) != info.order_table
    {
        return Err(tampered(
            "order_table".into(),
            "differs from the counterbalancing the protocol gives".into(),
        ));
    }
    Ok(())
}

/// Path of the first difference between two JSON values (`prefix.key`).
fn first_difference(a: &serde_json::Value, b: &serde_json::Value, prefix: String) -> String {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for (k, va) in x {
                match y.get(k) {
                    Some(vb) if vb == va => {}
                    Some(vb) => return first_difference(va, vb, format!("{prefix}.{k}")),
                    None => return format!("{prefix}.{k}"),
                }
            }
            y.keys()
                .find(|k| !x.contains_key(*k))
                .map_or(prefix.clone(), |k| format!("{prefix}.{k}"))
        }
        _ => prefix,
    }
}

/// Replaces `session.json` atomically with `info` (pretty JSON, the
/// per-field checksums as its last field [`INTEGRITY_KEY`], and a final
/// newline).
///
/// # Errors
/// JSON and I/O errors.
pub(crate) fn write_session(path: &Path, info: &SessionInfo) -> Result<()> {
    let json_err = |source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    };
    let text = serde_json::to_string_pretty(info).map_err(json_err)?;
    // The checksums are of the values as a reader parses them from this
    // very text (so they never depend on how floats round-trip).
    let doc: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(&text).map_err(json_err)?;
    let integrity = serde_json::json!({
        "algorithm": INTEGRITY_ALGORITHM,
        "fields": field_checksums(&doc),
    });
    let integrity = serde_json::to_string_pretty(&integrity)
        .map_err(json_err)?
        .replace('\n', "\n  ");
    let body = text.strip_suffix("\n}").unwrap_or(&text);
    let json = format!("{body},\n  \"{INTEGRITY_KEY}\": {integrity}\n}}\n");
    write_atomic(path, json.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::SittingTiming;

    #[test]
    fn the_timing_verdict_counts_late_blocks_and_late_commands_against_the_limit() {
        // 2 missed blocks of 10 samples in 10 000 samples: 0.2 % > 0.1 %.
        let t = SittingTiming::judge(10_000, 1_000, 2, 0.0042, 0, 10, 1e-3);
        assert!((t.late_fraction - 2e-3).abs() < 1e-15);
        assert!(t.is_late());
        assert!((t.worst_lateness_ms - 4.2).abs() < 1e-12);
        assert!(
            t.describe()
                .starts_with("LATE: 0.20 % of samples late (limit 0.10 %)")
        );
        // Exactly at the limit is on time; late commands count one sample each.
        let t = SittingTiming::judge(10_000, 1_000, 0, f64::NEG_INFINITY, 10, 10, 1e-3);
        assert_eq!(t.verdict, "on_time");
        assert_eq!(t.worst_lateness_ms, 0.0);
        // No samples: nothing was late.
        let t = SittingTiming::judge(0, 0, 3, 0.1, 0, 10, 0.0);
        assert_eq!(t.late_fraction, 0.0);
        assert_eq!(t.verdict, "on_time");
    }
}
