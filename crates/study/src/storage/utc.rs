//! UTC timestamps in ISO 8601 / RFC 3339 form, `YYYY-MM-DDTHH:MM:SS.mmmZ`.
//!
//! The calendar arithmetic (proleptic Gregorian, years 0000–9999) is the
//! `jiff` crate's; this module fixes the one spelling kilotouch writes
//! (always UTC, always milliseconds) and the strict parse of it, whose
//! errors say which part is wrong. Leap seconds are not represented (POSIX
//! time), as in every mainstream reader.

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

/// The civil date and time (UTC) of `ms` milliseconds since the epoch,
/// clamped to the representable range.
fn civil(ms: i64) -> jiff::civil::DateTime {
    // Civil arithmetic from the epoch: `jiff::Timestamp` stops a day short
    // of the year 9999's end (so that every offset applies), UTC needs none.
    EPOCH
        .checked_add(jiff::SignedDuration::from_millis(ms.clamp(MIN_MS, MAX_MS)))
        .unwrap_or(EPOCH)
}

/// 1970-01-01T00:00:00 (UTC).
const EPOCH: jiff::civil::DateTime = jiff::civil::datetime(1970, 1, 1, 0, 0, 0, 0);

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
        let (y, mo, d) = (num(0..4)?, num(5..7)?, num(8..10)?);
        let (h, mi, sec) = (num(11..13)?, num(14..16)?, num(17..19)?);
        if !(1..=12).contains(&mo) {
            return Err(err("month out of range"));
        }
        // Four digits, month checked: the narrowing casts are exact.
        let date = jiff::civil::Date::new(y as i16, mo as i8, d as i8)
            .map_err(|_| err("day out of range"))?;
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
        let since = date
            .at(h as i8, mi as i8, sec as i8, 0)
            .duration_since(EPOCH);
        Ok(Self {
            unix_ms: since.as_secs() * 1000 + frac_ms,
        })
    }
}

impl fmt::Display for UtcTime {
    /// `YYYY-MM-DDTHH:MM:SS.mmmZ`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = self.unix_ms.rem_euclid(1000);
        let t = civil(self.unix_ms);
        write!(
            f,
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{ms:03}Z",
            t.year(),
            t.month(),
            t.day(),
            t.hour(),
            t.minute(),
            t.second()
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

    /// Known instants, the range's ends and a leap day, both ways.
    #[test]
    fn known_instants_print_and_parse() {
        for (ms, text) in [
            (0, "1970-01-01T00:00:00.000Z"),
            (951_782_400_000, "2000-02-29T00:00:00.000Z"),
            (1_735_689_599_999, "2024-12-31T23:59:59.999Z"),
            (-1, "1969-12-31T23:59:59.999Z"),
            (MIN_MS, "0000-01-01T00:00:00.000Z"),
            (MAX_MS, "9999-12-31T23:59:59.999Z"),
        ] {
            let t = UtcTime::from_unix_millis(ms);
            assert_eq!(t.to_string(), text);
            assert_eq!(UtcTime::parse(text), Ok(t), "{text}");
        }
        assert!(
            UtcTime::parse("1900-02-29T00:00:00Z").is_err(),
            "not a leap year"
        );
        assert!(UtcTime::parse("2000-02-30T00:00:00Z").is_err());
    }

    /// Every day of a Gregorian cycle (146 097 days) on both sides of the
    /// epoch prints and parses back to itself, at a time of day that moves.
    #[test]
    fn every_day_of_four_centuries_round_trips() {
        for day in (-146_097_i64 - 719_468)..(146_097 + 10) {
            let ms = day * 86_400_000 + (day.rem_euclid(86_400)) * 1000 + day.rem_euclid(1000);
            let t = UtcTime::from_unix_millis(ms);
            assert_eq!(UtcTime::parse(&t.to_string()), Ok(t));
        }
    }
}
