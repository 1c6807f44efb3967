"""Issue 17's targets, checked on committed leaderboard rows: one planner against every other.

For each task and report time, the planner's mean uncertainty reduction minus each other
planner's, paired over the episodes both ran [95 % bootstrap interval, the report's
``bootstrap_ci``], and the verdicts the issue asks for:

- v1 frontier (``Grid*Eval-v1``): at least greedy's mean minus 1 point at every time, and no paper
  baseline (random, coverage, MCTS) ahead with an interval excluding 0;
- ``Hotspots30Eval-v2``: ahead of greedy with the interval above 0 at two or more times, ahead of
  every other baseline's mean at every time; the share of the oracle's headroom per time;
- ``Hotspots15Eval-v2``: no baseline ahead with an interval excluding 0;
- a deployment task (``MuJoCo*``): ahead of CMA-ES at 50 and 100 s with the interval above 0.

On the v2 tasks every other planner is a baseline except the oracle (a reference) and other weights
of the checked planner (``attention:checkpoint=B.pt`` when ``attention:checkpoint=A.pt`` is checked,
or the shipped ``attention``): candidates, not baselines; where one of them is ahead, a line of its
own says so, outside the verdict.

    python benchmarks/frontier_check.py baselines/v1/results.csv baselines/v2/results.csv \\
        baselines/deployment_v1/results.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ipp_bench.eval.report import Aggregate, bootstrap_ci
from ipp_bench.eval.results import read_results

PAPER = ("random", "coverage", "mcts")  # the paper's baselines (MCTS at whatever setting the rows hold)
KEY = "uncertainty_reduction_pct"


def load(paths: list[Path]) -> Aggregate:
    """The rows of every file, grouped by task, planner and time (the report's :class:`Aggregate`)."""
    rows = []
    for path in paths:
        try:
            rows += read_results(path)
        except ValueError as err:  # not a leaderboard's results.csv (its columns, say)
            raise ValueError(f"{path}: {err}") from None
    return Aggregate(rows)


def paired(a: dict[int, float], b: dict[int, float]) -> tuple[float, float | None, float | None]:
    seeds = sorted(set(a) & set(b))
    return bootstrap_ci([a[s] - b[s] for s in seeds])


def _fmt(ci) -> str:
    mean, lo, hi = ci
    bold = lo is not None and (lo > 0 or hi < 0)
    text = f"{mean:+.1f} [{lo:+.1f}, {hi:+.1f}]" if lo is not None else f"{mean:+.1f}"
    return f"**{text}**" if bold else text


def check(agg: Aggregate, planner: str) -> tuple[str, dict[str, bool]]:
    lines, verdicts = [], {}
    for task in sorted(agg.tasks):
        if not agg.episodes(task, planner):
            continue
        times = agg.times[task]
        planners = {p: {t: agg.by_seed(task, p, t, KEY) for t in times}
                    for p in agg.planners if agg.episodes(task, p)}
        me = planners[planner]
        others = [p for p in sorted(planners) if p != planner]
        family = planner.split(":")[0]
        siblings = [p for p in others if p.split(":")[0] == family]  # other weights of the same planner
        short = task.split("/")[-1]
        lines += [f"\n### {short}: {planner} minus each planner [95 % paired interval]\n",
                  "| planner | " + " | ".join(f"{t:g} s" for t in times) + " |",
                  "|---|" + "---|" * len(times)]
        diff = {p: {t: paired(me[t], planners[p][t]) for t in times} for p in others}
        for p in others:
            lines.append(f"| {p} | " + " | ".join(_fmt(diff[p][t]) for t in times) + " |")
        # v1: the paper's baselines; H15: every baseline (the oracle is a reference, not a baseline)
        rivals = ([p for p in others if p != "oracle" and p not in siblings] if "Hotspots15" in task
                  else [p for p in others if p.split(":")[0] in PAPER])
        ahead_of_me = [(p, t) for p in rivals for t in times if diff[p][t][2] is not None and diff[p][t][2] < 0]
        if "Eval-v1" in task and not short.startswith("MuJoCo"):
            g = diff.get("greedy", {})
            ok = all(g[t][0] >= -1.0 for t in g) and not ahead_of_me
            verdicts[short] = ok
            why = [f"greedy {g[t][0]:+.1f} at {t:g} s" for t in g if g[t][0] < -1.0]
            why += [f"{p} ahead at {t:g} s" for p, t in ahead_of_me]
            lines.append(f"\nv1 frontier: {'met' if ok else 'not met (' + '; '.join(why) + ')'}")
        elif short.startswith("Hotspots30"):
            g = diff.get("greedy", {})
            above = [t for t in g if g[t][1] is not None and g[t][1] > 0]
            behind = [(p, t) for p in others if p not in ("greedy", "oracle", *siblings) for t in times
                      if diff[p][t][0] <= 0]
            ok = len(above) >= 2 and not behind
            verdicts[short] = ok
            lines.append(f"\nH30: ahead of greedy with the interval above 0 at {', '.join(f'{t:g}' for t in above) or 'no'}"
                         f" s; behind another baseline's mean: {', '.join(f'{p} at {t:g} s' for p, t in behind) or 'none'}"
                         f" -> {'met' if ok else 'not met'}")
            if "oracle" in planners and "greedy" in planners:
                share = []
                for t in times:
                    seeds = sorted(set(me[t]) & set(planners["oracle"][t]) & set(planners["greedy"][t]))
                    room = sum(planners["oracle"][t][s] - planners["greedy"][t][s] for s in seeds)
                    gain = sum(me[t][s] - planners["greedy"][t][s] for s in seeds)
                    share.append(f"{100 * gain / room:.0f} %" if room else "n/a")
                lines.append(f"share of the oracle's headroom (mean over mean): {' / '.join(share)}")
        elif short.startswith("Hotspots15"):
            ok = not ahead_of_me
            verdicts[short] = ok
            lines.append(f"\nH15: {'met' if ok else 'not met (' + '; '.join(f'{p} at {t:g} s' for p, t in ahead_of_me) + ')'}")
        elif short.startswith("MuJoCo"):
            cm = next((p for p in others if p.startswith("cmaes")), None)
            if cm is not None:
                ok = all(t in diff[cm] and diff[cm][t][1] is not None and diff[cm][t][1] > 0 for t in (50.0, 100.0))
                verdicts[short] = ok
                lines.append(f"\ndeployment: ahead of {cm} at 50 and 100 s with the interval above 0: "
                             f"{'met' if ok else 'not met'}")
        if siblings and short.startswith(("Hotspots30", "Hotspots15")):
            key = 0 if short.startswith("Hotspots30") else 2  # H30: a mean ahead; H15: an interval below 0
            sib = [(p, t) for p in siblings for t in times
                   if diff[p][t][key] is not None and (diff[p][t][key] <= 0 if key == 0 else diff[p][t][key] < 0)]
            lines.append(f"other weights of {family} level or ahead (candidates, not baselines; not in the verdict): "
                         + (", ".join(f"{p} at {t:g} s" for p, t in sib) or "none"))
    return "\n".join(lines), verdicts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", type=Path, help="leaderboard results.csv files")
    ap.add_argument("--planner", default="attention", help="the planner checked (default: attention)")
    args = ap.parse_args(argv)
    missing = [str(p) for p in args.results if not p.is_file()]
    if missing:
        ap.error(f"not found: {', '.join(missing)}")
    try:
        agg = load(args.results)
    except ValueError as err:
        ap.error(str(err))
    text, verdicts = check(agg, args.planner)
    if not text:
        ap.error(f"no task in these files has rows of --planner {args.planner!r}")
    print(text)
    if verdicts:  # tasks without one of the targets (e.g. ten hectares) get the table only
        print("\n" + ", ".join(f"{t}: {'met' if ok else 'not met'}" for t, ok in verdicts.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
