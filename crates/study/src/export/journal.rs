//! The session journal: an append-only JSON-lines log with a CRC-32 per
//! line, from which a killed or crashed session is resumed.
//!
//! # Line format
//!
//! Every line is one JSON object, readable by `jq`, pandas
//! (`read_json(lines=True)`) or any JSON parser:
//!
//! ```text
//! {"seq":7,"utc":"2026-05-21T10:02:03.456Z","type":"trial_completed",…,"crc32":"1c291ca3"}
//! ```
//!
//! `seq` counts records from 0 without gaps, `utc` is the wall-clock time of
//! writing, `type` names the record ([`Record`]). The checksum is the CRC-32
//! (IEEE, [`crate::export::checksum::crc32`]) of the line's JSON object
//! *without* the `crc32` member, i.e. of the bytes
//! `line[..len−20] + "}"` — the last 20 bytes of a line are always
//! `,"crc32":"xxxxxxxx"}`. Each record is written with one `write` and
//! `fdatasync`ed before the call returns.
//!
//! # Reading after a crash
//!
//! A crash can only damage the record being appended. On reading, trailing
//! lines that are incomplete (no final newline) or fail their checksum form
//! the *torn tail*: they are ignored and reported ([`JournalRead::torn`]);
//! [`Journal::open`] saves a copy under `recovery/` and truncates them
//! before appending. A damaged line followed by valid ones cannot come from
//! a crash and is an error, as is a gap in `seq`, or a line whose checksum
//! holds but whose record is not understood (a newer version's record type,
//! or an edit with a recomputed checksum): such lines were written
//! completely and are never cut.
//!
//! # Records
//!
//! A *journal session* is one sitting: one [`crate::export::StudyStore`]
//! open … close. It is not the condition session of the paper (the
//! `session_index` column of `trials.csv`). See [`Record`] for the list and
//! `docs/STUDY.md` for the commit order.

use std::fs::File;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::checksum::{crc32, crc32_hex, parse_crc32_hex};
use super::session::{CalibrationRef, DeviceRecord, OrderRow, Sitting};
use crate::seeds::TrialKey;
use crate::storage::error::{ExportError, Position, Result, io_err};
use crate::storage::fsutil::{
    Checked, TornTail, append_durable, cut_torn_tail, open_append, split_lines, valid_prefix,
};
use crate::storage::utc::UtcTime;

/// File name of the journal in a study folder.
pub const JOURNAL_FILE: &str = "journal.jsonl";

/// Length of the `,"crc32":"xxxxxxxx"}` suffix of every line.
const CRC_SUFFIX_LEN: usize = 20;

/// What a sitting records when it opens the study folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionStart {
    /// Protocol name.
    pub protocol_name: String,
    /// SHA-256 of the protocol's canonical TOML
    /// ([`crate::protocol::Protocol::to_toml_string`]).
    pub protocol_sha256: String,
    /// Software version of the writer.
    pub software_version: String,
    /// Study seed (`seeds.study`), written as a decimal string (read also
    /// from a number: journals written before).
    #[serde(with = "crate::seeds::seed_string")]
    pub study_seed: u64,
    /// Rig identity (free text, e.g. `simulated` or a serial number).
    pub rig: String,
    /// Calibration file in use, if any.
    pub calibration: Option<CalibrationRef>,
    /// Participant → condition order table.
    pub orders: Vec<OrderRow>,
    /// Whether the folder already held data (a resume).
    pub resumed: bool,
    /// The live device the sitting runs on (absent: the simulated rig).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device: Option<DeviceRecord>,
}

/// What [`crate::export::StudyStore::open`] repaired or adopted.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RecoveryRecord {
    /// Bytes cut from the end of the journal (torn last record).
    pub journal_torn_bytes: u64,
    /// Bytes cut from the end of `trials.csv` (torn last row).
    pub trials_torn_bytes: u64,
    /// Rows found complete and checksummed in `trials.csv` whose
    /// `trial_completed` record was missing (crash between the two
    /// appends); they are kept and journaled now.
    pub adopted: Vec<TrialKey>,
    /// Trials started but neither completed nor aborted (crash during the
    /// trial); they will be run again with the same seeds.
    pub interrupted: Vec<TrialKey>,
}

