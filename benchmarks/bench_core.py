"""Speed of the IPP model: GP update, env step, observation build and greedy's decision at growing map
sizes, for both beliefs side by side (the dense GPBelief where it fits, the WindowBelief everywhere).

Prints figures, never pass/fail. Run: ``python benchmarks/bench_core.py [--sizes 15 30 50 128]
[--task ipp_bench/Hotspots30Eval-v2] [--beliefs dense window]`` (the task's settings at each size).
Columns: env build; the belief's update of one read-out at the map's centre, repeated (8 / 14 m); the
mission's update of one 8 m read-out at a fresh random place each time (``Mission.assimilate``: the
belief model's update and the metrics it records); a random-walk env step; the observation; greedy's
decision (``GreedyPlanner.act`` along a greedy flight from the task's start). Medians over many
repetitions; compare ratios measured in one run (the machine is noisy).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from ipp_bench.core._threads import limit_blas_threads
from ipp_bench.core.limits import check_sizes
from ipp_bench.envs import make_env, task_config
from ipp_bench.planners import RobotView, make_planner


def median_time(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def bench_size(task: str, n: int, steps: int, belief: str) -> dict[str, float]:
    t0 = time.perf_counter()
    env = make_env(task, rows=n, cols=n, budget_s=1e5, belief=belief)  # 2e5 m: more than any walk flies
    build_s = time.perf_counter() - t0
    obs, _ = env.reset(seed=0)
    mission = env.mission
    out = {"n_cells": n * n, "n_nodes": env.roadmap.n_nodes, "env_build_s": build_s}
    centre = ((n / 2) * 2.5, (n / 2) * 2.5)
    for h in (8.0, 14.0):
        o = env.sensor.observe((*centre, h))
        z = np.full(o.m, 0.5)
        belief_copy = mission.belief.copy()
        out[f"gp_update_{int(h)}m_us"] = 1e6 * median_time(
            lambda: belief_copy.update_local(o.cells, o.weights, z, o.var), repeat=max(20, 2000 // n))
        out[f"m_{int(h)}m"] = o.m
    agent = make_planner("greedy")
    agent.reset(RobotView(env), 0)
    ts = []
    for _ in range(steps):  # greedy's decisions along its own flight
        if not obs["action_mask"].any():
            break
        t0 = time.perf_counter()
        a = agent.act(obs)
        ts.append(time.perf_counter() - t0)
        obs, *_ = env.step(a)
    out["greedy_ms"] = 1e3 * float(np.median(ts))
    out["greedy_p90_ms"] = 1e3 * float(np.percentile(ts, 90))
    rng = np.random.default_rng(0)
    ts = []
    for _ in range(steps):
        a = int(rng.choice(np.flatnonzero(obs["action_mask"])))
        t0 = time.perf_counter()
        obs, *_ = env.step(a)
        ts.append(time.perf_counter() - t0)
    out["env_step_ms"] = 1e3 * float(np.median(ts))
    out["env_step_p90_ms"] = 1e3 * float(np.percentile(ts, 90))
    out["observation_ms"] = 1e3 * median_time(env._observation, repeat=200)
    width, height = env.config.grid.size_m
    looks = [env.sensor.observe((x, y, 8.0)) for x, y in rng.uniform(0.05, 0.95, (200, 2)) * (width, height)]
    ts = []
    for o in looks:  # last: it moves this episode's belief
        t0 = time.perf_counter()
        mission.assimilate([o], [np.full(o.m, 0.1)], mission.time_s)
        ts.append(time.perf_counter() - t0)
    out["mission_update_8m_ms"] = 1e3 * float(np.median(ts))
    out["belief_mb"] = belief_mb(mission.belief)
    return out


def belief_mb(belief) -> float:
    """[MB] the belief's arrays (the window belief's with its scratch and masks)."""
    return (belief.nbytes if hasattr(belief, "nbytes") else belief.mean.nbytes + belief.cov.nbytes) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--sizes", type=int, nargs="+", default=[15, 30, 50, 128])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--task", default="ipp_bench/Hotspots30Eval-v2", help="task whose settings are resized")
    parser.add_argument("--beliefs", nargs="+", default=["dense", "window"], choices=["dense", "window"])
    args = parser.parse_args()
    limit_blas_threads()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, BLAS threads 1; task {args.task}; "
          f"load {os.getloadavg()[0]:.2f}")
    print(f"{'grid':>7} {'belief':>6} {'cells':>6} {'nodes':>6} {'build s':>8} {'upd 8m us':>10} {'upd 14m us':>11} "
          f"{'mission 8m ms':>13} {'step ms':>8} {'p90 ms':>7} {'obs ms':>7} {'greedy ms':>9} {'p90 ms':>7} "
          f"{'belief MB':>9}")
    for n in args.sizes:
        for belief in args.beliefs:
            config = task_config(args.task, {"rows": n, "cols": n, "belief": belief})
            try:
                check_sizes(config)
            except ValueError as err:
                print(f"{n:>3}x{n:<3} {belief:>6} skipped: {str(err).split(':')[1].strip()}", flush=True)
                continue
            r = bench_size(args.task, n, args.steps, belief)
            print(f"{n:>3}x{n:<3} {belief:>6} {r['n_cells']:>6} {r['n_nodes']:>6} {r['env_build_s']:>8.2f} "
                  f"{r['gp_update_8m_us']:>10.0f} {r['gp_update_14m_us']:>11.0f} {r['mission_update_8m_ms']:>13.3f} "
                  f"{r['env_step_ms']:>8.3f} {r['env_step_p90_ms']:>7.3f} {r['observation_ms']:>7.3f} "
                  f"{r['greedy_ms']:>9.2f} {r['greedy_p90_ms']:>7.2f} {r['belief_mb']:>9.1f}", flush=True)
    print(f"load {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
