//! Durable file operations: fsync of files and directories, atomic
//! replacement, torn-tail bookkeeping; and links refused: every file of a
//! study folder is opened with `O_NOFOLLOW` ([`no_follow`]) and every
//! folder checked with `symlink_metadata` ([`refuse_link`]), so a symbolic
//! link planted in a study folder is reported by path
//! ([`ExportError::SymbolicLink`]) instead of being written through.
//!
//! POSIX guarantees nothing about a newly created directory entry until the
//! *directory* is fsynced, and nothing about appended data until the file is
//! fsynced (`fdatasync` suffices for appends: it flushes the data and the
//! file size). Every creation below is followed by an fsync of the parent
//! directory; on non-Unix targets directory fsync is a no-op (Windows cannot
//! open a directory as a file and NTFS journals its metadata).

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

use super::error::{ExportError, Result, io_err};
use super::utc::UtcTime;

/// Open options that refuse a symbolic link as the last component of the
/// path (`O_NOFOLLOW`: the open fails with `ELOOP`, which
/// [`super::error::io_err`] reports as [`ExportError::SymbolicLink`]).
pub fn no_follow() -> OpenOptions {
    #[allow(unused_mut)]
    let mut o = OpenOptions::new();
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.custom_flags(libc::O_NOFOLLOW);
    }
    o
}

/// Refuses `path` when it is a symbolic link (a missing path is fine).
///
/// # Errors
/// [`ExportError::SymbolicLink`].
pub fn refuse_link(path: &Path) -> Result<()> {
    match fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => Err(ExportError::SymbolicLink {
            path: path.to_path_buf(),
        }),
        _ => Ok(()),
    }
}

/// Whether `path` exists as a directory entry (a dangling link counts:
/// unlike [`Path::exists`], nothing is followed).
pub fn entry_exists(path: &Path) -> bool {
    fs::symlink_metadata(path).is_ok()
}

/// The bytes of a file, opened without following a link.
///
/// # Errors
/// I/O errors ([`ExportError::SymbolicLink`] for a link).
pub fn read_no_follow(path: &Path) -> Result<Vec<u8>> {
    read_no_follow_io(path).map_err(io_err(path, "read"))
}

/// [`read_no_follow`] with the I/O error (`NotFound` can be told apart).
pub(crate) fn read_no_follow_io(path: &Path) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let mut f = no_follow().read(true).open(path)?;
    let mut bytes = Vec::new();
    f.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Flushes a directory's entries (new, renamed files) to stable storage.
///
/// # Errors
/// The directory cannot be opened or synced.
pub fn sync_dir(dir: &Path) -> Result<()> {
    #[cfg(unix)]
    {
        let d = File::open(dir).map_err(io_err(dir, "open directory"))?;
        d.sync_all().map_err(io_err(dir, "fsync directory"))?;
    }
    #[cfg(not(unix))]
    {
        let _ = dir;
    }
    Ok(())
}

/// Parent directory of `path` (`.` for a bare file name).
pub fn parent_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Creates `dir` (and parents) and fsyncs it and its parent, so the new
/// entry survives a crash. A `dir` that is a symbolic link is refused (a
/// folder inside a study folder; the study folder itself, named by the
/// user, may be reached through links: see [`create_root_durable`]).
///
/// # Errors
/// [`ExportError::SymbolicLink`]; creation or fsync failure.
pub fn create_dir_durable(dir: &Path) -> Result<()> {
    refuse_link(dir)?;
    create_root_durable(dir)
}

/// [`create_dir_durable`] for the study folder itself: the path the user
/// gave may be a link to a folder (e.g. `/tmp` on macOS).
///
/// # Errors
/// Creation or fsync failure.
pub fn create_root_durable(dir: &Path) -> Result<()> {
    if !dir.is_dir() {
        fs::create_dir_all(dir).map_err(io_err(dir, "create directory"))?;
        sync_dir(&parent_of(dir))?;
    }
    sync_dir(dir)
}

/// Replaces `path` atomically with `bytes`: write `path.tmp`, fsync it,
/// rename over `path`, fsync the directory. A crash leaves either the old or
/// the new content, never a mixture.
///
/// # Errors
/// Any I/O failure (the temporary file may remain; it is overwritten by the
/// next attempt).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    refuse_link(path)?;
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    {
        let mut f = no_follow()
            .write(true)
            .create(true)
            .truncate(true)
            .open(&tmp)
            .map_err(io_err(&tmp, "create"))?;
        f.write_all(bytes).map_err(io_err(&tmp, "write"))?;
        f.sync_all().map_err(io_err(&tmp, "fsync"))?;
    }
    fs::rename(&tmp, path).map_err(io_err(path, "rename temporary file onto"))?;
    sync_dir(&parent_of(path))
}

