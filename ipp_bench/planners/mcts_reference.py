"""The MCTS's reference gains model (``mcts:search=reference``): every tree state holds its own dense covariance.

The direct form of the search's gains: every edge copies the parent's n x n covariance and downdates it
with the leg's Kalman update (:func:`~ipp_bench.core.belief.gain_factor`,
:func:`~ipp_bench.core.belief.downdate_inplace`), and every expanded state scores its legs with
:func:`~ipp_bench.core.belief.trace_reductions` on that copy; the rollout draws its moves in Python. It costs
O(n^2) memory and time per edge; the low-rank model (:mod:`~ipp_bench.planners.mcts_lowrank`) computes the
same gains from a low-rank factor and is what the leaderboard runs. This one is the reference the tests and
``benchmarks/bench_search.py`` compare it with.
"""

from __future__ import annotations

import numpy as np

from ..core.belief import LegBatch, downdate_inplace, gain_factor, trace_reductions
from .base import RobotView, softmax, stacked_leg


class ReferenceGains:
    """The dense gains model of :class:`~ipp_bench.planners.mcts.MCTSPlanner` for one episode (``view``).

    A state's covariance is ``state.cov``: the belief's at the root (not copied: never written), a downdated
    copy of its parent's below it.
    """

    def __init__(self, view: RobotView):
        self.view = view
        self._legs: dict[tuple[int, int], tuple | None] = {}
        self._batches: dict[int, LegBatch] = {}
        self._roi: np.ndarray | None = None

    @staticmethod
    def check_installed() -> None:
        """The reference needs nothing beyond numpy and scipy."""

    def begin(self, roi: np.ndarray) -> None:
        """A decision's search starts: the ROI its rewards are counted on."""
        self._roi = roi

    def _leg(self, node: int, action: int) -> tuple | None:
        """The stacked read-outs of the leg ``node -> action`` (cached; None: the camera sees nothing)."""
        key = (node, action)
        if key not in self._legs:
            self._legs[key] = stacked_leg(self.view, node, action)
        return self._legs[key]

    def _batch(self, node: int) -> LegBatch:
        """The legs out of ``node``, stacked for :func:`~ipp_bench.core.belief.trace_reductions` (cached)."""
        batch = self._batches.get(node)
        if batch is None:
            batch = self._batches[node] = LegBatch([self._leg(node, a) for a in range(self.view.roadmap.k)])
        return batch

    def leg_gains(self, cov: np.ndarray, node: int) -> np.ndarray:
        """(k,) reductions of Tr(P) over the decision's ROI by each leg out of ``node``, from covariance ``cov``."""
        return trace_reductions(cov, self._batch(node), self._roi)

    def enter(self, state) -> None:
        """A new state's covariance: the belief's at the root, else its parent's after the edge's update."""
        parent = state.parent
        if parent is None:
            state.cov = self.view.belief.cov
            return
        cov = parent.cov
        leg = self._leg(parent.node, state.action)
        if leg is not None:
            cov = cov.copy()
            downdate_inplace(cov, gain_factor(cov, *leg)[0])
        state.cov = cov

    def gains(self, state, actions: np.ndarray) -> np.ndarray:
        """(k,) predicted reductions of Tr(P) over the decision's ROI, one per leg out of ``state``."""
        return self.leg_gains(state.cov, state.node)

    def rollout(self, tree, state) -> float:
        """The rollout's return from the tree's new state ``state`` (``tree``: the planner, whose expansion and
        transitions it uses): moves drawn with ``tree.rng`` from the softmax of their gains per second."""
        lam = tree.settings.rollout_lambda
        total, discount = 0.0, 1.0
        while True:
            tree._expand_info(state)
            acts = state.order
            if acts.size == 0:
                break
            rate = state.gains[acts] / state.costs[acts]
            top = rate.max()
            if top <= 0:
                break
            logits = lam * rate / top
            a = int(tree.rng.choice(acts, p=softmax(logits)))
            state, r, d = tree._transition(state, a)
            total += discount * r
            discount *= d
        return total
