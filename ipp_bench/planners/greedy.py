"""Greedy: the neighbour with the highest predicted ROI trace reduction per second of flight."""

from __future__ import annotations

import weakref
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..core.belief import LegBatch
from ..core.gains import first_best
from .base import GraphPlanner, stacked_leg


@dataclass(frozen=True)
class GreedyConfig:
    """No settings: score = (Tr_ROI(P) - Tr_ROI(P+)) / travel time, belief ROI."""


_LEGS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: roadmap nodes whose legs are cached for the window belief, most recently used kept: about 0.3 MB a
#: node (20 legs of up to 3 looks), so a 128 x 128 roadmap of 32 768 nodes cached in full would be 10 GB
WINDOW_LEG_CACHE_NODES = 512


def leg_batch(view, node: int) -> LegBatch | list:
    """The read-outs of the legs from ``node`` to each of its neighbours, as the view's belief takes them.

    They depend only on the roadmap, the camera and the measurement spacing, so they are built once
    per roadmap (the planner's episodes and the attention policy's feature share them). The dense
    belief gets one :class:`~ipp_bench.core.belief.LegBatch` (weights padded to the union of the legs'
    cells) per node, every node kept; the window belief the per-leg list ``(cells, W, var)`` or None
    it is built from, the last :data:`WINDOW_LEG_CACHE_NODES` nodes kept.
    """
    rm = view.roadmap
    window = view.config.gp.belief == "window"
    key = (view.sensor.cfg, view.config.grid, view.config.mission.measurement_spacing, window)
    per_map = _LEGS.get(rm)
    if per_map is None or per_map[0] != key:
        per_map = _LEGS[rm] = (key, OrderedDict() if window else {})
    cache = per_map[1]
    batch = cache.get(node)
    if batch is None:
        legs = [stacked_leg(view, node, a) for a in range(rm.k)]
        batch = cache[node] = legs if window else LegBatch(legs)
        if window and len(cache) > WINDOW_LEG_CACHE_NODES:
            cache.popitem(last=False)
    elif window:
        cache.move_to_end(node)
    return batch


def greedy_scores(view, node: int, roi: np.ndarray | None = None, belief=None) -> np.ndarray:
    """(k,) predicted ROI trace reduction per second of flight of the leg to each neighbour of ``node``
    (from the view's position), unmasked: greedy's score. The ROI is the belief's (``roi=None``) or
    the mask given (the ``oracle`` reference passes the true one); the covariance the view's belief's
    or ``belief``'s (a team-aware planner's, with its teammates' committed read-outs fused)."""
    roi = view.belief_roi() if roi is None else roi
    gains = (view.belief if belief is None else belief).trace_reductions(leg_batch(view, node), roi)
    return gains / view.neighbour_durations(node, view.position)


class GreedyPlanner(GraphPlanner):
    """One-step look-ahead on the roadmap with the belief covariance only (no truth, no stepping)."""

    name = "greedy"
    Config = GreedyConfig

    def roi(self) -> np.ndarray | None:
        """The ROI the score is computed on: None, the belief's (``mu + beta sigma >= mu_th``)."""
        return None

    def belief(self):
        """The belief whose covariance the legs are scored on: the view's."""
        return self.view.belief

    def scores(self, obs) -> np.ndarray:
        """Predicted ROI trace reduction per second for each neighbour (-inf where masked)."""
        scores = greedy_scores(self.view, int(obs["current_node"][0]), self.roi(), self.belief())
        return np.where(obs["action_mask"].astype(bool), scores, -np.inf)

    def act(self, obs):
        return first_best(self.scores(obs))
