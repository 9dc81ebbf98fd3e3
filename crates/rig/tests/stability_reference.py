#!/usr/bin/env python3
"""Generate crates/rig/tests/data/stability_reference.json: independent
reference values for crates/rig/tests/stability.rs.

1. Margins of small discrete loops from python-control's
   `stability_margins` (the definitions kilotouch's `stability::margins`
   follows), also with a long pure delay.
2. The bilateral loop of the default rig file, built here from the paper's
   equations with numpy/scipy (plant of eq. 1 with the two side branches,
   exact ZOH by scipy.linalg.expm, Linkwitz-Riley crossover from
   scipy.signal.butter, C_H = K_sys F / G_H by the prewarped bilinear
   transform, the bead's exact Ornstein-Uhlenbeck drift, the wall damper)
   and analysed with python-control: margins from a dense frequency
   response (`frd`), closed-loop poles from the state-space feedback, and
   the critical force scale by bisection on the poles.
3. The same loop with an extra delay of d samples (z^-d): margins, poles
   with python-control's state space of the delay appended, and the delay
   at which the pressed D loop turns unstable.
4. The D loop with the high band rendered g_H times stronger (the
   Haptuator path g_H C_H): margins, poles and the critical g_H by
   bisection on the poles.

Regenerate with `python3 crates/rig/tests/stability_reference.py` (numpy,
scipy, control). Recorded with numpy 2.4, scipy 1.17, control 0.10.2.
"""
import json
import os
import tomllib

import control
import numpy as np
import scipy
from scipy import linalg, signal

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
cfg = tomllib.load(open(os.path.join(ROOT, "assets", "rigs", "default.toml"), "rb"))
FS = cfg["rig"]["sample_rate_hz"]
DT = 1.0 / FS
out = {"numpy": np.__version__, "scipy": scipy.__version__, "control": control.__version__}

# ---------------------------------------------------------------- 1. generic
generic = []
for num, den, fs in [
    ([0.05, 0.025], [1.0, -1.4, 0.45], 1.0),            # k(z+0.5)/((z-0.9)(z-0.5))
    ([0.0, 0.3, 0.1], [1.0, -1.5, 0.7], 1.0),
    ([0.02, 0.0, 0.0, 0.0], [1.0, -2.2, 1.7, -0.45], 1.0),
]:
    sys = control.tf(num, den, 1.0 / fs)
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(sys)
    generic.append({
        "num": num, "den": den, "fs": fs,
        "gain_margin_db": float(20 * np.log10(gm)) if np.isfinite(gm) else None,
        "phase_margin_deg": float(pm) if np.isfinite(pm) else None,
        "phase_crossover_hz": float(wpc / (2 * np.pi)) if np.isfinite(wpc) else None,
        "gain_crossover_hz": float(wgc / (2 * np.pi)) if np.isfinite(wgc) else None,
    })
out["generic"] = generic

# Small loops with a long pure delay z^-d (the phase turns d/2 times up to
# Nyquist): margins from a dense frequency response (`frd`, 20000 points
# from 0.01 Hz, the lower end of kilotouch's grid, to Nyquist: the delay
# turns by at most 35 deg between points; 50000 points change the margins
# by < 1e-9 dB and < 1e-4 deg).
generic_delayed = []
for num, den, fs, d in [
    ([0.02, 0.01], [1.0, -1.4, 0.45], 1.0, 1000),
    ([0.0, 0.3, 0.1], [1.0, -1.5, 0.7], 1.0, 300),
]:
    f = np.logspace(-2, np.log10(fs / 2 * (1 - 1e-9)), 20000)
    z = np.exp(2j * np.pi * f / fs)
    resp = np.polyval(num, z) / np.polyval(den, z) * z ** (-d)
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(control.frd(resp, 2 * np.pi * f))
    generic_delayed.append({
        "num": num, "den": den, "fs": fs, "delay_samples": d,
        "gain_margin_db": float(20 * np.log10(gm)) if np.isfinite(gm) else None,
        "phase_margin_deg": float(pm) if np.isfinite(pm) else None,
        "phase_crossover_hz": float(wpc / (2 * np.pi)) if np.isfinite(wpc) else None,
        "gain_crossover_hz": float(wgc / (2 * np.pi)) if np.isfinite(wgc) else None,
    })
out["generic_delayed"] = generic_delayed


