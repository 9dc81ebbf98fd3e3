//! The chain's kernels: the per-sample arithmetic of the two paths, packed
//! as the two lanes of `[f64; 2]` (lane 0 = low path, lane 1 = high path),
//! the coefficient and state layout they run on, and the per-sample guard
//! ([`guarded`]: flush schedule, non-finite events). [`super::Chain`] owns
//! the state between calls, the block chunking and the cross-fade.
//!
//! # Two kernels
//! * The fast kernel ([`run_norm`]): the low and high paths are independent,
//!   so they are processed stage by stage as two SIMD lanes (stage k = low
//!   section k and high section k; the shorter path is padded with identity
//!   sections, which pass the signal through exactly). With SSE2 (baseline
//!   x86-64) LLVM emits packed `mulpd`/`addpd`. Per lane the recursion is the
//!   TDF-II of [`crate::filter`] on the section normalised to b0 = 1 (its
//!   gain applied once at the path output) with y = v + s1 substituted into
//!   the state update (see [`Kernel`]): 4 instead of 5 multiplies per section
//!   and a feedback loop of one multiply and one subtraction. A first-order
//!   section (C_H of the paper has one) is placed last and skips its s2
//!   update. The stage count and first-order tail are const generics, so the
//!   kernel is straight-line code.
//! * The reference kernel ([`run_general`]), right after it: plain TDF-II per
//!   lane through [`crate::filter`]'s `tdf2_step`, the readable form of the
//!   same recursion. It runs any b0 (including 0) and is, operation for
//!   operation, the scalar [`Sos`](crate::filter::Sos) of the same sections
//!   (equal outputs, up to the sign of a zero).
//!
//! The fast kernel computes the same recursion as the reference, rounded
//! differently; `tests/equivalence.rs` compares the two over every
//! stage count (tolerance and its reason stated there).
//!
//! The recursive state must stay in registers to be fast: an f64 value
//! stored and reloaded through memory on every sample adds the
//! store-to-load forwarding latency (5–9 cycles on current x86 cores) to
//! every section's feedback loop, as much as the whole per-sample budget.
//! Hence straight-line code with constant state indices (`each_stage!`),
//! and one monomorphised kernel per (stage count, first-order tail) pair,
//! selected once per call by `with_kernel!`.

use crate::filter::{self, BiquadCoeffs, FLUSH_INTERVAL, FLUSH_THRESHOLD};

/// Maximum number of sections per path.
pub const MAX_STAGES: usize = 8;

/// One packed stage: lane 0 = low path, lane 1 = high path.
///
/// `orig` holds the sections as designed (used for responses and by the
/// reference kernel); `c1, c2, a1, a2` are the b0-normalised state-update
/// coefficients of the fast kernel (see [`Kernel`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct LaneStage {
    pub(super) orig: [BiquadCoeffs; 2],
    c1: [f64; 2],
    c2: [f64; 2],
    a1: [f64; 2],
    a2: [f64; 2],
}

impl LaneStage {
    const IDENTITY: Self = Self {
        orig: [BiquadCoeffs::IDENTITY; 2],
        c1: [0.0; 2],
        c2: [0.0; 2],
        a1: [0.0; 2],
        a2: [0.0; 2],
    };
}

/// State of one packed stage: [s1, s2], each [low, high].
pub(super) type LaneState = [[f64; 2]; 2];

/// State of all stages.
pub(super) type State = [LaneState; MAX_STAGES];

/// All-zero state.
pub(super) const ZERO_STATE: State = [[[0.0; 2]; 2]; MAX_STAGES];

/// Which kernel runs a coefficient set.
///
/// * `Norm`: every section has a normal, non-zero b0. Each section is
///   normalised to b0 = 1 (its gain moved to one output multiply per path)
///   and its TDF-II update is written with y = v + s1 substituted:
///
///   ```text
///   y   = v + s1
///   s1' = (c1 v + s2) − a1 s1,   c1 = b1/b0 − a1
///   s2' = c2 v − a2 s1,          c2 = b2/b0 − a2
///   ```
///
///   This is TDF-II on the normalised section (state = TDF-II state divided
///   by the cumulative b0), with 4 instead of 5 multiplies per section and a
///   feedback loop of one multiply and one subtraction. A last stage that is
///   first order in both lanes (`tail1`) skips the s2 update.
/// * `General`: the reference kernel, plain TDF-II per lane (any b0,
///   including 0), over all [`MAX_STAGES`]; used for hand-made sections that
///   cannot be normalised, and by [`super::Chain::new_reference`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kernel {
    Norm { stages: usize, tail1: bool },
    General,
}

