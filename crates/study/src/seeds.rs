//! Per-trial randomness derived from (study seed, participant, condition,
//! phase, trial).
//!
//! Every random draw of a trial (task layout, simulated rig noise, simulated
//! participant) must come from the generators of this module, so that a trial
//! run after a crash and resume produces exactly the row it would have
//! produced in an uninterrupted run: nothing depends on how many trials ran
//! before it in the same process.
//!
//! Two derivations, both fixed by test vectors (changing either changes every
//! recorded result, so the vectors must fail):
//!
//! * **Trial seed** ([`TrialKey::seed`]): a 64-bit digest written to the
//!   `seed` column of `trials.csv` (as `0x` + 16 hex digits) and to the
//!   journal. It identifies the trial's randomness and lets a reader check
//!   that a row belongs to the study seed. With the SplitMix64 finaliser
//!   (Steele, Lea & Flood 2014; constants of Vigna's `splitmix64.c`)
//!
//!   ```text
//!   mix(z)  = z ← (z ⊕ (z ≫ 30))·0xbf58476d1ce4e5b9;
//!             z ← (z ⊕ (z ≫ 27))·0x94d049bb133111eb;  z ⊕ (z ≫ 31)
//!   h₀      = mix(study ⊕ 0x6b742d747269616c)            ("kt-trial")
//!   hᵢ₊₁    = mix((hᵢ + 0x9e3779b97f4a7c15) ⊕ wᵢ)        (mod 2⁶⁴)
//!   seed    = h₄,  w = (participant, condition, phase, trial)
//!   ```
//!
//!   with participant the 0-based index (`P01` → 0), condition the ASCII code
//!   of its letter (V = 0x56, P = 0x50, D = 0x44), phase 0 = practice,
//!   1 = test, trial the 1-based number written in `trials.csv`. `mix` is a
//!   bijection of 64-bit words, so for a fixed prefix each last word gives a
//!   different seed.
//!
//! * **Trial generators** ([`TrialKey::rng`]): ChaCha20 (Bernstein 2008, 20
//!   rounds, 64-bit block counter and 64-bit stream id, as `rand_chacha`)
//!   keyed with an *injective* 32-byte encoding of the whole tuple, so two
//!   different trials can never share a key stream (unlike any 64-bit
//!   digest):
//!
//!   ```text
//!   key[0..8]   = study seed, little-endian
//!   key[8..16]  = 0x6b742d747269616c, little-endian   (domain tag "kt-trial")
//!   key[16..20] = participant index, u32 LE
//!   key[20]     = condition letter (ASCII)
//!   key[21]     = phase (0 practice, 1 test)
//!   key[22..24] = 0
//!   key[24..28] = trial number, u32 LE
//!   key[28..32] = 0
//!   stream      = sub-stream id (e.g. [`STREAM_RIG`])
//!   ```
//!
//!   The counterbalancing label permutation
//!   ([`crate::counterbalance::label_permutation`]) keys ChaCha20 with the
//!   study seed followed by 24 zero bytes; the non-zero domain tag keeps the
//!   trial keys disjoint from it. Independent consumers inside one trial use
//!   different stream ids ([`STREAM_TASK`], [`STREAM_RIG`],
//!   [`STREAM_PARTICIPANT`], or their own), each an independent ChaCha20
//!   key stream.

use std::fmt;
use std::str::FromStr;

use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::SeedableRng;
use serde::{Deserialize, Serialize};

use crate::protocol::Condition;

/// Domain tag of the trial derivations, ASCII `kt-trial` read big-endian.
pub const TRIAL_DOMAIN: u64 = 0x6b74_2d74_7269_616c;

/// Golden-ratio increment of SplitMix64, ⌊2⁶⁴/φ⌋ (odd).
pub const SPLITMIX_GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// Stream id for the task layout of a trial (obstacle placement, start
/// position, …).
pub const STREAM_TASK: u64 = 1;
/// Stream id for the simulated rig (Brownian forces, sensor noise).
pub const STREAM_RIG: u64 = 2;
/// Stream id for the simulated participant.
pub const STREAM_PARTICIPANT: u64 = 3;
/// Stream id of a trial's attention lapses in the simulated operator, ASCII
/// `kt-lapse` read big-endian.
pub const STREAM_LAPSE: u64 = 0x6b74_2d6c_6170_7365;

