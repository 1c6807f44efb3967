"""What every roadmap env does the same way: read its config, check its render mode, draw an episode.

The single-UAV env (:class:`~ipp_bench.envs.graph.GraphIPPEnv`) and the team env
(:class:`~ipp_bench.envs.team.TeamGraphEnv`) both call these, so the same task and seed give both
the same field, the same first start and the same first camera-noise stream.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core._threads import limit_blas_threads
from ..core.config import IPPConfig, invalid
from ..core.fields import make_field
from ..core.limits import check_sizes

#: the draws of one episode: three 63-bit seeds (field, start, camera noise) from the episode seed
SEED_HIGH = 2**63 - 1


def resolve_config(config: IPPConfig | dict | None, overrides: dict[str, Any]) -> IPPConfig:
    """The task's config: ``config`` (an :class:`IPPConfig`, a dict of its sections, or None: the
    defaults) with ``overrides`` (fields by name) applied, its sizes checked before anything is built.
    Limits numpy/scipy BLAS to one thread per process (``ipp_bench.core._threads``).

    Raises:
        ValueError: a config of the wrong type, an unknown field, a bad value, or a task too large.
    """
    if config is None:
        config = IPPConfig()
    elif isinstance(config, dict):
        config = IPPConfig.from_dict(config)
    elif not isinstance(config, IPPConfig):
        invalid("config", config, "an ipp_bench.core.config.IPPConfig, a dict of its sections or None "
                                  "(or set fields by name: gym.make(task, budget_s=100))")
    if overrides:
        config = config.replace(**overrides)
    check_sizes(config)  # before the roadmap: a map or spacing too large costs nothing
    limit_blas_threads()
    return config


def check_render_mode(render_mode: str | None, modes: list[str]) -> None:
    """Refuse a render mode the env does not have, naming the ones it has."""
    if render_mode not in (None, *modes):
        raise ValueError(f"render_mode={render_mode!r} is invalid: valid are {modes} or None")


def episode_seed(config: IPPConfig, seed: int | None, fresh) -> int:
    """The task's episode seed that ``reset(seed=...)`` plays: ``lo + seed mod (hi - lo)`` in the task's
    ``mission.episode_seeds`` [lo, hi); ``seed=None`` draws one with ``fresh(hi - lo)``.

    Raises:
        ValueError: a seed that is not None or an integer >= 0.
    """
    lo, hi = config.mission.episode_seeds
    if seed is None:
        seed = int(fresh(hi - lo))
    elif not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed = {seed!r} is invalid: expected an integer >= 0 or None")
    return lo + int(seed) % (hi - lo)


def draw_episode(config: IPPConfig, rng: np.random.Generator) -> tuple[np.ndarray, int, int]:
    """The ground truth, the start seed and the camera-noise seed of an episode, from ``rng``
    (the generator seeded with the episode seed)."""
    field_seed, start_seed, noise_seed = (int(v) for v in rng.integers(0, SEED_HIGH, size=3))
    truth = make_field(config.mission.field, config.grid, np.random.default_rng(field_seed))
    return truth, start_seed, noise_seed


__all__ = ["SEED_HIGH", "check_render_mode", "draw_episode", "episode_seed", "resolve_config"]
