//! Average ("mid") ranks with tie bookkeeping.

/// Ranks of `values` (1-based, ties get the mean of the ranks they span) as
/// *doubled* integers, so that mid-ranks of ties (multiples of ½) are exact,
/// plus the sizes of every tie group (groups of size 1 omitted).
///
/// Ties are exact `==` equality of the `f64` values, as in
/// `scipy.stats.rankdata`. Values must be finite (checked by callers).
pub(crate) fn doubled_ranks(values: &[f64]) -> (Vec<u64>, Vec<u64>) {
    let n = values.len();
    let mut idx: Vec<usize> = (0..n).collect();
    idx.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut ranks = vec![0_u64; n];
    let mut ties = Vec::new();
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && values[idx[end]] == values[idx[start]] {
            end += 1;
        }
        // Positions start+1 ..= end (1-based); mean = (start+1+end)/2, doubled:
        let doubled = (start + 1 + end) as u64;
        for &i in &idx[start..end] {
            ranks[i] = doubled;
        }
        let t = (end - start) as u64;
        if t > 1 {
            ties.push(t);
        }
        start = end;
    }
    (ranks, ties)
}

/// [`doubled_ranks`] of one block into `ranks` (same length as `values`),
/// with `order` as scratch space (no allocation once it has grown), and
/// its tie term Σ (t³ − t) ([`tie_term`]). O(k log k) for k values.
pub(crate) fn doubled_ranks_into(values: &[f64], order: &mut Vec<usize>, ranks: &mut [u64]) -> f64 {
    let n = values.len();
    order.clear();
    order.extend(0..n);
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut ties = 0.0;
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && values[order[end]] == values[order[start]] {
            end += 1;
        }
        let doubled = (start + 1 + end) as u64;
        for &i in &order[start..end] {
            ranks[i] = doubled;
        }
        let t = (end - start) as u64;
        ties += (t * t * t - t) as f64;
        start = end;
    }
    ties
}

/// Σ (t³ − t) over tie groups, the usual tie-correction term.
pub(crate) fn tie_term(ties: &[u64]) -> f64 {
    ties.iter().map(|&t| (t * t * t - t) as f64).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mid_ranks_and_ties() {
        let (r, t) = doubled_ranks(&[3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0, 5.0]);
        // sorted: 1,1,2,3,4,5,5,6,9 -> ranks 1.5,1.5,3,4,5,6.5,6.5,8,9
        let half: Vec<f64> = r.iter().map(|&x| x as f64 / 2.0).collect();
        assert_eq!(half, vec![4.0, 1.5, 5.0, 1.5, 6.5, 9.0, 3.0, 8.0, 6.5]);
        assert_eq!(t, vec![2, 2]);
        assert_eq!(tie_term(&t), 12.0);
        // Rank sum is n(n+1)/2 whatever the ties.
        assert_eq!(r.iter().sum::<u64>(), 9 * 10);
    }

    #[test]
    fn the_block_form_equals_the_allocating_form() {
        let v = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0, 5.0];
        let (r, t) = doubled_ranks(&v);
        let mut order = Vec::new();
        let mut into = vec![0; v.len()];
        let ties = doubled_ranks_into(&v, &mut order, &mut into);
        assert_eq!(into, r);
        assert_eq!(ties, tie_term(&t));
    }

    #[test]
    fn empty_and_all_tied() {
        assert_eq!(doubled_ranks(&[]), (vec![], vec![]));
        let (r, t) = doubled_ranks(&[2.0; 4]);
        assert_eq!(r, vec![5; 4]);
        assert_eq!(t, vec![4]);
    }
}
