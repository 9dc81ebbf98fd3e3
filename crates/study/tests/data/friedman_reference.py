#!/usr/bin/env python3
"""Generate friedman_reference.json: scipy.stats.friedmanchisquare on
subjects x conditions matrices that the Rust test regenerates from the same
integer generator (crates/study/tests/friedman_scipy.rs), so only the seeds,
shapes and results are stored.

Generator (shared with the Rust test): xorshift64* with state s (nonzero):
    s ^= s >> 12; s ^= s << 25 (mod 2^64); s ^= s >> 27;
    out = (s * 0x2545F4914F6CDD1D) mod 2^64
Cell (i, j) of case (seed, n, k, levels, scale): for i in subjects, for j in
conditions, u = out >> 11 (53 bits); value = (u mod levels) * scale + j * shift
where shift = 0 for most cases (no effect) and levels small gives many ties.

Regenerate with `python3 crates/study/tests/data/friedman_reference.py`
(numpy + scipy). Recorded with the scipy version stored in the JSON.
"""
import json
import os

import numpy as np
import scipy
from scipy import stats

MASK = (1 << 64) - 1


def matrix(seed, n, k, levels, scale, shift):
    s = seed & MASK
    out = np.empty((n, k))
    for i in range(n):
        for j in range(k):
            s ^= s >> 12
            s = (s ^ (s << 25)) & MASK
            s ^= s >> 27
            r = (s * 0x2545F4914F6CDD1D) & MASK
            u = r >> 11
            out[i, j] = (u % levels) * scale + j * shift
    return out


CASES = [
    # seed, n, k, levels, scale, shift
    (1, 5, 3, 1000, 0.25, 0.0),
    (2, 12, 4, 5, 1.0, 0.0),          # many ties
    (3, 30, 3, 3, 1.5, 0.0),          # heavy ties
    (4, 8, 6, 100, 0.01, 0.0),
    (5, 100, 3, 10, 1.0, 1.0),        # a condition effect with ties
    (6, 250, 3, 7, 2.0, 0.0),
    (7, 1000, 3, 1 << 40, 1e-3, 0.0),  # continuous-like, no ties
    (8, 10000, 3, 20, 1.0, 0.05),      # the benchmark's size, ties
    (9, 2, 5, 4, 1.0, 0.0),
    (10, 40, 3, 2, 1e300, 0.0),       # huge finite values, binary ties
]

cases = []
for seed, n, k, levels, scale, shift in CASES:
    m = matrix(seed, n, k, levels, scale, shift)
    res = stats.friedmanchisquare(*[m[:, j] for j in range(k)])
    cases.append({
        "seed": seed, "n": n, "k": k, "levels": levels, "scale": scale, "shift": shift,
        "first_row": m[0].tolist(),
        "chi2": float(res.statistic), "p": float(res.pvalue),
    })

doc = {"scipy_version": scipy.__version__, "numpy_version": np.__version__, "cases": cases}
path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "friedman_reference.json")
with open(path, "w") as f:
    json.dump(doc, f, indent=1)
    f.write("\n")
print(f"wrote {path}")
