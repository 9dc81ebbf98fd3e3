//! Reconciling a study folder when it is opened: what the journal,
//! `trials.csv` and `session.json` say becomes what
//! [`StudyStore::open`](super::StudyStore::open) keeps, adopts and runs
//! again ([`reconcile`]), and what it reports ([`Recovery`]). Pure: the
//! files are read and repaired by the opening steps around it
//! (`export/open.rs`); the crash cases are listed in the [`super`] module
//! documentation.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use super::checksum;
use super::journal::{JOURNAL_FILE, JournalRead, Record, sittings};
use super::plan::PlannedTrial;
use super::session::OrderRow;
use super::trials::{TRIALS_FILE, TaskKind, TrialRow, TrialsRead, first_difference};
use crate::seeds::TrialKey;
use crate::storage::error::{ExportError, Result};
use crate::storage::fsutil::TornTail;

/// What [`StudyStore::open`](super::StudyStore::open) found and repaired.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recovery {
    /// The folder already held a study.
    pub resumed: bool,
    /// Torn journal tail that was cut.
    pub journal_torn: Option<TornTail>,
    /// Torn `trials.csv` tail that was cut.
    pub trials_torn: Option<TornTail>,
    /// Rows kept although their `trial_completed` record was missing.
    pub adopted: Vec<TrialKey>,
    /// Trials started but not finished by an earlier sitting (to be run
    /// again).
    pub interrupted: Vec<TrialKey>,
    /// The previous sitting ended without `session_done` (crash, kill, or
    /// a runner that dropped the store without closing it).
    pub previous_sitting_unclosed: bool,
    /// Completed trials after recovery.
    pub completed: usize,
    /// Trials still to run.
    pub pending: usize,
    /// The record of a previous writer that ended without releasing the
    /// folder's lock (crash, kill, power loss).
    pub stale_lock: Option<crate::storage::lock::Holder>,
    /// Raw files of finished trials that failed their check on resume
    /// (moved to `recovery/quarantine/`).
    pub damaged_raw: Vec<DamagedRaw>,
}

/// A finished trial's raw file that failed its check on resume
/// (missing, truncated, header or checksum not matching its sidecar).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DamagedRaw {
    /// The trial.
    pub trial: TrialKey,
    /// The raw file, relative to the folder (`raw/…npy`).
    pub file: String,
    /// What is wrong with it.
    pub reason: String,
    /// Where the damaged file and its sidecar were moved, relative to the
    /// folder (`None`: nothing left to move).
    pub quarantined_to: Option<String>,
}

impl Recovery {
    /// True when nothing had to be repaired or adopted.
    pub fn is_clean(&self) -> bool {
        self.journal_torn.is_none()
            && self.trials_torn.is_none()
            && self.adopted.is_empty()
            && self.interrupted.is_empty()
            && self.damaged_raw.is_empty()
    }
}

impl fmt::Display for Recovery {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.resumed {
            write!(
                f,
                "resumed: {} trial(s) complete, {} pending",
                self.completed, self.pending
            )?;
        } else {
            write!(f, "new study folder, {} trial(s) planned", self.pending)?;
        }
        if self.previous_sitting_unclosed {
            f.write_str("; the previous sitting ended without closing (crash or kill)")?;
        }
        // Also in a folder that holds no study yet: the previous writer can
        // die after taking the folder and before creating the study.
        if let Some(h) = &self.stale_lock {
            write!(
                f,
                "; the previous writer, {h}, ended without releasing the folder"
            )?;
        }
        for t in [&self.journal_torn, &self.trials_torn]
            .into_iter()
            .flatten()
        {
            write!(
                f,
                "; cut {} torn byte(s) at line {} of {} ({})",
                t.len,
                t.line,
                t.file.display(),
                t.reason
            )?;
        }
        if !self.adopted.is_empty() {
            let list: Vec<String> = self.adopted.iter().map(ToString::to_string).collect();
            write!(
                f,
                "; adopted row(s) without journal record: {}",
                list.join(", ")
            )?;
        }
        if !self.interrupted.is_empty() {
            let list: Vec<String> = self.interrupted.iter().map(ToString::to_string).collect();
            write!(
                f,
                "; interrupted trial(s) to run again: {}",
                list.join(", ")
            )?;
        }
        for d in &self.damaged_raw {
            write!(
                f,
                "; DAMAGED raw file {} of trial {} ({}){}: the trial is flagged in the journal, \
                 its row kept without trusted signals",
                d.file,
                d.trial,
                d.reason,
                d.quarantined_to
                    .as_ref()
                    .map_or_else(String::new, |q| format!(", moved to {q}"))
            )?;
        }
        Ok(())
    }
}