/// A coefficient set in kernel form.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Coefs {
    pub(super) st: [LaneStage; MAX_STAGES],
    /// Output gain per lane (product of the b0) for `Norm`, else 1.
    gain: [f64; 2],
    /// Product of b0 over stages 0..=k per lane (`Norm`), else 1: the state
    /// of stage k is the TDF-II state divided by this.
    cum: [[f64; 2]; MAX_STAGES],
    pub(super) kernel: Kernel,
}

impl Coefs {
    /// The sections `low` and `high` (each 1..=[`MAX_STAGES`] long) in
    /// kernel form: the fast kernel when `fast` is set and every b0 can be
    /// normalised, the reference kernel otherwise.
    pub(super) fn new(low: &[BiquadCoeffs], high: &[BiquadCoeffs], fast: bool) -> Self {
        let stages = low.len().max(high.len());
        let mut st = [LaneStage::IDENTITY; MAX_STAGES];
        for (k, stage) in st.iter_mut().enumerate() {
            stage.orig = [
                *low.get(k).unwrap_or(&BiquadCoeffs::IDENTITY),
                *high.get(k).unwrap_or(&BiquadCoeffs::IDENTITY),
            ];
        }
        let mut c = Self {
            st,
            gain: [1.0; 2],
            cum: [[1.0; 2]; MAX_STAGES],
            kernel: Kernel::General,
        };
        if fast && c.normalise() {
            let last = &c.st[stages - 1].orig;
            let tail1 = last.iter().all(BiquadCoeffs::is_first_order);
            c.kernel = Kernel::Norm { stages, tail1 };
        } else {
            c.gain = [1.0; 2];
            c.cum = [[1.0; 2]; MAX_STAGES];
        }
        c
    }

    /// Fill the normalised coefficients; false if some b0 (or a product of
    /// them) is zero, subnormal or non-finite.
    fn normalise(&mut self) -> bool {
        let mut gain = [1.0f64; 2];
        for (stage, cum) in self.st.iter_mut().zip(self.cum.iter_mut()) {
            for (lane, g) in gain.iter_mut().enumerate() {
                let c = stage.orig[lane];
                if !c.b0.is_normal() {
                    return false;
                }
                stage.c1[lane] = c.b1 / c.b0 - c.a1;
                stage.c2[lane] = c.b2 / c.b0 - c.a2;
                stage.a1[lane] = c.a1;
                stage.a2[lane] = c.a2;
                if !(stage.c1[lane].is_finite() && stage.c2[lane].is_finite()) {
                    return false;
                }
                *g *= c.b0;
                if !g.is_normal() {
                    return false;
                }
                cum[lane] = *g;
            }
        }
        self.gain = gain;
        true
    }

    /// `from`'s state (in `from`'s scaling) converted to this set's scaling;
    /// an exact copy when the scalings are equal.
    pub(super) fn convert_state(&self, from: &Coefs, s: &State) -> State {
        let mut out = ZERO_STATE;
        for k in 0..MAX_STAGES {
            for lane in 0..2 {
                let r = from.cum[k][lane] / self.cum[k][lane];
                for j in 0..2 {
                    out[k][j][lane] = s[k][j][lane] * r;
                }
            }
        }
        out
    }
}

/// One normalised second-order stage on both lanes (see [`Kernel`]).
#[inline(always)]
fn norm_stage(st: &LaneStage, s: &mut LaneState, v: [f64; 2]) -> [f64; 2] {
    let y = [v[0] + s[0][0], v[1] + s[0][1]];
    let s1 = [
        (st.c1[0] * v[0] + s[1][0]) - st.a1[0] * s[0][0],
        (st.c1[1] * v[1] + s[1][1]) - st.a1[1] * s[0][1],
    ];
    let s2 = [
        st.c2[0] * v[0] - st.a2[0] * s[0][0],
        st.c2[1] * v[1] - st.a2[1] * s[0][1],
    ];
    *s = [s1, s2];
    y
}

