"""One report from the rows of several leaderboard folders: a new planner next to committed baselines.

A new attention checkpoint needs its rows next to every baseline's on the same episodes, and MCTS-24
alone takes more than an hour of the 2 cores on the v2 tasks. The leaderboard's episodes are fixed
by (task, seed) and its rows reproduce bit for bit, so the rows of the committed folders are those a
rerun would give: this script merges ``results.csv`` files (the later file wins a duplicated
(task, planner, seed, time) row, after checking that both agree), optionally renames planners, and
writes the leaderboard report (tables, paired intervals, plots) of the union.

    python benchmarks/combine_rows.py --out /tmp/combined --planners random coverage greedy \\
        mcts:simulations=24 cmaes oracle attention \\
        --rows baselines/v1/results.csv baselines/v2/results.csv runs/lb/results.csv \\
        --rename attention:checkpoint=runs/x/export.pt=attention-new

Only the rows of the listed planners (after renaming) and of episodes every one of them has are kept.
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

from ipp_bench.eval.report import write_report

KEY = ("task", "planner", "seed", "time_s")
METRICS = ("trace_roi", "rmse_roi", "uncertainty_reduction_pct", "rmse_reduction_pct", "decisions")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", nargs="+", required=True, help="results.csv files, merged in this order")
    parser.add_argument("--planners", nargs="+", required=True, help="planner names to keep (after --rename)")
    parser.add_argument("--rename", nargs="*", default=[], metavar="OLD=NEW",
                        help="rename a planner (the text after the last '=' is the new name)")
    parser.add_argument("--reference", default="greedy")
    parser.add_argument("--out", required=True)
    args = parser.parse_args(argv)
    renames = dict(r.rsplit("=", 1) for r in args.rename)
    rows: dict[tuple, dict] = {}
    fieldnames: list[str] = []
    for path in args.rows:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            fieldnames = fieldnames or list(reader.fieldnames or [])
            for r in reader:
                r["planner"] = renames.get(r["planner"], r["planner"])
                if r["planner"] not in args.planners:
                    continue
                k = tuple(r[c] for c in KEY)
                old = rows.get(k)
                if old is not None and any(not math.isclose(float(old[m]), float(r[m]), rel_tol=1e-12)
                                           for m in METRICS):
                    raise SystemExit(f"combine_rows: {path}: row {k} disagrees with an earlier file's")
                rows[k] = r
    episodes: dict[tuple, set] = {}
    for task, planner, seed, _ in rows:
        episodes.setdefault((task, seed), set()).add(planner)
    keep = {ep for ep, ps in episodes.items() if ps >= set(args.planners)}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    merged = out / "results.csv"
    with merged.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fieldnames)
        w.writeheader()
        w.writerows(r for k, r in sorted(rows.items()) if (k[0], k[2]) in keep)
    n_tasks = len({t for t, _ in keep})
    print(f"{len(keep)} episodes on {n_tasks} tasks with all of {args.planners}")
    cmd = "python benchmarks/combine_rows.py " + " ".join(
        ["--rows", *args.rows, "--planners", *args.planners]
        + (["--rename", *args.rename] if args.rename else []) + ["--out", args.out])
    for p in write_report(merged, out, planners=args.planners, command=cmd, reference=args.reference):
        print(f"wrote {p}")


if __name__ == "__main__":
    main()
