"""Design probe of benchmark v2: threshold, belief ROI width and prior of a hotspot task, measured.

For a v2 task (or a v1 task with ``--env field=weed_patches``), each setting of ``mu_th`` and
``beta`` (and, with ``--prior half``, the prior refitted with its mean fixed at the paper's 0.5) is
flown by greedy, coverage and the ``oracle`` reference on the same episodes, and the script prints
per planner the mean ROI uncertainty and RMSE reduction at the report times and each planner's
paired difference to greedy (mean and the standard deviation over episodes). It is how the v2
settings were chosen (``benchmarks/RESULTS.md``, "Benchmark v2"); the probe seeds (default 9000)
are not the leaderboard's (0).

    python benchmarks/bench_hotspots.py --task ipp_bench/Hotspots30Eval-v2 --episodes 6 \\
        --settings 0.2,2 0.2,3 0.3,2 0.3,3
    python benchmarks/bench_hotspots.py --task ipp_bench/Hotspots30Eval-v2 --episodes 6 --prior half --settings 0.3,3
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ipp_bench import gp_fit
from ipp_bench.envs import make_env, task_config
from ipp_bench.eval.plan import episode_seeds
from ipp_bench.eval.runner import run_episode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--task", default="ipp_bench/Hotspots30Eval-v2")
    ap.add_argument("--episodes", type=int, default=6)
    ap.add_argument("--seed", type=int, default=9000, help="base seed of the probe episodes")
    ap.add_argument("--planners", nargs="+", default=["greedy", "coverage", "oracle"])
    ap.add_argument("--settings", nargs="+", default=["0.3,3"], help="mu_th,beta pairs")
    ap.add_argument("--prior", choices=("task", "half"), default="task",
                    help="task: the task's prior; half: refitted with the mean fixed at 0.5 (the paper's)")
    args = ap.parse_args()
    prior: dict[str, float] = {}
    if args.prior == "half":
        fit = gp_fit.fit_prior(task_config(args.task).replace(prior_mean=0.5))
        prior = dict(length_scale=fit.length_scale, signal_variance=fit.signal_variance, nugget=fit.nugget,
                     prior_mean=0.5)
        print(f"prior refitted with mean 0.5: length scale {fit.length_scale:.3g} m, variance "
              f"{fit.signal_variance:.3g}, nugget {fit.nugget:.3g}")
    seeds = episode_seeds(args.seed, args.episodes)
    for setting in args.settings:
        mu_th, beta = (float(v) for v in setting.split(","))
        overrides = dict(prior, mu_th=mu_th, beta=beta)
        env = make_env(args.task, **overrides)
        t0 = time.perf_counter()
        runs = {}
        for planner in args.planners:
            reports = [run_episode(args.task, planner, s, env=env).report for s in seeds]
            runs[planner] = {key: np.array([[row[key] for row in r] for r in reports])
                             for key in ("uncertainty_reduction_pct", "rmse_reduction_pct")}
        print(f"{args.task} mu_th={mu_th:g} beta={beta:g} prior={args.prior}, {args.episodes} episodes "
              f"({time.perf_counter() - t0:.0f} s); ROI uncertainty / RMSE reduction [%] at the report times")
        for planner, r in runs.items():
            u = " / ".join(f"{x:5.1f}" for x in r["uncertainty_reduction_pct"].mean(0))
            e = " / ".join(f"{x:6.1f}" for x in r["rmse_reduction_pct"].mean(0))
            print(f"  {planner:10s} uncertainty {u}   RMSE {e}")
        if "greedy" in runs:
            g = runs["greedy"]["uncertainty_reduction_pct"]
            for planner, r in runs.items():
                if planner != "greedy":
                    d = r["uncertainty_reduction_pct"] - g
                    print(f"  {planner:10s} minus greedy {' / '.join(f'{x:+5.1f}' for x in d.mean(0))}   "
                          f"sd {' / '.join(f'{x:4.1f}' for x in d.std(0))}")


if __name__ == "__main__":
    main()
