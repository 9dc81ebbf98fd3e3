#!/usr/bin/env python3
"""Generate crates/study/tests/data/pingouin_reference.json: reference values
for crates/study/tests/stats_pingouin.rs (post-hoc tests, descriptives,
effect-size intervals) and crates/app/tests/stats_cli.rs (a simulated
study's trials.csv under the row rule).

Tools: pingouin `pairwise_tests(..., padjust="holm")` (paired t, Holm),
scipy.stats.wilcoxon (defaults), pingouin.multicomp (Holm on the Wilcoxon
p), pandas quantiles (describe), scipy.stats.ncf (η² interval by inverting
the noncentral F), scipy.stats.t (mean-difference interval), pingouin
rm_anova (listwise deletion of incomplete participants).

Regenerate with `python3 crates/study/tests/pingouin_reference.py` from the
repository root (pip install pingouin). The Rust tests need none of this.
"""
import json
import os

import numpy as np
import pandas as pd
import pingouin as pg
import scipy
from scipy import stats
from scipy.optimize import brentq

HERE = os.path.dirname(os.path.abspath(__file__))
APP_DATA = os.path.join(HERE, "..", "..", "app", "tests", "data")


def matrices():
    """Named subject x condition matrices (lists of rows)."""
    rng = np.random.default_rng(20240611)
    out = {}
    # The 5 x 3 repeated-measures example of docs/REFERENCE-VALUES.md.
    a = [2.2, 3.1, 4.3, 4.1, 7.2]
    b = [1.1, 2.5, 4.1, 5.2, 6.4]
    c = [8.2, 4.5, 3.4, 6.2, 7.2]
    out["rm5x3"] = {"conditions": ["A", "B", "C"], "values": np.column_stack([a, b, c]).tolist()}
    # 12 participants x 3 conditions, continuous (exact Wilcoxon).
    base = rng.normal(10.0, 2.0, size=(12, 1))
    eff = np.array([0.0, 0.8, 1.5])
    x = base + eff + rng.normal(0.0, 1.0, size=(12, 3))
    out["n12k3"] = {"conditions": ["V", "P", "D"], "values": np.round(x, 6).tolist()}
    # 20 x 4 with rounded values: ties among |d| (normal approximation, n > 13).
    base = rng.normal(5.0, 1.0, size=(20, 1))
    x = np.round(base + np.array([0.0, 0.3, 0.1, 0.6]) + rng.normal(0.0, 0.7, size=(20, 4)), 1)
    out["n20k4_ties"] = {"conditions": ["A", "B", "C", "D"], "values": x.tolist()}
    # 8 x 3 with a pair whose differences are constant (t undefined) and
    # ties with a zero difference (exact conditional Wilcoxon, n <= 13).
    v = rng.normal(3.0, 1.0, size=8)
    p = v + 0.5
    d = np.round(v + rng.normal(0.2, 0.4, size=8), 1)
    d[2] = v[2]
    out["n8_constant_pair"] = {"conditions": ["V", "P", "D"], "values": np.column_stack([v, p, d]).tolist()}
    return out


def long_frame(m):
    rows = []
    for i, row in enumerate(m["values"]):
        for c, val in zip(m["conditions"], row):
            rows.append({"s": f"s{i}", "c": c, "y": val})
    df = pd.DataFrame(rows)
    df["c"] = pd.Categorical(df["c"], categories=m["conditions"], ordered=True)
    return df


def pairwise(m):
    df = long_frame(m)
    conds = m["conditions"]
    values = np.array(m["values"])
    rows = []
    for i in range(len(conds)):
        for j in range(i + 1, len(conds)):
            dd = values[:, i] - values[:, j]
            n = len(dd)
            row = {"a": conds[i], "b": conds[j], "mean_diff": float(dd.mean())}
            sd = dd.std(ddof=1)
            if sd > 0:
                tt = stats.ttest_rel(values[:, i], values[:, j])
                q = stats.t.ppf(0.975, n - 1)
                half = q * sd / np.sqrt(n)
                row.update({"t": float(tt.statistic), "p": float(tt.pvalue),
                            "dz": float(dd.mean() / sd),
                            "mean_diff_ci": [float(dd.mean() - half), float(dd.mean() + half)]})
            else:
                row.update({"t": None, "p": None, "dz": None, "mean_diff_ci": None})
            if np.any(dd != 0):
                w = stats.wilcoxon(values[:, i], values[:, j])
                row.update({"wilcoxon_w": float(w.statistic), "wilcoxon_p": float(w.pvalue)})
            else:
                row.update({"wilcoxon_w": None, "wilcoxon_p": None})
            rows.append(row)
    # pingouin's post-hoc table (t, p-corr) where every pair is defined.
    if all(r["t"] is not None for r in rows):
        pt = pg.pairwise_tests(data=df, dv="y", within="c", subject="s", padjust="holm")
        for r, (_, prow) in zip(rows, pt.iterrows()):
            assert (prow["A"], prow["B"]) == (r["a"], r["b"]), (prow["A"], prow["B"])
            # pingouin's T is A - B as here.
            assert abs(prow["T"] - r["t"]) < 1e-9
            r["p_holm"] = float(prow["p_corr"] if "p_corr" in prow else prow["p-corr"])
            r["pingouin_t"] = float(prow["T"])
            r["pingouin_p_unc"] = float(prow["p_unc"] if "p_unc" in prow else prow["p-unc"])
    else:
        # Holm over the defined pairs (pingouin.multicomp ignores NaN).
        ps = np.array([np.nan if r["p"] is None else r["p"] for r in rows])
        _, adj = pg.multicomp(ps, method="holm")
        for r, a in zip(rows, adj):
            r["p_holm"] = None if np.isnan(a) else float(a)
    pw = np.array([np.nan if r["wilcoxon_p"] is None else r["wilcoxon_p"] for r in rows])
    _, adjw = pg.multicomp(pw, method="holm")
    for r, a in zip(rows, adjw):
        r["wilcoxon_p_holm"] = None if np.isnan(a) else float(a)
    return rows