/// One normalised first-order stage (b2 = a2 = 0 in both lanes).
#[inline(always)]
fn norm_stage1(st: &LaneStage, s: &mut LaneState, v: [f64; 2]) -> [f64; 2] {
    let y = [v[0] + s[0][0], v[1] + s[0][1]];
    s[0] = [
        st.c1[0] * v[0] - st.a1[0] * s[0][0],
        st.c1[1] * v[1] - st.a1[1] * s[0][1],
    ];
    y
}

/// Expand `$m!(k)` for every stage index k < [`MAX_STAGES`], as
/// straight-line code: the state is then addressed with constant indices
/// only, which lets the optimiser keep it in registers across a caller's
/// sample loop (a loop over stages, even a constant one, is unrolled too late
/// for that).
macro_rules! each_stage {
    ($m:ident) => {
        $m!(0);
        $m!(1);
        $m!(2);
        $m!(3);
        $m!(4);
        $m!(5);
        $m!(6);
        $m!(7);
    };
}
const _: () = assert!(MAX_STAGES == 8, "each_stage! expands 8 stages");

/// Flush the tiny values of one stage to zero (denormal policy of
/// [`crate::filter`]); false if any is non-finite.
#[inline(always)]
fn flush_stage(st: &mut LaneState) -> bool {
    let finite =
        st[0][0].is_finite() & st[0][1].is_finite() & st[1][0].is_finite() & st[1][1].is_finite();
    let f = |v: f64| if v.abs() < FLUSH_THRESHOLD { 0.0 } else { v };
    let [[a, b], [c, d]] = *st;
    *st = [[f(a), f(b)], [f(c), f(d)]];
    finite
}

/// Flush the first `N` stages; false if any state value is non-finite.
#[inline(always)]
fn flush_stages<const N: usize>(s: &mut State) -> bool {
    let mut finite = true;
    macro_rules! f {
        ($k:literal) => {
            if $k < N {
                finite &= flush_stage(&mut s[$k]);
            }
        };
    }
    each_stage!(f);
    finite
}

/// The fast kernel: N normalised stages (the last one first-order if `T`),
/// then the output gains; when `flush` is set the state is also flushed.
/// Straight-line code; LLVM packs each lane pair into SSE2 `mulpd`/`addpd`.
/// Returns the outputs and whether the state is finite (checked only when
/// flushing).
#[inline(always)]
pub(super) fn run_norm<const N: usize, const T: bool>(
    c: &Coefs,
    s: &mut State,
    x: f64,
    flush: bool,
) -> ([f64; 2], bool) {
    let mut v = [x, x];
    macro_rules! st {
        ($k:literal) => {
            if $k < N {
                v = if T && $k + 1 == N {
                    norm_stage1(&c.st[$k], &mut s[$k], v)
                } else {
                    norm_stage(&c.st[$k], &mut s[$k], v)
                };
            }
        };
    }
    each_stage!(st);
    let ok = if flush { flush_stages::<N>(s) } else { true };
    ([v[0] * c.gain[0], v[1] * c.gain[1]], ok)
}

/// The reference kernel: plain TDF-II per lane over all [`MAX_STAGES`]
/// stages, each section exactly as designed (padding stages are exact
/// identities). Same operations, in the same order, as an
/// [`Sos`](crate::filter::Sos) of the same sections.
#[inline(always)]
pub(super) fn run_general(c: &Coefs, s: &mut State, x: f64, flush: bool) -> ([f64; 2], bool) {
    let mut v = [x, x];
    macro_rules! lane {
        ($k:literal, $l:literal) => {
            let mut ls = [s[$k][0][$l], s[$k][1][$l]];
            v[$l] = filter::tdf2_step(&c.st[$k].orig[$l], &mut ls, v[$l]);
            s[$k][0][$l] = ls[0];
            s[$k][1][$l] = ls[1];
        };
    }
    macro_rules! st {
        ($k:literal) => {
            lane!($k, 0);
            lane!($k, 1);
        };
    }
    each_stage!(st);
    let ok = if flush {
        flush_stages::<MAX_STAGES>(s)
    } else {
        true
    };
    (v, ok)
}

