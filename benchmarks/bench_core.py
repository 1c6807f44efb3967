"""Speed of the IPP model: GP update, env step and observation build at growing map sizes.

Prints figures, never pass/fail. Run: ``python benchmarks/bench_core.py [--sizes 15 20 30 50]
[--task ipp_bench/Grid15Eval-v1]`` (the task's settings at each size).
Medians over many repetitions; compare ratios measured in one run (the machine is noisy).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from ipp_bench._threads import limit_blas_threads
from ipp_bench.envs import make_env


def median_time(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def bench_size(task: str, n: int, steps: int) -> dict[str, float]:
    t0 = time.perf_counter()
    env = make_env(task, rows=n, cols=n, budget_s=1e6)
    build_s = time.perf_counter() - t0
    obs, _ = env.reset(seed=0)
    mission = env.mission
    out = {"n_cells": n * n, "n_nodes": env.roadmap.n_nodes, "env_build_s": build_s}
    centre = ((n / 2) * 2.5, (n / 2) * 2.5)
    for h in (8.0, 14.0):
        o = env.sensor.observe((*centre, h))
        z = np.full(o.m, 0.5)
        belief = mission.belief.copy()
        out[f"gp_update_{int(h)}m_us"] = 1e6 * median_time(
            lambda: belief.update_local(o.cells, o.weights, z, o.var), repeat=max(20, 2000 // n))
        out[f"m_{int(h)}m"] = o.m
    rng = np.random.default_rng(0)
    ts = []
    for _ in range(steps):
        a = int(rng.choice(np.flatnonzero(obs["action_mask"])))
        t0 = time.perf_counter()
        obs, *_ = env.step(a)
        ts.append(time.perf_counter() - t0)
    out["env_step_ms"] = 1e3 * float(np.median(ts))
    out["env_step_p90_ms"] = 1e3 * float(np.percentile(ts, 90))
    out["measurements_per_step"] = (mission.n_measurements / max(len(mission.measurement_log), 1))
    out["observation_ms"] = 1e3 * median_time(env._observation, repeat=200)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[15, 20, 30, 50])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--task", default="ipp_bench/Grid15Eval-v1", help="task whose settings are resized")
    args = parser.parse_args()
    limit_blas_threads()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, BLAS threads 1")
    print(f"{'grid':>6} {'cells':>6} {'nodes':>6} {'build s':>8} {'upd 8m us':>10} {'upd 14m us':>11} "
          f"{'step ms':>8} {'p90 ms':>7} {'obs ms':>7}")
    for n in args.sizes:
        r = bench_size(args.task, n, args.steps)
        print(f"{n:>3}x{n:<2} {r['n_cells']:>6} {r['n_nodes']:>6} {r['env_build_s']:>8.2f} "
              f"{r['gp_update_8m_us']:>10.0f} {r['gp_update_14m_us']:>11.0f} {r['env_step_ms']:>8.3f} "
              f"{r['env_step_p90_ms']:>7.3f} {r['observation_ms']:>7.3f}", flush=True)


if __name__ == "__main__":
    main()
