"""The warm start's teachers: a registry planner as ``expert(obs) -> (action, scores)``, and the checks
that a teacher exists and can fly a training task, run before anything is written."""

from __future__ import annotations

from typing import Any

import numpy as np


def check_expert(name: str) -> None:
    """Raise ValueError unless ``name`` is a roadmap planner of the registry (called before a run starts)."""
    make_expert(name)


def check_expert_on(name: str, env: Any, task: str) -> None:
    """Raise ValueError (one line) unless the expert ``name`` can start an episode of ``env`` (the
    unwrapped task environment): a planner that needs the dense belief refuses a window-belief task
    at its reset, which comes before the run folder when checked here."""
    from ipp_bench.planners import view_for

    planner = make_expert(name).planner
    env.reset(seed=0)
    try:
        planner.reset(view_for(planner, env), 0)
    except ValueError as err:
        raise ValueError(f"--warm-start {name} on {task}: {err}") from None


def make_expert(name: str) -> PlannerExpert:
    """``expert(obs) -> (action, scores)`` from the planner registry (``greedy``, ``mcts``, ...)."""
    try:
        from ipp_bench.planners import make_planner
    except ImportError as err:
        raise ValueError(f"--warm-start {name}: the planner registry is not available ({err})") from None
    try:
        planner = make_planner(name)
    except (ValueError, TypeError) as err:
        raise ValueError(f"--warm-start {name!r} is invalid: {err}") from None
    if getattr(planner, "kind", None) != "graph":
        raise ValueError(f"--warm-start {name!r} is invalid: it is a {planner.kind} planner; a roadmap planner "
                         "(kind 'graph': greedy, mcts, random) is needed to label neighbours, or 'none'")
    return PlannerExpert(planner)


class PlannerExpert:
    """A registry planner as ``expert(obs) -> (action, scores)``; reset with the episode's view."""

    def __init__(self, planner: Any) -> None:
        self.planner = planner

    def __call__(self, obs: dict) -> tuple[int, np.ndarray | None]:
        """The expert's action and, where the planner exposes them, its scores per neighbour (None, a
        one-hot label, where the planner has none)."""
        if getattr(self.planner, "reads_truth", False):
            # a reference planner (the oracle) may fly towards a far target rather than its scores'
            # argmax: the label is its move, soft over its scores only where the two agree
            action = int(self.planner.act(obs))
            if hasattr(self.planner, "scores"):
                scores = np.asarray(self.planner.scores(obs), dtype=np.float64)
                if action == int(np.argmax(scores)):
                    return action, scores
            return action, None
        if hasattr(self.planner, "scores"):
            scores = np.asarray(self.planner.scores(obs), dtype=np.float64)
            # np.argmax, not the planners' first_best: the shipped checkpoint's warm starts were made
            # with it, and its recipe reproduces them (on the CPU kind that made them: a mirror tie
            # goes the way its rounding falls)
            return int(np.argmax(scores)), scores
        return int(self.planner.act(obs)), None


__all__ = ["PlannerExpert", "check_expert", "check_expert_on", "make_expert"]
