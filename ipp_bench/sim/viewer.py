"""Open the deployment in ``dm_control.viewer``: the environment loader and a planner as its policy.

    MUJOCO_GL=glfw python -m ipp_bench.sim.viewer --task ipp_bench/MuJoCoWeed15-v1 --planner greedy --seed 0

(``MUJOCO_GL=glfw``: the viewer opens a window, so it needs a display; off-screen rendering of the
benchmark itself uses EGL or OSMesa.) One viewer step is one planner decision: the drone flies
the chosen leg and the viewer shows the physics at the end of it, paced to real time. A roadmap
planner (``random``, ``greedy``, ``mcts``, ``attention``) chooses; without ``--planner`` the
viewer's default action (neighbour 0, ending the episode where it is masked) is sent.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np


def environment_loader(task_id: str = "ipp_bench/MuJoCoWeed15-v1", seed: int | None = 0,
                       **overrides: Any) -> Callable[[], Any]:
    """The zero-argument callable ``dm_control.viewer.launch`` takes: it builds :func:`ipp_bench.sim.load`."""
    def load():
        from ipp_bench.sim.dmenv import load as _load

        return _load(task_id, seed=seed, **overrides)

    return load


class PlannerPolicy:
    """A roadmap planner as a viewer policy (``time_step -> action``) on a loaded environment.

    Args:
        environment: an environment from :func:`ipp_bench.sim.load`.
        planner: a roadmap planner spec (``"greedy"``, ``"mcts:simulations=50"``).
        seed: the planner's seed of the first episode (then +1 per episode).
    """

    def __init__(self, environment, planner: str, seed: int = 0) -> None:
        from ipp_bench.planners import make_planner
        from ipp_bench.planners.base import RobotView

        self._env, self._seed = environment, int(seed)
        self._planner = make_planner(planner)
        if self._planner.kind != "graph":
            raise ValueError(f"--planner {planner!r} is a {self._planner.kind} planner: the viewer steps "
                             "roadmap decisions; use random, greedy, mcts or attention")
        self._view = RobotView

    def __call__(self, time_step) -> np.ndarray:
        task = self._env.task
        if time_step.first():
            self._planner.reset(self._view(task), self._seed)
            self._seed += 1
        obs = {k: v for k, v in time_step.observation.items() if k != "estimated_position"}
        return np.int64(self._planner.act(obs))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ipp_bench.sim.viewer", description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="ipp_bench/MuJoCoWeed15-v1")
    parser.add_argument("--planner", default=None, help="roadmap planner spec (default: none)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from dm_control import viewer

    loader = environment_loader(args.task, seed=args.seed)
    if args.planner is None:
        viewer.launch(loader)
        return 0
    env = loader()
    viewer.launch(lambda: env, policy=PlannerPolicy(env, args.planner, args.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
