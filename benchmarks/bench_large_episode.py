"""One whole episode of a planner on a large task, in this process: decision times, the mission's
measurement updates, and the process's peak memory (the targets at 128 x 128: a greedy decision <= 50 ms
median, an 8 m update <= 5 ms median, the process peak < 2 GB over a whole episode).

Prints figures, never pass/fail. Run in a fresh process (the peak is the process's):
``python benchmarks/bench_large_episode.py [--task ipp_bench/Hotspots128Eval-v2] [--planner greedy]
[--seed 0] [--budget-s S]``. Update times: every ``belief_model.update`` of the episode (one per leg
stretch between report times, all its read-outs fused), by the altitude of its read-outs.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time

import numpy as np

from ipp_bench.core._threads import limit_blas_threads, resident_bytes


def rss_mb() -> float:
    """[MB] the process's resident memory now (Linux /proc)."""
    return resident_bytes() / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--task", default="ipp_bench/Hotspots128Eval-v2")
    parser.add_argument("--planner", default="greedy")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget-s", type=float, default=None, help="override the task's budget [s]")
    args = parser.parse_args()
    limit_blas_threads()
    from ipp_bench.envs import make_env
    from ipp_bench.planners.episode import fly_episode

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}, numpy {np.__version__}, BLAS threads 1; load {os.getloadavg()[0]:.2f}")
    base = rss_mb()
    overrides = {} if args.budget_s is None else {"budget_s": args.budget_s,
                                                  "report_times": (args.budget_s,)}
    t0 = time.perf_counter()
    env = make_env(args.task, **overrides)
    build = time.perf_counter() - t0
    updates: list[tuple[float, float, int]] = []  # (seconds, highest altitude of its read-outs [m], rows)

    def on_reset(e) -> None:
        model = e.mission.belief_model
        inner = model.update

        def timed(observations, zs):
            t = time.perf_counter()
            inner(observations, zs)
            updates.append((time.perf_counter() - t, max(o.altitude for o in observations),
                            sum(o.m for o in observations)))
        model.update = timed

    after_build = rss_mb()
    result = fly_episode(env, args.planner, args.seed, on_reset=on_reset)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e6  # [MB] (Linux: KiB)
    d = np.asarray(result.decision_times_s) * 1e3
    u = np.asarray([t for t, _, _ in updates]) * 1e3
    rows = np.asarray([m for _, _, m in updates])
    belief = env.mission.belief
    print(f"{args.task}, {args.planner}, seed {args.seed}: budget {env.config.mission.budget_s:g} s, "
          f"{type(belief).__name__}{f' w = {belief.window}' if hasattr(belief, 'window') else ''}, "
          f"env build {build:.2f} s, episode {result.episode_wall_s:.1f} s")
    print(f"decisions: {result.decisions}, median {np.median(d):.2f} ms, p90 {np.percentile(d, 90):.2f}, "
          f"max {d.max():.1f}")
    print(f"belief updates: {u.size} (one per leg: {rows.mean():.0f} rows on average), median {np.median(u):.2f} ms, "
          f"p90 {np.percentile(u, 90):.2f}, max {u.max():.1f}")
    alts = np.asarray([a for _, a, _ in updates])
    for lo, hi, what in ((0.0, 10.0, "at 8 m only"), (10.0, np.inf, "with 14 m read-outs")):
        sel = (alts > lo) & (alts <= hi)
        if sel.any():
            print(f"  {what}: {sel.sum()} updates, {rows[sel].mean():.0f} rows on average, median "
                  f"{np.median(u[sel]):.2f} ms, p90 {np.percentile(u[sel], 90):.2f}")
    nbytes = belief.nbytes if hasattr(belief, "nbytes") else belief.mean.nbytes + belief.cov.nbytes
    print(f"memory: belief {nbytes / 1e6:.0f} MB; resident after imports {base:.0f} MB, after the env build "
          f"{after_build:.0f} MB, at the end {rss_mb():.0f} MB; process peak {peak:.0f} MB")
    print("report:", "; ".join(f"{r['time_s']:g} s {r['uncertainty_reduction_pct']:.1f} %" for r in result.report))
    print(f"load {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
