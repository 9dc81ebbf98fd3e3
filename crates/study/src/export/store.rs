//! [`StudyStore`]: an open study output folder and the trial lifecycle on
//! it (begin, raw file, commit or abort), with the [`TrialTicket`] that
//! ties a trial's steps together. Opening is in `open.rs` and
//! `reconcile.rs`; the folder layout and the commit order are in the
//! [`crate::export`] module documentation.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::checksum;
use super::journal::{Journal, Record, SessionStart, read_journal, sittings};
use super::open::{self, FolderRead, NewStudy};
use super::plan::{
    PlannedTrial, extend_with_rows, plan, practice_retry, raw_file_name, raw_layout_for,
};
use super::reconcile::{DamagedRaw, Expected, PendingQuarantine, Recovery, Verdict, reconcile};
use super::session::{
    self, OrderRow, Progress, SESSION_FILE, SessionInfo, SimulationInfo, SittingTiming, StudyMeta,
    read_session, write_session,
};
use super::summary::{SummaryFiles, regenerate_summaries};
use super::trials::{IDENTITY_COLUMNS, TaskKind, TrialRow, TrialsWriter, first_difference};
use super::{raw_check, settings};
use crate::protocol::Protocol;
use crate::rawsig::{NpyWriter, RawLayout, sidecar_path};
use crate::seeds::{TrialKey, format_seed};
use crate::storage::error::{ExportError, Result};
use crate::storage::fsutil::{entry_exists, refuse_link};
use crate::storage::lock::FolderLock;
use crate::storage::utc::UtcTime;

/// Each trial's position in `plan`.
fn index_plan(plan: &[PlannedTrial]) -> HashMap<TrialKey, usize> {
    plan.iter().enumerate().map(|(i, p)| (p.key, i)).collect()
}

/// Proof that a trial was begun ([`StudyStore::begin_trial`]); consumed by
/// [`StudyStore::commit_trial`] or [`StudyStore::abort_trial`].
#[derive(Debug)]
pub struct TrialTicket {
    planned: PlannedTrial,
    task: TaskKind,
    started_utc: UtcTime,
    raw_file: Option<String>,
}

impl TrialTicket {
    /// The trial.
    pub fn key(&self) -> TrialKey {
        self.planned.key
    }

    /// Its plan entry.
    pub fn planned(&self) -> &PlannedTrial {
        &self.planned
    }

    /// Start time given to `begin_trial`.
    pub fn started_utc(&self) -> UtcTime {
        self.started_utc
    }

    /// A row with the identity columns filled (participant, session, order,
    /// condition, phase, trial, task, seed, start time, raw file) and every
    /// result empty: `success = false`, metrics NA. The runner fills in the
    /// results.
    pub fn row(&self) -> TrialRow {
        let raw_file = self.raw_file.clone().unwrap_or_default();
        self.planned
            .blank_row(self.task, self.started_utc, raw_file)
    }
}

/// An open study output folder (see the [`crate::export`] module
/// documentation).
#[derive(Debug)]
pub struct StudyStore {
    dir: PathBuf,
    protocol: Protocol,
    task: TaskKind,
    orders: Vec<OrderRow>,
    plan: Vec<PlannedTrial>,
    plan_index: HashMap<TrialKey, usize>,
    completed: HashMap<TrialKey, u32>,
    open_trial: Option<TrialKey>,
    journal: Journal,
    trials: TrialsWriter,
    recovery: Recovery,
    info: SessionInfo,
    poisoned: Option<String>,
    /// The timing verdict `session_done` records ([`Self::set_timing`]).
    timing: Option<SittingTiming>,
    /// The folder's one-writer lock, released when the store is dropped.
    _lock: FolderLock,
    /// Test hook: fail the journal append of the next commit (simulates a
    /// crash between the row and its record).
    #[cfg(test)]
    fail_completion_record: bool,
}