/// Domain tag of the simulated operator's participant-trait generator, ASCII
/// `kt-pers` read big-endian with a zero low byte.
pub const TRAIT_DOMAIN: u64 = 0x6b74_2d70_6572_7300;

/// The SplitMix64 output function (finaliser): a bijection of `u64` with full
/// avalanche (Stafford's "Mix13" variant used by `splitmix64.c`).
pub const fn splitmix64_mix(z: u64) -> u64 {
    let z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    let z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The SplitMix64 generator of Vigna's `splitmix64.c`: `state += γ;
/// return mix(state)`. Exposed for tests and for light-weight needs; trial
/// randomness should come from [`TrialKey::rng`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// Generator with the given state.
    pub const fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// Next 64-bit output.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(SPLITMIX_GAMMA);
        splitmix64_mix(self.state)
    }
}

/// Practice (training block) or measured (test) trial.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Training trial (not analysed).
    Practice,
    /// Measured trial.
    Test,
}

impl Phase {
    /// `practice` or `test`, as written in `trials.csv`.
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Practice => "practice",
            Phase::Test => "test",
        }
    }

    /// Word used by the seed derivation: 0 practice, 1 test.
    pub fn code(self) -> u8 {
        match self {
            Phase::Practice => 0,
            Phase::Test => 1,
        }
    }
}

impl fmt::Display for Phase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Phase {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "practice" => Ok(Phase::Practice),
            "test" => Ok(Phase::Test),
            other => Err(format!(
                "unknown phase `{other}` (expected `practice` or `test`)"
            )),
        }
    }
}

/// Byte of a condition in the derivations: its ASCII letter.
pub fn condition_byte(c: Condition) -> u8 {
    match c {
        Condition::V => b'V',
        Condition::P => b'P',
        Condition::D => b'D',
    }
}

/// Identity of one trial within a study.
///
/// Ordered by participant, phase (practice first), condition, trial; the
/// session runner's plan order is given by
/// [`crate::export::StudyStore::plan`], not by this ordering.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct TrialKey {
    /// 0-based participant index (`P01` is 0), as in
    /// [`crate::protocol::ParticipantSessions::participant`].
    pub participant: u32,
    /// Practice or test.
    pub phase: Phase,
    /// Condition of the trial.
    pub condition: Condition,
    /// 1-based trial number within (participant, condition, phase), as in
    /// the `trial` column.
    pub trial: u32,
}

impl TrialKey {
    /// A key.
    pub fn new(participant: u32, condition: Condition, phase: Phase, trial: u32) -> Self {
        Self {
            participant,
            phase,
            condition,
            trial,
        }
    }

    /// The four words absorbed by [`TrialKey::seed`].
    fn words(&self) -> [u64; 4] {
        [
            u64::from(self.participant),
            u64::from(condition_byte(self.condition)),
            u64::from(self.phase.code()),
            u64::from(self.trial),
        ]
    }

    /// 64-bit trial seed (SplitMix64 chain, see the module documentation),
    /// written to the `seed` column.
    pub fn seed(&self, study_seed: u64) -> u64 {
        let mut h = splitmix64_mix(study_seed ^ TRIAL_DOMAIN);
        for w in self.words() {
            h = splitmix64_mix(h.wrapping_add(SPLITMIX_GAMMA) ^ w);
        }
        h
    }

    /// The 32-byte ChaCha20 key of this trial (injective in
    /// (study seed, participant, condition, phase, trial)).
    pub fn chacha_key(&self, study_seed: u64) -> [u8; 32] {
        let mut key = [0_u8; 32];
        key[0..8].copy_from_slice(&study_seed.to_le_bytes());
        key[8..16].copy_from_slice(&TRIAL_DOMAIN.to_le_bytes());
        key[16..20].copy_from_slice(&self.participant.to_le_bytes());
        key[20] = condition_byte(self.condition);
        key[21] = self.phase.code();
        key[24..28].copy_from_slice(&self.trial.to_le_bytes());
        key
    }