/// What the folder must hold: the protocol's task, order table and plan,
/// as `session.json` records them.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Expected<'a> {
    /// The protocol's task.
    pub task: TaskKind,
    /// Participant → condition order table.
    pub orders: &'a [OrderRow],
    /// Every trial of the protocol, in run order.
    pub plan: &'a [PlannedTrial],
    /// Index in `plan` of each trial.
    pub plan_index: &'a HashMap<TrialKey, usize>,
}

/// What the folder's append-only files hold (valid records and torn tails,
/// read before anything is modified), with their paths for the messages.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Found<'a> {
    /// The journal file.
    pub journal_path: &'a Path,
    /// Its records.
    pub journal: &'a JournalRead,
    /// `trials.csv`.
    pub trials_path: &'a Path,
    /// Its rows; `None` without the file or with only part of its header
    /// (a crash while it was created).
    pub trials: Option<&'a TrialsRead>,
}

/// What opening does with the trials of a consistent folder.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct Verdict {
    /// Rows kept: every trial with a valid row in `trials.csv`, with its
    /// `row_crc32`.
    pub completed: HashMap<TrialKey, u32>,
    /// Kept rows whose `trial_completed` record is missing (the crash came
    /// between the row and its record): journaled now, in file order.
    pub adopted: Vec<TrialKey>,
    /// Trials begun and neither completed nor aborted (the crash came
    /// during the trial): aborted now and run again, in journal order.
    pub interrupted: Vec<TrialKey>,
    /// The last sitting of the journal has no `session_done`.
    pub previous_sitting_unclosed: bool,
    /// Rows whose raw file was journaled as quarantined
    /// ([`Record::RawQuarantined`]) but not yet rewritten (a crash came
    /// between the record and the rewrite): finished by the opening.
    pub pending_quarantine: Vec<PendingQuarantine>,
}

/// A quarantine journaled but not yet carried out in `trials.csv`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct PendingQuarantine {
    /// The trial.
    pub trial: TrialKey,
    /// 1-based line of its row in `trials.csv`.
    pub line: u64,
    /// The raw file the row names.
    pub file: String,
    /// Where the record says it goes (`None`: nowhere, it was missing).
    pub moved_to: Option<String>,
    /// The rewritten row's CRC the record gives.
    pub row_crc32: u32,
}

/// Checks that every sitting of the journal ran the protocol `session.json`
/// records (`protocol_sha256`).
///
/// # Errors
/// [`ExportError::Inconsistent`] naming the first other sitting's line.
pub(crate) fn check_sittings(
    journal_path: &Path,
    journal: &JournalRead,
    protocol_sha256: &str,
) -> Result<()> {
    for (e, line) in journal.entries.iter().zip(&journal.lines) {
        if let Record::SessionStarted(s) = &e.record
            && s.protocol_sha256 != protocol_sha256
        {
            return Err(ExportError::Inconsistent {
                path: journal_path.to_path_buf(),
                message: format!(
                    "line {line}: sitting with protocol sha256 {} but session.json records {}",
                    s.protocol_sha256, protocol_sha256
                ),
            });
        }
    }
    Ok(())
}