/// A journal record (`type` member of the line).
// A sitting's opening record is the large one (protocol, orders, device);
// records are read and written once per event, never on a hot path, so the
// enum's size does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Record {
    /// A sitting opened the folder: protocol hash, software version, seeds,
    /// order table.
    SessionStarted(SessionStart),
    /// Crash repair done while opening (only when something was found).
    Recovered(RecoveryRecord),
    /// A trial began; its raw file may be partly written from now on.
    TrialStarted {
        /// The trial.
        trial: TrialKey,
        /// Trial seed, `0x…` ([`crate::seeds::format_seed`]).
        seed: String,
        /// Start time written to the row.
        started_utc: UtcTime,
    },
    /// The trial's row is in `trials.csv` (written and fsynced before this
    /// record).
    TrialCompleted {
        /// The trial.
        trial: TrialKey,
        /// The row's `row_crc32`.
        row_crc32: String,
        /// True when written by recovery for a row found without its record.
        #[serde(default)]
        adopted: bool,
    },
    /// The trial was abandoned (experimenter decision, device fault, or a
    /// crash found on resume); it stays pending and is run again.
    TrialAborted {
        /// The trial.
        trial: TrialKey,
        /// Why.
        reason: String,
    },
    /// A finished trial's raw file failed its check on resume: it was
    /// moved to `recovery/quarantine/` (or was missing) and the trial's row
    /// in `trials.csv` was rewritten to name where it went (`moved_to`,
    /// empty when nothing was left to move). Written before the move and
    /// the rewrite, so a crash in between is finished by the next opening.
    RawQuarantined {
        /// The trial.
        trial: TrialKey,
        /// The raw file the row named, relative to the folder.
        file: String,
        /// What is wrong with it.
        reason: String,
        /// Its new path relative to the folder (`None`: nothing to move).
        moved_to: Option<String>,
        /// The row's `row_crc32` before the rewrite.
        previous_row_crc32: String,
        /// The rewritten row's `row_crc32` (the row's CRC from now on).
        row_crc32: String,
    },
    /// Free-text note of the experimenter.
    Note {
        /// Text.
        text: String,
    },
    /// The session was paused.
    Paused {
        /// Why (may be empty).
        reason: String,
    },
    /// The session continues after a pause.
    Resumed,
    /// The sitting closed normally.
    SessionDone {
        /// Completed trials in the folder.
        completed: u64,
        /// Planned trials of the protocol.
        planned: u64,
        /// The sitting's timing verdict (absent: a batch simulation).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        timing: Option<super::session::SittingTiming>,
    },
}

/// One journal line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Sequence number, 0, 1, 2, … without gaps.
    pub seq: u64,
    /// Wall-clock time of writing.
    pub utc: UtcTime,
    /// The record.
    #[serde(flatten)]
    pub record: Record,
}

/// Encodes an entry as one line (with `crc32` member and final `\n`).
///
/// # Errors
/// Serialisation failure (cannot happen for the record types above).
pub fn encode_line(entry: &Entry) -> std::result::Result<String, serde_json::Error> {
    let json = serde_json::to_string(entry)?;
    let crc = crc32(json.as_bytes());
    // json ends with '}' (an object).
    let body = json.strip_suffix('}').unwrap_or(&json);
    Ok(format!("{body},\"crc32\":\"{}\"}}\n", crc32_hex(crc)))
}

/// Why a journal line was rejected by [`decode_line`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LineError {
    /// Not a complete, checksummed line (what a crash mid-append leaves).
    Damaged(String),
    /// The checksum holds but the record is not understood (edited with a
    /// recomputed checksum, or written by a newer version): never cut.
    Invalid(String),
}

