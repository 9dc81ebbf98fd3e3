#!/usr/bin/env python3
"""Generate power_reference.json: independent reference values for
crates/study/tests/power.rs.

* Power of the two-sided paired (one-sample) t-test from the noncentral t
  distribution (scipy.stats.nct): with n pairs, standardised effect
  dz = mean/sd of the differences, df = n - 1, nc = dz * sqrt(n),
  t_crit = t.ppf(1 - alpha/2, df):
      power = P(T > t_crit) + P(T < -t_crit),  T ~ nct(df, nc).
* Clopper-Pearson intervals from scipy.stats.beta.ppf.

Regenerate with `python3 crates/study/tests/data/power_reference.py`
(numpy + scipy needed; the Rust tests need neither).
"""
import json
import os

import scipy
from scipy import stats

out = {"scipy_version": scipy.__version__, "alpha": 0.05}
ns = [4, 6, 8, 12, 16, 24, 32]
curves = []
for dz in [0.5, 0.8]:
    powers = []
    for n in ns:
        df = n - 1
        tc = stats.t.ppf(1 - out["alpha"] / 2, df)
        nc = dz * n ** 0.5
        p = stats.nct.sf(tc, df, nc) + stats.nct.cdf(-tc, df, nc)
        powers.append(float(p))
    curves.append({"dz": dz, "n": ns, "power": powers})
out["paired_t_power"] = curves

cp = []
for x, n in [(0, 10), (3, 10), (10, 10), (37, 200), (1600, 2000), (1, 2000)]:
    lo = 0.0 if x == 0 else float(stats.beta.ppf(0.025, x, n - x + 1))
    hi = 1.0 if x == n else float(stats.beta.ppf(0.975, x + 1, n - x))
    cp.append({"x": x, "n": n, "lo": lo, "hi": hi})
out["clopper_pearson_95"] = cp

path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "power_reference.json")
with open(path, "w") as f:
    json.dump(out, f, indent=1)
    f.write("\n")
print(path)