# ----------------------------------------------------------------- 2. plant
def axis(x_axis, kf, bf):
    p, h = cfg["plant"], cfg["haptuator"]
    names = ["h", "v", "m1", "m2", "e", "l"] if x_axis else ["h", "m1", "m2", "e", "l"]
    ix = {n: i for i, n in enumerate(names)}
    nd = len(names)
    M = np.zeros(nd)
    K = np.zeros((nd, nd))
    C = np.zeros((nd, nd))

    def link(a, b, k, c):
        a, b = ix[a], ix[b]
        for (i, j, s) in [(a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)]:
            K[i, j] += s * k
            C[i, j] += s * c

    M[ix["h"]], M[ix["m1"]], M[ix["m2"]] = p["m_h"], p["m_1"], p["m_2"]
    if x_axis:
        M[ix["v"]] = p["m_v"]
        link("h", "v", p["k_v"], p["b_v"])
    link("m1", "m2", p["k_1"], p["b_1"])
    link("m2", "h", p["k_2"], p["b_2"])
    K[ix["h"], ix["h"]] += kf
    C[ix["h"], ix["h"]] += bf
    for br, node in [("motor_branch", "m1"), ("link_branch", "m2")]:
        b = p[br]
        end = "e" if br == "motor_branch" else "l"
        M[ix[end]] = b["mass"]
        link(node, end, b["stiffness"], b["damping"])
    n = 2 * nd + (1 if x_axis else 0)
    A = np.zeros((n, n))
    B = np.zeros((n, 2 if x_axis else 1))
    A[:nd, nd:2 * nd] = np.eye(nd)
    A[nd:2 * nd, :nd] = -K / M[:, None]
    A[nd:2 * nd, nd:2 * nd] = -C / M[:, None]
    B[nd + ix["m1"], 0] = 1.0 / p["m_1"]
    if x_axis:
        wd = 2 * np.pi * h["drive_corner_hz"]
        A[2 * nd, 2 * nd] = -wd
        B[2 * nd, 1] = wd * h["drive_gain_n_per_v"]
        A[nd + ix["h"], 2 * nd] = 1.0 / p["m_h"]
        A[nd + ix["v"], 2 * nd] = -1.0 / p["m_v"]
    Cx1 = np.zeros((1, n))
    Cx1[0, ix["m1"]] = 1.0
    Cacc = A[nd + ix["h"], :].copy()
    return A, B, Cx1, Cacc


def zoh(A, B):
    n, m = A.shape[0], B.shape[1]
    E = np.zeros((n + m, n + m))
    E[:n, :n] = A * DT
    E[:n, n:] = B * DT
    F = linalg.expm(E)
    return F[:n, :n], F[:n, n:]


# ------------------------------------------------- the as-designed chain
pl = cfg["plant"]
A0, B0, _, Cacc0 = axis(True, pl["k_f"], pl["b_f"])


def accel_resp(f, inp):
    s = 2j * np.pi * f
    return Cacc0 @ np.linalg.solve(s * np.eye(A0.shape[0]) - A0, B0[:, inp])


def geomean(ch, lo, hi, ref):
    fr = lo * (hi / lo) ** (np.arange(200) / 199)
    return float(np.exp(np.mean([np.log(abs(accel_resp(f, ch)) / ref(f)) for f in fr])))


gh_num = np.array([250.0, 6.40e5])
gh_den = np.array([1.0, 2135.0, 4.56e6])
g0 = geomean(0, 63.0, 200.0, lambda f: 1.0)
kgh = geomean(1, 100.0, 1000.0,
              lambda f: abs(np.polyval(gh_num, 2j * np.pi * f) / np.polyval(gh_den, 2j * np.pi * f)))
FC = 200.0
bl, al = signal.butter(2, FC, "low", fs=FS)
bh, ah = signal.butter(2, FC, "high", fs=FS)
low_b, low_a = np.polymul(bl, bl), np.polymul(al, al)          # C_L = K_sys/G0_L = 1
wf = 2 * np.pi * 1000.0
zf = 1 / np.sqrt(2)
ch_num = g0 * wf ** 2 * gh_den
ch_den = np.polymul([1.0, 2 * zf * wf, wf ** 2], kgh * gh_num)
fs_pw = np.pi * FC / np.tan(np.pi * FC / FS)                     # prewarped at f_c
chb, cha = signal.bilinear(ch_num, ch_den, fs_pw)
high_b, high_a = np.polymul(np.polymul(bh, bh), chb), np.polymul(np.polymul(ah, ah), cha)
out["chain"] = {"g0_l": g0, "g_h_scale": kgh}