impl StudyStore {
    /// Opens the output folder `dir` for `protocol`: creates it (with
    /// `session.json`, an empty `trials.csv` with its header, the journal
    /// and `raw/`) or resumes it — repairs torn tails, reconciles
    /// `trials.csv` with the journal (see the [`crate::export`] module
    /// documentation) — and journals `session_started`. The folder is
    /// locked for the store's life ([`FolderLock`]): a second writer is
    /// refused at once. On resume, the rig file, calibration and raw
    /// recording of `meta` must be those `session.json` records (or the
    /// change is recorded, [`StudyMeta::recorded_change`]), and every
    /// finished trial's raw file is checked; damaged ones are quarantined
    /// and reported in [`Recovery::damaged_raw`].
    ///
    /// # Errors
    /// [`ExportError::Locked`] when another writer has the folder;
    /// [`ExportError::SettingsChanged`] naming each differing setting;
    /// [`ExportError::Protocol`] for an invalid protocol,
    /// [`ExportError::ProtocolMismatch`] when the folder holds another
    /// protocol, [`ExportError::NotAStudyFolder`],
    /// [`ExportError::HeaderMismatch`], [`ExportError::Inconsistent`],
    /// [`ExportError::Checksum`], [`ExportError::Format`], I/O errors.
    pub fn open(dir: &Path, protocol: &Protocol, meta: &StudyMeta) -> Result<Self> {
        open::validate_protocol(protocol)?;
        let (protocol_toml, protocol_sha256) = session::protocol_identity(protocol)?;
        let table = protocol.assignment()?;
        let orders = session::order_rows(&table);
        let mut plan = plan(protocol, &orders);
        refuse_links(dir)?;
        let lock = FolderLock::acquire(
            dir,
            &format!("{} {}", meta.software_name, meta.software_version),
        )?;
        let session_path = dir.join(SESSION_FILE);
        let now = UtcTime::now();
        let resumed = entry_exists(&session_path);
        let (mut info, changes) = if resumed {
            resumed_session(&session_path, protocol, &protocol_sha256, meta)?
        } else {
            let info = NewStudy {
                protocol,
                identity: (&protocol_toml, &protocol_sha256),
                table: &table,
                orders: &orders,
                planned: plan.len(),
                meta,
                now,
            }
            .session_info();
            open::create_folder(dir, &info)?;
            (info, Vec::new())
        };
        // Read and check everything before modifying anything: an error
        // leaves the folder exactly as it was.
        let mut read = FolderRead::read(dir, &info.protocol_sha256)?;
        if let Some(t) = &read.trials {
            extend_with_rows(protocol, &orders, &mut plan, &t.rows);
        }
        let plan_index = index_plan(&plan);
        let task = TaskKind::of(&protocol.task);
        let verdict = reconcile(
            &read.found(),
            &Expected {
                task,
                orders: &orders,
                plan: &plan,
                plan_index: &plan_index,
            },
        )?;
        let damaged = damaged_raw_files(dir, &read, &orders, &verdict);
        // Checks passed: repair (cut torn tails, keeping copies) and open
        // for appending; damaged raw files are quarantined below.
        let (trials_file, mut journal) = read.repair(dir)?;
        let (damaged_raw, damaged_lines) = quarantine_plan(dir, damaged, now);
        let recovery = Recovery {
            resumed,
            journal_torn: read.journal.torn.clone(),
            trials_torn: read.trials_torn().cloned(),
            adopted: verdict.adopted,
            interrupted: verdict.interrupted,
            previous_sitting_unclosed: verdict.previous_sitting_unclosed,
            completed: verdict.completed.len(),
            pending: plan.len() - verdict.completed.len(),
            stale_lock: lock.stale().cloned(),
            damaged_raw,
        };
        let start = session_start(protocol, &info, meta, &orders, resumed);
        open::journal_opening(&mut journal, start, &recovery, &verdict.completed)?;
        let mut completed = verdict.completed;
        let quarantine = Quarantine {
            dir,
            stamp: now.unix_millis(),
            trials: read.trials.as_ref(),
            damaged: recovery.damaged_raw.iter().zip(damaged_lines).collect(),
            pending: &verdict.pending_quarantine,
        };
        let trials_file = quarantine.run(
            &mut journal,
            &mut completed,
            read.trials_path(),
            trials_file,
        )?;
        journal_checks(&mut journal, &changes, meta)?;
        settings::adopt(&mut info, meta);
        info.updated_utc = now;
        let mut store = Self {
            dir: dir.to_path_buf(),
            protocol: protocol.clone(),
            task,
            orders,
            plan,
            plan_index,
            completed,
            open_trial: None,
            journal,
            trials: TrialsWriter::from_file(read.trials_path().to_path_buf(), trials_file),
            recovery,
            info,
            poisoned: None,
            timing: None,
            _lock: lock,
            #[cfg(test)]
            fail_completion_record: false,
        };
        store.write_session_info()?;
        Ok(store)
    }

