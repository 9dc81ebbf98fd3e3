//! The real modal decomposition of a regime's ZOH map and the cache of the
//! slowly varying inputs' contribution.

use super::{IN_DRIVE, IN_FORCE, IN_HAND_POS, IN_HAND_VEL, IN_ONE, NU, OUT_ACCEL};
use crate::lanes::{A16, L2, l2_add, l2_mul};
use crate::lti;
use nalgebra::DMatrix;

/// Largest state dimension with a modal fast path (lanes of 2 states).
pub(super) const MODAL_MAX_STATES: usize = 14;
/// Lanes of the modal state.
pub(super) const LANES: usize = MODAL_MAX_STATES / 2;
/// Number of lanes in use for `n` states.
#[inline(always)]
pub(super) const fn lanes(n: usize) -> usize {
    n.div_ceil(2)
}
/// Flat state ↔ lanes (unused padding lanes are zero).
pub(super) fn to_lanes<const N: usize>(x: &[f64; N]) -> [L2; LANES] {
    let mut l = [[0.0; 2]; LANES];
    for (i, v) in x.iter().enumerate().take(MODAL_MAX_STATES) {
        l[i / 2][i % 2] = *v;
    }
    l
}
pub(super) fn from_lanes<const N: usize>(l: &[L2; LANES]) -> [f64; N] {
    let mut x = [0.0; N];
    for (i, v) in x.iter_mut().enumerate().take(MODAL_MAX_STATES) {
        *v = l[i / 2][i % 2];
    }
    x
}
/// Number of structure-of-arrays block groups (4 states each) for `n` states.
#[inline(always)]
pub(super) const fn groups(n: usize) -> usize {
    n / 4
}
/// Natural modal index (blocks in order, 2b and 2b + 1 for block b) of the
/// flat (lane) index `fl`; see [`ModalRegime`].
pub(super) const fn natural_index(fl: usize, n: usize) -> usize {
    if fl < 4 * groups(n) {
        let (g, r) = (fl / 4, fl % 4);
        2 * (2 * g + r % 2) + r / 2
    } else {
        fl
    }
}

/// The ZOH map of one regime in real modal coordinates x = T z:
/// z ← Λ z + T⁻¹Γ u with Λ block-diagonal: 2×2 blocks (an eigenvalue pair
/// a ± jb of Φ, or two real eigenvalues), then at most one single real
/// eigenvalue.
///
/// Basis. Each 2×2 block's basis columns are multiplied by a 2×2 matrix S
/// chosen from the block's part of T⁻¹Γ: with g_f = (p, q) (force) and
/// g_v = (r, w) (drive), S = [g_f g_v] when the two are far from parallel
/// (|sin ∠| ≥ 10⁻³, so round-off grows by at most 10³; x axis), else
/// S = [[p, −q], [q, p]] (a rotation-scaling, condition number 1, which
/// commutes with a pair's block [[a, b], [−b, a]]; y axis). Then S⁻¹g_f =
/// (1, 0) (and S⁻¹g_v = (0, 1)): the force costs one add per lane pair
/// instead of two multiply-adds, the drive another. The block itself becomes
/// S⁻¹ Λ_b S, a general 2×2 matrix, which the layout below handles at the
/// same cost. The map is the same exact ZOH map in another basis; only the
/// round-off differs.
///
/// Layout. Everything the step reads is stored as lanes of two states
/// ([`L2`]) in the *flat* order of the modal state. The first 4·⌊N/4⌋
/// states are groups of two blocks in structure-of-arrays form: lane 2g
/// holds the first coordinates of blocks 2g and 2g+1, lane 2g+1 their second
/// coordinates, so a group update is A' = c_s⊙A + c_p⊙B, B' = c_s⊙B + c_p⊙A
/// (four packed multiplies, no shuffle), the force adds [f, f] to A and,
/// when every group block takes the drive as (0, 1), the drive [u_v, u_v]
/// to B. The remaining states are "AoS" lanes (a whole block, or a single
/// real and a zero padding): z' = c_s⊙z + c_p⊙swap(z) + γ_f f + ….
/// Padding is zero.
#[derive(Debug, Clone)]
pub(super) struct ModalRegime<const N: usize> {
    /// Λ entries on the diagonal (c_s) and to the block partner (c_p).
    pub(super) cs: A16<[L2; LANES]>,
    pub(super) cp: A16<[L2; LANES]>,
    pub(super) gam: A16<[[L2; LANES]; NU]>,
    /// Output weights of flat state j: [(ẍ_h, x_1), (x_h, r)] rows of C T.
    pub(super) outw: A16<[[L2; 2]; MODAL_MAX_STATES]>,
    pub(super) acc_d: [f64; NU],
    /// Every structure-of-arrays block takes the drive as (0, 1).
    pub(super) drive_unit: bool,
    pub(super) t: [[f64; N]; N],
    pub(super) tinv: [[f64; N]; N],
}
/// Contribution of the slowly varying inputs (hand position, hand velocity,
/// constant 1) to the modal update and to the acceleration feed-through,
/// cached while those inputs and the regime stay the same (they are constant
/// over a block, or for ever when nobody moves the hand). Bit-identical to
/// computing them every step.
#[derive(Debug, Clone)]
pub(super) struct SlowInputs {
    pub(super) key: [u64; 4],
    pub(super) bias: A16<[L2; LANES]>,
    pub(super) acc: f64,
}
impl SlowInputs {
    pub(super) fn new() -> Self {
        Self {
            // Regime u64::MAX never occurs: the first step refreshes.
            key: [u64::MAX; 4],
            bias: A16([[0.0; 2]; LANES]),
            acc: 0.0,
        }
    }

