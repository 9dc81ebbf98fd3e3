//! Counterbalancing of session orders with balanced Latin squares.
//!
//! Williams (1949) design: for n conditions the first row is
//! 0, 1, n−1, 2, n−2, 3, …; row r adds r (mod n) to every entry. Every
//! condition then appears once in every position, and for even n every
//! ordered pair (a, b), a ≠ b, appears exactly once as immediate neighbours
//! (first-order carry-over balance). For odd n the n mirrored (reversed) rows
//! are appended: 2n rows, each condition twice per position, each ordered
//! pair exactly twice.
//!
//! Participant i (0-based) receives row i mod rows. When the number of
//! participants is not a multiple of the number of rows the design cannot be
//! balanced; [`BalanceReport`] records which orders are over-represented and
//! how often. Optionally the condition labels are permuted onto the square's
//! symbols with a seeded ChaCha20 stream ([`label_permutation`]), so the
//! plan is random but reproducible from the study seed.

use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::{Rng, SeedableRng};
use serde::Serialize;
use thiserror::Error;

/// Errors of the counterbalancing module.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum CounterbalanceError {
    /// A Latin square needs at least one condition.
    #[error("counterbalancing needs at least one condition")]
    NoConditions,
    /// A plan needs at least one participant.
    #[error("counterbalancing needs at least one participant")]
    NoParticipants,
}

/// Result alias of the counterbalancing module.
pub type Result<T> = std::result::Result<T, CounterbalanceError>;

/// ChaCha20 stream used for the label permutation (ASCII "kt-cbal"), so that
/// the study seed can drive other streams without correlation.
pub const LABEL_PERMUTATION_STREAM: u64 = 0x6b74_2d63_6261_6c00;

/// A Latin square of condition indices `0..n` (one row = one session order).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct LatinSquare {
    n: usize,
    rows: Vec<Vec<usize>>,
}

impl LatinSquare {
    /// Number of conditions n.
    pub fn n_conditions(&self) -> usize {
        self.n
    }

    /// Rows (orders) of the square: n rows for even n, 2n for odd n ≥ 3,
    /// one row for n = 1.
    pub fn rows(&self) -> &[Vec<usize>] {
        &self.rows
    }

    /// Number of rows.
    pub fn n_rows(&self) -> usize {
        self.rows.len()
    }

    /// Row assigned to participant `i` (0-based): row i mod rows.
    pub fn row_index_for(&self, participant: usize) -> usize {
        participant % self.rows.len()
    }

    /// The order for participant `i` (0-based).
    pub fn order_for(&self, participant: usize) -> &[usize] {
        &self.rows[self.row_index_for(participant)]
    }

    /// The same square with symbol s replaced by `perm[s]` (a permutation
    /// of `0..n`); relabelling preserves both balance properties.
    fn relabelled(&self, perm: &[usize]) -> Self {
        Self {
            n: self.n,
            rows: self
                .rows
                .iter()
                .map(|r| r.iter().map(|&s| perm[s]).collect())
                .collect(),
        }
    }
}

/// The Williams balanced Latin square for `n` conditions.
///
/// # Errors
/// [`CounterbalanceError::NoConditions`] for n = 0.
pub fn williams(n: usize) -> Result<LatinSquare> {
    if n == 0 {
        return Err(CounterbalanceError::NoConditions);
    }
    let first: Vec<usize> = (0..n)
        .map(|j| {
            if j == 0 {
                0
            } else if j % 2 == 1 {
                j.div_ceil(2)
            } else {
                n - j / 2
            }
        })
        .collect();
    let mut rows: Vec<Vec<usize>> = (0..n)
        .map(|r| first.iter().map(|&s| (s + r) % n).collect())
        .collect();
    if n % 2 == 1 && n > 1 {
        let mirrored: Vec<Vec<usize>> = rows
            .iter()
            .map(|r| r.iter().rev().copied().collect())
            .collect();
        rows.extend(mirrored);
    }
    Ok(LatinSquare { n, rows })
}

/// A one-row "square" `0, 1, …, n−1`: no counterbalancing, every
/// participant runs the conditions in the listed order.
///
/// # Errors
/// [`CounterbalanceError::NoConditions`] for n = 0.
pub fn fixed(n: usize) -> Result<LatinSquare> {
    if n == 0 {
        return Err(CounterbalanceError::NoConditions);
    }
    Ok(LatinSquare {
        n,
        rows: vec![(0..n).collect()],
    })
}

/// Uniform integer in `0..bound` (bound ≥ 1) by rejection: unbiased.
fn below(rng: &mut ChaCha20Rng, bound: u64) -> u64 {
    let zone = u64::MAX - (u64::MAX % bound + 1) % bound;
    loop {
        let x = rng.next_u64();
        if x <= zone {
            return x % bound;
        }
    }
}

