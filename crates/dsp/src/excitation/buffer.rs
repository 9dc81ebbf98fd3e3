//! Fallible allocation of generated signals: a length too large for memory
//! is an error naming the parameter that asked for it, never an abort.

use crate::{DspError, Result};

/// An empty `Vec` with room for exactly `len` samples, or `InvalidParameter`
/// naming `what` when `len` does not fit in `usize` or cannot be reserved.
pub(super) fn alloc_len(len: u128, what: &'static str) -> Result<Vec<f64>> {
    let too_long = || DspError::InvalidParameter {
        name: what,
        value: len as f64,
        reason: "requested signal is too long to allocate".into(),
    };
    let n = usize::try_from(len).map_err(|_| too_long())?;
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| too_long())?;
    Ok(v)
}