# ------------------------------------------------------- environment, damper
tw, cp = cfg["tweezer"], cfg["coupling"]
KAPPA, KC = tw["stiffness_n_per_m"], tw["contact_stiffness_n_per_m"]
GAMMA0 = 6 * np.pi * tw["viscosity_pa_s"] * tw["radius_m"]
S = cp["position_scale"]


def brenner(s):
    return 1.0 / (1 - 9 / 8 * s + 0.5 * s ** 3 - 57 / 100 * s ** 4 + 0.2 * s ** 5
                  + 7 / 200 * s ** 11 - 1 / 25 * s ** 12)


def environment(state, g, kappa=KAPPA):
    """F = E(z) x1: (b, a) in z^-1."""
    if state == "free":
        k, beta, gam = kappa, 1.0, GAMMA0
    else:
        k, beta, gam = kappa + KC, kappa / (kappa + KC), GAMMA0 * brenner(1 / 1.1)
    tau = gam / k
    c = np.exp(-DT / tau)
    a = tau * (1 - c) / DT
    gk = g * kappa * abs(S)
    return [gk * (beta * (1 - a) - 1), gk * (beta * (a - c) + c)], [1.0, -c]


bv, av = signal.butter(2, cp["velocity_filter_hz"], "low", fs=FS)
damp_b = np.polymul(bv, [FS, -FS])
# Coefficients are in z^-1 (scipy's convention); python-control reads them
# as polynomials in z, which is the same once both have the same length.
damp_a = np.concatenate([av, np.zeros(len(damp_b) - len(av))])


def loop(condition, state, kf, bf, g, kappa=KAPPA, gh=1.0):
    """The open loop L = -(E - b V)(P_f C_low + g_H P_v C_high) as a
    python-control state-space system (discrete, dt), x axis."""
    A, B, Cx1, _ = axis(True, kf, bf)
    Phi, Gam = zoh(A, B)
    # One plant with two inputs (a sum of two single-input copies would
    # carry a second, uncontrolled set of plant modes into the poles).
    plant = control.ss(Phi, Gam, Cx1, np.zeros((1, 2)), DT)
    if condition == "D":
        split = control.append(
            control.ss(control.tf(low_b, low_a, DT)),
            control.ss(control.tf(gh * high_b, high_a, DT)),
        ) * control.ss([], [], [], np.ones((2, 1)), DT)
    else:  # P, full band: the force on the Pantograph, nothing on the Haptuator
        split = control.ss([], [], [], np.array([[1.0], [0.0]]), DT)
    path = plant * split
    eb, ea = environment(state, g, kappa)
    env = control.ss(control.tf(eb, ea, DT))
    if state == "pressed":
        env = env - cp["contact_damping_n_s_per_m"] * control.ss(control.tf(damp_b, damp_a, DT))
    return -1.0 * (env * path)


def rho(L):
    cl = control.feedback(L, 1)
    return float(np.max(np.abs(np.linalg.eigvals(cl.A))))


def critical(stable, x0, cap=np.inf):
    """The gain at which `stable(x)` turns false, by bisection on a log scale
    from the stable x0 (steps of 1.25, then to 0.05 %); None at or above cap."""
    lo, hi = x0, x0
    while stable(hi) and hi < cap:
        lo, hi = hi, hi * 1.25
    if hi >= cap:
        return None
    while hi / lo > 1.0005:
        mid = np.sqrt(lo * hi)
        if stable(mid):
            lo = mid
        else:
            hi = mid
    return float(np.sqrt(lo * hi))


freqs = np.logspace(-2, np.log10(FS / 2 * (1 - 1e-9)), 40000)
cases = []
for condition, state, kf, bf in [
    ("D", "pressed", pl["k_f"], pl["b_f"]),
    ("P", "pressed", pl["k_f"], pl["b_f"]),
    ("D", "pressed", 200.0, 2.0),
    ("D", "free", pl["k_f"], pl["b_f"]),
]:
    L = loop(condition, state, kf, bf, cp["force_scale"])
    resp = L(np.exp(2j * np.pi * freqs / FS))
    frd = control.frd(np.asarray(resp).reshape(-1), 2 * np.pi * freqs)
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(frd)
    # Critical force scale of this case: bisection on the poles.
    crit = critical(lambda x: rho(loop(condition, state, kf, bf, x)) < 1, cp["force_scale"])
    cases.append({
        "condition": condition, "state": state, "hand_stiffness_n_per_m": kf,
        "hand_damping_n_s_per_m": bf,
        "gain_margin_db": float(20 * np.log10(gm)) if np.isfinite(gm) else None,
        "phase_margin_deg": float(pm) if np.isfinite(pm) else None,
        "gain_crossover_hz": float(wgc / (2 * np.pi)) if np.isfinite(wgc) else None,
        "spectral_radius": rho(L),
        "critical_force_scale": crit,
    })