    /// Resumes an existing folder with the protocol recorded in its
    /// `session.json` (see [`StudyStore::open`]).
    ///
    /// # Errors
    /// [`ExportError::NotAStudyFolder`] without `session.json`; those of
    /// [`read_session`] and [`StudyStore::open`].
    pub fn open_existing(dir: &Path, meta: &StudyMeta) -> Result<Self> {
        let path = dir.join(SESSION_FILE);
        refuse_link(&path)?;
        if !path.is_file() {
            return Err(ExportError::NotAStudyFolder {
                path: dir.to_path_buf(),
                reason: format!("no `{SESSION_FILE}`"),
            });
        }
        let info = read_session(&path)?;
        Self::open(dir, &info.protocol, meta)
    }

    /// Records in `session.json` how a simulated study is run (fidelity,
    /// shard) and rewrites the file.
    ///
    /// # Errors
    /// I/O and JSON errors.
    pub fn set_simulation(&mut self, simulation: SimulationInfo) -> Result<()> {
        self.info.simulation = Some(simulation);
        self.write_session_info()
    }

    fn write_session_info(&mut self) -> Result<()> {
        let jread = read_journal(self.journal.path())?;
        self.info.sittings = sittings(&jread.entries);
        self.info.updated_utc = UtcTime::now();
        self.info.progress = Progress {
            planned: self.plan.len() as u64,
            completed: self.completed.len() as u64,
        };
        write_session(&self.dir.join(SESSION_FILE), &self.info)
    }

    fn check_usable(&self, key: TrialKey) -> Result<()> {
        match &self.poisoned {
            Some(why) => Err(ExportError::Trial {
                key,
                message: format!(
                    "the store is unusable after a failed write ({why}); reopen the folder to \
                     repair it"
                ),
            }),
            None => Ok(()),
        }
    }

