//! Tabulated exact Ornstein–Uhlenbeck coefficients near an obstacle: the
//! normal and tangential relaxation factors, step gains, noise scales and
//! the Itô drift as cubic pieces in s = R/h, evaluated by the fast
//! near-obstacle step instead of the exponentials and drag laws (the exact
//! coefficients are the reference they are checked against).

use super::drag::{
    DRAG_CLAMP_GAP_OVER_R, faxen_parallel_mobility, perpendicular_mobility,
    perpendicular_mobility_ds,
};
use crate::lanes::{l2_add, l2_mul};
use std::f64::consts::PI;

/// Number of cubic pieces of [`DragTable`] over s ∈ [0, s_clamp].
pub const DRAG_TABLE_PIECES: usize = 512;
/// Exact-OU coefficients of one full sample near an obstacle, for a trapped
/// bead outside the contact zone, as functions of s = R/h (h = distance from
/// the bead centre to the obstacle surface), in lane pairs (normal,
/// tangent): c = e^{−dt k μ}, g = τ(1 − c) = (1 − c)/(k μ),
/// σ = √((k_BT/k)(1 − c²)), and the Itô drift's displacement v_d·g⊥ (normal
/// only), with μ⊥ = μ₀·[`perpendicular_mobility`], μ∥ = μ₀·Faxén's parallel
/// mobility, k = κ and v_d = k_BT μ₀ p′(s)(−s²/R) (module docs).
///
/// These are the exact step's coefficients (two exponentials, a division
/// and two square roots per direction, two mobility polynomials). Tabulated
/// as piecewise cubics on [`DRAG_TABLE_PIECES`] equal pieces of
/// [0, s_clamp], s_clamp = 1/(1 + [`DRAG_CLAMP_GAP_OVER_R`]) (the clamp
/// region and the contact zone take the exact path), each cubic
/// interpolating at the four Chebyshev points of its piece. The largest
/// relative deviation from the exact coefficients is measured at
/// construction on a grid 8× finer than the pieces (see
/// [`SimTweezer::drag_table_error`]; ≈ 1e-13 for the defaults) and the
/// table is not used if it exceeds 1e-9.
/// One cubic piece of [`DragTable`]: `[power][pair][lane]`.
pub(super) type DragPiece = [[[f64; 2]; 4]; 4];
/// 1.5·2⁵²: (x − 0.5) + this (x ∈ [0, 2⁵⁰]) is 1.5·2⁵² + round(x − 0.5),
/// in the binade [2⁵², 2⁵³) of unit spacing, i.e. ⌊x⌋ (or ⌊x⌋ − 1 when x
/// is an odd integer: the tie rounds to even; then t = 1 on the piece
/// below), so the piece index is in the low bits of the sum — no
/// saturating float→integer conversion.
pub(super) const PIECE_ROUND: f64 = 6_755_399_441_055_744.0;
#[derive(Debug, Clone)]
pub(super) struct DragTable {
    inv_ds: f64,
    /// Per piece, the monomial coefficients (t⁰…t³, t ∈ [0, 1] across the
    /// piece) of the four lane pairs (c, g, σ, drift), contiguous (256
    /// bytes per piece); a fixed-size array so that a masked index needs
    /// no bounds check.
    coef: Box<[DragPiece; DRAG_TABLE_PIECES]>,
    pub(super) max_rel_err: f64,
}
impl DragTable {
    /// Largest accepted relative interpolation error.
    const MAX_REL_ERR: f64 = 1e-9;

    /// Exact coefficients at s (see the type docs): [c⊥, c∥, g⊥, g∥, σ⊥, σ∥, drift⊥].
    pub(super) fn exact(
        s: f64,
        k: f64,
        h: f64,
        kt: f64,
        mu0: f64,
        inv_r: f64,
        drift: bool,
    ) -> [f64; 7] {
        let mp = mu0 * perpendicular_mobility(s);
        let mt = mu0 * faxen_parallel_mobility(s);
        let vd = if drift {
            kt * mu0 * perpendicular_mobility_ds(s) * (-(s * s) * inv_r)
        } else {
            0.0
        };
        let one = |mu: f64| {
            let kmu = k * mu;
            let c = (-h * kmu).exp();
            (c, (1.0 - c) / kmu, (kt / k * (1.0 - c * c)).sqrt())
        };
        let (cp, gp, sp) = one(mp);
        let (ct, gt, st) = one(mt);
        [cp, ct, gp, gt, sp, st, vd * gp]
    }

