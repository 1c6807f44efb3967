"""The graph twin of the MuJoCo deployment: the roadmap MDP with the camera's error drawn, not rendered."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.config import IPPConfig
from ..core.mission import Mission
from ..core.twin import CameraErrorLegs
from .graph import GraphIPPEnv


class TwinIPPEnv(GraphIPPEnv):
    """``ipp_bench/Weed15Twin-v1``: the deployment's graph twin (no MuJoCo).

    ## Description
    The roadmap MDP of :class:`~ipp_bench.envs.graph.GraphIPPEnv` on the deployment's problem
    (``MuJoCoWeed15-v1``'s grid, roadmap, weed-patch field family, fitted prior, threshold and
    camera-error constants, copied into its task file), with a sensor that draws the calibrated
    camera error (:class:`~ipp_bench.core.twin.CameraErrorLegs`: persistent per cell, resolution and
    episode, spatially correlated so that binned blocks share it, white noise on top, and the rows of
    the cells a tilted frame misses dropped). Legs are
    straight at the mission speed (no velocity ramps, wind or estimator). The belief is the
    deployment's (camera-error states).

    ## Action Space, Observation Space, Rewards, Episode End
    As :class:`~ipp_bench.envs.graph.GraphIPPEnv`.

    ## Arguments
    As :class:`~ipp_bench.envs.graph.GraphIPPEnv`, and ``neighbour_corr`` (default: the task's
    ``sensor.persistent_neighbour_corr``, 0.59, which the belief models too): the correlation of
    neighbouring cells' persistent errors that the twin's camera draws.

    ## Version History
    - v1: initial release (the constants of ``MuJoCoWeed15-v1``).
    """

    def __init__(self, config: IPPConfig | dict | None = None, render_mode: str | None = None,
                 task_id: str | None = None, neighbour_corr: float | None = None, **overrides: Any):
        if neighbour_corr is not None:
            CameraErrorLegs(neighbour_corr)  # a bad value fails here, naming itself
        super().__init__(config, render_mode=render_mode, task_id=task_id, **overrides)
        self.neighbour_corr = float(self.config.sensor.persistent_neighbour_corr if neighbour_corr is None
                                    else neighbour_corr)

    def _make_mission(self, truth: np.ndarray, rng: np.random.Generator, start_xyz: np.ndarray) -> Mission:
        return Mission(self.config, truth, rng, start_xyz, sensor=self.sensor,
                       platform=CameraErrorLegs(self.neighbour_corr))