impl std::fmt::Display for LineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LineError::Damaged(s) | LineError::Invalid(s) => f.write_str(s),
        }
    }
}

/// Decodes and verifies one line (without its `\n`).
///
/// # Errors
/// [`LineError`] with a short reason.
pub fn decode_line(text: &[u8]) -> std::result::Result<Entry, LineError> {
    let damaged = |s: &str| LineError::Damaged(s.to_owned());
    let s = std::str::from_utf8(text).map_err(|_| damaged("not UTF-8"))?;
    if s.len() < CRC_SUFFIX_LEN + 2 || !s.is_char_boundary(s.len() - CRC_SUFFIX_LEN) {
        return Err(damaged("too short for a record"));
    }
    let (body, suffix) = s.split_at(s.len() - CRC_SUFFIX_LEN);
    let stored = suffix
        .strip_prefix(",\"crc32\":\"")
        .and_then(|r| r.strip_suffix("\"}"))
        .ok_or_else(|| damaged("no crc32 member at the end of the line"))?;
    let stored = parse_crc32_hex(stored).ok_or_else(|| damaged("malformed crc32"))?;
    let json = format!("{body}}}");
    let computed = crc32(json.as_bytes());
    if computed != stored {
        return Err(LineError::Damaged(format!(
            "checksum mismatch (stored {stored:08x}, computed {computed:08x})"
        )));
    }
    serde_json::from_str(&json).map_err(|e| LineError::Invalid(format!("invalid record: {e}")))
}

/// The valid records of a journal file and its torn tail.
#[derive(Debug, Clone, PartialEq)]
pub struct JournalRead {
    /// Valid entries in order.
    pub entries: Vec<Entry>,
    /// 1-based line number of each entry.
    pub lines: Vec<u64>,
    /// Discarded tail (crash mid-append), if any.
    pub torn: Option<TornTail>,
}

impl JournalRead {
    /// Sequence number of the next record.
    pub fn next_seq(&self) -> u64 {
        self.entries.last().map_or(0, |e| e.seq + 1)
    }
}

/// Parses journal bytes (see the module documentation for the rules).
///
/// # Errors
/// [`ExportError::Format`] / [`ExportError::Checksum`] for an invalid line
/// followed by valid ones; [`ExportError::Inconsistent`] for a gap in `seq`.
pub fn parse_journal(path: &Path, bytes: &[u8]) -> Result<JournalRead> {
    let lines = split_lines(bytes);
    let checked = lines
        .into_iter()
        .map(|line| {
            let at = Position {
                line: line.number,
                column: None,
            };
            let c = if !line.complete {
                Checked::Bad(
                    ExportError::Format {
                        path: path.to_path_buf(),
                        at,
                        message: "incomplete record".into(),
                    },
                    "incomplete last line (no newline)".into(),
                )
            } else {
                match decode_line(line.text) {
                    Ok(e) => Checked::Good(e),
                    Err(LineError::Invalid(reason)) => Checked::Fatal(ExportError::Format {
                        path: path.to_path_buf(),
                        at,
                        message: format!(
                            "{reason} (the line's checksum is valid: it was written like this; \
                             a newer version's journal, or edited)"
                        ),
                    }),
                    Err(LineError::Damaged(reason)) => Checked::Bad(
                        ExportError::Format {
                            path: path.to_path_buf(),
                            at,
                            message: format!(
                                "invalid journal record followed by valid ones ({reason}); the \
                                 journal was modified or damaged"
                            ),
                        },
                        reason,
                    ),
                }
            };
            (line, c)
        })
        .collect();
    let (good, torn) = valid_prefix(path, bytes, checked)?;
    let mut entries = Vec::with_capacity(good.len());
    let mut numbers = Vec::with_capacity(good.len());
    for (expected, (line, e)) in good.into_iter().enumerate() {
        if e.seq != expected as u64 {
            return Err(ExportError::Inconsistent {
                path: path.to_path_buf(),
                message: format!(
                    "line {line}: journal sequence number {} where {expected} was expected \
                     (records missing or reordered)",
                    e.seq
                ),
            });
        }
        entries.push(e);
        numbers.push(line);
    }
    Ok(JournalRead {
        entries,
        lines: numbers,
        torn,
    })
}