    fn poison<T>(&mut self, r: Result<T>) -> Result<T> {
        if let Err(e) = &r {
            self.poisoned = Some(e.to_string());
        }
        r
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The protocol.
    pub fn protocol(&self) -> &Protocol {
        &self.protocol
    }

    /// Participant → order table.
    pub fn orders(&self) -> &[OrderRow] {
        &self.orders
    }

    /// Content of `session.json`.
    pub fn info(&self) -> &SessionInfo {
        &self.info
    }

    /// What opening found and repaired.
    pub fn recovery(&self) -> &Recovery {
        &self.recovery
    }

    /// The complete plan, in run order ([`plan`]).
    pub fn plan(&self) -> &[PlannedTrial] {
        &self.plan
    }

    /// Plan entry of a trial.
    pub fn planned(&self, key: &TrialKey) -> Option<&PlannedTrial> {
        self.plan_index.get(key).map(|&i| &self.plan[i])
    }

    /// Whether a trial's row is in `trials.csv`.
    pub fn is_completed(&self, key: &TrialKey) -> bool {
        self.completed.contains_key(key)
    }

    /// Number of completed trials.
    pub fn completed_count(&self) -> usize {
        self.completed.len()
    }

    /// Trials still to run, in plan order.
    pub fn pending(&self) -> impl Iterator<Item = &PlannedTrial> {
        self.plan
            .iter()
            .filter(|p| !self.completed.contains_key(&p.key))
    }

    /// The first unfinished trial in plan order (where a resumed session
    /// continues), or `None` when the study is complete.
    pub fn next_pending(&self) -> Option<&PlannedTrial> {
        self.pending().next()
    }

    /// Path of a file of the folder given relative to it.
    pub fn path_of(&self, relative: &str) -> PathBuf {
        self.dir.join(relative)
    }

    /// Starts a trial: journals `trial_started` (fsync) and returns its
    /// ticket. `started_utc` is written to the row (pass
    /// [`UtcTime::now`] in a real session).
    ///
    /// # Errors
    /// [`ExportError::Trial`] when the trial is not in the plan, already
    /// completed, or another trial is open; I/O errors.
    pub fn begin_trial(&mut self, key: TrialKey, started_utc: UtcTime) -> Result<TrialTicket> {
        self.check_usable(key)?;
        if let Some(open) = self.open_trial {
            return Err(ExportError::Trial {
                key,
                message: format!("trial {open} is still open: commit or abort it first"),
            });
        }
        let planned = self
            .planned(&key)
            .cloned()
            .ok_or_else(|| ExportError::Trial {
                key,
                message: "not in the protocol's plan".into(),
            })?;
        if self.is_completed(&key) {
            return Err(ExportError::Trial {
                key,
                message: "already completed (its row is in trials.csv)".into(),
            });
        }
        let r = self.journal.append(Record::TrialStarted {
            trial: key,
            seed: format_seed(planned.seed),
            started_utc,
        });
        self.poison(r)?;
        self.open_trial = Some(key);
        Ok(TrialTicket {
            planned,
            task: self.task,
            started_utc,
            raw_file: None,
        })
    }

    /// Creates the raw-signal writer of the ticket's trial
    /// (`raw/<P>_<C>_<phase>_<trial>.npy`, truncating a partial file left by
    /// an interrupted run) and records its path in the ticket, so
    /// [`TrialTicket::row`] fills `raw_file`. The sidecar's `attrs` get the
    /// trial identity. Call [`NpyWriter::finish`] before
    /// [`StudyStore::commit_trial`].
    ///
    /// # Errors
    /// Those of [`NpyWriter::create`].
    pub fn raw_writer(&self, ticket: &mut TrialTicket, layout: RawLayout) -> Result<NpyWriter> {
        let rel = raw_file_name(&ticket.planned);
        let layout = raw_layout_for(&ticket.planned, ticket.started_utc, layout);
        let w = NpyWriter::create(&self.dir.join(&rel), layout)?;
        ticket.raw_file = Some(rel);
        Ok(w)
    }

    /// Records in the ticket a raw file that was written before the trial
    /// was begun in the store (by a worker thread that ran the trial, with
    /// [`raw_layout_for`] and the same start time), so [`TrialTicket::row`]
    /// fills `raw_file`. The file must be finished.
    ///
    /// # Errors
    /// [`ExportError::Trial`] when the file or its sidecar does not exist.
    pub fn attach_raw(&self, ticket: &mut TrialTicket) -> Result<()> {
        let rel = raw_file_name(&ticket.planned);
        let path = self.dir.join(&rel);
        if !path.is_file() || !sidecar_path(&path).is_file() {
            return Err(ExportError::Trial {
                key: ticket.key(),
                message: format!("raw file `{rel}` or its sidecar does not exist"),
            });
        }
        ticket.raw_file = Some(rel);
        Ok(())
    }

    /// Commits a finished trial: checks the row against its ticket and
    /// the validity rules ([`TrialRow::validate`]), appends it to
    /// `trials.csv` (one write + fdatasync), then journals
    /// `trial_completed` (fsync). When this returns `Ok` the row is on
    /// stable storage and the next trial may begin. Returns the row's CRC.
    ///
    /// # Errors
    /// [`ExportError::Trial`] when the row's identity columns differ from
    /// the ticket or the raw file it names does not exist;
    /// [`ExportError::InvalidRow`]. Nothing is written then and the trial
    /// stays open ([`StudyStore::abort_open_trial`]). I/O errors, after
    /// which the store refuses further writes until reopened (reopening
    /// repairs a torn row).
    pub fn commit_trial(&mut self, ticket: TrialTicket, row: &TrialRow) -> Result<u32> {
        let key = ticket.key();
        self.check_usable(key)?;
        if let Some((column, e, f)) = first_difference(&ticket.row(), row, &IDENTITY_COLUMNS) {
            return Err(ExportError::Trial {
                key,
                message: format!(
                    "column `{column}` is `{f}` but the ticket gives `{e}` (build rows with \
                     TrialTicket::row)"
                ),
            });
        }
        row.validate(key)?;
        if !row.raw_file.is_empty() && !self.dir.join(&row.raw_file).is_file() {
            return Err(ExportError::Trial {
                key,
                message: format!(
                    "raw file `{}` does not exist (finish the NpyWriter before committing)",
                    row.raw_file
                ),
            });
        }
        let (line, crc) = row.encode()?;
        let r = self.trials.append_line(&line);
        self.poison(r)?;
        #[cfg(test)]
        if self.fail_completion_record {
            let r = Err(ExportError::Trial {
                key,
                message: "injected failure before trial_completed".into(),
            });
            return self.poison(r);
        }
        let r = self.journal.append(Record::TrialCompleted {
            trial: key,
            row_crc32: checksum::crc32_hex(crc),
            adopted: false,
        });
        self.poison(r)?;
        self.completed.insert(key, crc);
        self.open_trial = None;
        if !row.success
            && let Some((at, extra)) = practice_retry(&self.protocol, &self.plan, key)
        {
            self.plan.insert(at, extra);
            self.plan_index = index_plan(&self.plan);
        }
        Ok(crc)
    }

    /// Abandons a begun trial: journals `trial_aborted`; the trial stays
    /// pending and is run again later with the same seeds.
    ///
    /// # Errors
    /// I/O errors.
    pub fn abort_trial(&mut self, ticket: TrialTicket, reason: &str) -> Result<()> {
        self.journal_abort(ticket.key(), reason)
    }

    /// Aborts the open trial without its ticket (e.g. after
    /// [`StudyStore::commit_trial`] refused a row, which leaves the trial
    /// open). Returns the trial aborted, if one was open.
    ///
    /// # Errors
    /// I/O errors.
    pub fn abort_open_trial(&mut self, reason: &str) -> Result<Option<TrialKey>> {
        let Some(key) = self.open_trial else {
            return Ok(None);
        };
        self.journal_abort(key, reason)?;
        Ok(Some(key))
    }

    /// Journals `trial_aborted` for `key` and closes the open trial.
    fn journal_abort(&mut self, key: TrialKey, reason: &str) -> Result<()> {
        self.check_usable(key)?;
        let r = self.journal.append(Record::TrialAborted {
            trial: key,
            reason: reason.to_owned(),
        });
        self.poison(r)?;
        self.open_trial = None;
        Ok(())
    }

    /// The trial begun and not yet committed or aborted.
    pub fn open_trial(&self) -> Option<TrialKey> {
        self.open_trial
    }

    /// Journals a free-text note.
    ///
    /// # Errors
    /// I/O errors.
    pub fn note(&mut self, text: &str) -> Result<()> {
        self.journal
            .append(Record::Note {
                text: text.to_owned(),
            })
            .map(|_| ())
    }

    /// Journals a pause.
    ///
    /// # Errors
    /// I/O errors.
    pub fn pause(&mut self, reason: &str) -> Result<()> {
        self.journal
            .append(Record::Paused {
                reason: reason.to_owned(),
            })
            .map(|_| ())
    }

    /// Journals the end of a pause.
    ///
    /// # Errors
    /// I/O errors.
    pub fn resume(&mut self) -> Result<()> {
        self.journal.append(Record::Resumed).map(|_| ())
    }

    /// Regenerates `cells_long.csv`, `cells_wide.csv` (from `trials.csv`)
    /// and `session.json` (sittings and progress from the journal).
    ///
    /// # Errors
    /// Those of [`regenerate_summaries`]; I/O errors.
    pub fn regenerate_summaries(&mut self) -> Result<SummaryFiles> {
        let files = regenerate_summaries(&self.dir)?;
        self.write_session_info()?;
        Ok(files)
    }

    /// The timing verdict `session_done` will record for this sitting
    /// (the real-time engine's; a batch simulation records none). Update it
    /// as the sitting goes: whichever ends the sitting writes the latest.
    pub fn set_timing(&mut self, t: Option<SittingTiming>) {
        self.timing = t;
    }

    /// Ends this sitting without closing the study (a participant finished,
    /// or the experimenter stopped the sitting): journals `session_done`
    /// with the progress so far and rewrites `session.json`; the next
    /// opening resumes the folder and reports no unclosed sitting. The
    /// summaries are written by [`StudyStore::close`] when the study ends.
    ///
    /// # Errors
    /// [`ExportError::Trial`] when a trial is still open; I/O errors.
    pub fn end_sitting(mut self) -> Result<()> {
        self.refuse_open_trial("ending the sitting")?;
        self.session_done()
    }

    /// Closes the sitting: regenerates the summaries and journals
    /// `session_done`. (Dropping the store without `close` is equivalent to
    /// a crash between trials: nothing is lost; the next open reports an
    /// unclosed sitting.)
    ///
    /// # Errors
    /// [`ExportError::Trial`] when a trial is still open; those of
    /// [`StudyStore::regenerate_summaries`].
    pub fn close(mut self) -> Result<SummaryFiles> {
        self.refuse_open_trial("closing")?;
        let files = regenerate_summaries(&self.dir)?;
        self.session_done()?;
        Ok(files)
    }

    /// [`ExportError::Trial`] when a trial is still open, naming what the
    /// caller was doing (`closing`).
    fn refuse_open_trial(&self, doing: &str) -> Result<()> {
        match self.open_trial {
            Some(key) => Err(ExportError::Trial {
                key,
                message: format!("still open: commit or abort it before {doing}"),
            }),
            None => Ok(()),
        }
    }

    /// Journals `session_done` with the progress so far and rewrites
    /// `session.json`.
    fn session_done(&mut self) -> Result<()> {
        self.journal.append(Record::SessionDone {
            completed: self.completed.len() as u64,
            planned: self.plan.len() as u64,
            timing: self.timing.take(),
        })?;
        self.write_session_info()
    }
}

/// Refuses a study folder in which any file or folder the store opens or
/// creates is a symbolic link (checked before anything is opened; every
/// open also uses `O_NOFOLLOW`, so a link planted later is refused too).
///
/// # Errors
/// [`ExportError::SymbolicLink`] naming the first link.
pub fn refuse_links(dir: &Path) -> Result<()> {
    use super::datapackage::DATAPACKAGE_FILE;
    use super::journal::JOURNAL_FILE;
    use super::open::RECOVERY_DIR;
    use super::plan::RAW_DIR;
    use super::summary::{CELLS_LONG_FILE, CELLS_WIDE_FILE};
    use super::trials::TRIALS_FILE;
    use crate::storage::lock::LOCK_FILE;
    for name in [
        LOCK_FILE,
        SESSION_FILE,
        TRIALS_FILE,
        JOURNAL_FILE,
        RAW_DIR,
        RECOVERY_DIR,
        CELLS_LONG_FILE,
        CELLS_WIDE_FILE,
        DATAPACKAGE_FILE,
    ] {
        refuse_link(&dir.join(name))?;
    }
    refuse_link(&dir.join(RECOVERY_DIR).join(raw_check::QUARANTINE_DIR))
}

/// The `session.json` of a folder being resumed and the settings of `meta`
/// that differ from it.
///
/// # Errors
/// Those of [`open::load_session`]; [`ExportError::SettingsChanged`] naming
/// each differing setting unless `meta` records the change.
fn resumed_session(
    session_path: &Path,
    protocol: &Protocol,
    protocol_sha256: &str,
    meta: &StudyMeta,
) -> Result<(SessionInfo, Vec<settings::SettingChange>)> {
    let info = open::load_session(session_path, protocol, protocol_sha256)?;
    let changes = settings::changes(&info, meta);
    if !changes.is_empty() && meta.recorded_change.is_none() {
        let list: Vec<String> = changes.iter().map(ToString::to_string).collect();
        return Err(ExportError::SettingsChanged {
            path: session_path.to_path_buf(),
            changes: list.join("; "),
        });
    }
    Ok((info, changes))
}

/// The damaged raw files found by [`damaged_raw_files`] as recovery
/// entries with the place each will be quarantined to (stamped `now`), and
/// their `trials.csv` lines in the same order.
fn quarantine_plan(
    dir: &Path,
    damaged: Vec<(TrialKey, u64, String, String)>,
    now: UtcTime,
) -> (Vec<DamagedRaw>, Vec<u64>) {
    let mut damaged_raw = Vec::with_capacity(damaged.len());
    let mut damaged_lines = Vec::with_capacity(damaged.len());
    for (trial, line, file, reason) in damaged {
        let quarantined_to = raw_check::quarantine_target(dir, &file, now.unix_millis());
        damaged_lines.push(line);
        damaged_raw.push(DamagedRaw {
            trial,
            file,
            reason,
            quarantined_to,
        });
    }
    (damaged_raw, damaged_lines)
}

/// The journal's `session_started` record of a sitting.
fn session_start(
    protocol: &Protocol,
    info: &SessionInfo,
    meta: &StudyMeta,
    orders: &[OrderRow],
    resumed: bool,
) -> SessionStart {
    SessionStart {
        protocol_name: protocol.name.clone(),
        protocol_sha256: info.protocol_sha256.clone(),
        software_version: meta.software_version.clone(),
        study_seed: protocol.seeds.study,
        rig: meta.rig.clone(),
        calibration: meta.calibration.clone(),
        orders: orders.to_vec(),
        resumed,
        device: meta.device.clone(),
    }
}

/// The finished trials whose raw file fails its check, as (trial, line of
/// its row, file, reason), in file order. Rows whose quarantine is already
/// journaled (a crash before their rewrite) are finished by [`Quarantine`]
/// instead.
fn damaged_raw_files(
    dir: &Path,
    read: &FolderRead,
    orders: &[OrderRow],
    verdict: &Verdict,
) -> Vec<(TrialKey, u64, String, String)> {
    let index: HashMap<&str, u32> = orders
        .iter()
        .map(|o| (o.participant.as_str(), o.index))
        .collect();
    let Some(trials) = read.trials.as_ref() else {
        return Vec::new();
    };
    trials
        .rows
        .iter()
        .zip(&trials.lines)
        // Rows without raw signals, or whose file is already in quarantine.
        .filter(|(r, _)| r.has_trusted_raw())
        .filter_map(|(r, &line)| {
            let key = r.key(*index.get(r.participant.as_str())?);
            if !verdict.completed.contains_key(&key)
                || verdict.pending_quarantine.iter().any(|p| p.trial == key)
            {
                return None;
            }
            raw_check::damage(dir, &r.raw_file).map(|why| (key, line, r.raw_file.clone(), why))
        })
        .collect()
}

/// Quarantining the damaged raw files of an opening: for each, journal
/// [`Record::RawQuarantined`] (with the rewritten row's CRC), move the file
/// and its sidecar to `recovery/quarantine/`, and rewrite its row's
/// `raw_file` to the new path (empty when the file was missing) — in that
/// order, so a crash between the steps is finished by the next opening
/// (`pending`, from [`reconcile`]).
struct Quarantine<'a> {
    dir: &'a Path,
    stamp: i64,
    trials: Option<&'a super::trials::TrialsRead>,
    /// Damaged files found now, with the line of their row.
    damaged: Vec<(&'a DamagedRaw, u64)>,
    /// Quarantines journaled by an earlier opening that crashed.
    pending: &'a [PendingQuarantine],
}

impl Quarantine<'_> {
    /// Carries out the quarantines; returns the append handle of
    /// `trials.csv` (a new one when the file was rewritten).
    fn run(
        &self,
        journal: &mut Journal,
        completed: &mut HashMap<TrialKey, u32>,
        trials_path: &Path,
        trials_file: std::fs::File,
    ) -> Result<std::fs::File> {
        let Some(trials) = self.trials else {
            return Ok(trials_file);
        };
        if self.damaged.is_empty() && self.pending.is_empty() {
            return Ok(trials_file);
        }
        let row_at = |line: u64| {
            trials
                .lines
                .iter()
                .position(|&l| l == line)
                .map(|i| &trials.rows[i])
        };
        let mut replace: HashMap<u64, String> = HashMap::new();
        for &(d, line) in &self.damaged {
            let Some(row) = row_at(line) else { continue };
            let mut new_row = row.clone();
            new_row.raw_file = d.quarantined_to.clone().unwrap_or_default();
            let (text, crc) = new_row.encode()?;
            let previous = completed.get(&d.trial).copied().unwrap_or_default();
            journal.append(Record::RawQuarantined {
                trial: d.trial,
                file: d.file.clone(),
                reason: d.reason.clone(),
                moved_to: d.quarantined_to.clone(),
                previous_row_crc32: checksum::crc32_hex(previous),
                row_crc32: checksum::crc32_hex(crc),
            })?;
            raw_check::quarantine(self.dir, &d.file, d.quarantined_to.as_deref(), self.stamp)?;
            replace.insert(line, text);
            completed.insert(d.trial, crc);
        }
        for p in self.pending {
            let Some(row) = row_at(p.line) else { continue };
            let mut new_row = row.clone();
            new_row.raw_file = p.moved_to.clone().unwrap_or_default();
            let (text, crc) = new_row.encode()?;
            if crc != p.row_crc32 {
                return Err(ExportError::Inconsistent {
                    path: trials_path.to_path_buf(),
                    message: format!(
                        "line {}: trial {}: the journaled quarantine of `{}` gives row_crc32 \
                         {:08x}, the rewritten row has {crc:08x}",
                        p.line, p.trial, p.file, p.row_crc32
                    ),
                });
            }
            raw_check::quarantine(self.dir, &p.file, p.moved_to.as_deref(), self.stamp)?;
            replace.insert(p.line, text);
            completed.insert(p.trial, crc);
        }
        drop(trials_file);
        super::trials::rewrite_lines(trials_path, &replace)
    }
}

