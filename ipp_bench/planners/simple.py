"""Baselines without look-ahead: uniform random moves and a boustrophedon lawnmower."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import check_number
from .base import ContinuousPlanner, GraphPlanner


@dataclass(frozen=True)
class RandomConfig:
    """No settings: the next node is uniform over the affordable neighbours."""


class RandomPlanner(GraphPlanner):
    """Uniform over the affordable neighbours of the current node (seeded per episode)."""

    name = "random"
    Config = RandomConfig

    def act(self, obs):
        return int(self.rng.choice(np.flatnonzero(obs["action_mask"])))


@dataclass(frozen=True)
class CoverageConfig:
    """Lawnmower settings.

    Attributes:
        altitude: flight altitude [m]; None = the task's lowest altitude level.
        overlap: fraction of the footprint shared by neighbouring lanes, in [0, 1).
    """

    altitude: float | None = None  # [m]
    overlap: float = 0.0  # [-]

    def __post_init__(self):
        if self.altitude is not None:
            check_number("coverage.altitude", self.altitude, 0.0, low_open=True, unit="m")
        check_number("coverage.overlap", self.overlap, 0.0, 1.0, high_open=True)


class CoveragePlanner(ContinuousPlanner):
    """Boustrophedon lawnmower at the lowest altitude (paper baseline (b)).

    Lanes run along x, one footprint apart (less ``overlap``), from the corner nearest the start;
    the mission measures every ``measurement_spacing`` metres along them, so measurements are
    equally spaced. When the pattern ends it is flown again in reverse until the budget is spent.
    """

    name = "coverage"
    Config = CoverageConfig

    def __init__(self, config: CoverageConfig | None = None):
        super().__init__(config or CoverageConfig())

    def reset(self, view, seed):
        super().reset(view, seed)
        cfg = view.config
        alt = self.settings.altitude or cfg.graph.altitudes[0]
        half = view.sensor.footprint_side(alt) / 2.0
        width, height = cfg.grid.size_m
        half_x, half_y = min(half, width / 2), min(half, height / 2)
        step = 2 * half * (1.0 - self.settings.overlap)
        n_lanes = max(1, math.ceil((height - 2 * half_y) / step - 1e-9) + 1)
        ys = np.linspace(half_y, height - half_y, n_lanes) if n_lanes > 1 else np.array([height / 2])
        xs = (half_x, width - half_x)
        start = view.position
        if abs(start[1] - ys[-1]) < abs(start[1] - ys[0]):
            ys = ys[::-1]
        if abs(start[0] - xs[1]) < abs(start[0] - xs[0]):
            xs = xs[::-1]
        pattern = []
        for i, y in enumerate(ys):
            a, b = (xs[0], xs[1]) if i % 2 == 0 else (xs[1], xs[0])
            pattern += [(a, y, alt), (b, y, alt)]
        self._targets = self._cycle(np.array(pattern))
        self._target = next(self._targets)

    @staticmethod
    def _cycle(pattern):
        while True:
            yield from pattern
            pattern = pattern[::-1]

    def next_waypoint(self):
        while np.linalg.norm(self._target - self.view.position) <= 1e-6:
            self._target = next(self._targets)
        return self.affordable(self._target)