/// Reads a journal file without modifying it (a missing file reads as
/// empty).
///
/// # Errors
/// I/O errors and those of [`parse_journal`].
pub fn read_journal(path: &Path) -> Result<JournalRead> {
    parse_journal(path, &read_bytes(path)?)
}

/// The bytes of a journal file (empty when it does not exist).
///
/// # Errors
/// I/O failures other than a missing file.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    match crate::storage::fsutil::read_no_follow_io(path) {
        Ok(b) => Ok(b),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(io_err(path, "read")(e)),
    }
}

/// Append handle on a journal.
#[derive(Debug)]
pub struct Journal {
    path: PathBuf,
    file: File,
    next_seq: u64,
}

impl Journal {
    /// Opens (creating if needed) the journal at `path` for appending:
    /// reads it, cuts a torn tail (a copy goes to `recovery_dir`) and
    /// positions after the last valid record. Returns the handle and what
    /// was read (with `torn.saved_to` set when a tail was cut).
    ///
    /// # Errors
    /// Those of [`read_journal`] and I/O failures.
    pub fn open(path: &Path, recovery_dir: &Path) -> Result<(Self, JournalRead)> {
        let bytes = read_bytes(path)?;
        let mut read = parse_journal(path, &bytes)?;
        let journal = Self::resume(path, &mut read, &bytes, recovery_dir)?;
        Ok((journal, read))
    }

    /// Second half of [`Journal::open`] for a caller that has already read
    /// and checked the file (`bytes`, `read` from [`parse_journal`]): cuts
    /// the torn tail (setting `read.torn.saved_to`) and opens for appending.
    ///
    /// # Errors
    /// I/O failures.
    pub fn resume(
        path: &Path,
        read: &mut JournalRead,
        bytes: &[u8],
        recovery_dir: &Path,
    ) -> Result<Self> {
        if let Some(torn) = read.torn.as_mut() {
            let tail = &bytes[torn.offset as usize..];
            torn.saved_to = Some(cut_torn_tail(path, torn, tail, recovery_dir)?);
        }
        let file = open_append(path)?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
            next_seq: read.next_seq(),
        })
    }

    /// Appends `record` stamped with the current time and fsyncs; returns
    /// the entry written.
    ///
    /// # Errors
    /// I/O failure (the record may then be torn; the next open repairs it).
    pub fn append(&mut self, record: Record) -> Result<Entry> {
        let entry = Entry {
            seq: self.next_seq,
            utc: UtcTime::now(),
            record,
        };
        let line = encode_line(&entry).map_err(|source| ExportError::Json {
            path: self.path.clone(),
            source,
        })?;
        append_durable(&mut self.file, &self.path, line.as_bytes())?;
        self.next_seq += 1;
        Ok(entry)
    }

    /// Path of the journal.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Sequence number of the next record.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }
}

/// Sittings recorded in a journal.
pub(crate) fn sittings(entries: &[Entry]) -> Vec<Sitting> {
    let mut out: Vec<Sitting> = Vec::new();
    for e in entries {
        match &e.record {
            Record::SessionStarted(s) => out.push(Sitting {
                journal_seq: e.seq,
                started_utc: e.utc,
                done_utc: None,
                software_version: s.software_version.clone(),
                rig: s.rig.clone(),
                calibration: s.calibration.clone(),
                resumed: s.resumed,
                device: s.device.clone(),
                timing: None,
            }),
            Record::SessionDone { timing, .. } => {
                if let Some(last) = out.last_mut() {
                    last.done_utc = Some(e.utc);
                    last.timing.clone_from(timing);
                }
            }
            _ => {}
        }
    }
    out
}
