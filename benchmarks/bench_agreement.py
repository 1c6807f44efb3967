"""How often does a planner choose what greedy would, in the states it visits itself?

A learned planner that is level with greedy may simply repeat greedy's choice; this prints, per
task, the share of its decisions (along its own trajectories, leaderboard seeds) where its
neighbour is greedy's argmax in the same state, and where it is one of greedy's two best.

    python benchmarks/bench_agreement.py --planner attention:checkpoint=PATH --episodes 4 \\
        --tasks Grid15Eval-v1 Grid30Eval-v1 Hotspots30Eval-v2
    python benchmarks/bench_agreement.py --planner attention:checkpoint=PATH --episodes 20 \\
        --env 'altitudes=[8,10,14]' --env k=21      # the tasks with a third flight level
"""

from __future__ import annotations

import argparse

import numpy as np

from ipp_bench.envs import make_env, parse_overrides
from ipp_bench.eval.plan import episode_seeds, resolve_task
from ipp_bench.planners import make_planner
from ipp_bench.planners.base import RobotView


def agreement(task: str, spec: str, seeds: list[int], env_overrides: dict | None = None) -> tuple[int, float, float]:
    env = make_env(task, **(env_overrides or {}))
    same = top2 = n = 0
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        view = RobotView(env)
        planner, greedy = make_planner(spec), make_planner("greedy")
        planner.reset(view, seed)
        greedy.reset(view, seed)
        while True:
            scores = greedy.scores(obs)
            a = planner.act(obs)
            order = np.argsort(-scores)
            same += int(a == order[0])
            top2 += int(a in order[:2])
            n += 1
            obs, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                break
    return n, same / max(n, 1), top2 / max(n, 1)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--planner", required=True)
    parser.add_argument("--tasks", nargs="+", default=["Grid15Eval-v1", "Grid20Eval-v1", "Grid30Eval-v1",
                                                       "Hotspots15Eval-v2", "Hotspots30Eval-v2"])
    parser.add_argument("--episodes", type=int, default=4, help="the first leaderboard seeds (seed 0)")
    parser.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                        help="override a task config field, as ipp-bench leaderboard --env (e.g. "
                             "--env altitudes=[8,10,14] --env k=21: a third flight level)")
    args = parser.parse_args(argv)
    try:
        env = parse_overrides(args.env)
        tasks = [resolve_task(task) for task in args.tasks]
        for task in tasks:
            make_env(task, **env)  # an unknown task or a bad override is refused before any episode
        make_planner(args.planner)
    except ValueError as e:
        parser.error(str(e))
    seeds = episode_seeds(0, args.episodes)
    print(f"{args.planner}: decisions equal to greedy's choice in the same state, {args.episodes} leaderboard episodes"
          + (f", env overrides {env}" if env else ""))
    print("| task | decisions | greedy's best | one of greedy's two best |")
    print("|---|---|---|---|")
    for task, full in zip(args.tasks, tasks):
        n, same, top2 = agreement(full, args.planner, seeds, env)
        print(f"| {task} | {n} | {100 * same:.0f} % | {100 * top2:.0f} % |", flush=True)


if __name__ == "__main__":
    main()