/// Seeded permutation of `0..n`: `perm[s]` is the condition index placed on
/// symbol s of the Latin square.
///
/// Generator: ChaCha20 (Bernstein 2008) keyed with the seed's 8 little-endian
/// bytes followed by 24 zero bytes, stream [`LABEL_PERMUTATION_STREAM`];
/// shuffle: Fisher–Yates (Durstenfeld), i from n−1 down to 1 swapping with a
/// uniform j ∈ [0, i] drawn by rejection. The result depends only on
/// (seed, n).
pub fn label_permutation(n: usize, seed: u64) -> Vec<usize> {
    let mut key = [0_u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    let mut rng = ChaCha20Rng::from_seed(key);
    rng.set_stream(LABEL_PERMUTATION_STREAM);
    let mut perm: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        let j = below(&mut rng, i as u64 + 1) as usize;
        perm.swap(i, j);
    }
    perm
}

/// The session order of one participant.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Assignment {
    /// Participant index (0-based, in recruitment order).
    pub participant: usize,
    /// Row of the square used (participant mod rows).
    pub row: usize,
    /// Condition indices in session order.
    pub order: Vec<usize>,
}

/// How often one order (row) is used.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct OrderUsage {
    /// Row index.
    pub row: usize,
    /// Condition indices of the row.
    pub order: Vec<usize>,
    /// Number of participants with this order.
    pub count: usize,
    /// The participants (0-based) with this order.
    pub participants: Vec<usize>,
}

/// Balance of an assignment.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct BalanceReport {
    /// Rows of the square.
    pub rows: usize,
    /// Participants assigned.
    pub participants: usize,
    /// Complete passes through the square, participants / rows.
    pub complete_blocks: usize,
    /// Participants of the incomplete last pass, participants mod rows.
    pub remainder: usize,
    /// True when every row is used equally often and positions and
    /// first-order carry-over are exactly balanced (for a Williams square:
    /// participants is a non-zero multiple of rows).
    pub balanced: bool,
    /// Times each row is used.
    pub row_usage: Vec<usize>,
    /// Orders given to two or more participants.
    pub repeated: Vec<OrderUsage>,
    /// Orders used once more than the others (the incomplete last pass);
    /// empty when balanced.
    pub overrepresented: Vec<OrderUsage>,
    /// Rows never used (only when participants < rows).
    pub unused_rows: Vec<usize>,
    /// `position_counts[c][p]`: participants with condition c in session p.
    pub position_counts: Vec<Vec<usize>>,
    /// `carryover_counts[a][b]`: participants with b immediately after a.
    pub carryover_counts: Vec<Vec<usize>>,
    /// max − min of `position_counts` (0 = positions balanced).
    pub position_spread: usize,
    /// max − min of the off-diagonal `carryover_counts` (0 = carry-over
    /// balanced).
    pub carryover_spread: usize,
}

impl BalanceReport {
    /// One-paragraph human summary with condition `labels`.
    pub fn describe<L: AsRef<str>>(&self, labels: &[L]) -> String {
        let name = |order: &[usize]| {
            order
                .iter()
                .map(|&c| labels.get(c).map_or("?", |l| l.as_ref()))
                .collect::<Vec<_>>()
                .join("-")
        };
        let mut s = format!(
            "{} participants over {} orders: ",
            self.participants, self.rows
        );
        if self.balanced {
            s.push_str(&format!(
                "fully balanced ({} complete pass(es)).",
                self.complete_blocks
            ));
            return s;
        }
        s.push_str("not a multiple, cannot be fully balanced; ");
        if self.overrepresented.is_empty() {
            s.push_str("no order over-represented");
        } else {
            let list: Vec<String> = self
                .overrepresented
                .iter()
                .map(|u| format!("{} ×{}", name(&u.order), u.count))
                .collect();
            s.push_str(&format!(
                "over-represented: {} (others ×{})",
                list.join(", "),
                self.complete_blocks
            ));
        }
        if !self.unused_rows.is_empty() {
            s.push_str(&format!("; {} order(s) unused", self.unused_rows.len()));
        }
        s.push_str(&format!(
            "; position spread {}, carry-over spread {}.",
            self.position_spread, self.carryover_spread
        ));
        s
    }
}