/// Decides, from what the files hold, which rows are kept, which are
/// adopted and which trials run again (see the module documentation of
/// [`super`] for the crash cases).
///
/// # Errors
/// [`ExportError::Inconsistent`] for anything a crash cannot produce: a
/// malformed or repeated completion record, a row of a participant or
/// trial not in the plan or with other identity columns (seed, session,
/// order, task) than the plan gives, a row whose CRC differs from its
/// journal record, a journaled completion without its row.
pub(crate) fn reconcile(found: &Found<'_>, expected: &Expected<'_>) -> Result<Verdict> {
    let JournalTrials {
        mut done,
        mut started,
        mut quarantined,
    } = journal_trials(found.journal_path, found.journal)?;
    let mut pending_quarantine = Vec::new();
    let by_id: HashMap<&str, &OrderRow> = expected
        .orders
        .iter()
        .map(|o| (o.participant.as_str(), o))
        .collect();
    let mut completed: HashMap<TrialKey, u32> = HashMap::new();
    let mut adopted = Vec::new();
    if let Some(read) = found.trials {
        for ((row, &crc), &line) in read.rows.iter().zip(&read.crcs).zip(&read.lines) {
            let incon = |message: String| ExportError::Inconsistent {
                path: found.trials_path.to_path_buf(),
                message: format!("line {line}: {message}"),
            };
            let key = planned_key(row, &by_id, expected).map_err(incon)?;
            let q = quarantined.remove(&key);
            match done.remove(&key) {
                // Quarantine journaled, row not yet rewritten.
                Some((jcrc, _)) if jcrc != crc && q.as_ref().is_some_and(|q| q.0 == crc) => {
                    if let Some((_, file, moved_to)) = q {
                        pending_quarantine.push(PendingQuarantine {
                            trial: key,
                            line,
                            file,
                            moved_to,
                            row_crc32: jcrc,
                        });
                    }
                }
                Some((jcrc, jline)) if jcrc != crc => {
                    return Err(incon(format!(
                        "trial {key}: row_crc32 {crc:08x} differs from the journal's {jcrc:08x} \
                         ({JOURNAL_FILE} line {jline}): the row was changed after it was written"
                    )));
                }
                Some(_) => {}
                None => adopted.push(key),
            }
            started.remove(&key);
            completed.insert(key, crc);
        }
    }
    if let Some((key, (crc, line))) = done.iter().min_by_key(|(_, (_, l))| *l) {
        return Err(ExportError::Inconsistent {
            path: found.trials_path.to_path_buf(),
            message: format!(
                "{JOURNAL_FILE} line {line} records trial {key} as completed (row_crc32 \
                 {crc:08x}) but {TRIALS_FILE} has no such row: rows were lost or removed; \
                 nothing was changed"
            ),
        });
    }
    let mut interrupted: Vec<(u64, TrialKey)> = started.into_iter().map(|(k, l)| (l, k)).collect();
    interrupted.sort();
    let previous_sitting_unclosed = sittings(&found.journal.entries)
        .last()
        .is_some_and(|s| s.done_utc.is_none());
    Ok(Verdict {
        completed,
        adopted,
        interrupted: interrupted.into_iter().map(|(_, k)| k).collect(),
        previous_sitting_unclosed,
        pending_quarantine,
    })
}

/// The trials of the journal: completed (row CRC and line of the record)
/// and begun without an end yet (line of `trial_started`).
struct JournalTrials {
    done: HashMap<TrialKey, (u32, u64)>,
    started: HashMap<TrialKey, u64>,
    /// Last quarantine of each trial: (the row's CRC before it, file,
    /// where it went).
    quarantined: HashMap<TrialKey, (u32, String, Option<String>)>,
}

/// Replays the journal's trial records ([`JournalTrials`]).
///
/// # Errors
/// [`ExportError::Inconsistent`] for a malformed `row_crc32` or a trial
/// completed twice.
fn journal_trials(journal_path: &Path, journal: &JournalRead) -> Result<JournalTrials> {
    let mut done: HashMap<TrialKey, (u32, u64)> = HashMap::new();
    let mut started: HashMap<TrialKey, u64> = HashMap::new();
    let mut quarantined = HashMap::new();
    for (e, &line) in journal.entries.iter().zip(&journal.lines) {
        let incon = |message: String| ExportError::Inconsistent {
            path: journal_path.to_path_buf(),
            message: format!("line {line}: {message}"),
        };
        let parse = |hex: &str| {
            checksum::parse_crc32_hex(hex)
                .ok_or_else(|| incon(format!("malformed row_crc32 `{hex}`")))
        };
        match &e.record {
            Record::RawQuarantined {
                trial,
                file,
                moved_to,
                previous_row_crc32,
                row_crc32,
                ..
            } => {
                let (previous, new) = (parse(previous_row_crc32)?, parse(row_crc32)?);
                match done.get(trial) {
                    Some(&(c, _)) if c == previous => {}
                    _ => {
                        return Err(incon(format!(
                            "trial {trial}: raw file quarantined from a row with row_crc32 \
                             {previous_row_crc32}, not the trial's recorded row"
                        )));
                    }
                }
                done.insert(*trial, (new, line));
                quarantined.insert(*trial, (previous, file.clone(), moved_to.clone()));
            }
            Record::TrialStarted { trial, .. } => {
                started.insert(*trial, line);
            }
            Record::TrialAborted { trial, .. } => {
                started.remove(trial);
            }
            Record::TrialCompleted {
                trial, row_crc32, ..
            } => {
                started.remove(trial);
                let crc = parse(row_crc32)?;
                if done.insert(*trial, (crc, line)).is_some() {
                    return Err(incon(format!("trial {trial} completed twice")));
                }
            }
            _ => {}
        }
    }
    Ok(JournalTrials {
        done,
        started,
        quarantined,
    })
}

