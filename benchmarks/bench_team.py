"""What a team decision and a team episode cost against one UAV's.

Prints figures, never pass/fail. Run: ``python benchmarks/bench_team.py [--episodes 2] [--seed 1000] [--budget-s S]``.
Per decision: ``greedy`` on one UAV (``Hotspots30Eval-v2``), and ``team-greedy`` on the 2- and 4-UAV
tasks split into its two parts, fusing the teammates' committed read-outs into a copy of the
covariance (``belief_ahead``) and greedy's scoring on it. Per episode: the wall time of a whole
episode, team over one UAV (all in one run, so the ratios hold on a loaded machine; the load average
is printed first). One greedy episode first fills the legs' cache that every task on this map shares.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from ipp_bench.core._threads import limit_blas_threads
from ipp_bench.envs import make_env
from ipp_bench.planners.episode import fly_episode

SINGLE = "ipp_bench/Hotspots30Eval-v2"
TEAMS = ("ipp_bench/Hotspots30Team2Eval-v2", "ipp_bench/Hotspots30Team4Eval-v2")


def _team_decision_parts(task: str, seed: int, over: dict) -> tuple[list[float], list[float], list[int]]:
    """One team-greedy episode, each decision split into belief_ahead and the scoring [s]."""
    env = make_env(task, **over)
    ahead_s, score_s, pending = [], [], []
    from ipp_bench.planners.episode import start_team_episode

    agents = start_team_episode(env, "team-greedy", seed)
    for name in env.agent_iter():
        obs, _, terminated, _, _ = env.last()
        if terminated:
            env.step(None)
            continue
        agent = agents[env.uav_index(name)]
        t0 = time.perf_counter()
        agent._ahead = agent.view.belief_ahead()
        t1 = time.perf_counter()
        action = int(np.argmax(agent.scores(obs)))
        t2 = time.perf_counter()
        ahead_s.append(t1 - t0)
        score_s.append(t2 - t1)
        pending.append(len(agent.view.teammates_pending()))
        env.step(action)
    return ahead_s, score_s, pending


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--budget-s", type=float, default=None, help="each UAV's budget [s] (default: the tasks')")
    args = parser.parse_args()
    over = {} if args.budget_s is None else {"budget_s": args.budget_s, "report_times": [args.budget_s]}
    limit_blas_threads()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}, "
          "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    seeds = [args.seed + i for i in range(args.episodes)]
    single_env = make_env(SINGLE, **over)
    fly_episode(single_env, "greedy", args.seed - 1)  # warm-up: greedy's leg cache (one per roadmap, shared)
    single = [fly_episode(single_env, "greedy", s) for s in seeds]
    single_dec = np.concatenate([r.decision_times_s for r in single])
    single_ep = float(np.mean([r.episode_wall_s for r in single]))
    print(f"\nper decision, median ms (decisions):\n  {'greedy, one UAV':<40} {1e3 * np.median(single_dec):7.2f} "
          f"({single_dec.size})")
    for task in TEAMS:
        parts = [_team_decision_parts(task, s, over) for s in seeds]
        ahead = np.concatenate([p[0] for p in parts])
        score = np.concatenate([p[1] for p in parts])
        pending = np.concatenate([p[2] for p in parts])
        name = task.split("/")[1]
        print(f"  {'team-greedy, ' + name:<40} {1e3 * np.median(ahead + score):7.2f} ({ahead.size}): fusion ahead "
              f"{1e3 * np.median(ahead):.2f} (median {np.median(pending):.0f} read-outs pending) + scoring "
              f"{1e3 * np.median(score):.2f}")
    print("\nper episode, mean wall s:")
    print(f"  {'greedy, one UAV':<40} {single_ep:7.2f}")
    for task in TEAMS:
        env = make_env(task, **over)
        for spec in ("greedy", "team-greedy"):
            wall = float(np.mean([fly_episode(env, spec, s).episode_wall_s for s in seeds]))
            print(f"  {spec + ', ' + task.split('/')[1]:<40} {wall:7.2f}  ({wall / single_ep:.2f}x one UAV's)")


if __name__ == "__main__":
    main()