out["loop_cases"] = cases

# ------------------------------------------- 3. an extra loop delay z^-d
# A live loop's block exchange and command lead delay the command by d more
# samples: L_d = z^-d L. Margins from the delayed frequency response
# (python-control `frd`), the closed-loop poles from python-control's own
# state space of z^-d appended to the loop, and the delay at which the
# pressed D loop with the rig file's finger turns unstable (bisection on
# the poles over whole samples).
def delayed(L, d):
    return L * control.ss(control.tf([1.0], [1.0] + [0.0] * d, DT))


delay_cases = []
for condition, state, kf, bf, d in [
    ("D", "pressed", pl["k_f"], pl["b_f"], 30),
    ("D", "pressed", pl["k_f"], pl["b_f"], 100),
    ("P", "pressed", pl["k_f"], pl["b_f"], 60),
    ("D", "pressed", 200.0, 2.0, 30),
    ("D", "free", pl["k_f"], pl["b_f"], 100),
]:
    L = loop(condition, state, kf, bf, cp["force_scale"])
    zs = np.exp(2j * np.pi * freqs / FS)
    resp = np.asarray(L(zs)).reshape(-1) * zs ** (-d)
    frd = control.frd(resp, 2 * np.pi * freqs)
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(frd)
    delay_cases.append({
        "condition": condition, "state": state, "hand_stiffness_n_per_m": kf,
        "hand_damping_n_s_per_m": bf, "delay_samples": d,
        "gain_margin_db": float(20 * np.log10(gm)) if np.isfinite(gm) else None,
        "phase_margin_deg": float(pm) if np.isfinite(pm) else None,
        "gain_crossover_hz": float(wgc / (2 * np.pi)) if np.isfinite(wgc) else None,
        "phase_crossover_hz": float(wpc / (2 * np.pi)) if np.isfinite(wpc) else None,
        "spectral_radius": rho(delayed(L, d)),
    })
out["delay_cases"] = delay_cases

L = loop("D", "pressed", pl["k_f"], pl["b_f"], cp["force_scale"])
lo, hi = 0, 400                       # stable at lo, unstable at hi
assert rho(L) < 1 and rho(delayed(L, hi)) >= 1
while hi - lo > 1:
    mid = (lo + hi) // 2
    if rho(delayed(L, mid)) < 1:
        lo = mid
    else:
        hi = mid
out["critical_delay"] = {
    "condition": "D", "state": "pressed", "hand_stiffness_n_per_m": pl["k_f"],
    "hand_damping_n_s_per_m": pl["b_f"],
    "last_stable_samples": lo, "first_unstable_samples": hi,
}

# ------------------------------------- 4. the high band's rendering gain g_H
high_gain_cases = []
for state, kf, bf, gh in [
    ("pressed", pl["k_f"], pl["b_f"], 10.0),
    ("free", pl["k_f"], pl["b_f"], 10.0),
    ("pressed", 200.0, 2.0, 40.0),
    ("pressed", 800.0, 4.5, 40.0),
]:
    g = cp["force_scale"]
    L = loop("D", state, kf, bf, g, gh=gh)
    resp = L(np.exp(2j * np.pi * freqs / FS))
    frd = control.frd(np.asarray(resp).reshape(-1), 2 * np.pi * freqs)
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(frd)
    crit = critical(lambda x: rho(loop("D", state, kf, bf, g, gh=x)) < 1, gh, cap=1e6)
    high_gain_cases.append({
        "state": state, "hand_stiffness_n_per_m": kf, "hand_damping_n_s_per_m": bf,
        "high_band_gain": gh,
        "gain_margin_db": float(20 * np.log10(gm)) if np.isfinite(gm) else None,
        "phase_margin_deg": float(pm) if np.isfinite(pm) else None,
        "spectral_radius": rho(L),
        "critical_high_band_gain": crit,
    })
out["high_gain_cases"] = high_gain_cases

os.makedirs(os.path.join(HERE, "data"), exist_ok=True)
with open(os.path.join(HERE, "data", "stability_reference.json"), "w") as f:
    json.dump(out, f, indent=1)
print(json.dumps(out, indent=1))
