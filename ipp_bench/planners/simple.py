"""Baselines without look-ahead: uniform random moves and a boustrophedon lawnmower."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.config import check_number, invalid
from .base import MIN_LEG_M, ContinuousPlanner, GraphPlanner


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
        altitude: flight altitude [m], within the task's flight envelope (``graph.altitudes``, checked
            when an episode starts); None = the task's lowest altitude level.
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
    Where one footprint covers the whole map, the pattern is one point above the map's centre: the
    planner flies there and the mission ends (nothing is left to cover).
    """

    name = "coverage"
    Config = CoverageConfig

    def __init__(self, config: CoverageConfig | None = None):
        super().__init__(config or CoverageConfig())

    def reset(self, view, seed):
        """Lay out the lanes; refuses (one line) an altitude outside the task's flight envelope."""
        super().reset(view, seed)
        cfg = view.config
        alt = self.settings.altitude
        if alt is None:
            alt = cfg.graph.altitudes[0]
        else:
            low, high = cfg.altitude_range
            if not low <= alt <= high:
                invalid("coverage.altitude", alt, f"an altitude in [{low:g}, {high:g}] m (the task's flight "
                        "envelope, graph.altitudes)")
        half = view.sensor.footprint_side(alt) / 2.0
        width, _ = cfg.grid.size_m
        y_low, y_high = self.band(view)
        height = y_high - y_low
        half_x, half_y = min(half, width / 2), min(half, height / 2)
        step = 2 * half * (1.0 - self.settings.overlap)
        n_lanes = max(1, math.ceil((height - 2 * half_y) / step - 1e-9) + 1)
        ys = (np.linspace(y_low + half_y, y_high - half_y, n_lanes) if n_lanes > 1
              else np.array([(y_low + y_high) / 2]))
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
        pattern = np.array(pattern)
        # where the footprint covers the whole map every lane point is one point: one look there sees it all
        self._single = bool(np.all(np.linalg.norm(pattern - pattern[0], axis=1) <= MIN_LEG_M))
        self._targets = self._cycle(pattern)
        self._target = next(self._targets)

    def band(self, view) -> tuple[float, float]:
        """[m] the stretch of y the lanes cover: the whole map."""
        return 0.0, view.config.grid.size_m[1]

    @staticmethod
    def _cycle(pattern):
        while True:
            yield from pattern
            pattern = pattern[::-1]

    def next_waypoint(self):
        """The next lane end (cut where the budget ends); None when the budget is spent, or when the
        footprint covers the whole map and the UAV is at the one point that sees it."""
        if self._single:
            if np.linalg.norm(self._target - self.view.position) <= MIN_LEG_M:
                return None
            return self.affordable(self._target)
        while np.linalg.norm(self._target - self.view.position) <= MIN_LEG_M:
            self._target = next(self._targets)
        return self.affordable(self._target)
