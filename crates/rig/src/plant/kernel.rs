//! The packed two-lane kernel of the modal update: the modal state is
//! stored as lanes of two states ([`L2`]) so that every product and sum is
//! a packed (SSE2) operation on baseline x86-64; the layout is described at
//! [`super::modal::ModalRegime`]. Bit-identical to the same arithmetic done
//! state by state; the dense update of [`super::axis_sim`] is the reference
//! it is checked against.

use super::modal::{LANES, MODAL_MAX_STATES, ModalRegime, groups, lanes};
use super::{IN_DRIVE, IN_FORCE};
use crate::lanes::{A16, L2, l2_add, l2_mul, l2_mul_add};

/// Adds the output contributions of the two states in lane `zk` (weights
/// `w0`, `w1`, each [(ẍ_h, x_1), (x_h, r)]) to the pair accumulators `p`:
/// each state is broadcast to a lane pair, so every product and sum is
/// vertical (packed), with even and odd states in separate accumulators.
#[inline(always)]
pub(super) fn outputs_add(p: &mut [L2; 4], w0: &[L2; 2], w1: &[L2; 2], zk: L2) {
    let (lo, hi) = ([zk[0], zk[0]], [zk[1], zk[1]]);
    p[0] = l2_mul_add(p[0], w0[0], lo);
    p[2] = l2_mul_add(p[2], w0[1], lo);
    p[1] = l2_mul_add(p[1], w1[0], hi);
    p[3] = l2_mul_add(p[3], w1[1], hi);
}
/// Outputs (ẍ_h without feed-through, x_1, x_h, r) of the pair accumulators.
#[inline(always)]
pub(super) fn outputs_sum(p: &[L2; 4]) -> [f64; 4] {
    let am = l2_add(p[0], p[1]);
    let ts = l2_add(p[2], p[3]);
    [am[0], am[1], ts[0], ts[1]]
}
/// Outputs (ẍ_h without feed-through, x_1, x_h, r) of the modal state `z`:
/// Σ_j w_j z_j, same order of operations as [`modal_pass`].
#[inline(always)]
pub(super) fn modal_outputs<const N: usize>(
    w: &[[L2; 2]; MODAL_MAX_STATES],
    z: &[L2; LANES],
) -> [f64; 4] {
    let mut p = [[0.0f64; 2]; 4];
    for (k, zk) in z.iter().enumerate().take(lanes(N)) {
        outputs_add(&mut p, &w[2 * k], &w[2 * k + 1], *zk);
    }
    outputs_sum(&p)
}
/// One modal update z ← Λz + γ_f f (+ γ_v u_v when `DRIVE`) + bias and the
/// outputs (ẍ_h without feed-through, x_1, x_h, r) of the new state, in one
/// pass over the lanes (layout in [`ModalRegime`]; outputs as in
/// [`modal_outputs`]). `DRIVE = false` skips the drive column where it is
/// identically zero, `STOPS = false` the stroke output (y axis: no magnet,
/// r = 0), `TIP = false` the tip position (returned as 0; ground truth only,
/// see [`AxisSim::tip_m`]).
#[inline(always)]
pub(super) fn modal_pass<
    const N: usize,
    const DRIVE: bool,
    const DUNIT: bool,
    const STOPS: bool,
    const TIP: bool,
>(
    m: &ModalRegime<N>,
    z: &[L2; LANES],
    bias: &[L2; LANES],
    f: f64,
    v: f64,
) -> (A16<[L2; LANES]>, [f64; 4]) {
    let (gf, gv) = (&m.gam.0[IN_FORCE], &m.gam.0[IN_DRIVE]);
    let (cs, cp) = (&m.cs.0, &m.cp.0);
    let w = &m.outw.0;
    let (ff, vv) = ([f, f], [v, v]);
    let mut zn = A16([[0.0; 2]; LANES]);
    let mut p = [[0.0f64; 2]; 4];
    for g in 0..groups(N) {
        let (l, h) = (2 * g, 2 * g + 1);
        let (a, b) = (z[l], z[h]);
        // Force input (1, 0) per block: A only.
        let mut an = l2_add(l2_add(l2_mul(cs[l], a), l2_mul(cp[l], b)), ff);
        let mut bn = l2_add(l2_mul(cs[h], b), l2_mul(cp[h], a));
        if DRIVE && DUNIT {
            // Drive input (0, 1) per block: B only.
            bn = l2_add(bn, vv);
        } else if DRIVE {
            an = l2_mul_add(an, gv[l], vv);
            bn = l2_mul_add(bn, gv[h], vv);
        }
        an = l2_add(an, bias[l]);
        bn = l2_add(bn, bias[h]);
        zn.0[l] = an;
        zn.0[h] = bn;
        outputs_add(&mut p, &w[2 * l], &w[2 * l + 1], an);
        outputs_add(&mut p, &w[2 * h], &w[2 * h + 1], bn);
    }
    for k in 2 * groups(N)..lanes(N) {
        let zk = z[k];
        let rot = l2_mul_add(l2_mul(cs[k], zk), cp[k], [zk[1], zk[0]]);
        let inp = if DRIVE {
            l2_mul_add(l2_mul(gf[k], ff), gv[k], vv)
        } else {
            l2_mul(gf[k], ff)
        };
        let y = l2_add(l2_add(rot, inp), bias[k]);
        zn.0[k] = y;
        outputs_add(&mut p, &w[2 * k], &w[2 * k + 1], y);
    }
    let out = outputs_sum(&p);
    // Without end stops the stroke weights are zero: r = +0 exactly.
    (
        zn,
        [
            out[0],
            out[1],
            if TIP { out[2] } else { 0.0 },
            if STOPS { out[3] } else { 0.0 },
        ],
    )
}
/// Column-major matrix–vector product y = M x (M given by its columns).
#[inline]
pub(super) fn colmul<const N: usize>(cols: &[[f64; N]; N], x: &[f64; N]) -> [f64; N] {
    let mut y = [0.0; N];
    for (col, &xj) in cols.iter().zip(x) {
        for (yi, ci) in y.iter_mut().zip(col) {
            *yi += ci * xj;
        }
    }
    y
}
