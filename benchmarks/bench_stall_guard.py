"""How often does the attention planner's stall guard decide, and where?

The ``attention`` planner hands a decision to its stall guard when the belief's total variance fell
by less than ``stall_cells`` times its mean cell variance over the last ``stall_legs`` decisions
(``AttentionConfig``); this
prints, per task, the share of the planner's decisions that the guard made, how many episodes it
fired in, and the ROI uncertainty reduction at the end with and without it (``stall_legs=0``),
over the leaderboard's episode seeds (``--seed 0``) or others (``--seed 1``: the validation used to
choose the guard's settings).

    python benchmarks/bench_stall_guard.py --episodes 20
    python benchmarks/bench_stall_guard.py --planner attention:stall_cells=1 --tasks Weed15Twin-v1
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

DEFAULT_TASKS = ["Grid15Eval-v1", "Grid20Eval-v1", "Grid30Eval-v1", "Hotspots15Eval-v2", "Hotspots30Eval-v2",
                 "Weed15Twin-v1"]


def guard_share(task: str, spec: str, seeds: list[int]) -> tuple[int, int, int, float, float]:
    """(guard decisions, decisions, episodes it fired in, mean final reduction with it, without it)."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners import make_planner
    from ipp_bench.planners.episode import fly_episode

    env = make_env(task)
    guard = decisions = fired = 0
    with_it, without = [], []
    alone = f"{spec},stall_legs=0" if ":" in spec else f"{spec}:stall_legs=0"
    for seed in seeds:
        planner = make_planner(spec)
        res = fly_episode(env, planner, seed)
        guard += planner.guard_decisions
        decisions += res.decisions
        fired += planner.guard_decisions > 0
        with_it.append(res.report[-1]["uncertainty_reduction_pct"])
        without.append(fly_episode(env, make_planner(alone), seed).report[-1]["uncertainty_reduction_pct"])
    return guard, decisions, fired, float(np.mean(with_it)), float(np.mean(without))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--planner", default="attention", help="an attention planner spec (default: attention)")
    parser.add_argument("--tasks", nargs="+", default=DEFAULT_TASKS)
    parser.add_argument("--episodes", type=int, default=20, help="episodes per task (the leaderboard's seeds)")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the episode seeds (the leaderboard's: 0)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        print(f"error: --episodes {args.episodes} is invalid: expected an integer >= 1", file=sys.stderr)
        return 2
    from ipp_bench.eval.plan import episode_seeds, resolve_task
    from ipp_bench.planners import make_planner, parse_spec

    try:
        if parse_spec(args.planner)[0] != "attention":
            raise ValueError(f"--planner {args.planner!r} is invalid: expected an attention planner spec")
        make_planner(args.planner)
        tasks = [resolve_task(t) for t in args.tasks]
    except (ValueError, KeyError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    seeds = episode_seeds(args.seed, args.episodes)
    print(f"{args.planner}, {args.episodes} episodes per task (seed {args.seed})\n")
    print("| task | guard's share of decisions | episodes it fired in | reduction at the end, with / without [%] |")
    print("|---|---|---|---|")
    for task in tasks:
        guard, n, fired, with_it, without = guard_share(task, args.planner, seeds)
        print(f"| `{task.split('/')[-1]}` | {guard} / {n} ({100 * guard / max(n, 1):.1f} %) | {fired} / {len(seeds)} "
              f"| {with_it:.1f} / {without:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
