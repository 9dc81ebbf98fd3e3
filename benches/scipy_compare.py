#!/usr/bin/env python3
"""scipy reference timings for docs/PERFORMANCE.md.

Measures, on this machine, the same work that `kilotouch bench` measures:

* the paper's chain (LR4 crossover at 200 Hz, C_L gain, C_H = F/G_H with
  G_H(s) = (250 s + 6.40e5)/(s^2 + 2135 s + 4.56e6) and F a 2nd-order
  Butterworth low-pass at 1 kHz) as six second-order sections streamed by
  scipy.signal.sosfilt over 1e6 samples (2 low sections + 4 high sections);
* scipy.signal.welch on 1e6 samples, nperseg 4096 (Hann, 50 % overlap,
  density, constant detrend).

Prints one JSON object. Usage: python3 benches/scipy_compare.py
Requires numpy and scipy (pip install numpy scipy); not needed by the tests.
"""
import json
import time

import numpy as np
from scipy import signal

FS = 10_000.0
FC = 200.0
N = 1_000_000


def best_of(fn, reps):
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def paper_chain_sos():
    bl = signal.butter(2, FC, "low", fs=FS, output="sos")
    bh = signal.butter(2, FC, "high", fs=FS, output="sos")
    low = np.vstack([bl, bl])
    wf = 2 * np.pi * 1000.0
    # C_H(s) = F(s)/G_H(s) = wf^2 (s^2+2135 s+4.56e6) / ((s^2+sqrt2 wf s+wf^2)(250 s+6.4e5))
    num = wf**2 * np.array([1.0, 2135.0, 4.56e6])
    den = np.polymul([1.0, np.sqrt(2) * wf, wf**2], [250.0, 6.40e5])
    z, p, k = signal.tf2zpk(num, den)
    zd, pd, kd = signal.bilinear_zpk(z, p, k, FS)
    ch = signal.zpk2sos(zd, pd, kd)
    high = np.vstack([bh, bh, ch])
    return low, high


def main():
    rng = np.random.default_rng(1)
    x = rng.standard_normal(N)
    low, high = paper_chain_sos()
    six = np.vstack([low, high])  # the six sections as one cascade, as the issue times it
    t_six = best_of(lambda: signal.sosfilt(six, x), 5)
    t_split = best_of(lambda: (signal.sosfilt(low, x), signal.sosfilt(high, x)), 5)
    t_welch = best_of(lambda: signal.welch(x, fs=FS, nperseg=4096), 10)
    print(
        json.dumps(
            {
                "scipy_version": __import__("scipy").__version__,
                "numpy_version": np.__version__,
                "sections": int(six.shape[0]),
                "sosfilt_six_sections_ns_per_sample": t_six / N * 1e9,
                "sosfilt_low_plus_high_ns_per_sample": t_split / N * 1e9,
                "welch_1e6_nperseg4096_ms": t_welch * 1e3,
            }
        )
    )


if __name__ == "__main__":
    main()
