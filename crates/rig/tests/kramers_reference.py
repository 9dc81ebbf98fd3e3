#!/usr/bin/env python3
"""Generate crates/rig/tests/data/kramers_reference.json: independent
reference values for the Gaussian trap profile (crates/rig/tests/gaussian_trap.rs).

The trap: F(d) = -kappa d exp(-2|d|^2/w0^2) in the plane, potential
U(r) = U0 (1 - exp(-2 r^2/w0^2)), depth U0 = kappa w0^2/4 (Rayleigh-regime
gradient force of a Gaussian beam). Overdamped bead, D = kT/gamma,
gamma = 6 pi eta R (no wall), p(r) = exp(-U(r)/kT).

1. Mean first-passage time from the trap centre to the circle |d| = b
   (absorbing), radially symmetric 2-D diffusion. The backward equation
   D (T'' + T'/r - T' U'/kT) = -1, i.e. (1/(r p)) (r p T')' = -1/D, with
   T'(0) finite and T(b) = 0, integrates to
       T(0) = int_0^b dr 1/(D r p(r)) int_0^r r' p(r') dr'.
   Evaluated by nested scipy.integrate.quad. Also:
   - the Kramers flux-over-population estimate (harmonic well): the inner
     integral replaced by its harmonic-well value (kT/kappa)(1 - exp(-kappa
     r^2/2kT)), i.e. the well population of the small-d spring;
   - the shift of T when b moves outwards by 0.5826 sqrt(2 D dt) (the
     Siegmund correction for a boundary monitored every dt: how much the
     discrete escape check can lengthen the measured time).
2. The Boltzmann radial density r p(r) on the disc r <= b (a bead kept in
   the disc by a reflecting circle): the probability of each histogram bin.
3. A deep trap (the default rig's bead and stiffness, w0 = 0.5 um): the
   Boltzmann variance per axis <r^2>/2 over r < 2 w0, compared with kT/kappa.
4. Escape of a bead pulled by a trap moving at speed v (along x, from the
   bead at rest at the centre): in the trap's frame the bead drifts with
   mu(d) = F(d)/gamma - v x, so the mean first-passage time to |d| = b
   solves the 2-D backward equation D lap T + mu . grad T = -1, T(b) = 0.
   Solved by central differences on a polar grid (scipy.sparse spsolve),
   checked against the exact radial integral of 1. at v = 0, and
   Richardson-extrapolated from two grids. The critical speed
   v_c = F_max/gamma (F_max = kappa w0 exp(-1/2)/2, the escape force) is
   where the tilt removes the barrier: below it escape is thermally
   activated, above it the bead is dragged out.

Regenerate with `python3 crates/rig/tests/kramers_reference.py` (numpy,
scipy). Recorded with numpy 2.x, scipy 1.17.
"""
import json
import math
import os

import numpy as np
import scipy
from scipy import integrate

HERE = os.path.dirname(os.path.abspath(__file__))
KB = 1.380649e-23
T = 293.15
ETA = 1.0016e-3
R = 1.5e-6
KT = KB * T
GAMMA = 6.0 * math.pi * ETA * R
D = KT / GAMMA
SIEGMUND = 0.5826


def potential_kt(r, kappa, w0):
    """U(r)/kT."""
    return kappa * w0 * w0 / 4.0 * (1.0 - math.exp(-2.0 * r * r / (w0 * w0))) / KT


def quad(f, a, b, points=None):
    v, err = integrate.quad(f, a, b, epsabs=0.0, epsrel=1e-11, limit=400, points=points)
    return v


def mfpt(kappa, w0, b):
    """Exact MFPT from 0 to b (s)."""

    def inner(r):
        return quad(lambda s: s * math.exp(-potential_kt(s, kappa, w0)), 0.0, r)

    def outer(r):
        if r == 0.0:
            return 0.0
        return inner(r) / (D * r * math.exp(-potential_kt(r, kappa, w0)))

    return quad(outer, 0.0, b, points=[w0 / 2.0, w0])


def mfpt_kramers(kappa, w0, b):
    """Flux-over-population estimate with the harmonic-well population (s)."""
    z = KT / kappa

    def outer(r):
        if r == 0.0:
            return 0.0
        return z * (-math.expm1(-r * r / (2.0 * z))) * math.exp(potential_kt(r, kappa, w0)) / (D * r)

    return quad(outer, 0.0, b, points=[w0 / 2.0, w0])


out = {"numpy": np.__version__, "scipy": scipy.__version__, "kt_j": KT, "gamma_n_s_m": GAMMA}

# ------------------------------------------------------------- 1. escape
escape = []
for w0, barrier_kt, dt_over_tau in [(0.4e-6, 4.0, 0.02), (0.4e-6, 5.5, 0.02)]:
    kappa = 4.0 * barrier_kt * KT / (w0 * w0)
    tau = GAMMA / kappa
    fs = 1.0 / (dt_over_tau * tau)
    b = 2.0 * w0
    t = mfpt(kappa, w0, b)
    tk = mfpt_kramers(kappa, w0, b)
    db = SIEGMUND * math.sqrt(2.0 * D / fs)
    t_shift = mfpt(kappa, w0, b + db)
    escape.append(
        {
            "waist_m": w0,
            "barrier_kt": barrier_kt,
            "stiffness_n_per_m": kappa,
            "fs_hz": fs,
            "escape_radius_m": b,
            "mfpt_s": t,
            "mfpt_kramers_s": tk,
            "mfpt_shifted_s": t_shift,
            "tau_s": tau,
        }
    )
out["escape"] = escape

