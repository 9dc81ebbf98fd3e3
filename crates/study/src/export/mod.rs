//! The study output folder: crash-safe trial storage, resume, summaries.
//!
//! A [`StudyStore`] owns one output folder per study:
//!
//! ```text
//! <folder>/
//!   session.json      protocol, seeds, order table, software, rig, calibration, sittings
//!   trials.csv        one row per finished trial (append-only, CRC per row)
//!   journal.jsonl     append-only session journal (CRC per line)
//!   cells_long.csv    participant × condition means (regenerated)
//!   cells_wide.csv    one row per participant (regenerated)
//!   datapackage.json  Frictionless data package: the three tables' fields,
//!                     types, units, constraints (regenerated with them)
//!   raw/<P>_<C>_<phase>_<trial>.npy + .json   full-rate signals per trial
//!   recovery/         copies of torn tails cut on resume
//!   recovery/quarantine/  raw files of finished trials that failed their check
//!   writer.lock       the one-writer lock (PID, host, program of the holder),
//!                     removed by a clean close
//! ```
//!
//! No file or folder inside is ever a symbolic link: the store refuses one
//! by path before opening anything ([`refuse_links`]) and opens every file
//! with `O_NOFOLLOW`. `session.json` carries a checksum of every field and
//! is checked against its protocol text when read
//! ([`session::read_session`]).
//!
//! # One writer, checked resumes
//!
//! [`StudyStore::open`] takes the folder's lock ([`lock::FolderLock`]) for
//! the store's life: a second writer, in this or another process, is
//! refused at once with the holder's PID and host. On resume it refuses a
//! rig file, calibration or raw recording other than `session.json`'s
//! ([`settings`]) unless the change is recorded, and checks every finished
//! trial's raw file (size, header, CRC-32 in the sidecar): a damaged one
//! is moved to `recovery/quarantine/`, named in the [`Recovery`] report,
//! journaled (`raw_quarantined`) and its row's `raw_file` rewritten to
//! where it went (empty when it was missing).
//!
//! # Commit order (per trial)
//!
//! 1. journal `trial_started` (fsync);
//! 2. raw signals streamed to `raw/…npy`; [`NpyWriter::finish`] patches the
//!    header, fsyncs the file, writes the sidecar, fsyncs the directory;
//! 3. the row is appended to `trials.csv` in one `write`, then `fdatasync`;
//! 4. journal `trial_completed` with the row's CRC (fsync);
//! 5. only then does [`StudyStore::commit_trial`] return and the next trial
//!    may start.
//!
//! `trials.csv` is the record of truth; the journal is the log that makes a
//! crash at any point recoverable:
//!
//! | crash during / after | found on [`StudyStore::open`] | action |
//! |---|---|---|
//! | 1–2 | `trial_started` without completion | reported *interrupted*, journaled `trial_aborted`, run again (same seeds → same row) |
//! | 3 (partial row) | last line without `\n` / bad CRC | cut (copy in `recovery/`), trial run again |
//! | between 3 and 4 | complete, checksummed row without `trial_completed` | row *adopted*: kept, `trial_completed` journaled now |
//! | 4 (partial record) | torn last journal line | cut (copy in `recovery/`); row adopted as above |
//!
//! Anything a crash cannot produce — a journaled completion whose row is
//! missing, a row whose CRC differs from its journal record, a damaged line
//! followed by valid ones, duplicate rows, rows of another protocol or
//! seed — is an error and nothing is modified.
//!
//! # Code
//!
//! `store.rs`: [`StudyStore`] and the trial lifecycle ([`TrialTicket`]);
//! `open.rs`: the file-system steps of [`StudyStore::open`], around the pure
//! `reconcile.rs` (the table above, and the [`Recovery`] report);
//! `plan.rs`: the trials of a protocol in run order ([`plan`]); one module
//! per file format: [`trials`], [`journal`], [`session`], [`summary`],
//! with [`checksum`]. Errors, durable file operations and timestamps
//! ([`error`], [`fsutil`], [`utc`]) are shared with [`crate::rawsig`].
//!
//! [`NpyWriter::finish`]: crate::rawsig::NpyWriter::finish

pub mod checksum;
pub mod datapackage;
pub mod journal;
mod open;
mod plan;
mod raw_check;
mod reconcile;
pub mod session;
pub mod settings;
mod store;
pub mod summary;
pub mod trials;

pub use crate::storage::{error, fsutil, lock, utc};

pub use datapackage::{DATAPACKAGE_FILE, SummaryLayout, write_datapackage};
pub use error::{ExportError, Position, Result};
pub use fsutil::TornTail;
pub use open::RECOVERY_DIR;
pub use plan::{
    PlannedTrial, RAW_DIR, extend_with_rows, plan, plan_with_rows, practice_retry, raw_file_name,
    raw_layout_for,
};
pub use raw_check::QUARANTINE_DIR;
pub use reconcile::{DamagedRaw, Recovery};
pub use session::{
    CalibrationRef, DeviceRecord, OrderRow, Progress, SESSION_FILE, SOFTWARE_VERSION, SessionInfo,
    SimulationInfo, Sitting, SittingTiming, StudyMeta, TweezerDeviceRecord, read_session,
};
pub use store::{StudyStore, TrialTicket, refuse_links};
pub use summary::{
    CELLS_LONG_FILE, CELLS_WIDE_FILE, Summary, SummaryFiles, Table, regenerate_summaries, summarize,
};
pub use trials::{
    Metric, ReadOptions, TRIALS_COLUMNS, TRIALS_FILE, TaskKind, TrialRow, TrialsRead, read_trials,
    read_trials_with,
};
pub use utc::UtcTime;
