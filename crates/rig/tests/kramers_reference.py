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

with open(os.path.join(HERE, "data", "kramers_reference.json"), "w") as f:
    json.dump(out, f, indent=1)
print(json.dumps(out, indent=1))
