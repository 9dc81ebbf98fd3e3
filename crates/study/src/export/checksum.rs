//! Checksums: CRC-32 for line integrity, SHA-256 for file identity, from
//! well-kept crates (`crc`, `sha2`); this module fixes the variants and the
//! hex spelling the files use.
//!
//! * CRC-32 is the IEEE 802.3 / zlib / PNG code (ITU-T V.42): reflected
//!   polynomial 0xEDB88320, initial value and final XOR 0xFFFFFFFF. Check
//!   value `crc32(b"123456789") = 0xCBF43926`. It detects every burst error
//!   up to 32 bits and every odd number of bit errors, which is what a torn
//!   or zero-filled line after a crash looks like; it is not a defence against
//!   deliberate tampering.
//! * SHA-256 (FIPS 180-4) identifies files (protocol, calibration) in
//!   `session.json` and the journal.

use std::fmt::Write as _;

use sha2::Digest as _;

/// The CRC-32 of this module (the `crc` crate's `CRC_32_ISO_HDLC`, the
/// IEEE/zlib/PNG code), table-driven.
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// CRC-32 (IEEE) of `data`.
pub fn crc32(data: &[u8]) -> u32 {
    CRC32.checksum(data)
}

/// A CRC-32 computed piece by piece: [`Crc32::finish`] of the pieces fed
/// to [`Crc32::update`] equals [`crc32`] of their concatenation.
pub struct Crc32(crc::Digest<'static, u32>);

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// Nothing fed yet.
    pub fn new() -> Self {
        Self(CRC32.digest())
    }

    /// Feeds the next piece.
    pub fn update(&mut self, data: &[u8]) {
        self.0.update(data);
    }

    /// The CRC-32 of everything fed.
    pub fn finish(self) -> u32 {
        self.0.finalize()
    }
}

impl std::fmt::Debug for Crc32 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Crc32")
    }
}

/// 8 lowercase hex digits of a CRC-32.
pub fn crc32_hex(crc: u32) -> String {
    format!("{crc:08x}")
}

/// Parses exactly 8 hex digits.
pub fn parse_crc32_hex(s: &str) -> Option<u32> {
    if s.len() == 8 && s.bytes().all(|b| b.is_ascii_hexdigit()) {
        u32::from_str_radix(s, 16).ok()
    } else {
        None
    }
}

/// Streaming SHA-256 (FIPS 180-4), the RustCrypto `sha2` crate's.
#[derive(Debug, Clone, Default)]
pub struct Sha256(sha2::Sha256);

impl Sha256 {
    /// Fresh hasher.
    pub fn new() -> Self {
        Self(sha2::Sha256::new())
    }

    /// Absorbs `data`.
    pub fn update(&mut self, data: &[u8]) {
        self.0.update(data);
    }

    /// The 32-byte digest.
    pub fn finish(self) -> [u8; 32] {
        self.0.finalize().into()
    }
}

/// SHA-256 of `data`.
pub fn sha256(data: &[u8]) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(data);
    h.finish()
}

/// Lowercase hex of a byte string.
pub fn hex(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        let _ = write!(s, "{b:02x}");
    }
    s
}

/// Lowercase hex SHA-256 of `data`.
pub fn sha256_hex(data: &[u8]) -> String {
    hex(&sha256(data))
}
