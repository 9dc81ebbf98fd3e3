//! The check a resume makes of every finished trial's raw file: it exists,
//! its sidecar reads, its header is exactly the one [`NpyWriter`] writes
//! for the sidecar's dtype and shape, its size is the header plus
//! rows × channels × the sample size, and the CRC-32 of its data matches
//! the sidecar's `data_crc32`. A file that fails is moved with its
//! sidecar to `recovery/quarantine/` and reported by name
//! ([`super::reconcile::DamagedRaw`]); it is never silently kept.
//!
//! [`NpyWriter`]: crate::rawsig::NpyWriter

use std::fs::{self, File};
use std::io::Read;
use std::path::Path;

use super::checksum::{crc32_hex, parse_crc32_hex};
use super::open::RECOVERY_DIR;
use crate::rawsig::{data_crc32, npy_header, read_sidecar, sidecar_path};
use crate::storage::error::{Result, io_err};
use crate::storage::fsutil::{create_dir_durable, sync_dir};

/// Folder (inside [`RECOVERY_DIR`]) of raw files that failed their check.
pub const QUARANTINE_DIR: &str = "quarantine";

/// What is wrong with the raw file `rel` of folder `dir`, or `None` when
/// it passes every check (module docs).
pub(crate) fn damage(dir: &Path, rel: &str) -> Option<String> {
    let npy = dir.join(rel);
    let meta = match fs::metadata(&npy) {
        Ok(m) => m,
        Err(e) => return Some(format!("cannot be read ({e})")),
    };
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
    let mut file = match File::open(&npy) {
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

/// Moves the raw file `rel` of `dir` and its sidecar (those that exist)
/// to `recovery/quarantine/`, named with the time `stamp` so nothing is
/// overwritten. Returns the new path of the `.npy`, relative to `dir`
/// (`None`: neither file existed).
///
/// # Errors
/// I/O errors.
pub(crate) fn quarantine(dir: &Path, rel: &str, stamp: i64) -> Result<Option<String>> {
    let npy = dir.join(rel);
    let side = sidecar_path(&npy);
    if !npy.exists() && !side.exists() {
        return Ok(None);
    }
    let qdir = dir.join(RECOVERY_DIR).join(QUARANTINE_DIR);
    create_dir_durable(&qdir)?;
    let mut moved = None;
    for from in [&npy, &side] {
        let Some(name) = from.file_name() else {
            continue;
        };
        if !from.exists() {
            continue;
        }
        let new_name = format!("{stamp}-{}", name.to_string_lossy());
        let to = qdir.join(&new_name);
        fs::rename(from, &to).map_err(io_err(from, "move to quarantine"))?;
        if from == &npy {
            moved = Some(format!("{RECOVERY_DIR}/{QUARANTINE_DIR}/{new_name}"));
        }
    }
    sync_dir(&qdir)?;
    if let Some(parent) = npy.parent() {
        sync_dir(parent)?;
    }
    Ok(moved.or_else(|| Some(format!("{RECOVERY_DIR}/{QUARANTINE_DIR}/"))))
}
