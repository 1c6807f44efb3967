"""Greedy: the neighbour with the highest predicted ROI trace reduction per second of flight."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import GraphPlanner


@dataclass(frozen=True)
class GreedyConfig:
    """No settings: score = (Tr_ROI(P) - Tr_ROI(P+)) / travel time, belief ROI."""


class GreedyPlanner(GraphPlanner):
    """One-step look-ahead on the roadmap with the belief covariance only (no truth, no stepping)."""

    name = "greedy"
    Config = GreedyConfig

    def scores(self, obs) -> np.ndarray:
        """Predicted ROI trace reduction per second for each neighbour (-inf where masked)."""
        view = self.view
        roadmap = view.roadmap
        node = int(obs["current_node"][0])
        here = roadmap.positions[node]
        belief = view.belief
        roi = view.belief_roi()
        before = view.roi_trace(belief.variance, roi)
        out = np.full(roadmap.k, -np.inf)
        for a in np.flatnonzero(obs["action_mask"]):
            target = roadmap.positions[roadmap.neighbours[node, a]]
            var = view.predict_variance(belief, view.leg_observations(here, target))
            out[a] = (before - view.roi_trace(var, roi)) / roadmap.costs[node, a]
        return out

    def act(self, obs):
        return int(np.argmax(self.scores(obs)))
