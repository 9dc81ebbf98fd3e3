//! Content hashes for rig identities and calibration files.
//!
//! FNV-1a, 64 bit (Fowler, Noll, Vo; offset basis 0xcbf29ce484222325, prime
//! 0x100000001b3), over a canonical byte encoding of a serde value: the value
//! is converted to a `toml::Value` and walked with sorted table keys, floats
//! as their IEEE-754 bit patterns and every item tagged and length-prefixed.
//! The hash therefore depends on the data, not on how a TOML writer
//! formats it. It detects accidental corruption and edits; it is not a
//! cryptographic signature.

use super::error::{CalibrationError, Result};
use serde::Serialize;

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// Incremental FNV-1a (64 bit).
#[derive(Debug, Clone, Copy)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Self(FNV_OFFSET)
    }
}

impl Fnv1a {
    /// Feed bytes.
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(FNV_PRIME);
        }
    }

    /// The hash so far.
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// FNV-1a 64 of `bytes`.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h = Fnv1a::default();
    h.write(bytes);
    h.finish()
}

fn walk(h: &mut Fnv1a, v: &toml::Value) {
    let len = |h: &mut Fnv1a, n: usize| h.write(&(n as u64).to_le_bytes());
    match v {
        toml::Value::String(s) => {
            h.write(b"S");
            len(h, s.len());
            h.write(s.as_bytes());
        }
        toml::Value::Integer(i) => {
            h.write(b"I");
            h.write(&i.to_le_bytes());
        }
        toml::Value::Float(f) => {
            h.write(b"F");
            h.write(&f.to_bits().to_le_bytes());
        }
        toml::Value::Boolean(b) => h.write(if *b { b"B1" } else { b"B0" }),
        toml::Value::Datetime(d) => {
            let s = d.to_string();
            h.write(b"D");
            len(h, s.len());
            h.write(s.as_bytes());
        }
        toml::Value::Array(a) => {
            h.write(b"A");
            len(h, a.len());
            for x in a {
                walk(h, x);
            }
        }
        toml::Value::Table(t) => {
            h.write(b"T");
            len(h, t.len());
            let mut keys: Vec<&String> = t.keys().collect();
            keys.sort();
            for k in keys {
                len(h, k.len());
                h.write(k.as_bytes());
                walk(h, &t[k.as_str()]);
            }
        }
    }
}

/// Canonical content hash of a serialisable value, formatted
/// `fnv1a64:` + 16 hex digits.
pub fn content_hash<T: Serialize + ?Sized>(value: &T) -> Result<String> {
    let v = toml::Value::try_from(value).map_err(|e| CalibrationError::File {
        origin: "<hash>".into(),
        message: format!("cannot encode value for hashing: {e}"),
    })?;
    let mut h = Fnv1a::default();
    walk(&mut h, &v);
    Ok(format!("fnv1a64:{:016x}", h.finish()))
}

/// Current UTC time as RFC 3339 (`YYYY-MM-DDThh:mm:ssZ`), from the system
/// clock.
pub fn utc_now_rfc3339() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    rfc3339_from_unix(secs)
}

/// RFC 3339 UTC timestamp of `secs` seconds after 1970-01-01T00:00:00Z
/// (the `jiff` crate's proleptic Gregorian calendar; clamped to the year
/// 9999).
pub fn rfc3339_from_unix(secs: u64) -> String {
    const EPOCH: jiff::civil::DateTime = jiff::civil::datetime(1970, 1, 1, 0, 0, 0, 0);
    let last = jiff::civil::datetime(9999, 12, 31, 23, 59, 59, 0);
    let secs = i64::try_from(secs).unwrap_or(i64::MAX);
    let z = EPOCH
        .checked_add(jiff::SignedDuration::from_secs(secs))
        .unwrap_or(last);
    format!(
        "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}Z",
        z.year(),
        z.month(),
        z.day(),
        z.hour(),
        z.minute(),
        z.second()
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Serialize;

    /// Published FNV-1a 64 test vectors (Fowler–Noll–Vo reference page).
    #[test]
    fn fnv1a_reference_vectors() {
        assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
    }

    #[derive(Serialize)]
    struct A {
        x: f64,
        name: String,
        v: Vec<f64>,
    }

    #[test]
    fn content_hash_sees_every_bit_but_not_formatting() {
        let a = A {
            x: 0.1,
            name: "rig".into(),
            v: vec![1.0, 2.0],
        };
        let h = content_hash(&a).unwrap();
        assert!(h.starts_with("fnv1a64:") && h.len() == 8 + 16);
        assert_eq!(h, content_hash(&a).unwrap());
        let b = A {
            x: f64::from_bits(0.1f64.to_bits() + 1),
            ..a
        };
        assert_ne!(h, content_hash(&b).unwrap());
        // Same data through a TOML round trip (different text, same values).
        let text = toml::to_string(&b).unwrap();
        let back: toml::Value = toml::from_str(&text).unwrap();
        assert_eq!(content_hash(&back).unwrap(), content_hash(&b).unwrap());
    }

    /// Known dates: the epoch, 2000-02-29 (leap day, century divisible by
    /// 400) and 2024-12-31T23:59:59Z.
    #[test]
    fn rfc3339_known_dates() {
        assert_eq!(rfc3339_from_unix(0), "1970-01-01T00:00:00Z");
        assert_eq!(rfc3339_from_unix(951_782_400), "2000-02-29T00:00:00Z");
        assert_eq!(rfc3339_from_unix(1_735_689_599), "2024-12-31T23:59:59Z");
        assert_eq!(rfc3339_from_unix(253_402_300_799), "9999-12-31T23:59:59Z");
        assert_eq!(rfc3339_from_unix(u64::MAX), "9999-12-31T23:59:59Z");
    }
}