/// The trial of a `trials.csv` row, checked against the plan: its
/// participant is in the order table (`by_id`: by participant id), its trial in the plan, and its seed,
/// session index, session order and task are the plan's.
///
/// # Errors
/// The message of the first problem (without the line).
fn planned_key(
    row: &TrialRow,
    by_id: &HashMap<&str, &OrderRow>,
    expected: &Expected<'_>,
) -> std::result::Result<TrialKey, String> {
    let order = by_id.get(row.participant.as_str()).ok_or_else(|| {
        format!(
            "participant `{}` is not in the protocol's order table",
            row.participant
        )
    })?;
    let key = row.key(order.index);
    let planned = expected
        .plan_index
        .get(&key)
        .map(|&i| &expected.plan[i])
        .ok_or_else(|| format!("trial {key} is not in the protocol's plan"))?;
    let plan_row = planned.blank_row(expected.task, row.started_utc, row.raw_file.clone());
    let columns = ["seed", "session_index", "session_order", "task"];
    match first_difference(&plan_row, row, &columns) {
        Some((column, expected, found)) => Err(format!(
            "trial {key}: column `{column}` is `{found}`, the protocol gives `{expected}` (row \
             of another study or seed?)"
        )),
        None => Ok(key),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::journal::{Entry, encode_line, parse_journal};
    use crate::export::plan::plan;
    use crate::export::session::order_rows;
    use crate::export::trials::{ReadOptions, header_line, parse_trials};
    use crate::protocol::Protocol;
    use crate::storage::utc::UtcTime;

    /// A study of 1 participant, conditions V and D, 2 test trials each.
    struct Study {
        protocol: Protocol,
        orders: Vec<OrderRow>,
        plan: Vec<PlannedTrial>,
        plan_index: HashMap<TrialKey, usize>,
    }

    impl Study {
        fn new() -> Self {
            let protocol = Protocol::from_toml_str(
                "name = \"reconcile\"\nparticipants = 1\nconditions = [\"V\", \"D\"]\n\
                 trials_per_session = 2\n[training]\npractice_trials = 0\n[task.circling]\n",
                "<test>",
            )
            .unwrap();
            let orders = order_rows(&protocol.assignment().unwrap());
            let plan = plan(&protocol, &orders);
            let plan_index = plan.iter().enumerate().map(|(i, p)| (p.key, i)).collect();
            Self {
                protocol,
                orders,
                plan,
                plan_index,
            }
        }

        fn expected(&self) -> Expected<'_> {
            Expected {
                task: TaskKind::of(&self.protocol.task),
                orders: &self.orders,
                plan: &self.plan,
                plan_index: &self.plan_index,
            }
        }

        /// The `trials.csv` line of planned trial `i` and its CRC.
        fn row(&self, i: usize) -> (String, u32) {
            let mut row = self.plan[i].blank_row(
                self.expected().task,
                UtcTime::from_unix_millis(0),
                String::new(),
            );
            row.success = true;
            row.time_s = Some(1.0);
            row.encode().unwrap()
        }
    }

    /// Journal bytes of `records` (sequence numbers from 0).
    fn journal(records: Vec<Record>) -> Vec<u8> {
        let mut out = String::new();
        for (seq, record) in records.into_iter().enumerate() {
            let entry = Entry {
                seq: seq as u64,
                utc: UtcTime::from_unix_millis(0),
                record,
            };
            out.push_str(&encode_line(&entry).unwrap());
        }
        out.into_bytes()
    }

    fn started(key: TrialKey) -> Record {
        Record::TrialStarted {
            trial: key,
            seed: String::new(),
            started_utc: UtcTime::from_unix_millis(0),
        }
    }

    fn completed(key: TrialKey, crc: u32) -> Record {
        Record::TrialCompleted {
            trial: key,
            row_crc32: checksum::crc32_hex(crc),
            adopted: false,
        }
    }

    /// Parses the two files as `StudyStore::open` does and reconciles them.
    fn run(study: &Study, journal_bytes: &[u8], trials_bytes: &[u8]) -> Result<Verdict> {
        let (jpath, tpath) = (Path::new(JOURNAL_FILE), Path::new(TRIALS_FILE));
        let jread = parse_journal(jpath, journal_bytes)?;
        let tread = parse_trials(tpath, trials_bytes, ReadOptions::default())?;
        let found = Found {
            journal_path: jpath,
            journal: &jread,
            trials_path: tpath,
            trials: Some(&tread),
        };
        reconcile(&found, &study.expected())
    }

    #[test]
    fn a_clean_folder_keeps_every_row() {
        let s = Study::new();
        let (line, crc) = s.row(0);
        let key = s.plan[0].key;
        let j = journal(vec![started(key), completed(key, crc)]);
        let v = run(&s, &j, (header_line() + &line).as_bytes()).unwrap();
        assert_eq!(v.completed, HashMap::from([(key, crc)]));
        assert!(v.adopted.is_empty() && v.interrupted.is_empty());
        // No sitting recorded: none left unclosed.
        assert!(!v.previous_sitting_unclosed);
        // A new folder: nothing at all.
        let v = run(&s, &[], header_line().as_bytes()).unwrap();
        assert_eq!(v, Verdict::default());
    }

    /// A crash during the append of the second row: the torn row is not
    /// kept and its trial, begun in the journal, runs again.
    #[test]
    fn a_torn_row_is_not_kept_and_its_trial_runs_again() {
        let s = Study::new();
        let (k0, k1) = (s.plan[0].key, s.plan[1].key);
        let (line0, crc0) = s.row(0);
        let (line1, _) = s.row(1);
        let trials = header_line() + &line0 + &line1[..line1.len() / 2];
        let j = journal(vec![started(k0), completed(k0, crc0), started(k1)]);
        let v = run(&s, &j, trials.as_bytes()).unwrap();
        assert_eq!(v.completed, HashMap::from([(k0, crc0)]));
        assert!(v.adopted.is_empty());
        assert_eq!(v.interrupted, vec![k1]);
    }

    /// A crash between the row and its `trial_completed` record: the row is
    /// adopted. A crash during a trial: the trial runs again.
    #[test]
    fn a_row_without_record_is_adopted_and_an_unfinished_trial_interrupted() {
        let s = Study::new();
        let (k0, k1, k2) = (s.plan[0].key, s.plan[1].key, s.plan[2].key);
        let (line0, crc0) = s.row(0);
        let (line1, crc1) = s.row(1);
        let j = journal(vec![
            started(k0),
            completed(k0, crc0),
            started(k1),
            // crash after the row of k1; a later sitting begins k2 and crashes.
            started(k2),
        ]);
        let trials = header_line() + &line0 + &line1;
        let v = run(&s, &j, trials.as_bytes()).unwrap();
        assert_eq!(v.completed, HashMap::from([(k0, crc0), (k1, crc1)]));
        assert_eq!(v.adopted, vec![k1]);
        assert_eq!(v.interrupted, vec![k2]);
        // An aborted trial is not interrupted.
        let j = journal(vec![
            started(k0),
            Record::TrialAborted {
                trial: k0,
                reason: "test".into(),
            },
        ]);
        let v = run(&s, &j, header_line().as_bytes()).unwrap();
        assert!(v.interrupted.is_empty());
    }

    #[test]
    fn what_no_crash_produces_is_an_error() {
        let s = Study::new();
        let k0 = s.plan[0].key;
        let (line0, crc0) = s.row(0);
        // A journaled completion without its row.
        let j = journal(vec![started(k0), completed(k0, crc0)]);
        let e = run(&s, &j, header_line().as_bytes()).unwrap_err();
        assert!(e.to_string().contains("has no such row"), "{e}");
        // A row whose CRC is not the journal's.
        let j = journal(vec![started(k0), completed(k0, crc0 ^ 1)]);
        let e = run(&s, &j, (header_line() + &line0).as_bytes()).unwrap_err();
        assert!(e.to_string().contains("differs from the journal's"), "{e}");
        // A row of another seed.
        let mut row =
            s.plan[0].blank_row(TaskKind::Circling, UtcTime::from_unix_millis(0), "".into());
        row.success = true;
        row.seed ^= 1;
        let (line, _) = row.encode().unwrap();
        let e = run(&s, &[], (header_line() + &line).as_bytes()).unwrap_err();
        assert!(e.to_string().contains("column `seed`"), "{e}");
    }
}
