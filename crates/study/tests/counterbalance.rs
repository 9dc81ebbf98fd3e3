//! Williams balanced Latin squares: Latin and first-order carry-over
//! balance for n = 2..=8, assignment rule, the 3-condition / 8-participant
//! case of docs/REFERENCE-VALUES.md, and the seeded label permutation.

use std::collections::{HashMap, HashSet};

use kilotouch_study::counterbalance::{
    self, CounterbalanceError, LABEL_PERMUTATION_STREAM, LatinSquare,
};
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::{Rng, SeedableRng};

fn assert_permutation(row: &[usize], n: usize) {
    let mut sorted = row.to_vec();
    sorted.sort_unstable();
    assert_eq!(sorted, (0..n).collect::<Vec<_>>(), "row {row:?}");
}

/// Each block of n rows is a Latin square: every column a permutation.
fn assert_latin_block(rows: &[Vec<usize>], n: usize) {
    assert_eq!(rows.len(), n);
    for p in 0..n {
        let column: Vec<usize> = rows.iter().map(|r| r[p]).collect();
        assert_permutation(&column, n);
    }
}

fn carryover(square: &LatinSquare) -> HashMap<(usize, usize), usize> {
    let mut counts = HashMap::new();
    for r in square.rows() {
        for w in r.windows(2) {
            *counts.entry((w[0], w[1])).or_insert(0) += 1;
        }
    }
    counts
}

#[test]
fn williams_squares_are_latin_and_carryover_balanced() {
    for n in 2..=8 {
        let sq = counterbalance::williams(n).unwrap();
        let expected_rows = if n % 2 == 0 { n } else { 2 * n };
        assert_eq!(sq.n_rows(), expected_rows, "n = {n}");
        for r in sq.rows() {
            assert_permutation(r, n);
        }
        for block in sq.rows().chunks(n) {
            assert_latin_block(block, n);
        }
        // Every ordered pair of distinct conditions is adjacent equally
        // often: once per n rows for even n, twice over 2n rows for odd n.
        let per_pair = if n % 2 == 0 { 1 } else { 2 };
        let counts = carryover(&sq);
        for a in 0..n {
            assert_eq!(counts.get(&(a, a)), None, "self-succession");
            for b in 0..n {
                if a != b {
                    assert_eq!(
                        counts.get(&(a, b)),
                        Some(&per_pair),
                        "n = {n}, pair ({a},{b})"
                    );
                }
            }
        }
        // Orders are distinct.
        let distinct: HashSet<&Vec<usize>> = sq.rows().iter().collect();
        assert_eq!(distinct.len(), sq.n_rows());
    }
}

#[test]
fn three_conditions_give_all_six_orders() {
    let sq = counterbalance::williams(3).unwrap();
    let set: HashSet<Vec<usize>> = sq.rows().iter().cloned().collect();
    let all: HashSet<Vec<usize>> = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ]
    .iter()
    .map(|r| r.to_vec())
    .collect();
    assert_eq!(set, all);
}

/// docs/REFERENCE-VALUES.md: 3 conditions → 6 rows; 8 participants cannot be fully
/// balanced. With participant i → row i mod 6, rows 0 and 1 are used by
/// participants (0, 6) and (1, 7); rows 2..5 once.
#[test]
fn eight_participants_three_conditions_report_the_repeats() {
    let plan = counterbalance::plan(3, 8, None).unwrap();
    let rep = &plan.report;
    assert_eq!(rep.rows, 6);
    assert!(!rep.balanced);
    assert_eq!((rep.complete_blocks, rep.remainder), (1, 2));
    assert_eq!(rep.row_usage, vec![2, 2, 1, 1, 1, 1]);
    let repeated: Vec<(usize, usize, Vec<usize>)> = rep
        .repeated
        .iter()
        .map(|u| (u.row, u.count, u.participants.clone()))
        .collect();
    assert_eq!(repeated, vec![(0, 2, vec![0, 6]), (1, 2, vec![1, 7])]);
    assert_eq!(rep.overrepresented, rep.repeated);
    assert!(rep.unused_rows.is_empty());
    for a in &plan.assignments {
        assert_eq!(a.row, a.participant % 6);
        assert_eq!(a.order, plan.square.rows()[a.row]);
    }
    // Positions are then unbalanced: each condition is first twice in the
    // six rows, and the extra rows 0 1 2 and 1 2 0 put 0 and 1 first once
    // more.
    assert_eq!(plan.square.rows()[0], vec![0, 1, 2]);
    assert_eq!(plan.square.rows()[1], vec![1, 2, 0]);
    let first: Vec<usize> = rep.position_counts.iter().map(|r| r[0]).collect();
    assert_eq!(first, vec![3, 3, 2]);
    assert_eq!(rep.position_spread, 1);
    let counted: usize = rep.position_counts.iter().map(|r| r[0]).sum();
    assert_eq!(counted, 8);
    let text = rep.describe(&["V", "P", "D"]);
    assert!(text.contains("cannot be fully balanced"), "{text}");
    assert!(text.contains("×2"), "{text}");
}

