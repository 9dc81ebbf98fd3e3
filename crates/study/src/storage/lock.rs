//! One writer per study folder: an exclusive OS advisory lock on
//! `<folder>/writer.lock`, held for the life of a
//! [`crate::export::StudyStore`] (the CLI's `study simulate` and the GUI's
//! session thread both open their folder through it).
//!
//! The lock is the operating system's (`flock` on Unix, `LockFileEx` on
//! Windows, through [`std::fs::File::try_lock`]): it belongs to the open
//! file, so the kernel releases it when the holder exits *in any way* —
//! a crash or `kill -9` leaves no lock behind, only the file with the dead
//! holder's record. That record (PID, host, program, start time) is what a
//! refused writer names; a writer that acquires the lock and finds a record
//! left by a holder that never released it reports the previous writer as
//! ended without closing ([`FolderLock::stale`]).
//!
//! A clean release deletes the file, so a closed study folder holds no
//! `writer.lock`. Deleting a lock file races with a writer that opened it
//! just before: that writer would then hold a lock on a file no longer in
//! the folder while a third writer creates a new one. So the holder
//! deletes the file *while still holding the lock*, and a writer that
//! acquires the lock checks that the file it locked is still the one at
//! `writer.lock` (same device and inode); if not, it opens the new file and
//! tries again. A writer that dies leaves the file with its record: the
//! stale-lock report above. The file is opened with `O_NOFOLLOW`: a link
//! in its place is refused.

use std::fs::{File, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::error::{ExportError, Result, io_err};
use super::fsutil::{create_root_durable, no_follow, sync_dir};
use super::utc::UtcTime;

/// File name of the lock inside a study folder.
pub const LOCK_FILE: &str = "writer.lock";

/// Largest lock record read, bytes (a record is ≈ 150 bytes; anything
/// longer is not one of ours and is not read whole).
const MAX_RECORD: u64 = 4096;

/// Who holds (or held) a study folder.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Holder {
    /// Process id.
    pub pid: u32,
    /// Host name.
    pub host: String,
    /// Program and version, e.g. `kilotouch 0.1.0`.
    pub program: String,
    /// When the lock was taken.
    pub since_utc: UtcTime,
}

impl Holder {
    /// This process, now.
    fn this_process(program: &str) -> Self {
        Self {
            pid: std::process::id(),
            host: gethostname::gethostname().to_string_lossy().into_owned(),
            program: program.to_owned(),
            since_utc: UtcTime::now(),
        }
    }
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "PID {} on host `{}` ({}, since {})",
            self.pid,
            kilotouch_rig::text::printable(&self.host, 64),
            kilotouch_rig::text::printable(&self.program, 64),
            self.since_utc
        )
    }
}

/// The exclusive lock of a study folder, released when dropped.
#[derive(Debug)]
pub struct FolderLock {
    file: File,
    path: PathBuf,
    stale: Option<Holder>,
}

/// Reads the holder record of an open lock file (`None`: empty or not a
/// record).
fn read_record(file: &mut File) -> Option<Holder> {
    let mut bytes = Vec::new();
    file.seek(SeekFrom::Start(0)).ok()?;
    Read::by_ref(file)
        .take(MAX_RECORD)
        .read_to_end(&mut bytes)
        .ok()?;
    serde_json::from_slice(&bytes).ok()
}

impl FolderLock {
    /// Takes the lock of the folder `dir` (created if missing) without
    /// waiting, and records this process (`program`) as the holder.
    ///
    /// # Errors
    /// [`ExportError::Locked`] naming the holder when another writer — in
    /// this or another process — has the folder; I/O errors (also on file
    /// systems without advisory locks).
    pub fn acquire(dir: &Path, program: &str) -> Result<Self> {
        create_root_durable(dir)?;
        let path = dir.join(LOCK_FILE);
        let mut file = Self::lock_current(dir, &path)?;
        let stale = read_record(&mut file);
        let me = Holder::this_process(program);
        let record = serde_json::to_vec(&me).map_err(|source| ExportError::Json {
            path: path.clone(),
            source,
        })?;
        file.set_len(0)
            .and_then(|()| file.seek(SeekFrom::Start(0)))
            .and_then(|_| file.write_all(&record))
            .and_then(|()| file.write_all(b"\n"))
            .and_then(|()| file.sync_data())
            .map_err(io_err(&path, "write the lock record to"))?;
        Ok(Self { file, path, stale })
    }