/// Reads a JSON file (`session.json`, a raw file's sidecar).
///
/// # Errors
/// I/O errors; [`ExportError::Json`] naming the file.
pub(crate) fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let bytes = read_no_follow(path)?;
    serde_json::from_slice(&bytes).map_err(|source| ExportError::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// Appends `bytes` with a single `write_all` and `fdatasync`s the file: when
/// this returns `Ok`, the bytes are on stable storage.
///
/// # Errors
/// Write or sync failure.
pub fn append_durable(file: &mut File, path: &Path, bytes: &[u8]) -> Result<()> {
    file.write_all(bytes).map_err(io_err(path, "append to"))?;
    file.sync_data().map_err(io_err(path, "fsync"))
}

/// Opens `path` for appending, creating it (and fsyncing the directory) if
/// needed.
///
/// # Errors
/// Open / fsync failure.
pub fn open_append(path: &Path) -> Result<File> {
    let existed = entry_exists(path);
    let f = no_follow()
        .create(true)
        .append(true)
        .open(path)
        .map_err(io_err(path, "open for appending"))?;
    if !existed {
        f.sync_all().map_err(io_err(path, "fsync"))?;
        sync_dir(&parent_of(path))?;
    }
    Ok(f)
}

/// Bytes at the end of an append-only file that do not form a complete,
/// checksummed record: what a crash in the middle of an append leaves.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TornTail {
    /// File.
    pub file: PathBuf,
    /// Byte offset of the first invalid byte (the file is truncated here).
    pub offset: u64,
    /// Number of bytes discarded.
    pub len: u64,
    /// 1-based line number at which the torn part starts.
    pub line: u64,
    /// Why the bytes were rejected (no final newline, checksum, …).
    pub reason: String,
    /// Up to 120 characters of the discarded bytes, escaped.
    pub preview: String,
    /// Copy of the discarded bytes kept for inspection, if saved.
    pub saved_to: Option<PathBuf>,
}

/// Escaped preview of at most 120 characters.
pub fn preview(bytes: &[u8]) -> String {
    let s = String::from_utf8_lossy(bytes);
    let mut out: String = s.chars().take(120).flat_map(char::escape_default).collect();
    if s.chars().count() > 120 {
        out.push('…');
    }
    out
}

/// Truncates the torn tail of `path` (keeping a copy of the discarded bytes
/// in `recovery_dir`) and fsyncs. Returns the copy's path.
///
/// # Errors
/// I/O failure.
pub fn cut_torn_tail(
    path: &Path,
    torn: &TornTail,
    bytes: &[u8],
    recovery_dir: &Path,
) -> Result<PathBuf> {
    create_dir_durable(recovery_dir)?;
    let name = path
        .file_name()
        .map_or_else(|| "file".into(), |n| n.to_string_lossy().into_owned());
    let stamp = UtcTime::now().unix_millis();
    let copy = recovery_dir.join(format!("{name}.{stamp}.torn"));
    write_atomic(&copy, bytes)?;
    let f = no_follow()
        .write(true)
        .open(path)
        .map_err(io_err(path, "open for truncation"))?;
    f.set_len(torn.offset).map_err(io_err(path, "truncate"))?;
    f.sync_all().map_err(io_err(path, "fsync"))?;
    Ok(copy)
}

/// One line of an append-only file.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Line<'a> {
    /// 1-based line number.
    pub number: u64,
    /// Byte offset of the line start.
    pub offset: u64,
    /// Content without the terminating `\n`.
    pub text: &'a [u8],
    /// Whether the line ends with `\n`.
    pub complete: bool,
}

/// Splits `bytes` into lines (the last one may be incomplete).
pub(crate) fn split_lines(bytes: &[u8]) -> Vec<Line<'_>> {
    let mut out = Vec::new();
    let mut start = 0_usize;
    let mut number = 1_u64;
    while start < bytes.len() {
        match bytes[start..].iter().position(|&b| b == b'\n') {
            Some(i) => {
                out.push(Line {
                    number,
                    offset: start as u64,
                    text: &bytes[start..start + i],
                    complete: true,
                });
                start += i + 1;
            }
            None => {
                out.push(Line {
                    number,
                    offset: start as u64,
                    text: &bytes[start..],
                    complete: false,
                });
                start = bytes.len();
            }
        }
        number += 1;
    }
    out
}

/// Outcome of checking one line.
pub(crate) enum Checked<T> {
    /// A valid record.
    Good(T),
    /// An invalid line: the error to report if valid lines follow it, and a
    /// short reason for the torn-tail report otherwise.
    Bad(ExportError, String),
    /// A line that passed its checksum (so was written completely as it is)
    /// but cannot be understood: never cut, always an error.
    Fatal(ExportError),
}

/// Valid records with their 1-based line numbers, and the torn tail.
pub(crate) type ValidPrefix<T> = (Vec<(u64, T)>, Option<TornTail>);

/// Splits checked lines into the valid prefix and the torn tail.
///
/// Only the tail can be torn by a crash (every record is fsynced before the
/// next is written): invalid lines followed by a valid one are corruption
/// and return the first one's error.
pub(crate) fn valid_prefix<T>(
    path: &Path,
    bytes: &[u8],
    checked: Vec<(Line<'_>, Checked<T>)>,
) -> Result<ValidPrefix<T>> {
    let last_good = checked
        .iter()
        .rposition(|(_, c)| matches!(c, Checked::Good(_)));
    let mut good = Vec::new();
    let mut torn = None;
    for (i, (line, c)) in checked.into_iter().enumerate() {
        match c {
            Checked::Good(v) => good.push((line.number, v)),
            Checked::Fatal(err) => return Err(err),
            Checked::Bad(err, reason) => {
                if last_good.is_some_and(|g| i < g) {
                    return Err(err);
                }
                if torn.is_none() {
                    let tail = &bytes[line.offset as usize..];
                    torn = Some(TornTail {
                        file: path.to_path_buf(),
                        offset: line.offset,
                        len: tail.len() as u64,
                        line: line.number,
                        reason,
                        preview: preview(tail),
                        saved_to: None,
                    });
                }
            }
        }
    }
    Ok((good, torn))
}
