//! A shard of a simulated study: a deterministic slice of its participants
//! (`study simulate --shard K/N`), so that N independent runs — N cluster
//! jobs — together run the whole study, and `study merge` joins their
//! folders into the folder an unsharded run writes.
//!
//! Shard K of N (1 ≤ K ≤ N) runs the participants whose 0-based index i has
//! i mod N = K − 1 (round robin: every shard gets rows of the
//! counterbalancing square in turn, and shards differ in size by at most one
//! participant). Each trial is a pure function of its key and the study seed
//! ([`crate::seeds`]), so a trial's row does not depend on the shard that
//! ran it.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Largest shard count (bounds the folders a merge reads).
pub const MAX_SHARDS: u32 = 100_000;

/// Shard `index` of `count` (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Shard {
    /// 1-based shard number K.
    pub index: u32,
    /// Number of shards N.
    pub count: u32,
}

impl Shard {
    /// Shard `index` (1-based) of `count`.
    ///
    /// # Errors
    /// A message naming the rule when `index` is not in 1..=`count` or
    /// `count` exceeds [`MAX_SHARDS`].
    pub fn new(index: u32, count: u32) -> Result<Self, String> {
        if count == 0 || count > MAX_SHARDS {
            return Err(format!(
                "shard count {count} must be between 1 and {MAX_SHARDS}"
            ));
        }
        if index == 0 || index > count {
            return Err(format!(
                "shard {index}/{count}: the shard number must be between 1 and {count}"
            ));
        }
        Ok(Self { index, count })
    }

    /// Whether the participant with 0-based index `participant` belongs to
    /// this shard.
    pub fn contains(self, participant: u32) -> bool {
        participant % self.count == self.index - 1
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = String;
    /// `K/N`, e.g. `3/8`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("shard `{s}`: expected K/N with 1 ≤ K ≤ N, e.g. 3/8");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let k: u32 = k.trim().parse().map_err(|_| bad())?;
        let n: u32 = n.trim().parse().map_err(|_| bad())?;
        Self::new(k, n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every participant is in exactly one shard, for every shard count.
    #[test]
    fn shards_partition_the_participants() {
        for n in 1..=7u32 {
            for p in 0..50u32 {
                let owners: Vec<u32> = (1..=n)
                    .filter(|&k| Shard::new(k, n).is_ok_and(|s| s.contains(p)))
                    .collect();
                assert_eq!(owners.len(), 1, "participant {p}, {n} shards");
            }
        }
    }

    #[test]
    fn parse_and_reject() {
        assert_eq!("2/5".parse::<Shard>(), Ok(Shard { index: 2, count: 5 }));
        assert_eq!(Shard { index: 2, count: 5 }.to_string(), "2/5");
        for bad in ["0/3", "4/3", "3", "a/b", "1/0", "-1/3", "1/100001"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }
}