    /// The cached contribution for hand position `hp` (m), hand velocity
    /// `hv` (m/s) and constant input `one` in `regime`.
    #[inline(always)]
    pub(super) fn get<const N: usize>(
        &mut self,
        m: &ModalRegime<N>,
        regime: usize,
        [hp, hv, one]: [f64; 3],
    ) -> (&[L2; LANES], f64) {
        let key = [hp.to_bits(), hv.to_bits(), one.to_bits(), regime as u64];
        // One test for the four words (no early exits).
        let diff = (key[0] ^ self.key[0])
            | (key[1] ^ self.key[1])
            | (key[2] ^ self.key[2])
            | (key[3] ^ self.key[3]);
        if diff != 0 {
            self.refresh(m, regime, [hp, hv, one]);
        }
        (&self.bias.0, self.acc)
    }

    // Not `#[cold]`: while the hand moves (study tasks, the GUI's mouse) it
    // runs every sample.
    #[inline(never)]
    fn refresh<const N: usize>(&mut self, m: &ModalRegime<N>, regime: usize, u: [f64; 3]) {
        let [hp, hv, one] = u;
        let key = [hp.to_bits(), hv.to_bits(), one.to_bits(), regime as u64];
        // Lane pairs (packed); per entry (γ_p hp + γ_v hv) + γ_1 one.
        let g = &m.gam.0;
        let (hp2, hv2, one2) = ([hp, hp], [hv, hv], [one, one]);
        let lanes_in = g[IN_HAND_POS].iter().zip(&g[IN_HAND_VEL]).zip(&g[IN_ONE]);
        for (b, ((gp, gv), g1)) in self.bias.0.iter_mut().zip(lanes_in).take(lanes(N)) {
            *b = l2_add(
                l2_add(l2_mul(*gp, hp2), l2_mul(*gv, hv2)),
                l2_mul(*g1, one2),
            );
        }
        self.acc = (m.acc_d[IN_HAND_POS] * hp + m.acc_d[IN_HAND_VEL] * hv) + m.acc_d[IN_ONE] * one;
        self.key = key;
    }
}
/// A real eigenbasis of Φ: T with the real and imaginary parts of one
/// eigenvector per complex pair (ascending modulus) and one per real
/// eigenvalue (ascending), Λ block-diagonal with T⁻¹ΦT = Λ. `None` for
/// repeated eigenvalues, an ill-conditioned basis (κ(T) ≥ 1e8) or a residual
/// ‖ΦT − TΛ‖ above 1e-11 relative. Eigenvectors by inverse iteration.
pub(super) fn real_eigenbasis(
    phi: &DMatrix<f64>,
) -> Option<(DMatrix<f64>, DMatrix<f64>, DMatrix<f64>)> {
    use num_complex::Complex64 as C;
    let n = phi.nrows();
    let ev = lti::eigenvalues(phi);
    let scale = ev.iter().map(|z| z.norm()).fold(1.0, f64::max);
    let tol = 1e-9 * scale;
    let mut pairs: Vec<C> = ev.iter().copied().filter(|z| z.im > tol).collect();
    let mut reals: Vec<f64> = ev
        .iter()
        .filter(|z| z.im.abs() <= tol)
        .map(|z| z.re)
        .collect();
    if 2 * pairs.len() + reals.len() != n {
        return None;
    }
    pairs.sort_by(|x, y| x.norm().total_cmp(&y.norm()));
    reals.sort_by(f64::total_cmp);
    // Distinct eigenvalues only (inverse iteration and diagonalisability).
    let all: Vec<C> = pairs
        .iter()
        .copied()
        .chain(reals.iter().map(|&r| C::new(r, 0.0)))
        .collect();
    for i in 0..all.len() {
        for j in 0..i {
            if (all[i] - all[j]).norm() < 1e-7 * scale {
                return None;
            }
        }
    }
    let eigvec = |lam: C| -> Option<Vec<C>> {
        let mu = lam + C::new(1e-11, 1e-11) * scale;
        let m = DMatrix::<C>::from_fn(n, n, |i, j| {
            let v = C::new(phi[(i, j)], 0.0);
            if i == j { v - mu } else { v }
        });
        let lu = m.lu();
        let mut v = DMatrix::<C>::from_fn(n, 1, |i, _| {
            C::new(1.0 + 0.1 * i as f64, 0.3 - 0.05 * i as f64)
        });
        for _ in 0..3 {
            v = lu.solve(&v)?;
            let nv = v.iter().map(|z| z.norm_sqr()).sum::<f64>().sqrt();
            if !(nv.is_finite() && nv > 0.0) {
                return None;
            }
            v /= C::new(nv, 0.0);
        }
        Some(v.iter().copied().collect())
    };
    let mut t = DMatrix::<f64>::zeros(n, n);
    let mut lam = DMatrix::<f64>::zeros(n, n);
    for (k, &p) in pairs.iter().enumerate() {
        let v = eigvec(p)?;
        for i in 0..n {
            t[(i, 2 * k)] = v[i].re;
            t[(i, 2 * k + 1)] = v[i].im;
        }
        lam[(2 * k, 2 * k)] = p.re;
        lam[(2 * k, 2 * k + 1)] = p.im;
        lam[(2 * k + 1, 2 * k)] = -p.im;
        lam[(2 * k + 1, 2 * k + 1)] = p.re;
    }
    let np = pairs.len();
    for (k, &r) in reals.iter().enumerate() {
        let v = eigvec(C::new(r, 0.0))?;
        // Make the vector real: rotate by the phase of its largest entry.
        let big = v
            .iter()
            .copied()
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))?;
        let ph = big / C::new(big.norm(), 0.0);
        for i in 0..n {
            t[(i, 2 * np + k)] = (v[i] / ph).re;
        }
        lam[(2 * np + k, 2 * np + k)] = r;
    }
    let tinv = t.clone().try_inverse()?;
    let cond = t.norm() * tinv.norm();
    let resid = (phi * &t - &t * &lam).norm() / (phi.norm().max(1.0) * t.norm());
    if !(cond.is_finite() && cond < 1e8 && resid < 1e-11) {
        return None;
    }
    Some((t, tinv, lam))
}

