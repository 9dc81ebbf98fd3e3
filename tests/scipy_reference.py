#!/usr/bin/env python3
"""Generate tests/data/scipy_reference.json: independent reference values from
scipy.signal for tests/scipy_crosscheck.rs.

Regenerate with `python3 tests/scipy_reference.py` (numpy + scipy needed;
the tests themselves need neither). Recorded with scipy 1.17.1.
"""
import json
import os

import numpy as np
import scipy
from scipy import signal

FS = 10_000.0
out = {"scipy_version": scipy.__version__}

# 1. Butterworth designs (scipy prewarps at the cut-off when fs is given).
freqs = [0.1, 0.5, 1.0, 2.0, 10.0, 63.0957, 200.0, 1000.0, 4000.0, 4500.0]
designs = []
for order, fc, kind in [(2, 200.0, "low"), (4, 200.0, "high"), (8, 1.0, "low"), (3, 4500.0, "low"), (5, 1000.0, "high")]:
    z, p, k = signal.butter(order, fc, kind, fs=FS, output="zpk")
    _, h = signal.freqz_zpk(z, p, k, worN=freqs, fs=FS)
    designs.append({"order": order, "fc": fc, "kind": kind, "f": freqs, "re": h.real.tolist(), "im": h.imag.tolist()})
out["butter"] = designs

# 2. LR4 crossover at 200 Hz: low = butter2 low squared, high = butter2 high squared.
zl, pl, kl = signal.butter(2, 200.0, "low", fs=FS, output="zpk")
zh, ph, kh = signal.butter(2, 200.0, "high", fs=FS, output="zpk")
_, hl = signal.freqz_zpk(np.r_[zl, zl], np.r_[pl, pl], kl * kl, worN=freqs, fs=FS)
_, hh = signal.freqz_zpk(np.r_[zh, zh], np.r_[ph, ph], kh * kh, worN=freqs, fs=FS)
out["lr4_200"] = {"f": freqs, "low_re": hl.real.tolist(), "low_im": hl.imag.tolist(),
                  "high_re": hh.real.tolist(), "high_im": hh.imag.tolist()}

# 3. C_H = F/G_H (paper eq. 2, F = 2nd-order Butterworth at 1 kHz), bilinear without prewarp.
wf = 2 * np.pi * 1000.0
num = wf**2 * np.array([1.0, 2135.0, 4.56e6])
den = np.polymul([1.0, np.sqrt(2) * wf, wf**2], [250.0, 6.40e5])
z, p, k = signal.tf2zpk(num, den)
zd, pd, kd = signal.bilinear_zpk(z, p, k, FS)
_, hc = signal.freqz_zpk(zd, pd, kd, worN=freqs, fs=FS)
out["c_h_bilinear"] = {"num": num.tolist(), "den": den.tolist(), "f": freqs,
                       "re": hc.real.tolist(), "im": hc.imag.tolist()}

# 4. Welch on a deterministic signal (two tones, a trend, nperseg 64, odd length).
n = np.arange(1001)
x = np.sin(2 * np.pi * 0.1234 * n) + 0.5 * np.cos(2 * np.pi * 0.31 * n + 0.3) + 1e-3 * n + 0.25
y = 0.8 * np.roll(x, 3) + 0.1 * np.sin(2 * np.pi * 0.05 * n)
f, pxx = signal.welch(x, fs=FS, nperseg=64)
_, pxy = signal.csd(x, y, fs=FS, nperseg=64)
_, cxy = signal.coherence(x, y, fs=FS, nperseg=64)
out["welch"] = {"x": x.tolist(), "y": y.tolist(), "nperseg": 64, "f": f.tolist(), "pxx": pxx.tolist(),
                "pxy_re": pxy.real.tolist(), "pxy_im": pxy.imag.tolist(), "coh": cxy.tolist()}

# 5. MLS order 10 (scipy taps) first period.
out["mls10"] = signal.max_len_seq(10)[0].astype(int).tolist()

path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "scipy_reference.json")
with open(path, "w") as fh:
    json.dump(out, fh, indent=None, separators=(",", ":"))
print("wrote", path)
