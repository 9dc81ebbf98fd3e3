//! Reading input files with a size cap: a rig file, protocol or
//! calibration file is a few kilobytes, so a path to something endless
//! (`/dev/zero`, a pipe, a multi-gigabyte file given by mistake) must end
//! in a prompt, clear error rather than in reading until memory runs out.

use std::io::{self, Read};
use std::path::Path;

/// Size cap of a configuration file (rig file, protocol, calibration):
/// 16 MiB, a thousand times the largest real one.
pub const MAX_CONFIG_BYTES: u64 = 16 << 20;

/// Reads at most `max_bytes` of `path` as UTF-8 text.
///
/// # Errors
/// I/O errors; [`io::ErrorKind::FileTooLarge`] naming the cap when the
/// file (or device) holds more; [`io::ErrorKind::InvalidData`] for text
/// that is not UTF-8.
pub fn read_text_capped(path: &Path, max_bytes: u64) -> io::Result<String> {
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(io::Error::new(
            io::ErrorKind::FileTooLarge,
            format!(
                "more than {} MiB: not a kilotouch input file (a device, pipe or wrong \
                 file?); the limit is {max_bytes} bytes",
                max_bytes >> 20
            ),
        ));
    }
    String::from_utf8(bytes).map_err(|e| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn an_endless_device_is_refused_at_the_cap() {
        let e = read_text_capped(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::FileTooLarge);
        assert!(e.to_string().contains("1048576 bytes"), "{e}");
    }

    #[test]
    fn small_text_is_read_and_non_utf8_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.toml");
        std::fs::write(&p, "x = 1\n").unwrap();
        assert_eq!(read_text_capped(&p, 100).unwrap(), "x = 1\n");
        std::fs::write(&p, b"x = \xff\n").unwrap();
        let e = read_text_capped(&p, 100).unwrap_err();
        assert!(e.to_string().contains("offset 4"), "{e}");
    }
}