#[test]
fn full_blocks_are_exactly_balanced_with_or_without_seed() {
    for n in 2..=8 {
        let rows = counterbalance::williams(n).unwrap().n_rows();
        for seed in [None, Some(1), Some(2016), Some(u64::MAX)] {
            for blocks in 1..=2 {
                let plan = counterbalance::plan(n, blocks * rows, seed).unwrap();
                let rep = &plan.report;
                assert!(rep.balanced);
                assert_eq!(rep.position_spread, 0, "n = {n}");
                assert_eq!(rep.carryover_spread, 0, "n = {n}");
                assert!(rep.overrepresented.is_empty());
                assert_eq!(rep.repeated.len(), if blocks == 2 { rows } else { 0 });
                // Each condition blocks·rows/n times in each position.
                for c in 0..n {
                    for p in 0..n {
                        assert_eq!(rep.position_counts[c][p], blocks * rows / n);
                    }
                }
            }
        }
    }
}

#[test]
fn fewer_participants_than_rows_lists_unused_orders() {
    let plan = counterbalance::plan(5, 4, None).unwrap();
    assert_eq!(plan.report.rows, 10);
    assert_eq!(plan.report.unused_rows, vec![4, 5, 6, 7, 8, 9]);
    assert!(plan.report.repeated.is_empty());
    assert_eq!(plan.report.overrepresented.len(), 4);
    assert_eq!(
        counterbalance::plan(3, 0, None).unwrap_err(),
        CounterbalanceError::NoParticipants
    );
    assert_eq!(
        counterbalance::plan(0, 3, None).unwrap_err(),
        CounterbalanceError::NoConditions
    );
}

#[test]
fn label_permutation_is_deterministic_and_uniform() {
    for n in 1..=8 {
        let p = counterbalance::label_permutation(n, 42);
        assert_permutation(&p, n);
        assert_eq!(p, counterbalance::label_permutation(n, 42));
    }
    // Over 6000 seeds all 3! permutations appear ≈ 1000 times each
    // (binomial sd ≈ 29; allow 5 sd).
    let mut counts: HashMap<Vec<usize>, usize> = HashMap::new();
    for seed in 0..6000_u64 {
        *counts
            .entry(counterbalance::label_permutation(3, seed))
            .or_insert(0) += 1;
    }
    assert_eq!(counts.len(), 6);
    for (perm, c) in &counts {
        assert!((855..=1145).contains(c), "{perm:?}: {c}");
    }
    // The seeded plan is the Williams square relabelled.
    let plan = counterbalance::plan(4, 4, Some(7)).unwrap();
    let base = counterbalance::williams(4).unwrap();
    for (r, b) in plan.square.rows().iter().zip(base.rows()) {
        let mapped: Vec<usize> = b.iter().map(|&s| plan.label_permutation[s]).collect();
        assert_eq!(r, &mapped);
    }
}

/// The generator is the standard ChaCha20: with an all-zero key, nonce
/// (stream) 0 and counter 0 the keystream starts 76 b8 e0 ad a0 f1 3d 90
/// (RFC 7539, appendix A.1, test vector #1), read little-endian.
#[test]
fn generator_is_standard_chacha20() {
    let mut rng = ChaCha20Rng::from_seed([0; 32]);
    assert_eq!(rng.next_u64(), 0x903d_f1a0_ade0_b876);
    assert_eq!(rng.next_u64(), 0x28bd_8653_e56a_5d40);
    // The label stream is a different stream of the same key.
    let mut other = ChaCha20Rng::from_seed([0; 32]);
    other.set_stream(LABEL_PERMUTATION_STREAM);
    assert_ne!(other.next_u64(), 0x903d_f1a0_ade0_b876);
}
