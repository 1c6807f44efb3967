"""Greedy: the neighbour with the highest predicted ROI trace reduction per second of flight."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..belief import LegBatch, trace_reductions
from ..sensor import stack
from .base import GraphPlanner


@dataclass(frozen=True)
class GreedyConfig:
    """No settings: score = (Tr_ROI(P) - Tr_ROI(P+)) / travel time, belief ROI."""


class GreedyPlanner(GraphPlanner):
    """One-step look-ahead on the roadmap with the belief covariance only (no truth, no stepping)."""

    name = "greedy"
    Config = GreedyConfig

    def reset(self, view, seed):
        super().reset(view, seed)
        self._batches: dict[int, LegBatch] = {}

    def _batch(self, node: int) -> LegBatch:
        """The measurements of the legs to every neighbour of ``node`` (cached per episode)."""
        batch = self._batches.get(node)
        if batch is None:
            rm = self.view.roadmap
            legs = []
            for target in rm.neighbours[node]:
                obs = self.view.leg_observations(rm.positions[node], rm.positions[target])
                legs.append(stack(obs) if obs else None)
            batch = self._batches[node] = LegBatch(legs)
        return batch

    def scores(self, obs) -> np.ndarray:
        """Predicted ROI trace reduction per second for each neighbour (-inf where masked)."""
        view = self.view
        node = int(obs["current_node"][0])
        gains = trace_reductions(view.belief.cov, self._batch(node), view.belief_roi())
        scores = gains / view.neighbour_durations(node, view.position)
        return np.where(obs["action_mask"].astype(bool), scores, -np.inf)

    def act(self, obs):
        return int(np.argmax(self.scores(obs)))