/// Any coefficient set over all [`MAX_STAGES`] (the cross-fade's old design;
/// same values as the specialised kernels, padding stages are identities).
#[inline(always)]
pub(super) fn run_full(c: &Coefs, s: &mut State, x: f64, flush: bool) -> ([f64; 2], bool) {
    match c.kernel {
        Kernel::Norm { .. } => run_norm::<MAX_STAGES, false>(c, s, x, flush),
        Kernel::General => run_general(c, s, x, flush),
    }
}

/// Zero a state with one store per lane pair. The zero goes through
/// [`std::hint::black_box`] so that the optimiser cannot merge the stores
/// into a `memset` call, whose clobbered registers would cost the kernels
/// around it their register allocation.
#[inline(always)]
pub(super) fn zero_state(s: &mut State) {
    let z = std::hint::black_box(0.0);
    macro_rules! zs {
        ($k:literal) => {
            s[$k] = [[z, z], [z, z]];
        };
    }
    each_stage!(zs);
}

/// Marks the branch it is called from as unlikely (the `#[cold]` polyfill of
/// `std::hint::cold_path`, which is newer than the workspace's MSRV), for
/// the event paths of the kernels.
#[cold]
#[inline(always)]
pub(super) fn cold() {}

/// 0 for a finite `v`, NaN for ±∞ or NaN (v − v, exact in IEEE 754). Summed
/// over a chunk it flags any non-finite output with two vector additions per
/// sample and no branch.
#[inline(always)]
#[allow(clippy::eq_op)]
pub(super) fn nan_if_nonfinite(v: f64) -> f64 {
    v - v
}

/// The guarded per-sample step of kernel (N, T) (N = 0: reference kernel) on
/// a state, outside any cross-fade: non-finite input or output → (0, 0),
/// state zeroed, event counted; every [`FLUSH_INTERVAL`]-th sample the state
/// is flushed and checked.
///
/// A non-finite input needs no test of its own: x enters every output lane
/// (through b0·x, or x itself after normalisation), so the output of that
/// sample is non-finite too (∞·0 and ∞ − ∞ are NaN), and the output test
/// catches it before anything reaches the caller; the poisoned state is
/// then zeroed.
#[inline(always)]
pub(super) fn guarded<const N: usize, const T: bool>(
    c: &Coefs,
    s: &mut State,
    tick: &mut u32,
    events: &mut u64,
    x: f64,
) -> (f64, f64) {
    *tick += 1;
    let flush = *tick >= FLUSH_INTERVAL;
    if flush {
        *tick = 0;
    }
    let (y, ok) = if N == 0 {
        run_general(c, s, x, flush)
    } else {
        run_norm::<N, T>(c, s, x, flush)
    };
    if !(ok && y[0].is_finite() && y[1].is_finite()) {
        cold();
        *events += 1;
        zero_state(s);
        *tick = 0;
        return (0.0, 0.0);
    }
    (y[0], y[1])
}

/// Evaluate `$body` with the const generics `$n: usize` and `$t: bool` of
/// the kernel `$kernel` selects: (stage count, first-order tail) for
/// [`Kernel::Norm`], (0, false) for [`Kernel::General`]. This is the one
/// place where a runtime [`Kernel`] becomes a monomorphised kernel; it
/// expands to one match arm per (stage count, tail) pair, each with `$body`
/// specialised, e.g. `with_kernel!(c.kernel, N, T => self.step::<N, T>(x))`.
macro_rules! with_kernel {
    ($kernel:expr, $n:ident, $t:ident => $body:expr) => {
        with_kernel!(@arms $kernel, $n, $t, $body, [1 2 3 4 5 6 7 8])
    };
    (@arms $kernel:expr, $n:ident, $t:ident, $body:expr, [$($k:literal)*]) => {
        match $kernel {
            $(
                $crate::chain::kernel::Kernel::Norm { stages: $k, tail1: false } => {
                    const $n: usize = $k;
                    const $t: bool = false;
                    $body
                }
                $crate::chain::kernel::Kernel::Norm { stages: $k, tail1: true } => {
                    const $n: usize = $k;
                    const $t: bool = true;
                    $body
                }
            )*
            // `N = 0` selects the reference kernel (no `Norm` has another
            // stage count: `Coefs::new` takes 1..=MAX_STAGES sections).
            _ => {
                const $n: usize = 0;
                const $t: bool = false;
                $body
            }
        }
    };
}
pub(super) use with_kernel;
const _: () = assert!(MAX_STAGES == 8, "with_kernel! expands 8 stage counts");
