//! The file-system steps of [`StudyStore::open`](super::StudyStore::open):
//! loading or creating the folder and its `session.json`, reading the
//! append-only files before anything is modified ([`FolderRead`]), cutting
//! torn tails, and journaling the sitting. What to keep, adopt and run
//! again is decided in between by the pure [`super::reconcile`] step.

use std::collections::HashMap;
use std::fs::File;
use std::path::{Path, PathBuf};

use super::checksum;
use super::journal::{self, JOURNAL_FILE, Journal, JournalRead, Record, RecoveryRecord};
use super::plan::RAW_DIR;
use super::reconcile::{Found, Recovery, check_sittings};
use super::session::{self, OrderRow, Progress, SESSION_FILE, SessionInfo, StudyMeta};
use super::trials::{self, ReadOptions, TRIALS_FILE, TrialsRead};
use crate::protocol::{AssignmentTable, Location, Protocol, ProtocolError};
use crate::seeds::TrialKey;
use crate::storage::error::{ExportError, Result};
use crate::storage::fsutil::{
    TornTail, create_dir_durable, create_root_durable, cut_torn_tail, entry_exists, open_append,
    read_no_follow,
};
use crate::storage::utc::UtcTime;

/// Folder of the copies of cut torn tails.
pub const RECOVERY_DIR: &str = "recovery";

/// Checks the protocol's values.
///
/// # Errors
/// [`ExportError::Protocol`] naming the protocol and the invalid field.
pub(crate) fn validate_protocol(protocol: &Protocol) -> Result<()> {
    protocol.validate().map_err(|invalid| {
        ExportError::Protocol(ProtocolError::Invalid {
            location: Location {
                file: format!("<protocol `{}`>", protocol.name),
                line: None,
                column: None,
            },
            invalid,
        })
    })
}

/// Reads the `session.json` of an existing study and checks that it is of
/// this format and of `protocol` (SHA-256 `protocol_sha256` of its
/// canonical TOML).
///
/// # Errors
/// [`ExportError::NotAStudyFolder`] for another format,
/// [`ExportError::ProtocolMismatch`]; those of [`session::read_session`].
pub(crate) fn load_session(
    session_path: &Path,
    protocol: &Protocol,
    protocol_sha256: &str,
) -> Result<SessionInfo> {
    let info = session::read_session(session_path)?;
    if info.format != session::FORMAT {
        return Err(ExportError::NotAStudyFolder {
            path: session_path.to_path_buf(),
            reason: format!("format `{}` is not `{}`", info.format, session::FORMAT),
        });
    }
    // Equal hashes, or an equal protocol whose canonical TOML text
    // changed with a newer `toml` crate.
    if info.protocol_sha256 != protocol_sha256 && info.protocol != *protocol {
        return Err(ExportError::ProtocolMismatch {
            path: session_path.to_path_buf(),
            expected_name: protocol.name.clone(),
            expected_sha256: protocol_sha256.to_owned(),
            found_name: info.protocol.name.clone(),
            found_sha256: info.protocol_sha256.clone(),
        });
    }
    Ok(info)
}

/// What a new study's `session.json` records.
#[derive(Debug, Clone, Copy)]
pub(crate) struct NewStudy<'a> {
    /// The protocol.
    pub protocol: &'a Protocol,
    /// Its canonical TOML and the SHA-256 of that text
    /// ([`session::protocol_identity`]).
    pub identity: (&'a str, &'a str),
    /// Its assignment of condition orders.
    pub table: &'a AssignmentTable,
    /// The order table drawn from it.
    pub orders: &'a [OrderRow],
    /// Number of planned trials.
    pub planned: usize,
    /// Writer and hardware.
    pub meta: &'a StudyMeta,
    /// Creation time.
    pub now: UtcTime,
}

impl NewStudy<'_> {
    /// The `session.json` content of the new study (no sitting yet).
    pub(crate) fn session_info(&self) -> SessionInfo {
        let (protocol_toml, protocol_sha256) = self.identity;
        SessionInfo {
            format: session::FORMAT.into(),
            software: session::Software {
                name: self.meta.software_name.clone(),
                version: self.meta.software_version.clone(),
            },
            protocol: self.protocol.clone(),
            protocol_toml: protocol_toml.to_owned(),
            protocol_sha256: protocol_sha256.to_owned(),
            seeds: session::SeedInfo {
                study: self.protocol.seeds.study,
                trial_derivation: session::TRIAL_DERIVATION.into(),
            },
            order_table: self.orders.to_vec(),
            order_balance: self.table.summary.clone(),
            rig: self.meta.rig.clone(),
            calibration: self.meta.calibration.clone(),
            rig_hash: self.meta.rig_hash.clone(),
            raw_signals: self.meta.raw_signals,
            trap_calibration: self.meta.trap_calibration.clone(),
            camera: self.meta.camera,
            created_utc: self.now,
            updated_utc: self.now,
            sittings: Vec::new(),
            progress: Progress {
                planned: self.planned as u64,
                completed: 0,
            },
            simulation: None,
        }
    }
}

/// Creates the folder `dir` of a new study and writes its `session.json`.
///
/// # Errors
/// [`ExportError::NotAStudyFolder`] when `trials.csv` or the journal exists
/// without `session.json`; I/O errors.
pub(crate) fn create_folder(dir: &Path, info: &SessionInfo) -> Result<()> {
    for p in [dir.join(TRIALS_FILE), dir.join(JOURNAL_FILE)] {
        if entry_exists(&p) {
            return Err(ExportError::NotAStudyFolder {
                path: dir.to_path_buf(),
                reason: format!(
                    "`{}` exists but `{SESSION_FILE}` does not: not a kilotouch study \
                     folder (or its session.json was removed)",
                    p.file_name()
                        .map(|n| n.to_string_lossy())
                        .unwrap_or_default()
                ),
            });
        }
    }
    create_root_durable(dir)?;
    session::write_session(&dir.join(SESSION_FILE), info)
}

