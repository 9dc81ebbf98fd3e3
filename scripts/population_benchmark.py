#!/usr/bin/env python3
"""Population benchmark of the simulated paper study (docs/PAPER.md).

Runs `kilotouch study simulate --protocol paper` at the paper's design
(8 participants x V/P/D x 10 test trials) for many study seeds and reports,
per seed and pooled:

* how many participants have a lower mean displacement error in D than in P
  (the paper: "consistent across the subjects", Fig. 11d);
* the one-way ANOVA over V/P/D of the per-participant mean displacement
  error (scipy.stats.f_oneway; the paper: p < 0.01) and of the success count
  (the paper: p < 0.005);
* the paired t-test of D against P on the displacement error, and the
  pooled paired effect size d_z = mean(P - D) / SD(P - D) over every
  participant of every seed;
* whether V is worst on all four of the paper's Fig. 12 metrics (fewest
  successes, longest time, largest optical force, largest displacement
  error; means over participants).

Usage (from the repository root, after `cargo build --release`):

    python3 scripts/population_benchmark.py --seeds 1-20 --out /tmp/pop \
        [--kilotouch target/release/kilotouch] [--rig-config FILE] [--json]

Folders already complete under --out are reused (delete them to rerun).
Needs numpy and scipy.

`--check` exits with status 1 unless the pooled figures meet the
population criteria the project holds the model to: D's mean
displacement error below P's in >= 70 % of seeds, pooled d_z (P - D) in
[0.2, 0.6], P vs D not significant in >= 60 % of seeds, the displacement
error's one-way p < 0.01 in >= 50 % of seeds, the successes' p < 0.005 and
V worst on all four metrics in >= 90 % of seeds. CI runs it on seeds 1-4.
"""

import argparse
import csv
import json
import math
import os
import subprocess
import sys

from scipy import stats


def seed_list(text):
    out = []
    for part in text.split(","):
        if "-" in part:
            a, b = part.split("-")
            out.extend(range(int(a), int(b) + 1))
        else:
            out.append(int(part))
    return out


def cells(folder):
    """{participant: {condition: row}} from cells_long.csv."""
    path = os.path.join(folder, "cells_long.csv")
    table = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            table.setdefault(row["participant"], {})[row["condition"]] = row
    return table


def number(text):
    return float(text) if text not in ("", None) else math.nan


def analyse(folder):
    table = cells(folder)
    disp = {c: [] for c in "VPD"}
    succ = {c: [] for c in "VPD"}
    time = {c: [] for c in "VPD"}
    force = {c: [] for c in "VPD"}
    d_better = 0
    pairs = []
    for person in sorted(table):
        row = table[person]
        for c in "VPD":
            disp[c].append(number(row[c]["disp_err_mean_um"]))
            succ[c].append(number(row[c]["n_success"]))
            time[c].append(number(row[c]["time_s"]))
            force[c].append(number(row[c]["force_mean_pn"]))
        p, d = disp["P"][-1], disp["D"][-1]
        if math.isfinite(p) and math.isfinite(d):
            pairs.append((p, d))
            d_better += d < p
    finite = {c: [v for v in disp[c] if math.isfinite(v)] for c in "VPD"}
    anova_disp = stats.f_oneway(*(finite[c] for c in "VPD")).pvalue
    anova_succ = stats.f_oneway(*(succ[c] for c in "VPD")).pvalue
    t = stats.ttest_rel([p for p, _ in pairs], [d for _, d in pairs])
    mean = {c: sum(finite[c]) / len(finite[c]) for c in "VPD"}

    def avg(values):
        v = [x for x in values if math.isfinite(x)]
        return sum(v) / len(v) if v else math.nan

    v_worst = (
        avg(succ["V"]) < min(avg(succ["P"]), avg(succ["D"]))
        and avg(time["V"]) > max(avg(time["P"]), avg(time["D"]))
        and avg(force["V"]) > max(avg(force["P"]), avg(force["D"]))
        and mean["V"] > max(mean["P"], mean["D"])
    )
    return {
        "v_worst_on_all_four": bool(v_worst),
        "p_minus_d": [p - d for p, d in pairs],
        "participants": len(table),
        "d_better_than_p": d_better,
        "pairs": len(pairs),
        "p_oneway_disp_err": anova_disp,
        "p_oneway_success": anova_succ,
        "p_paired_d_vs_p": t.pvalue,
        "t_paired_p_minus_d": t.statistic,
        "mean_disp_err_um": mean,
        "mean_success": {c: sum(succ[c]) / len(succ[c]) for c in "VPD"},
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="1-20")
    ap.add_argument("--participants", type=int, default=8)
    ap.add_argument("--out", required=True)
    ap.add_argument("--kilotouch", default="target/release/kilotouch")
    ap.add_argument("--rig-config")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 unless the population criteria hold (module docs)")
    a = ap.parse_args()
    rows = []
    for s in seed_list(a.seeds):
        folder = os.path.join(a.out, f"seed{s}")
        if not os.path.exists(os.path.join(folder, "cells_long.csv")):
            cmd = [a.kilotouch, "study", "simulate", "--protocol", "paper",
                   "--participants", str(a.participants), "--seed", str(s),
                   "--no-raw", "--out", folder]
            if a.threads:
                cmd += ["--threads", str(a.threads)]
            if a.rig_config:
                cmd += ["--rig-config", a.rig_config]
            print(f"seed {s}: {' '.join(cmd)}", file=sys.stderr)
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        r = analyse(folder)
        r["seed"] = s
        rows.append(r)
    n = len(rows)
    diffs = [x for r in rows for x in r.pop("p_minus_d")]
    m_diff = sum(diffs) / len(diffs)
    sd_diff = math.sqrt(sum((x - m_diff) ** 2 for x in diffs) / (len(diffs) - 1))
    pooled = {
        "seeds_d_mean_below_p": int(sum(
            r["mean_disp_err_um"]["D"] < r["mean_disp_err_um"]["P"] for r in rows)),
        "pooled_d_z": m_diff / sd_diff,
        "seeds_d_vs_p_not_significant": int(sum(r["p_paired_d_vs_p"] >= 0.05 for r in rows)),
        "seeds_v_worst_on_all_four": int(sum(r["v_worst_on_all_four"] for r in rows)),
        "seeds": n,
        "d_better_than_p": sum(r["d_better_than_p"] for r in rows),
        "pairs": sum(r["pairs"] for r in rows),
        "seeds_disp_err_p_below_0_01": int(sum(r["p_oneway_disp_err"] < 0.01 for r in rows)),
        "seeds_success_p_below_0_005": int(sum(r["p_oneway_success"] < 0.005 for r in rows)),
        "seeds_d_vs_p_p_below_0_05": int(sum(
            r["p_paired_d_vs_p"] < 0.05 and r["t_paired_p_minus_d"] > 0 for r in rows)),
        "mean_disp_err_um": {c: sum(r["mean_disp_err_um"][c] for r in rows) / n for c in "VPD"},
        "mean_success": {c: sum(r["mean_success"][c] for r in rows) / n for c in "VPD"},
    }
    failed = check(pooled) if a.check else []
    if a.json:
        print(json.dumps({"per_seed": rows, "pooled": pooled}, indent=1, default=float))
    else:
        table(rows, pooled)
    for f in failed:
        print(f"criterion not met: {f}", file=sys.stderr)
    if failed:
        sys.exit(1)


