"""Checks of a leaderboard plan before a results folder is written: tasks a planner cannot be flown isolated on,
seeds that play an episode twice, and the start of every task's first episode with every planner.

Split from :mod:`ipp_bench.eval.plan`, which imports these for :func:`~ipp_bench.eval.plan.make_plan`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..envs import task_config, task_spec
from ..envs.registry import is_team_task


def check_isolation(tasks: Sequence[str], isolated: Sequence[str], why: str) -> None:
    """Refuse, in one line naming task and planner, a planner to isolate on a task that cannot be flown
    isolated: a team task (one planner per UAV shares the team's belief) or a MuJoCo deployment (its clock).
    ``why``: what isolates it (``--isolate``, a plugin, an ``--against`` submission); a planner isolated by
    default must never run beside the truth, so the run is refused rather than flown in-process."""
    if not isolated:
        return
    for t in tasks:
        if is_team_task(t):
            reason = "a team task (one planner per UAV shares the team's belief)"
        elif "deployment" in task_spec(t).tags:
            reason = "a MuJoCo deployment (its clock runs in the world's process)"
        else:
            continue
        raise ValueError(f"task {t}, planner {isolated[0]}: cannot be flown isolated, in a process of its own "
                         f"({why}): {t} is {reason}; leave that task out"
                         + (" or drop --isolate" if why == "--isolate" else ""))


def check_distinct_episodes(task: str, seeds: Sequence[int], env_overrides: dict[str, Any]) -> None:
    """Refuse seeds that play the same episode twice on ``task`` (its ``episode_seeds`` range is
    narrower than the run): repeated episodes would be bootstrapped as independent ones."""
    lo, hi = task_config(task, env_overrides).mission.episode_seeds
    played = {lo + s % (hi - lo) for s in seeds}
    if len(played) < len(seeds):
        raise ValueError(
            f"task {task}: its episode_seeds [{lo}, {hi}) play {len(played)} distinct episodes of the {len(seeds)} "
            f"asked for (seed s plays {lo} + s mod {hi - lo}); repeated episodes are not independent samples: "
            "widen episode_seeds or lower --episodes")


def check_episode_starts(tasks: Sequence[str], planners: dict[str, Any], seed: int,
                         env_overrides: dict[str, Any]) -> None:
    """Reset every task's env for episode ``seed`` and every planner on it (no decision); a planner given as
    None is isolated: its spec starts in the planner's own process
    (:func:`~ipp_bench.planners.isolation.start_isolated`), never in this one.

    Raises:
        ValueError: naming task and planner: a start that pays for no first move, a planner that
            refuses the task (an attention checkpoint made for another ``pe_dim``), ...
    """
    from ..envs import make_env
    from ..planners.episode import is_team_env, start_episode

    for task in tasks:
        env = make_env(task, **env_overrides)
        try:
            try:
                env.reset(seed=int(seed))
            except ValueError as err:
                raise ValueError(f"task {task}: {err}") from None
            for spec, planner in planners.items():
                try:  # a team task builds one planner per UAV from the spec
                    started, _ = start_episode(env, spec if is_team_env(env) or planner is None else planner, seed,
                                               isolate=planner is None)
                    if planner is None:
                        started.finish()
                except ValueError as err:
                    raise ValueError(f"task {task}, planner {spec}: {err}") from None
        finally:
            env.close()


__all__ = ["check_episode_starts", "check_isolation", "check_distinct_episodes"]
