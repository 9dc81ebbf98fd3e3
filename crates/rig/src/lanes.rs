//! Pairs of f64 as lanes: element-wise arithmetic on `[f64; 2]` that the
//! compiler turns into packed SSE2 instructions on baseline x86-64. Shared by
//! the plant's modal kernel, the tweezer's near-obstacle step, the safety
//! layer and the study's task geometry ([`norm2`]).

/// Two adjacent states, processed together (packed SSE2 on baseline x86-64).
pub type L2 = [f64; 2];
/// 16-byte aligned wrapper: packed SSE2 arithmetic can then read lane
/// arrays straight from memory (no separate unaligned loads).
#[derive(Debug, Clone, Copy)]
#[repr(C, align(16))]
pub struct A16<T>(pub T);
#[inline(always)]
pub fn l2_add(a: L2, b: L2) -> L2 {
    [a[0] + b[0], a[1] + b[1]]
}
#[inline(always)]
pub fn l2_mul(a: L2, b: L2) -> L2 {
    [a[0] * b[0], a[1] * b[1]]
}
#[inline(always)]
pub fn l2_mul_add(acc: L2, a: L2, b: L2) -> L2 {
    [acc[0] + a[0] * b[0], acc[1] + a[1] * b[1]]
}

/// Lane-wise a − b.
#[inline(always)]
pub fn l2_sub(a: L2, b: L2) -> L2 {
    [a[0] - b[0], a[1] - b[1]]
}

/// Euclidean norm √(x² + y²) of a pair: several times cheaper than
/// `f64::hypot` (a libm call). Callers pass values bounded by the limits (no
/// overflow) or accept +∞ for |x| ≳ 1e154, which their comparisons then
/// treat as too large, correctly.
#[inline(always)]
pub fn norm2(v: L2) -> f64 {
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}