def check(p):
    """The population criteria (module docs) that `p` does not meet."""
    n = p["seeds"]
    failed = []

    def at_least(key, share, what):
        if p[key] < share * n:
            failed.append(f"{what}: {p[key]} of {n} seeds, want >= {share:.0%}")

    at_least("seeds_d_mean_below_p", 0.7, "D's mean displacement error below P's")
    at_least("seeds_d_vs_p_not_significant", 0.6, "P vs D not significant")
    at_least("seeds_disp_err_p_below_0_01", 0.5, "displacement error one-way p < 0.01")
    at_least("seeds_success_p_below_0_005", 0.9, "successes one-way p < 0.005")
    at_least("seeds_v_worst_on_all_four", 0.9, "V worst on all four metrics")
    if not 0.2 <= p["pooled_d_z"] <= 0.6:
        failed.append(f"pooled d_z (P - D) = {p['pooled_d_z']:.2f}, want 0.2 to 0.6")
    return failed


def table(rows, pooled):
    n = len(rows)
    print("| seed | D < P (participants) | one-way p, disp. error | one-way p, successes | paired p, D vs P | mean disp. error V / P / D (µm) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        m = r["mean_disp_err_um"]
        print(f"| {r['seed']} | {r['d_better_than_p']} of {r['pairs']} | {r['p_oneway_disp_err']:.2g} | "
              f"{r['p_oneway_success']:.2g} | {r['p_paired_d_vs_p']:.2g} | "
              f"{m['V']:.4f} / {m['P']:.4f} / {m['D']:.4f} |")
    p = pooled
    m = p["mean_disp_err_um"]
    print(f"\nPooled over {n} seeds: D < P in {p['d_better_than_p']} of {p['pairs']} participants; "
          f"disp. error one-way p < 0.01 in {p['seeds_disp_err_p_below_0_01']} of {n} seeds; "
          f"successes p < 0.005 in {p['seeds_success_p_below_0_005']} of {n}; "
          f"D better than P at paired p < 0.05 in {p['seeds_d_vs_p_p_below_0_05']} of {n}; "
          f"mean disp. error V/P/D {m['V']:.4f} / {m['P']:.4f} / {m['D']:.4f} µm; "
          f"D's mean below P's in {p['seeds_d_mean_below_p']} of {n} seeds; pooled d_z (P - D) "
          f"{p['pooled_d_z']:.2f}; P vs D not significant (paired p >= 0.05) in "
          f"{p['seeds_d_vs_p_not_significant']} of {n}; V worst on all four Fig. 12 metrics "
          f"in {p['seeds_v_worst_on_all_four']} of {n}.")


if __name__ == "__main__":
    main()