/// The journal and `trials.csv` of a folder as read, checked and parsed
/// before anything is modified.
#[derive(Debug)]
pub(crate) struct FolderRead {
    journal_path: PathBuf,
    journal_bytes: Vec<u8>,
    /// The journal's records and torn tail.
    pub journal: JournalRead,
    trials_path: PathBuf,
    trials_bytes: Option<Vec<u8>>,
    /// The rows and torn tail of `trials.csv` (`None`: no file, or a
    /// partial header).
    pub trials: Option<TrialsRead>,
    /// `trials.csv` holds part of its header (a crash while it was
    /// created): written again on repair.
    rewrite_header: bool,
}

impl FolderRead {
    /// Reads the journal (checking that its sittings ran the protocol
    /// `session.json` records, SHA-256 `protocol_sha256`) and then
    /// `trials.csv`.
    ///
    /// # Errors
    /// I/O errors; those of [`journal::parse_journal`], [`check_sittings`]
    /// and [`trials::parse_trials`].
    pub(crate) fn read(dir: &Path, protocol_sha256: &str) -> Result<Self> {
        let journal_path = dir.join(JOURNAL_FILE);
        let trials_path = dir.join(TRIALS_FILE);
        let journal_bytes = journal::read_bytes(&journal_path)?;
        let journal = journal::parse_journal(&journal_path, &journal_bytes)?;
        check_sittings(&journal_path, &journal, protocol_sha256)?;
        let trials_bytes = if entry_exists(&trials_path) {
            Some(read_no_follow(&trials_path)?)
        } else {
            None
        };
        let rewrite_header = trials_bytes
            .as_deref()
            .is_some_and(trials::is_partial_header);
        let trials = match &trials_bytes {
            Some(b) if !rewrite_header => Some(trials::parse_trials(
                &trials_path,
                b,
                ReadOptions::default(),
            )?),
            _ => None,
        };
        Ok(Self {
            journal_path,
            journal_bytes,
            journal,
            trials_path,
            trials_bytes,
            trials,
            rewrite_header,
        })
    }

    /// What the files hold, for [`super::reconcile::reconcile`].
    pub(crate) fn found(&self) -> Found<'_> {
        Found {
            journal_path: &self.journal_path,
            journal: &self.journal,
            trials_path: &self.trials_path,
            trials: self.trials.as_ref(),
        }
    }

    /// Repairs the folder and opens it for appending: creates `raw/`, cuts
    /// the torn tails of `trials.csv` and the journal (copies go to
    /// `recovery/`, the tails' `saved_to` is set), writes a partial header
    /// again or creates a missing `trials.csv`.
    ///
    /// # Errors
    /// I/O errors.
    pub(crate) fn repair(&mut self, dir: &Path) -> Result<(File, Journal)> {
        let recovery_dir = dir.join(RECOVERY_DIR);
        create_dir_durable(&dir.join(RAW_DIR))?;
        if let (Some(read), Some(bytes)) = (self.trials.as_mut(), &self.trials_bytes)
            && let Some(torn) = read.torn.as_mut()
        {
            let tail = &bytes[torn.offset as usize..];
            torn.saved_to = Some(cut_torn_tail(&self.trials_path, torn, tail, &recovery_dir)?);
        }
        let trials_file = if self.rewrite_header {
            trials::rewrite_header(&self.trials_path)?
        } else if self.trials.is_some() {
            open_append(&self.trials_path)?
        } else {
            trials::create_trials_file(&self.trials_path)?
        };
        let journal = Journal::resume(
            &self.journal_path,
            &mut self.journal,
            &self.journal_bytes,
            &recovery_dir,
        )?;
        Ok((trials_file, journal))
    }

    /// Torn tail of `trials.csv` (cut once [`FolderRead::repair`] ran).
    pub(crate) fn trials_torn(&self) -> Option<&TornTail> {
        self.trials.as_ref().and_then(|t| t.torn.as_ref())
    }

    /// Path of `trials.csv`.
    pub(crate) fn trials_path(&self) -> &Path {
        &self.trials_path
    }
}

/// Journals the opening of a sitting: `session_started`, and when
/// something was repaired or adopted, `recovered`, `trial_completed` for
/// each adopted row (`completed`: row CRCs) and `trial_aborted` for each
/// interrupted trial.
///
/// # Errors
/// I/O errors.
pub(crate) fn journal_opening(
    journal: &mut Journal,
    start: journal::SessionStart,
    recovery: &Recovery,
    completed: &HashMap<TrialKey, u32>,
) -> Result<()> {
    journal.append(Record::SessionStarted(start))?;
    if recovery.is_clean() {
        return Ok(());
    }
    journal.append(Record::Recovered(RecoveryRecord {
        journal_torn_bytes: recovery.journal_torn.as_ref().map_or(0, |t| t.len),
        trials_torn_bytes: recovery.trials_torn.as_ref().map_or(0, |t| t.len),
        adopted: recovery.adopted.clone(),
        interrupted: recovery.interrupted.clone(),
    }))?;
    for key in &recovery.adopted {
        journal.append(Record::TrialCompleted {
            trial: *key,
            row_crc32: checksum::crc32_hex(completed[key]),
            adopted: true,
        })?;
    }
    for key in &recovery.interrupted {
        journal.append(Record::TrialAborted {
            trial: *key,
            reason: "interrupted: the sitting ended during the trial (crash or kill); \
                     it will be run again with the same seeds"
                .into(),
        })?;
    }
    Ok(())
}