/// Journals a recorded change of settings with its reason.
fn journal_checks(
    journal: &mut Journal,
    changes: &[settings::SettingChange],
    meta: &StudyMeta,
) -> Result<()> {
    if let (false, Some(reason)) = (changes.is_empty(), &meta.recorded_change) {
        let list: Vec<String> = changes.iter().map(ToString::to_string).collect();
        journal.append(Record::Note {
            text: format!(
                "settings_changed: new sitting with a recorded change: {} — reason: {reason}",
                list.join("; ")
            ),
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::journal::JOURNAL_FILE;
    use crate::export::trials::{TRIALS_FILE, read_trials};
    use crate::seeds::Phase;

    fn protocol() -> Protocol {
        Protocol::from_toml_str(
            "name = \"order\"\nparticipants = 1\nconditions = [\"V\", \"D\"]\n\
             trials_per_session = 2\n[training]\npractice_trials = 0\n[task.circling]\n",
            "<test>",
        )
        .unwrap()
    }

    fn commit(store: &mut StudyStore, key: TrialKey) -> Result<u32> {
        let ticket = store.begin_trial(key, UtcTime::from_unix_millis(0))?;
        let mut row = ticket.row();
        row.success = true;
        row.time_s = Some(1.5);
        store.commit_trial(ticket, &row)
    }

    /// The row is on disk before its journal record: a failure (crash) after
    /// the row leaves a row without record, which the next open adopts —
    /// never a record without row.
    #[test]
    fn commit_writes_the_row_before_the_journal_record() {
        let dir = std::env::temp_dir().join(format!(
            "kilotouch-commit-order-{}-{}",
            std::process::id(),
            UtcTime::now().unix_millis()
        ));
        let p = protocol();
        let meta = StudyMeta::new("test");
        let mut store = StudyStore::open(&dir, &p, &meta).unwrap();
        let k1 = TrialKey::new(0, store.plan()[0].key.condition, Phase::Test, 1);
        commit(&mut store, k1).unwrap();
        let k2 = store.next_pending().unwrap().key;
        store.fail_completion_record = true;
        assert!(commit(&mut store, k2).is_err());
        // Poisoned: no further writes until reopened.
        store.fail_completion_record = false;
        let k3 = store.plan()[2].key;
        let e = store
            .begin_trial(k3, UtcTime::from_unix_millis(0))
            .unwrap_err();
        assert!(e.to_string().contains("reopen"), "{e}");
        let rows = read_trials(&dir.join(TRIALS_FILE)).unwrap().rows;
        assert_eq!(rows.len(), 2, "the row reached trials.csv");
        let j = read_journal(&dir.join(JOURNAL_FILE)).unwrap();
        let completed = j
            .entries
            .iter()
            .filter(|e| matches!(e.record, Record::TrialCompleted { .. }))
            .count();
        assert_eq!(completed, 1, "its record did not");
        drop(store);
        let store = StudyStore::open(&dir, &p, &meta).unwrap();
        assert_eq!(store.recovery().adopted, vec![k2]);
        assert_eq!(store.completed_count(), 2);
        drop(store);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