def describe(m):
    values = np.array(m["values"])
    out = []
    for j, c in enumerate(m["conditions"]):
        s = pd.Series(values[:, j])
        q1, med, q3 = s.quantile([0.25, 0.5, 0.75])
        out.append({"condition": c, "n": int(s.count()), "mean": float(s.mean()),
                    "sd": float(s.std(ddof=1)), "median": float(med),
                    "q1": float(q1), "q3": float(q3), "iqr": float(q3 - q1)})
    return out


def eta2_ci(f, df1, df2, level=0.95):
    """Two-sided noncentral-F interval of partial eta^2 (Steiger 2004)."""
    alpha = 1.0 - level

    def lam(target):
        g = lambda l: stats.ncf.cdf(f, df1, df2, l) - target
        if stats.f.cdf(f, df1, df2) <= target:
            return 0.0
        hi = max(f * df1, 1.0)
        while g(hi) > 0:
            hi *= 2.0
        return brentq(g, 0.0, hi, xtol=1e-14, rtol=1e-14)

    lo, hi = lam(1 - alpha / 2), lam(alpha / 2)
    conv = lambda l: l / (l + df1 + df2 + 1.0)
    return [conv(lo), conv(hi)]


def rm(m):
    df = long_frame(m)
    a = pg.rm_anova(data=df, dv="y", within="c", subject="s", detailed=True)
    f = float(a["F"][0])
    df1, df2 = float(a["DF"][0]), float(a["DF"][1])
    return {"F": f, "df1": df1, "df2": df2, "np2": float(a["np2"][0]) if "np2" in a else None,
            "np2_ci": eta2_ci(f, df1, df2)}


def study_reference():
    """The simulated study in crates/app/tests/data/study_small: pingouin
    rm_anova on the cell means of the successful test trials, with and
    without one participant's V test trials (listwise deletion)."""
    path = os.path.join(APP_DATA, "study_small", "trials.csv")
    if not os.path.exists(path):
        return None
    t = pd.read_csv(path, comment="#")
    out = {"rows_total": int(len(t))}
    used = t[(t["phase"] == "test") & (t["success"] == 1)].dropna(subset=["time_s"])
    out["rows_used"] = int(len(used))
    out["rows_excluded_practice"] = int((t["phase"] == "practice").sum())
    out["rows_excluded_rejected"] = int(((t["phase"] == "test") & (t["success"] == 0)).sum())
    a = pg.rm_anova(data=used, dv="time_s", within="condition", subject="participant")
    out["F"] = float(a["F"][0])
    out["p"] = float(a["p_unc"][0] if "p_unc" in a else a["p-unc"][0])
    # Every row averaged, as the command did before the row rule.
    a_all = pg.rm_anova(data=t, dv="time_s", within="condition", subject="participant")
    out["F_all_rows"] = float(a_all["F"][0])
    cells = used.groupby(["participant", "condition"]).size().unstack()
    incomplete = sorted(cells.index[cells.isna().any(axis=1)])
    # Participants without a successful test trial in some condition:
    # pingouin drops them (listwise deletion).
    out["participants_dropped"] = [str(x) for x in incomplete]
    out["participants_used"] = int(len(cells.index) - len(incomplete))
    fr = pg.friedman(data=used, dv="time_s", within="condition", subject="participant")
    out["friedman_q"] = float(fr["Q"].iloc[0])
    # One participant without successful V test trials: pingouin drops it.
    first = sorted(p for p in t["participant"].unique() if p not in incomplete)[0]
    drop = (used["participant"] == first) & (used["condition"] == "V")
    partial = used[~drop]
    b = pg.rm_anova(data=partial, dv="time_s", within="condition", subject="participant")
    out["dropped_participant"] = str(first)
    out["participants_dropped_then"] = sorted([str(x) for x in incomplete] + [str(first)])
    out["F_dropped"] = float(b["F"][0])
    out["p_dropped"] = float(b["p_unc"][0] if "p_unc" in b else b["p-unc"][0])
    pt = pg.pairwise_tests(data=partial.groupby(["participant", "condition"], as_index=False)["time_s"].mean(),
                           dv="time_s", within="condition", subject="participant", padjust="holm")
    out["pairs_dropped"] = [{"a": r["A"], "b": r["B"], "t": float(r["T"]),
                             "p_holm": float(r["p_corr"] if "p_corr" in r else r["p-corr"])}
                            for _, r in pt.iterrows()]
    return out


def main():
    out = {"pingouin_version": pg.__version__, "scipy_version": scipy.__version__,
           "pandas_version": pd.__version__, "cases": {}}
    for name, m in matrices().items():
        case = {"matrix": m, "pairs": pairwise(m), "describe": describe(m)}
        try:
            case["rm"] = rm(m)
        except Exception as e:  # noqa: BLE001 - a degenerate case has no ANOVA
            case["rm"] = None
        out["cases"][name] = case
    study = study_reference()
    if study is not None:
        out["study_small"] = study
    with open(os.path.join(HERE, "data", "pingouin_reference.json"), "w") as f:
        json.dump(out, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
