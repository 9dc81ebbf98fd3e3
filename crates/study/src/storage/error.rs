//! Typed errors of the storage layer (`export`, `journal`, `rawsig`).

use std::fmt;
use std::io;
use std::path::PathBuf;

use thiserror::Error;

use crate::protocol::ProtocolError;
use crate::seeds::TrialKey;

/// Result alias of the storage layer.
pub type Result<T> = std::result::Result<T, ExportError>;

/// `line 12` or `line 12, column \`time_s\``.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Position {
    /// 1-based line (the CSV header is line 1).
    pub line: u64,
    /// Column name, when the problem is in one cell.
    pub column: Option<String>,
}

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}", self.line)?;
        if let Some(c) = &self.column {
            write!(f, ", column `{c}`")?;
        }
        Ok(())
    }
}

/// Every fallible operation of the storage layer returns this error.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum ExportError {
    /// A file-system operation failed.
    #[error("{}: cannot {op}: {source}", path.display())]
    Io {
        /// File or directory.
        path: PathBuf,
        /// What was attempted (`open`, `append to`, `fsync`, …).
        op: &'static str,
        /// Underlying error.
        source: io::Error,
    },
    /// A file or folder of a study folder is a symbolic link: the store
    /// never follows one (it could write outside the folder).
    #[error(
        "{}: is a symbolic link; a study folder never follows links (replace it by the file or \
         folder itself, or open the folder the link points to)",
        path.display()
    )]
    SymbolicLink {
        /// The link.
        path: PathBuf,
    },
    /// `session.json` no longer holds what was written: a field was edited
    /// (its checksum, or what it is re-derived from, does not match).
    #[error("{}: field `{field}` was changed after it was written: {detail}", path.display())]
    SessionTampered {
        /// `session.json`.
        path: PathBuf,
        /// The field, e.g. `protocol_toml` or `seeds.study`.
        field: String,
        /// What does not match.
        detail: String,
    },
    /// A line of a file cannot be parsed (bad cell, wrong field count,
    /// malformed JSON, bad NPY header, …).
    #[error("{}: {at}: {message}", path.display())]
    Format {
        /// File.
        path: PathBuf,
        /// Line (and column) of the problem.
        at: Position,
        /// What is wrong.
        message: String,
    },
    /// The header of an existing `trials.csv` is not the one this version
    /// writes: appending would mix two layouts.
    #[error(
        "{}: header does not match the trials.csv layout of this version ({detail}); \
         refusing to append (use a new output folder, or convert the file)",
        path.display()
    )]
    HeaderMismatch {
        /// File.
        path: PathBuf,
        /// Expected header line.
        expected: String,
        /// Header found.
        found: String,
        /// First difference, e.g. "column 3 is `condition`, expected `session_order`".
        detail: String,
    },
    /// A complete line fails its CRC-32 although valid lines follow it: the
    /// file was modified or damaged after writing (a crash can only tear the
    /// last line).
    #[error(
        "{}: {at}: checksum mismatch (stored {stored}, computed {computed:08x}): the line was \
         changed or damaged after it was written",
        path.display()
    )]
    Checksum {
        /// File.
        path: PathBuf,
        /// Line.
        at: Position,
        /// Stored checksum text.
        stored: String,
        /// CRC-32 of the line's content.
        computed: u32,
    },
    /// Journal and `trials.csv` disagree in a way no crash can produce
    /// (a journaled trial without its row, a row hash mismatch, duplicate
    /// rows, a row of another study…): nothing is changed, the data need a
    /// human decision.
    #[error("{}: {message}", path.display())]
    Inconsistent {
        /// File in which the problem was found.
        path: PathBuf,
        /// Description naming the trial and line.
        message: String,
    },
    /// The folder holds a study recorded with a different protocol.
    #[error(
        "{}: the folder was created with protocol `{found_name}` (sha256 {found_sha256}), \
         not `{expected_name}` (sha256 {expected_sha256}); refusing to mix data — use a new \
         output folder",
        path.display()
    )]
    ProtocolMismatch {
        /// `session.json` of the folder.
        path: PathBuf,
        /// Name of the protocol passed to `open`.
        expected_name: String,
        /// Its hash.
        expected_sha256: String,
        /// Name recorded in the folder.
        found_name: String,
        /// Hash recorded in the folder.
        found_sha256: String,
    },
    /// The folder is not (or not entirely) a kilotouch study folder.
    #[error("{}: {reason}", path.display())]
    NotAStudyFolder {
        /// Folder.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A trial row carries an invalid value (non-finite metric, control
    /// character in a text cell, success with a reject reason, …).
    #[error("trial {key}: column `{column}`: {message}")]
    InvalidRow {
        /// The trial.
        key: TrialKey,
        /// Column.
        column: &'static str,
        /// What is wrong.
        message: String,
    },
    /// A trial operation out of sequence (unknown trial, already completed,
    /// another trial still open, row not matching its ticket).
    #[error("trial {key}: {message}")]
    Trial {
        /// The trial.
        key: TrialKey,
        /// What is wrong.
        message: String,
    },
    /// Invalid raw-signal writer usage or layout.
    #[error("{}: {message}", path.display())]
    Raw {
        /// File.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// JSON (de)serialisation failed outside a line-oriented file.
    #[error("{}: JSON: {source}", path.display())]
    Json {
        /// File.
        path: PathBuf,
        /// Underlying error.
        source: serde_json::Error,
    },
    /// A resume with a rig file, calibration or raw recording other than
    /// those the folder records.
    #[error(
        "{}: this resume differs from the study's set-up: {changes}; resuming would mix two \
         set-ups in one study — resume with the recorded files and settings, or start a new \
         sitting with the change recorded (`--new-sitting \"reason\"`)",
        path.display()
    )]
    SettingsChanged {
        /// `session.json` of the folder.
        path: PathBuf,
        /// Each difference (`rig file was …, now …`), `; `-separated.
        changes: String,
    },
    /// Another writer (this or another process) has the study folder open.
    #[error(
        "{}: the study folder is in use by another writer{}; two writers would corrupt it \
         — wait for that run to finish (or stop it), then resume",
        dir.display(),
        holder.as_ref().map_or_else(String::new, |h| format!(": {h}"))
    )]
    Locked {
        /// The folder.
        dir: PathBuf,
        /// The holder (PID, host, program, since), when its record could
        /// be read.
        holder: Option<String>,
    },
    /// The protocol is invalid or cannot be serialised.
    #[error("protocol: {0}")]
    Protocol(#[from] ProtocolError),
    /// The protocol cannot be written as TOML (non-finite number).
    #[error("protocol cannot be serialised: {0}")]
    ProtocolToml(String),
}

/// `map_err` helper: an I/O error with its path and operation.
pub(crate) fn io_err(
    path: impl Into<PathBuf>,
    op: &'static str,
) -> impl FnOnce(io::Error) -> ExportError {
    let path = path.into();
    move |source| {
        if is_link_error(&source) {
            ExportError::SymbolicLink { path }
        } else {
            ExportError::Io { path, op, source }
        }
    }
}

/// Whether an open with `O_NOFOLLOW` failed because the last component is
/// a symbolic link (`ELOOP`).
fn is_link_error(e: &io::Error) -> bool {
    #[cfg(unix)]
    {
        e.raw_os_error() == Some(libc::ELOOP)
    }
    #[cfg(not(unix))]
    {
        let _ = e;
        false
    }
}