# ------------------------------------------------- 2. radial Boltzmann density
w0, barrier_kt = 0.2e-6, 3.0
kappa = 4.0 * barrier_kt * KT / (w0 * w0)
b = 2.0 * w0
edges = list(np.linspace(0.0, b, 17))
weights = [
    quad(lambda r: r * math.exp(-potential_kt(r, kappa, w0)), edges[i], edges[i + 1])
    for i in range(len(edges) - 1)
]
tot = sum(weights)
out["radial"] = {
    "waist_m": w0,
    "barrier_kt": barrier_kt,
    "stiffness_n_per_m": kappa,
    "fs_hz": 1.0 / (0.02 * GAMMA / kappa),
    "disc_radius_m": b,
    "edges_m": edges,
    "probability": [x / tot for x in weights],
}

# ------------------------------------------------------------- 3. deep trap
kappa, w0 = 2.0e-5, 0.5e-6
b = 2.0 * w0
z = quad(lambda r: r * math.exp(-potential_kt(r, kappa, w0)), 0.0, b, points=[0.05e-6])
m2 = quad(lambda r: r**3 * math.exp(-potential_kt(r, kappa, w0)), 0.0, b, points=[0.05e-6])
out["deep"] = {
    "waist_m": w0,
    "stiffness_n_per_m": kappa,
    "barrier_kt": kappa * w0 * w0 / 4.0 / KT,
    "variance_per_axis_m2": m2 / z / 2.0,
    "variance_linear_m2": KT / kappa,
}


# ------------------------------------------------------- 4. pulled trap
def mfpt_pulled(kappa, w0, b, v, nr, nt):
    """MFPT from the centre to |d| = b, trap moving at v along x (s)."""
    from scipy.sparse import lil_matrix
    from scipy.sparse.linalg import spsolve

    dr = b / nr
    th = np.arange(nt) * 2.0 * math.pi / nt
    dth = 2.0 * math.pi / nt
    n = (nr - 1) * nt + 1  # rings i = 1..nr-1 (T = 0 at i = nr), plus the centre

    def idx(i, j):
        return 1 + (i - 1) * nt + (j % nt)

    a = lil_matrix((n, n))
    rhs = -np.ones(n)
    for i in range(1, nr):
        r = i * dr
        mr_trap = -kappa / GAMMA * r * math.exp(-2.0 * r * r / (w0 * w0))
        for j in range(nt):
            mr = mr_trap - v * math.cos(th[j])
            mt = v * math.sin(th[j])
            k = idx(i, j)
            # D (T_rr + T_r / r + T_tt / r^2) + mr T_r + mt T_t / r
            c_out = D / dr**2 + (D / r + mr) / (2.0 * dr)
            c_in = D / dr**2 - (D / r + mr) / (2.0 * dr)
            c_t = D / (r * dth) ** 2
            c_tp = c_t + mt / (r * 2.0 * dth)
            c_tm = c_t - mt / (r * 2.0 * dth)
            a[k, k] = -2.0 * D / dr**2 - 2.0 * c_t
            if i + 1 < nr:
                a[k, idx(i + 1, j)] = c_out
            if i == 1:
                a[k, 0] += c_in
            else:
                a[k, idx(i - 1, j)] = c_in
            a[k, idx(i, j + 1)] += c_tp
            a[k, idx(i, j - 1)] += c_tm
    # Centre: lap T = 4 (mean of ring 1 - T0) / dr^2; grad T . (-v x) from
    # the first Fourier mode of ring 1.
    for j in range(nt):
        a[0, idx(1, j)] += 4.0 * D / (dr * dr * nt) - v * 2.0 * math.cos(th[j]) / (nt * dr)
    a[0, 0] = -4.0 * D / (dr * dr)
    t = spsolve(a.tocsr(), rhs)
    return float(t[0])


def mfpt_pulled_extrapolated(kappa, w0, b, v):
    """Richardson extrapolation (second order) of two polar grids."""
    coarse = mfpt_pulled(kappa, w0, b, v, 80, 64)
    fine = mfpt_pulled(kappa, w0, b, v, 160, 128)
    return (4.0 * fine - coarse) / 3.0, abs(fine - coarse)


w0, barrier_kt, dt_over_tau = 0.4e-6, 5.5, 0.02
kappa = 4.0 * barrier_kt * KT / (w0 * w0)
b = 2.0 * w0
f_max = kappa * w0 * math.exp(-0.5) / 2.0
v_c = f_max / GAMMA
t0_exact = mfpt(kappa, w0, b)
t0_grid, _ = mfpt_pulled_extrapolated(kappa, w0, b, 0.0)
assert abs(t0_grid / t0_exact - 1.0) < 2e-3, (t0_grid, t0_exact)
pulled = []
for frac in [0.25, 0.5, 0.75, 1.25]:
    t, diff = mfpt_pulled_extrapolated(kappa, w0, b, frac * v_c)
    pulled.append({"speed_over_critical": frac, "speed_m_s": frac * v_c, "mfpt_s": t,
                   "grid_difference_s": diff})
tau = GAMMA / kappa
fs = 1.0 / (dt_over_tau * tau)
out["pulled"] = {
    "waist_m": w0,
    "barrier_kt": barrier_kt,
    "stiffness_n_per_m": kappa,
    "fs_hz": fs,
    "escape_radius_m": b,
    "escape_force_n": f_max,
    "critical_speed_m_s": v_c,
    "mfpt_at_rest_s": t0_exact,
    "mfpt_at_rest_grid_s": t0_grid,
    "siegmund_shift_m": SIEGMUND * math.sqrt(2.0 * D / fs),
    "speeds": pulled,
}

with open(os.path.join(HERE, "data", "kramers_reference.json"), "w") as f:
    json.dump(out, f, indent=1)
print(json.dumps(out, indent=1))
