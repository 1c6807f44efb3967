"""One episode of one planner on one task, by task id and planner spec (the leaderboard's unit).

The loop itself is :func:`ipp_bench.planners.episode.fly_episode`, shared with the MuJoCo demo
and the training code's validation; this module adds what the command line needs around it:
the task's env (:func:`ipp_bench.envs.make_env`) and saving the episode's figure.
"""

from __future__ import annotations

from ..envs import make_env
from ..planners.episode import Decision, EpisodeResult, fly_episode


def run_episode(task: str, planner: str, seed: int, env=None, render_path: str | None = None,
                on_reset=None, on_decision=None, isolate: bool = False, **env_overrides) -> EpisodeResult:
    """Fly one episode of ``planner`` (a spec such as ``"mcts:simulations=50"``) on ``task``.

    The episode seed fixes field, start and sensor noise, so every planner meets the same episode.
    ``env`` reuses an environment of ``task``; ``render_path`` saves the episode's figure as a PNG
    (:func:`~ipp_bench.eval.figure.save_episode_figure`);
    ``on_reset`` and ``on_decision`` are the hooks of :func:`~ipp_bench.planners.episode.fly_episode`;
    ``isolate`` flies the planner in a process of its own (the same metrics; ``result.isolated``).
    """
    env = env if env is not None else make_env(task, **env_overrides)
    result = fly_episode(env, planner, seed, on_reset=on_reset, on_decision=on_decision, isolate=isolate)
    result.task = task
    if render_path is not None:
        from .figure import save_episode_figure

        save_episode_figure(env.mission, render_path, f"{task}, {planner}, seed {seed}")
    return result


__all__ = ["Decision", "EpisodeResult", "run_episode"]