/// The map in the basis T·S of the blocks' input normalisation (see
/// [`ModalRegime`]): (T, T⁻¹, Λ, Γ) become (T S, S⁻¹T⁻¹, S⁻¹ΛS, S⁻¹T⁻¹Γ)
/// with the force column (1, 0) and, where chosen, the drive column (0, 1)
/// written exactly; returns also whether every structure-of-arrays block
/// takes the drive as (0, 1). `None` if a grouped block has no force input.
#[allow(clippy::type_complexity)]
fn normalise_inputs<const N: usize>(
    t: DMatrix<f64>,
    tinv: DMatrix<f64>,
    lam: DMatrix<f64>,
    gamma: &DMatrix<f64>,
) -> Option<(DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, bool)> {
    let n = t.nrows();
    // Input normalisation of the 2×2 blocks (see `ModalRegime`).
    let g0 = &tinv * gamma;
    let gmax = (0..n).map(|i| g0[(i, IN_FORCE)].abs()).fold(0.0, f64::max);
    let vmax = (0..n).map(|i| g0[(i, IN_DRIVE)].abs()).fold(0.0, f64::max);
    let mut sm = DMatrix::<f64>::identity(n, n);
    let mut si = DMatrix::<f64>::identity(n, n);
    // Per block: 0 = as is, 1 = force (1, 0), 2 = force (1, 0) and drive (0, 1).
    let mut kind = vec![0u8; n / 2];
    for (bk, kd) in kind.iter_mut().enumerate() {
        let (i, j) = (2 * bk, 2 * bk + 1);
        let (p, q) = (g0[(i, IN_FORCE)], g0[(j, IN_FORCE)]);
        let (r, w) = (g0[(i, IN_DRIVE)], g0[(j, IN_DRIVE)]);
        let nn = p * p + q * q;
        if !(nn.is_finite() && nn > 0.0 && nn.sqrt() > 1e-12 * gmax) {
            // The structure-of-arrays groups add the force as (1, 0).
            if bk < 2 * groups(N) {
                return None;
            }
            continue;
        }
        // S = [γ_f γ_v] when the two columns are far from parallel
        // (|sin angle| ≥ 1e-3: round-off grows by at most 1/|sin|).
        let det = p * w - q * r;
        let nv = (r * r + w * w).sqrt();
        if vmax > 0.0 && nv > 1e-12 * vmax && det.abs() >= 1e-3 * nn.sqrt() * nv {
            (sm[(i, i)], sm[(i, j)], sm[(j, i)], sm[(j, j)]) = (p, r, q, w);
            (si[(i, i)], si[(i, j)], si[(j, i)], si[(j, j)]) =
                (w / det, -r / det, -q / det, p / det);
            *kd = 2;
        } else {
            (sm[(i, i)], sm[(i, j)], sm[(j, i)], sm[(j, j)]) = (p, -q, q, p);
            (si[(i, i)], si[(i, j)], si[(j, i)], si[(j, j)]) = (p / nn, q / nn, -q / nn, p / nn);
            *kd = 1;
        }
    }
    let t = &t * &sm;
    let tinv = &si * &tinv;
    let lam = &si * &lam * &sm;
    let mut g = &si * &g0;
    for (bk, &kd) in kind.iter().enumerate() {
        if kd >= 1 {
            g[(2 * bk, IN_FORCE)] = 1.0;
            g[(2 * bk + 1, IN_FORCE)] = 0.0;
        }
        if kd == 2 {
            g[(2 * bk, IN_DRIVE)] = 0.0;
            g[(2 * bk + 1, IN_DRIVE)] = 1.0;
        }
    }
    let drive_unit = kind[..2 * groups(N)].iter().all(|&k| k == 2);
    Some((t, tinv, lam, g, drive_unit))
}