    /// Independent ChaCha20 generator of this trial for sub-stream `stream`
    /// (e.g. [`STREAM_RIG`]), positioned at the start of the key stream.
    pub fn rng(&self, study_seed: u64, stream: u64) -> ChaCha20Rng {
        let mut rng = ChaCha20Rng::from_seed(self.chacha_key(study_seed));
        rng.set_stream(stream);
        rng
    }
}

impl fmt::Display for TrialKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "P{:02}/{}/{}/{}",
            u64::from(self.participant) + 1,
            self.condition,
            self.phase,
            self.trial
        )
    }
}

/// Domain tag of the power-analysis replications, ASCII `kt-power` read
/// big-endian.
pub const POWER_DOMAIN: u64 = 0x6b74_2d70_6f77_6572;

/// Independent ChaCha20 generator of one simulated study of a power
/// analysis (`kilotouch study power`): replication `replication` at `n`
/// participants and `trials` trials per condition, for the analysis seed
/// `seed`. The key is the injective encoding
///
/// ```text
/// key[0..8]   = seed, little-endian
/// key[8..16]  = 0x6b742d706f776572 ("kt-power"), little-endian
/// key[16..20] = n, u32 LE
/// key[20..24] = trials, u32 LE
/// key[24..32] = replication, u64 LE
/// ```
///
/// so a replication's draws depend on nothing else (not on the thread that
/// runs it, nor on the other sample sizes of the run), and the domain tag
/// keeps these keys disjoint from the trial keys of [`TrialKey::chacha_key`].
pub fn replication_rng(seed: u64, n: u32, trials: u32, replication: u64) -> ChaCha20Rng {
    let mut key = [0_u8; 32];
    key[0..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&POWER_DOMAIN.to_le_bytes());
    key[16..20].copy_from_slice(&n.to_le_bytes());
    key[20..24].copy_from_slice(&trials.to_le_bytes());
    key[24..32].copy_from_slice(&replication.to_le_bytes());
    ChaCha20Rng::from_seed(key)
}

/// `0x` + 16 lowercase hex digits: the `seed` column's text form (a string
/// in every reader, so no precision is lost to doubles or signed 64-bit
/// integers).
pub fn format_seed(seed: u64) -> String {
    format!("0x{seed:016x}")
}

/// Parses [`format_seed`]'s form (also accepts a plain decimal integer).
pub fn parse_seed(s: &str) -> Option<u64> {
    match s.strip_prefix("0x") {
        Some(hex) if !hex.is_empty() && hex.len() <= 16 => u64::from_str_radix(hex, 16).ok(),
        Some(_) => None,
        None => s.parse().ok(),
    }
}

/// Serde form of a 64-bit seed in JSON files read by other tools: a
/// decimal **string** (`"18446744073709551615"`), because JSON readers that
/// hold numbers as doubles (pandas, JavaScript) round integers above 2⁵³.
/// Reading accepts that string, [`format_seed`]'s `0x…` form and, for files
/// written before, a JSON number. Use with `#[serde(with = "seed_string")]`.
pub mod seed_string {
    use serde::{Deserialize, Deserializer, Serializer};

    /// Writes the seed as a decimal string.
    ///
    /// # Errors
    /// Those of the serializer.
    pub fn serialize<S: Serializer>(seed: &u64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&seed.to_string())
    }

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Repr {
        Number(u64),
        Text(String),
    }

    /// Reads a decimal or `0x` string, or a (legacy) JSON number.
    ///
    /// # Errors
    /// A string that is not a seed, a negative or fractional number.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        match Repr::deserialize(d)? {
            Repr::Number(n) => Ok(n),
            Repr::Text(t) => super::parse_seed(t.trim()).ok_or_else(|| {
                serde::de::Error::custom(format!(
                    "`{t}` is not a seed (a decimal or 0x-hexadecimal 64-bit integer)"
                ))
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_text_round_trips() {
        for s in [0, 1, u64::MAX, 0x0123_4567_89ab_cdef] {
            assert_eq!(parse_seed(&format_seed(s)), Some(s));
        }
        assert_eq!(format_seed(255), "0x00000000000000ff");
        assert_eq!(parse_seed("0x"), None);
        assert_eq!(parse_seed("0x1ffffffffffffffff"), None);
        assert_eq!(parse_seed("42"), Some(42));
    }
}