    #[allow(clippy::needless_range_loop)] // q indexes the 7 coefficients of every table row
    pub(super) fn new(k: f64, h: f64, kt: f64, mu0: f64, inv_r: f64, drift: bool) -> Option<Self> {
        let n = DRAG_TABLE_PIECES;
        let s_max = 1.0 / (1.0 + DRAG_CLAMP_GAP_OVER_R);
        let ds = s_max / n as f64;
        let f = |s: f64| Self::exact(s, k, h, kt, mu0, inv_r, drift);
        // Chebyshev points of [0, 1] and the cubic through them (Newton
        // divided differences, then expanded to monomials in t).
        let tn: [f64; 4] =
            std::array::from_fn(|j| 0.5 * (1.0 - ((2 * j + 1) as f64 * PI / 8.0).cos()));
        let mut coef = Vec::with_capacity(n);
        for i in 0..n {
            let vals: [[f64; 7]; 4] = std::array::from_fn(|j| f((i as f64 + tn[j]) * ds));
            let mut piece = [[[0.0; 2]; 4]; 4];
            for q in 0..7 {
                let y: [f64; 4] = std::array::from_fn(|j| vals[j][q]);
                // Divided differences.
                let mut d = y;
                for lvl in 1..4 {
                    for j in (lvl..4).rev() {
                        d[j] = (d[j] - d[j - 1]) / (tn[j] - tn[j - lvl]);
                    }
                }
                // Newton form → monomials: p(t) = d0 + (t−t0)(d1 + (t−t1)(d2 + (t−t2) d3)).
                let mut m = [d[3], 0.0, 0.0, 0.0]; // coefficients of the inner polynomial, t⁰ first
                for lvl in (0..3).rev() {
                    // m ← m·(t − t_lvl) + d_lvl
                    let mut nm = [0.0; 4];
                    for p in 0..4 {
                        if p + 1 < 4 {
                            nm[p + 1] += m[p];
                        }
                        nm[p] -= tn[lvl] * m[p];
                    }
                    nm[0] += d[lvl];
                    m = nm;
                }
                let (pair, lane) = (q / 2, q % 2);
                for (p, mp) in m.iter().enumerate() {
                    piece[p][pair][lane] = *mp;
                }
            }
            coef.push(piece);
        }
        let coef: Box<[DragPiece; DRAG_TABLE_PIECES]> = coef.into_boxed_slice().try_into().ok()?;
        let mut t = Self {
            inv_ds: 1.0 / ds,
            coef,
            max_rel_err: 0.0,
        };
        // Measure the interpolation error on a grid 8× finer than the pieces.
        let mut err: f64 = 0.0;
        for i in 0..=(8 * n) {
            let s = s_max * i as f64 / (8 * n) as f64;
            let e = f(s);
            let a = t.eval(s);
            let got = [
                a[0][0], a[0][1], a[1][0], a[1][1], a[2][0], a[2][1], a[3][0],
            ];
            for q in 0..7 {
                // The drift displacement is measured against the step's
                // noise amplitude σ⊥ (it vanishes at s = 0).
                let scale = if q == 6 { e[4] } else { e[q].abs() };
                err = err.max((got[q] - e[q]).abs() / scale);
            }
        }
        if err.is_nan() || err > Self::MAX_REL_ERR {
            return None;
        }
        t.max_rel_err = err;
        Some(t)
    }

    /// The four lane pairs (c, g, σ, drift) at s ∈ [0, s_max].
    #[inline(always)]
    pub(super) fn eval(&self, s: f64) -> [[f64; 2]; 4] {
        // Piece i = ⌊x⌋ (x ≥ 0; [`PIECE_ROUND`]) and t = x − i ∈ [0, 1]; the
        // mask and the clamp keep i in the table for any s (out of
        // [0, s_max] the value is meaningless but nothing panics).
        let x = s * self.inv_ds;
        let y = (x - 0.5) + PIECE_ROUND;
        let i = ((y.to_bits() as usize) & (2 * DRAG_TABLE_PIECES - 1)).min(DRAG_TABLE_PIECES - 1);
        let t = x - i as f64;
        let c = &self.coef[i];
        std::array::from_fn(|q| {
            let mut v = c[3][q];
            for p in (0..3).rev() {
                v = l2_add(l2_mul(v, [t; 2]), c[p][q]);
            }
            v
        })
    }
}
