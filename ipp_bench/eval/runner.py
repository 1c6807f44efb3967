"""Run one episode of one planner on one task, timing every decision."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

import ipp_bench.envs  # noqa: F401  (registers the tasks)

from ..planners import RobotView, make_planner

MAX_DECISIONS = 100_000

REPORT_KEYS = ("trace_roi", "rmse_roi", "uncertainty_reduction_pct", "rmse_reduction_pct")


@dataclass
class EpisodeResult:
    """Metrics of one episode at the task's report times, and the planner's decision times.

    Attributes:
        report: one dict per report time within the budget, with ``time_s`` and ``REPORT_KEYS``.
        decision_times_s: wall time of every decision [s].
    """

    task: str
    planner: str
    seed: int
    report: list[dict[str, float]]
    decisions: int
    decision_times_s: list[float] = field(repr=False)
    episode_wall_s: float
    final: dict[str, float]

    @property
    def decision_time_mean_s(self) -> float:
        return float(np.mean(self.decision_times_s)) if self.decision_times_s else 0.0

    @property
    def decision_time_max_s(self) -> float:
        return float(np.max(self.decision_times_s)) if self.decision_times_s else 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def make_env(task: str, render: bool = False, **overrides):
    """The unwrapped environment of a task (planners drive it directly)."""
    return gym.make(task, render_mode="rgb_array" if render else None, **overrides).unwrapped


def run_episode(task: str, planner: str, seed: int, env=None, render_path: str | None = None,
                **env_overrides) -> EpisodeResult:
    """Fly one episode of ``planner`` (a spec such as ``"mcts:simulations=50"``) on ``task``.

    The episode seed fixes field, start and sensor noise, so every planner meets the same episode.
    """
    env = env if env is not None else make_env(task, render=render_path is not None, **env_overrides)
    agent = make_planner(planner)
    obs, _ = env.reset(seed=int(seed))
    agent.reset(RobotView(env), int(seed))
    times: list[float] = []
    t_start = time.perf_counter()
    if agent.kind == "graph":
        while obs["action_mask"].any():
            t0 = time.perf_counter()
            action = agent.act(obs)
            times.append(time.perf_counter() - t0)
            obs, _, terminated, _, _ = env.step(action)
            if terminated or len(times) >= MAX_DECISIONS:
                break
    else:
        while len(times) < MAX_DECISIONS:
            t0 = time.perf_counter()
            waypoint = agent.next_waypoint()
            times.append(time.perf_counter() - t0)
            if waypoint is None:
                times.pop()
                break
            env.mission.fly_to(waypoint)
    if len(times) >= MAX_DECISIONS:
        raise RuntimeError(f"planner {planner!r} made {MAX_DECISIONS} decisions without ending the episode")
    wall = time.perf_counter() - t_start
    mission = env.mission
    report = []
    for t in mission.config.mission.report_times:
        if t <= mission.budget_s + 1e-9:
            at = mission.metrics_at(t)
            report.append({"time_s": float(t), **{k: float(at[k]) for k in REPORT_KEYS}})
    if render_path is not None:
        save_png(env.render(), render_path)
    return EpisodeResult(task, planner, int(seed), report, len(times), times, wall, mission.metrics())


def save_png(image: np.ndarray, path: str) -> None:
    """Write an RGB uint8 image as PNG (matplotlib's writer; part of the ``eval`` extra)."""
    try:
        import matplotlib.image as mpimg
    except ImportError:
        raise ImportError('saving a PNG needs matplotlib: pip install "ipp-bench[eval]"') from None
    mpimg.imsave(path, image)