/// A complete counterbalancing plan.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct CounterbalancePlan {
    /// Number of conditions.
    pub n_conditions: usize,
    /// Seed of the label permutation, if any.
    pub seed: Option<u64>,
    /// `label_permutation[s]` = condition index on symbol s of the Williams
    /// square (identity without a seed).
    pub label_permutation: Vec<usize>,
    /// The relabelled square (condition indices).
    pub square: LatinSquare,
    /// One entry per participant.
    pub assignments: Vec<Assignment>,
    /// Balance of the assignment.
    pub report: BalanceReport,
}

fn spread<'a>(counts: impl Iterator<Item = &'a usize>) -> usize {
    let (lo, hi) = counts.fold((usize::MAX, 0), |(lo, hi), &c| (lo.min(c), hi.max(c)));
    hi.saturating_sub(lo)
}

/// Balance report of `assignments` over `square`.
pub fn balance_report(square: &LatinSquare, assignments: &[Assignment]) -> BalanceReport {
    let n = square.n_conditions();
    let rows = square.n_rows();
    let participants = assignments.len();
    let mut row_usage = vec![0; rows];
    let mut users: Vec<Vec<usize>> = vec![Vec::new(); rows];
    let mut position_counts = vec![vec![0; n]; n];
    let mut carryover_counts = vec![vec![0; n]; n];
    for a in assignments {
        row_usage[a.row] += 1;
        users[a.row].push(a.participant);
        for (p, &c) in a.order.iter().enumerate() {
            position_counts[c][p] += 1;
        }
        for w in a.order.windows(2) {
            carryover_counts[w[0]][w[1]] += 1;
        }
    }
    let usage = |r: usize| OrderUsage {
        row: r,
        order: square.rows()[r].clone(),
        count: row_usage[r],
        participants: users[r].clone(),
    };
    let min_use = row_usage.iter().copied().min().unwrap_or(0);
    let max_use = row_usage.iter().copied().max().unwrap_or(0);
    let repeated = (0..rows)
        .filter(|&r| row_usage[r] >= 2)
        .map(usage)
        .collect();
    let overrepresented = if max_use > min_use {
        (0..rows)
            .filter(|&r| row_usage[r] == max_use)
            .map(usage)
            .collect()
    } else {
        Vec::new()
    };
    let unused_rows = (0..rows).filter(|&r| row_usage[r] == 0).collect();
    let position_spread = spread(position_counts.iter().flatten());
    let carryover_spread = spread(
        carryover_counts
            .iter()
            .enumerate()
            .flat_map(|(a, row)| row.iter().enumerate().filter(move |(b, _)| *b != a))
            .map(|(_, c)| c),
    );
    BalanceReport {
        rows,
        participants,
        complete_blocks: participants / rows,
        remainder: participants % rows,
        balanced: participants > 0
            && participants.is_multiple_of(rows)
            && position_spread == 0
            && carryover_spread == 0,
        row_usage,
        repeated,
        overrepresented,
        unused_rows,
        position_counts,
        carryover_counts,
        position_spread,
        carryover_spread,
    }
}

/// Plans the session orders of `participants` participants over
/// `n_conditions` conditions: Williams square, optional seeded label
/// permutation, participant i → row i mod rows, and the balance report.
///
/// # Errors
/// No condition or no participant.
pub fn plan(
    n_conditions: usize,
    participants: usize,
    seed: Option<u64>,
) -> Result<CounterbalancePlan> {
    if participants == 0 {
        return Err(CounterbalanceError::NoParticipants);
    }
    let base = williams(n_conditions)?;
    let label_permutation = match seed {
        Some(s) => label_permutation(n_conditions, s),
        None => (0..n_conditions).collect(),
    };
    let square = base.relabelled(&label_permutation);
    let assignments: Vec<Assignment> = (0..participants)
        .map(|i| Assignment {
            participant: i,
            row: square.row_index_for(i),
            order: square.order_for(i).to_vec(),
        })
        .collect();
    let report = balance_report(&square, &assignments);
    Ok(CounterbalancePlan {
        n_conditions,
        seed,
        label_permutation,
        square,
        assignments,
        report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_rows_follow_the_williams_pattern() {
        assert_eq!(williams(4).unwrap().rows()[0], vec![0, 1, 3, 2]);
        assert_eq!(williams(5).unwrap().rows()[0], vec![0, 1, 4, 2, 3]);
        assert_eq!(williams(6).unwrap().rows()[0], vec![0, 1, 5, 2, 4, 3]);
        assert_eq!(williams(1).unwrap().rows(), &[vec![0]]);
        assert_eq!(williams(0), Err(CounterbalanceError::NoConditions));
    }

    #[test]
    fn bounded_draw_is_in_range() {
        let mut rng = ChaCha20Rng::from_seed([7; 32]);
        for bound in 1..50 {
            for _ in 0..20 {
                assert!(below(&mut rng, bound) < bound);
            }
        }
    }
}
