"""Per-decision wall time of every planner on the benchmark tasks.

Prints figures, never pass/fail. Run: ``python benchmarks/bench_planners.py [--episodes 2]
[--planners random coverage greedy mcts cmaes attention] [--tasks ...]``. All planners are timed
in the same run, so their ratios are comparable even on a noisy machine (the load average is printed
first). ``benchmarks/bench_search.py`` times MCTS and CMA-ES against their reference evaluations.
"""

from __future__ import annotations

import argparse
import os
import platform

import numpy as np

from ipp_bench.core._threads import limit_blas_threads
from ipp_bench.envs import tagged
from ipp_bench.eval.runner import run_episode
from ipp_bench.planners import is_team_planner, planner_names


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--tasks", nargs="+", default=tagged("benchmark"))
    parser.add_argument("--planners", nargs="+", default=[p for p in planner_names() if not is_team_planner(p)])
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    limit_blas_threads()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    print(f"{'task':<26} {'planner':<34} {'decisions':>9} {'median ms':>10} {'mean ms':>9} {'max ms':>9}")
    for task in args.tasks:
        for spec in args.planners:
            try:
                results = [run_episode(task, spec, args.seed + i) for i in range(args.episodes)]
            except ImportError as err:  # an optional extra is missing: say so, keep going
                print(f"{task:<26} {spec:<34} skipped: {err}")
                continue
            times = np.concatenate([r.decision_times_s for r in results]) * 1e3
            print(f"{task:<26} {spec:<34} {len(times):>9} {np.median(times):>10.3f} {times.mean():>9.3f} "
                  f"{times.max():>9.3f}", flush=True)


if __name__ == "__main__":
    main()
