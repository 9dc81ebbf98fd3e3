//! Bead trajectories read back from a trial's raw file, decimated for
//! drawing.

use super::ResultsError;
use crate::rawsig::{read_npy, read_sidecar, sidecar_path};
use std::path::Path;

/// A bead trajectory read from a raw file.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Trial number.
    pub trial: u32,
    /// Trial successful.
    pub success: bool,
    /// Bead (x, y), µm, decimated.
    pub bead_um: Vec<[f64; 2]>,
    /// Samples in the file.
    pub samples: u64,
}

/// Read the bead trajectory (`bead_x`, `bead_y`, m → µm) of a raw trial file
/// ([`crate::rawsig`]: NPY + JSON sidecar naming the channels),
/// decimated to at most `max_points` points; non-finite samples are
/// skipped.
pub fn read_trajectory(
    path: &Path,
    trial: u32,
    success: bool,
    max_points: usize,
) -> Result<Trajectory, ResultsError> {
    let side = read_sidecar(&sidecar_path(path))?;
    let col = |name: &str| {
        side.channels
            .iter()
            .position(|c| c.name == name)
            .ok_or_else(|| ResultsError::MissingChannel {
                path: path.to_path_buf(),
                name: name.to_owned(),
            })
    };
    let (cx, cy) = (col("bead_x")?, col("bead_y")?);
    let arr = read_npy(path)?;
    if cx >= arr.cols || cy >= arr.cols {
        return Err(ResultsError::TooFewColumns {
            path: path.to_path_buf(),
            cols: arr.cols,
        });
    }
    let n = usize::try_from(arr.rows).map_err(|_| ResultsError::TooLarge)?;
    let bead_um = decimate_indices(n, max_points)
        .into_iter()
        .filter_map(|i| {
            let r = arr.row(i);
            let (x, y) = (r[cx] * 1e6, r[cy] * 1e6);
            (x.is_finite() && y.is_finite()).then_some([x, y])
        })
        .collect();
    Ok(Trajectory {
        trial,
        success,
        bead_um,
        samples: arr.rows,
    })
}

/// Indices of at most `max` samples of a record of `n`, evenly strided, the
/// last sample always included (a trajectory keeps its end point).
pub fn decimate_indices(n: usize, max: usize) -> Vec<usize> {
    if n == 0 || max == 0 {
        return Vec::new();
    }
    if n <= max {
        return (0..n).collect();
    }
    let stride = n.div_ceil(max.saturating_sub(1).max(1));
    let mut v: Vec<usize> = (0..n).step_by(stride).collect();
    if v.last() != Some(&(n - 1)) {
        v.push(n - 1);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimation_keeps_ends_and_bounds_the_count() {
        assert!(decimate_indices(0, 10).is_empty());
        assert_eq!(decimate_indices(5, 10), vec![0, 1, 2, 3, 4]);
        for (n, max) in [(100_000, 2000), (2001, 2000), (10, 3), (7, 2)] {
            let idx = decimate_indices(n, max);
            assert!(idx.len() <= max, "{n} {max}: {}", idx.len());
            assert_eq!(idx[0], 0);
            assert_eq!(*idx.last().unwrap(), n - 1);
            assert!(idx.windows(2).all(|w| w[0] < w[1]));
        }
    }
}