/// Real modal decomposition of Φ: `None` if Φ is defective, has repeated
/// eigenvalues or an ill-conditioned eigenbasis (the dense update is used then).
pub(super) fn modal_regime<const N: usize>(
    phi: &DMatrix<f64>,
    gamma: &DMatrix<f64>,
    c: &DMatrix<f64>,
    d: &DMatrix<f64>,
    picks: (usize, usize, Option<usize>),
) -> Option<ModalRegime<N>> {
    let n = phi.nrows();
    if n != N || N > MODAL_MAX_STATES {
        return None;
    }
    let (t, tinv, lam) = real_eigenbasis(phi)?;
    let (t, tinv, lam, g, drive_unit) = normalise_inputs::<N>(t, tinv, lam, gamma)?;
    let ct = c * &t;
    let (h, m1, v) = picks;
    let nat = |fl: usize| natural_index(fl, N);
    let flat = |f: &dyn Fn(usize) -> f64| -> [L2; LANES] {
        let x: [f64; N] = std::array::from_fn(|fl| f(nat(fl)));
        to_lanes(&x)
    };
    let mut m = ModalRegime::<N> {
        cs: A16(flat(&|i| lam[(i, i)])),
        cp: A16(flat(&|i| if i ^ 1 < n { lam[(i, i ^ 1)] } else { 0.0 })),
        gam: A16(std::array::from_fn(|j| flat(&|i| g[(i, j)]))),
        outw: A16(std::array::from_fn(|fl| {
            if fl < N {
                let i = nat(fl);
                [
                    [ct[(OUT_ACCEL, i)], t[(m1, i)]],
                    [t[(h, i)], v.map_or(0.0, |v| t[(v, i)] - t[(h, i)])],
                ]
            } else {
                [[0.0; 2]; 2]
            }
        })),
        acc_d: std::array::from_fn(|j| d[(OUT_ACCEL, j)]),
        drive_unit,
        t: [[0.0; N]; N],
        tinv: [[0.0; N]; N],
    };
    for i in 0..N {
        for j in 0..N {
            m.t[j][i] = t[(i, nat(j))];
            m.tinv[j][i] = tinv[(nat(i), j)];
        }
    }
    Some(m)
}
