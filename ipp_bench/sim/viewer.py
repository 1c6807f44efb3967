"""Open the deployment in ``dm_control.viewer``: the environment loader and a planner as its policy.

    python -m ipp_bench.sim.viewer --task ipp_bench/MuJoCoWeed15-v1 --planner greedy --seed 0

(The viewer opens a window, so it needs a display and MuJoCo's GLFW backend: ``MUJOCO_GL`` unset
or ``glfw``; off-screen rendering of the benchmark itself uses EGL or OSMesa. Without a display, or
with an off-screen backend, it says so in one line and exits with status 2.) One viewer step is one
planner decision: the drone flies
the chosen leg and the viewer shows the physics at the end of it, paced to real time. A roadmap
planner (``random``, ``greedy``, ``mcts``, ``attention``) chooses; without ``--planner`` the
viewer's default action (neighbour 0, ending the episode where it is masked) is sent.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

PROG = "python -m ipp_bench.sim.viewer"


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
            self._planner.reset(self._view(task.env), self._seed)
            self._seed += 1
        obs = {k: v for k, v in time_step.observation.items() if k != "estimated_position"}
        return np.int64(self._planner.act(obs))


NO_DISPLAY = ("the viewer opens a window and no display was found (DISPLAY and WAYLAND_DISPLAY are unset): run it "
              "on a desktop or over 'ssh -X'; without a display, 'ipp-bench demo' renders an episode to a video")


def _has_display() -> bool:
    """Whether a window can be opened: always off Linux (macOS, Windows), else an X or Wayland display."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def main(argv: list[str] | None = None) -> int:
    """``python -m ipp_bench.sim.viewer``; returns the exit status (2: it cannot start, one line on stderr)."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="ipp_bench/MuJoCoWeed15-v1")
    parser.add_argument("--planner", default=None, help="roadmap planner spec (default: none)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        import ipp_bench.envs as envs

        spec = envs.task_spec(args.task)
        from ipp_bench.envs.registry import is_team_task

        single = [t for t in envs.tagged("deployment") if not is_team_task(t)]
        if "deployment" not in spec.tags or is_team_task(spec.id):
            raise ValueError(f"--task {args.task!r} is not a single-drone MuJoCo deployment: valid are {single}")
        if args.planner is not None:
            from ipp_bench.planners import make_planner

            make_planner(args.planner)  # a bad spec, before any window
        if not _has_display():
            raise RuntimeError(NO_DISPLAY)
        if not os.environ.get("MUJOCO_GL", "").strip():
            os.environ["MUJOCO_GL"] = "glfw"  # read when mujoco is first imported (below)
        backend = os.environ["MUJOCO_GL"].strip().lower()
        if backend != "glfw":
            raise RuntimeError(f"the viewer draws into a window: run it with MUJOCO_GL=glfw (or unset; MUJOCO_GL="
                               f"{backend!r} renders off-screen only)")
        loader = environment_loader(spec.id, seed=args.seed)
        with warnings.catch_warnings():  # GLFW warns of each failed step before the one error said below
            warnings.filterwarnings("ignore", module="glfw")
            from dm_control import viewer

            if args.planner is None:
                viewer.launch(loader)
                return 0
            env = loader()
            viewer.launch(lambda: env, policy=PlannerPolicy(env, args.planner, args.seed))
    except (ValueError, ImportError, RuntimeError) as err:
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        if text == "Failed to create window":  # GLFW's (dm_control.viewer), whatever the reason
            text = f"cannot open the viewer's window (GLFW: {text}); {NO_DISPLAY.split(': ', 1)[1]}"
        warnings.filterwarnings("ignore", module="glfw")  # and GLFW's own at exit, after the one line
        print(f"{PROG}: error: {text}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