    /// Opens (creating) and locks the file at `path`, again while the file
    /// locked is not the one at `path` any more (its holder deleted it on
    /// release between this open and this lock). Bounded: a folder whose
    /// lock file changes under every attempt is reported as in use.
    fn lock_current(dir: &Path, path: &Path) -> Result<File> {
        const ATTEMPTS: usize = 100;
        for _ in 0..ATTEMPTS {
            let mut file = no_follow()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(path)
                .map_err(io_err(path, "open the lock file"))?;
            match file.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    return Err(ExportError::Locked {
                        dir: dir.to_path_buf(),
                        holder: read_record(&mut file).map(|h| h.to_string()),
                    });
                }
                Err(TryLockError::Error(e)) => return Err(io_err(path, "lock")(e)),
            }
            if is_same_file(&file, path)? {
                return Ok(file);
            }
        }
        Err(ExportError::Locked {
            dir: dir.to_path_buf(),
            holder: Some(format!(
                "writers that released it {ATTEMPTS} times while this one tried to take it"
            )),
        })
    }

    /// The record of a previous writer that ended without releasing the
    /// folder (crash, kill, power loss), if one was found.
    pub fn stale(&self) -> Option<&Holder> {
        self.stale.as_ref()
    }

    /// Path of the lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Whether the open `file` is the file now at `path` (Unix: same device
/// and inode; elsewhere files are not deleted on release, so always).
fn is_same_file(file: &File, path: &Path) -> Result<bool> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let open = file
            .metadata()
            .map_err(io_err(path, "stat the lock file"))?;
        Ok(match std::fs::symlink_metadata(path) {
            Ok(now) => now.dev() == open.dev() && now.ino() == open.ino(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => false,
            Err(e) => return Err(io_err(path, "stat the lock file")(e)),
        })
    }
    #[cfg(not(unix))]
    {
        let _ = (file, path);
        Ok(true)
    }
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        // A clean release deletes the file while the lock is still held
        // (module docs), then releases the lock with the handle. Where an
        // open file cannot be deleted (Windows) it is emptied instead.
        #[cfg(unix)]
        {
            if std::fs::remove_file(&self.path).is_ok()
                && let Some(dir) = self.path.parent()
            {
                let _ = sync_dir(dir);
            }
        }
        #[cfg(not(unix))]
        {
            let _ = self.file.set_len(0);
            let _ = self.file.sync_data();
        }
        let _ = self.file.unlock();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_is_refused_with_the_holder_and_released_on_drop() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::acquire(dir.path(), "test 1").unwrap();
        assert!(first.stale().is_none());
        let e = FolderLock::acquire(dir.path(), "test 2").unwrap_err();
        let text = e.to_string();
        assert!(
            text.contains(&format!("PID {}", std::process::id())) && text.contains("test 1"),
            "{text}"
        );
        drop(first);
        assert!(
            !dir.path().join(LOCK_FILE).exists(),
            "a clean release deletes the lock file"
        );
        let again = FolderLock::acquire(dir.path(), "test 3").unwrap();
        assert!(again.stale().is_none(), "a clean release leaves no record");
    }

    /// A writer that opened the lock file before its holder released (and
    /// deleted) it must not keep a lock on the deleted file: it takes the
    /// lock of the file now in the folder, so two writers never both
    /// believe they hold the folder.
    #[cfg(unix)]
    #[test]
    fn a_lock_on_a_deleted_file_is_not_kept() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(LOCK_FILE);
        let first = FolderLock::acquire(dir.path(), "first").unwrap();
        // What a late writer holds: the old file, opened before the release.
        let old = no_follow().read(true).write(true).open(&path).unwrap();
        drop(first);
        assert!(!is_same_file(&old, &path).unwrap());
        let second = FolderLock::acquire(dir.path(), "second").unwrap();
        assert!(is_same_file(&second.file, &path).unwrap());
        // The old handle can lock its deleted file, but a third writer is
        // still refused: the folder's lock is the second writer's.
        old.try_lock().unwrap();
        let e = FolderLock::acquire(dir.path(), "third").unwrap_err();
        assert!(e.to_string().contains("second"), "{e}");
    }

    /// A symbolic link in place of the lock file is refused, and its target
    /// is left untouched.
    #[cfg(unix)]
    #[test]
    fn a_link_in_place_of_the_lock_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let outside = dir.path().join("outside.txt");
        std::fs::write(&outside, "keep me").unwrap();
        let study = dir.path().join("study");
        std::fs::create_dir(&study).unwrap();
        std::os::unix::fs::symlink(&outside, study.join(LOCK_FILE)).unwrap();
        let e = FolderLock::acquire(&study, "test").unwrap_err();
        assert!(matches!(e, ExportError::SymbolicLink { .. }), "{e:?}");
        assert!(e.to_string().contains("writer.lock"), "{e}");
        assert_eq!(std::fs::read_to_string(&outside).unwrap(), "keep me");
    }

    #[test]
    fn a_record_left_by_a_dead_holder_is_reported_as_stale() {
        let dir = tempfile::tempdir().unwrap();
        let dead = Holder {
            pid: 999_999,
            host: "elsewhere".into(),
            program: "kilotouch 0.0.1".into(),
            since_utc: UtcTime::from_unix_millis(0),
        };
        std::fs::write(
            dir.path().join(LOCK_FILE),
            serde_json::to_vec(&dead).unwrap(),
        )
        .unwrap();
        let lock = FolderLock::acquire(dir.path(), "test").unwrap();
        assert_eq!(lock.stale(), Some(&dead));
    }
}
