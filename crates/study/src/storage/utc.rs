//! UTC timestamps in ISO 8601 / RFC 3339 form, `YYYY-MM-DDTHH:MM:SS.mmmZ`.
//!
//! Formatted by hand from [`std::time::SystemTime`] (no date crate): the
//! civil-from-days and days-from-civil conversions of the proleptic Gregorian
//! calendar by H. Hinnant ("chrono-Compatible Low-Level Date Algorithms",
//! 2013), exact for every day of years 0000–9999. Leap seconds are not
//! represented (POSIX time), as in every mainstream reader.

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Milliseconds since 1970-01-01T00:00:00Z (POSIX, no leap seconds).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct UtcTime {
    unix_ms: i64,
}

/// First representable instant, 0000-01-01T00:00:00.000Z.
const MIN_MS: i64 = -62_167_219_200_000;
/// Last representable instant, 9999-12-31T23:59:59.999Z.
const MAX_MS: i64 = 253_402_300_799_999;

/// Days since 1970-01-01 of a proleptic Gregorian date (Hinnant).
fn days_from_civil(y: i64, m: u32, d: u32) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = i64::from(m);
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + i64::from(d) - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Date (year, month 1–12, day 1–31) of a day count since 1970-01-01.
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

fn is_leap(y: i64) -> bool {
    (y % 4 == 0 && y % 100 != 0) || y % 400 == 0
}

fn days_in_month(y: i64, m: u32) -> u32 {
    match m {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        _ if is_leap(y) => 29,
        _ => 28,
    }
}

impl UtcTime {
    /// The current time (clamped to the representable range).
    pub fn now() -> Self {
        Self::from_system_time(SystemTime::now())
    }

    /// Converts a [`SystemTime`] (sub-millisecond part truncated toward the
    /// past; clamped to years 0000–9999).
    pub fn from_system_time(t: SystemTime) -> Self {
        let ms = match t.duration_since(UNIX_EPOCH) {
            Ok(d) => i64::try_from(d.as_millis()).unwrap_or(MAX_MS),
            Err(e) => {
                let d = e.duration();
                let ms = i64::try_from(d.as_millis()).unwrap_or(i64::MAX);
                // Truncate toward the past: 1.5 ms before the epoch → −2 ms.
                let carry = i64::from(d.subsec_nanos() % 1_000_000 != 0);
                -(ms.saturating_add(carry))
            }
        };
        Self::from_unix_millis(ms)
    }

    /// From milliseconds since the epoch (clamped to years 0000–9999).
    pub fn from_unix_millis(ms: i64) -> Self {
        Self {
            unix_ms: ms.clamp(MIN_MS, MAX_MS),
        }
    }

    /// Milliseconds since the epoch.
    pub fn unix_millis(self) -> i64 {
        self.unix_ms
    }

    /// As a [`SystemTime`].
    pub fn to_system_time(self) -> SystemTime {
        if self.unix_ms >= 0 {
            UNIX_EPOCH + Duration::from_millis(self.unix_ms.unsigned_abs())
        } else {
            UNIX_EPOCH - Duration::from_millis(self.unix_ms.unsigned_abs())
        }
    }

    /// Parses `YYYY-MM-DDTHH:MM:SS[.f{1,9}]Z` (fractions beyond milliseconds
    /// are truncated). Offsets other than `Z` are rejected: every timestamp
    /// written by kilotouch is UTC.
    pub fn parse(s: &str) -> Result<Self, String> {
        let err = |why: &str| format!("invalid UTC timestamp `{s}`: {why}");
        let b = s.as_bytes();
        if b.len() < 20 || !s.is_ascii() {
            return Err(err("expected YYYY-MM-DDTHH:MM:SS[.fff]Z"));
        }
        let num = |range: std::ops::Range<usize>| -> Result<u32, String> {
            let part = &s[range];
            if part.bytes().all(|c| c.is_ascii_digit()) {
                part.parse::<u32>()
                    .map_err(|_| err("expected YYYY-MM-DDTHH:MM:SS[.fff]Z"))
            } else {
                Err(err("expected YYYY-MM-DDTHH:MM:SS[.fff]Z"))
            }
        };
        if b[4] != b'-' || b[7] != b'-' || b[10] != b'T' || b[13] != b':' || b[16] != b':' {
            return Err(err("expected YYYY-MM-DDTHH:MM:SS[.fff]Z"));
        }
        let (y, mo, d) = (i64::from(num(0..4)?), num(5..7)?, num(8..10)?);
        let (h, mi, sec) = (num(11..13)?, num(14..16)?, num(17..19)?);
        if !(1..=12).contains(&mo) {
            return Err(err("month out of range"));
        }
        if d == 0 || d > days_in_month(y, mo) {
            return Err(err("day out of range"));
        }
        if h > 23 || mi > 59 || sec > 59 {
            return Err(err("time of day out of range"));
        }
        let rest = &s[19..];
        let frac_ms = if let Some(frac) = rest.strip_prefix('.') {
            let digits = frac.strip_suffix('Z').ok_or_else(|| err("missing `Z`"))?;
            if digits.is_empty() || digits.len() > 9 || !digits.bytes().all(|c| c.is_ascii_digit())
            {
                return Err(err("bad fraction of a second"));
            }
            let mut ms = 0_i64;
            for (i, c) in digits.bytes().take(3).enumerate() {
                ms += i64::from(c - b'0') * [100, 10, 1][i];
            }
            ms
        } else if rest == "Z" {
            0
        } else {
            return Err(err("expected `Z` (UTC) after the seconds"));
        };
        let days = days_from_civil(y, mo, d);
        let secs = days * 86_400 + i64::from(h) * 3600 + i64::from(mi) * 60 + i64::from(sec);
        Ok(Self {
            unix_ms: secs * 1000 + frac_ms,
        })
    }
}

impl fmt::Display for UtcTime {
    /// `YYYY-MM-DDTHH:MM:SS.mmmZ`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = self.unix_ms.rem_euclid(1000);
        let secs = self.unix_ms.div_euclid(1000);
        let days = secs.div_euclid(86_400);
        let sod = secs.rem_euclid(86_400);
        let (y, m, d) = civil_from_days(days);
        write!(
            f,
            "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{ms:03}Z",
            sod / 3600,
            (sod / 60) % 60,
            sod % 60
        )
    }
}

impl FromStr for UtcTime {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s)
    }
}

impl Serialize for UtcTime {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for UtcTime {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Self::parse(&s).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_round_trip_over_four_centuries() {
        // 146 097 days = one Gregorian cycle, both sides of the epoch.
        for z in (-146_097 - 719_468)..(146_097 + 10) {
            let (y, m, d) = civil_from_days(z);
            assert_eq!(days_from_civil(y, m, d), z);
            assert!(d >= 1 && d <= days_in_month(y, m));
        }
    }
}
