//! The check a resume makes of every finished trial's raw file: it exists,
//! its sidecar reads, its header is exactly the one [`NpyWriter`] writes
//! for the sidecar's dtype and shape, its size is the header plus
//! rows × channels × the sample size, and the CRC-32 of its data matches
//! the sidecar's `data_crc32`. A file that fails is moved with its
//! sidecar to `recovery/quarantine/` and reported by name
//! ([`super::reconcile::DamagedRaw`]); it is never silently kept.
//!
//! [`NpyWriter`]: crate::rawsig::NpyWriter

use std::fs;
use std::io::Read;
use std::path::Path;

use super::checksum::{crc32_hex, parse_crc32_hex};
use super::open::RECOVERY_DIR;
use crate::rawsig::{data_crc32, npy_header, read_sidecar, sidecar_path};
use crate::storage::error::{Result, io_err};
use crate::storage::fsutil::{create_dir_durable, entry_exists, no_follow, sync_dir};

/// Folder (inside [`RECOVERY_DIR`]) of raw files that failed their check.
pub const QUARANTINE_DIR: &str = "quarantine";

/// What is wrong with the raw file `rel` of folder `dir`, or `None` when
/// it passes every check (module docs).
pub(crate) fn damage(dir: &Path, rel: &str) -> Option<String> {
    let npy = dir.join(rel);
    let meta = match fs::symlink_metadata(&npy) {
        Ok(m) if m.file_type().is_symlink() => {
            return Some("is a symbolic link (a study folder never follows links)".into());
        }
        Ok(m) => m,
        Err(e) => return Some(format!("cannot be read ({e})")),
    };
    if fs::symlink_metadata(sidecar_path(&npy)).is_ok_and(|m| m.file_type().is_symlink()) {
        return Some("its sidecar is a symbolic link (a study folder never follows links)".into());
    }
    let side = sidecar_path(&npy);
    let sidecar = match read_sidecar(&side) {
        Ok(s) => s,
        Err(e) => return Some(format!("its sidecar cannot be read ({e})")),
    };
    let [rows, cols] = sidecar.shape;
    let Ok(cols) = usize::try_from(cols) else {
        return Some(format!(
            "its sidecar gives an impossible shape {:?}",
            sidecar.shape
        ));
    };
    let header = npy_header(sidecar.dtype, rows, cols);
    let expected = rows
        .checked_mul(cols as u64)
        .and_then(|n| n.checked_mul(sidecar.dtype.size() as u64))
        .and_then(|n| n.checked_add(header.len() as u64));
    let Some(expected) = expected else {
        return Some(format!(
            "its sidecar gives an impossible shape {:?}",
            sidecar.shape
        ));
    };
    if meta.len() != expected {
        return Some(format!(
            "{} bytes, but its sidecar's shape {rows} × {cols} ({}) needs {expected}",
            meta.len(),
            sidecar.dtype.descr()
        ));
    }
    let mut file = match no_follow().read(true).open(&npy) {
        Ok(f) => f,
        Err(e) => return Some(format!("cannot be opened ({e})")),
    };
    let mut found = vec![0u8; header.len()];
    if file.read_exact(&mut found).is_err() || found != header {
        return Some("its NPY header does not match its sidecar's dtype and shape".into());
    }
    let Some(stored) = sidecar.data_crc32.as_deref() else {
        // Written before checksums were recorded: size and header only.
        return None;
    };
    let Some(stored) = parse_crc32_hex(stored) else {
        return Some(format!(
            "its sidecar's data_crc32 `{stored}` is not 8 hex digits"
        ));
    };
    match data_crc32(&mut file, header.len() as u64) {
        Ok(c) if c == stored => None,
        Ok(c) => Some(format!(
            "data checksum {} differs from the sidecar's {} (the file changed after it was \
             written)",
            crc32_hex(c),
            crc32_hex(stored)
        )),
        Err(e) => Some(format!("cannot be read ({e})")),
    }
}

/// Where [`quarantine`] moves the raw file `rel` of `dir`:
/// `recovery/quarantine/<stamp>-<name>.npy`, relative to `dir`, named with
/// the time `stamp` so nothing is overwritten (`None`: the file does not
/// exist, nothing will name it).
pub(crate) fn quarantine_target(dir: &Path, rel: &str, stamp: i64) -> Option<String> {
    let npy = dir.join(rel);
    if !entry_exists(&npy) {
        return None;
    }
    let name = npy.file_name()?.to_string_lossy().into_owned();
    Some(format!("{RECOVERY_DIR}/{QUARANTINE_DIR}/{stamp}-{name}"))
}

/// Moves the raw file `rel` of `dir` to `target` (relative to `dir`, from
/// [`quarantine_target`]) and its sidecar beside it; with no target (the
/// `.npy` is missing) a sidecar left behind is moved to
/// `recovery/quarantine/<stamp>-<name>.json`. Entries are moved, never
/// followed (a link is moved as a link).
///
/// # Errors
/// I/O errors.
pub(crate) fn quarantine(dir: &Path, rel: &str, target: Option<&str>, stamp: i64) -> Result<()> {
    let npy = dir.join(rel);
    let side = sidecar_path(&npy);
    let qdir = dir.join(RECOVERY_DIR).join(QUARANTINE_DIR);
    let side_to = match target {
        Some(t) => sidecar_path(&dir.join(t)),
        None => {
            let name = side.file_name().map(|n| n.to_string_lossy().into_owned());
            qdir.join(format!("{stamp}-{}", name.unwrap_or_default()))
        }
    };
    let moves = [
        (npy.clone(), target.map(|t| dir.join(t))),
        (side, Some(side_to)),
    ];
    if !moves
        .iter()
        .any(|(from, to)| to.is_some() && entry_exists(from))
    {
        return Ok(());
    }
    create_dir_durable(&qdir)?;
    for (from, to) in moves {
        if let Some(to) = to
            && entry_exists(&from)
        {
            fs::rename(&from, &to).map_err(io_err(&from, "move to quarantine"))?;
        }
    }
    sync_dir(&qdir)?;
    if let Some(parent) = npy.parent() {
        sync_dir(parent)?;
    }
    Ok(())
}
