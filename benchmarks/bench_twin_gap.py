"""The deployment gap: the graph twin (``Weed15Twin-v1``) against MuJoCo (``MuJoCoWeed15-v1``), per planner.

    python benchmarks/bench_twin_gap.py --mujoco baselines/deployment_v1/results.csv \\
        --twin baselines/deployment_v1/twin/results.csv --out baselines/deployment_v1/gap.md

Both result files come from ``ipp-bench leaderboard`` with the same seed and episode count, so
each episode seed plays the same field in both. Printed and written: per planner and report time,
the mean ROI uncertainty reduction in each and the gap (twin - MuJoCo, target |gap| <= 3 points at
100 / 150 / 200 s); then every pair of planners whose paired 95 % bootstrap interval over MuJoCo's
episodes excludes 0, and whether the twin's paired mean difference has the same sign.
"""

from __future__ import annotations

import argparse
import csv
import itertools
from collections import defaultdict

import numpy as np

from ipp_bench.eval.aggregate import bootstrap_ci

METRIC = "uncertainty_reduction_pct"


def _read(path: str) -> dict[tuple[str, float], dict[int, float]]:
    out: dict[tuple[str, float], dict[int, float]] = defaultdict(dict)
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            out[(r["planner"], float(r["time_s"]))][int(r["seed"])] = float(r[METRIC])
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--mujoco", required=True)
    p.add_argument("--twin", required=True)
    p.add_argument("--times", type=float, nargs="+", default=[100.0, 150.0, 200.0])
    p.add_argument("--tolerance", type=float, default=3.0, help="[points] allowed |twin - MuJoCo|")
    p.add_argument("--out", default=None, help="markdown file to write")
    args = p.parse_args(argv)
    mj, tw = _read(args.mujoco), _read(args.twin)
    planners = sorted({k[0] for k in mj} & {k[0] for k in tw})
    lines = ["# Deployment gap: graph twin against MuJoCo", "",
             "Made by `python benchmarks/bench_twin_gap.py --mujoco " + args.mujoco + " --twin " + args.twin
             + (f" --out {args.out}`" if args.out else "`") + "; ROI uncertainty reduction [%], mean over the "
             "episodes both files share (same seeds, same fields).", "",
             "| planner | " + " | ".join(f"{t:g} s MuJoCo / twin / gap" for t in args.times) + " |",
             "|---|" + "---|" * len(args.times)]
    worst = 0.0
    for name in planners:
        cells = []
        for t in args.times:
            seeds = sorted(set(mj[(name, t)]) & set(tw[(name, t)]))
            a = np.mean([mj[(name, t)][s] for s in seeds])
            b = np.mean([tw[(name, t)][s] for s in seeds])
            worst = max(worst, abs(b - a))
            flag = "" if abs(b - a) <= args.tolerance else " **"
            cells.append(f"{a:.1f} / {b:.1f} / {b - a:+.1f}{flag}")
        lines.append(f"| {name} (n={len(seeds)}) | " + " | ".join(cells) + " |")
    lines += ["", f"Largest |gap|: {worst:.1f} points (target <= {args.tolerance:g}; ** marks a miss).", "",
              "Orderings: pairs whose paired 95 % bootstrap interval over MuJoCo's episodes excludes 0.", "",
              "| time | pair (a - b) | MuJoCo mean [95 % interval] | twin mean | same order |", "|---|---|---|---|---|"]
    agree = total = 0
    for t in args.times:
        for a, b in itertools.combinations(planners, 2):
            seeds = sorted(set(mj[(a, t)]) & set(mj[(b, t)]) & set(tw[(a, t)]) & set(tw[(b, t)]))
            d = [mj[(a, t)][s] - mj[(b, t)][s] for s in seeds]
            mean, lo, hi = bootstrap_ci(d)
            if lo <= 0.0 <= hi:
                continue
            dt = float(np.mean([tw[(a, t)][s] - tw[(b, t)][s] for s in seeds]))
            same = np.sign(dt) == np.sign(mean)
            agree += int(same)
            total += 1
            lines.append(f"| {t:g} s | {a} - {b} | {mean:+.1f} [{lo:+.1f}, {hi:+.1f}] | {dt:+.1f} | "
                         f"{'yes' if same else '**no**'} |")
    lines += ["", f"The twin orders {agree} of the {total} separated pairs as MuJoCo does."]
    text = "\n".join(lines) + "\n"
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
