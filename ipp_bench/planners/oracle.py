"""Oracle: greedy's rule scored on the true region of interest, a reference row that reads the truth.

Greedy scores each neighbour by the predicted reduction of the ROI trace per second of flight, with
the ROI the belief can compute (``mu + beta sigma >= mu_th``). The oracle scores on the *evaluation*
ROI (the cells whose true value is at least ``mu_th``, the cells the metrics are computed on), which
it reads through a :class:`~ipp_bench.planners.base.TruthView`; the covariance, the read-outs of a
leg and the clock are greedy's.

Scored on the true ROI alone, greedy's one-leg rule hovers: once the patch nearest to it is mapped,
the tiny gains of short legs over it beat every leg into empty ground, and a patch two legs away
is never reached (measured on ``Hotspots30Eval-v2``: stuck at 18 % for 60 s on seeds where greedy
reaches 48 %). So the oracle scores, besides its neighbours' legs, every roadmap node above a true
ROI cell as a target: the ROI trace reduction of one look there per second of the quickest flight
to it along the roadmap (by the mission's clock), and flies the first leg of that path when a
target beats every neighbour. It is the same criterion, gain per second of flight, over a larger
set of moves; it remains myopic (one look at the target, no plan beyond it), so its row indicates
the room that knowing where the ROI lies opens above greedy, not an upper bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import first_best
from .far import far_move
from .greedy import GreedyPlanner


@dataclass(frozen=True)
class OracleConfig:
    """No settings: score = (Tr_ROI(P) - Tr_ROI(P+)) / flight time over the true ROI, for the
    neighbours' legs and for one look at every node above a true ROI cell."""


class LookBatch:
    """Single read-outs (one per target node), each on its own cells, padded for batched algebra.

    Unlike :class:`~ipp_bench.belief.LegBatch` (one union of cells for all legs, right for the
    neighbours of one node), each look keeps its own few cells, so looks spread over the whole map
    cost what their own cells cost.
    """

    def __init__(self, observations):
        m = max(o.weights.shape[0] for o in observations)
        c = max(o.cells.size for o in observations)
        self.cells = np.zeros((len(observations), c), dtype=np.int64)  # padding: cell 0 with weight 0
        self.W = np.zeros((len(observations), m, c))
        self.var = np.ones((len(observations), m))  # padding rows: unit variance, zero weight
        for j, o in enumerate(observations):
            rows, q = o.weights.shape
            self.cells[j, :q] = o.cells
            self.W[j, :rows, :q] = o.weights
            self.var[j, :rows] = o.var

    def trace_reductions(self, cov: np.ndarray, roi: np.ndarray) -> np.ndarray:
        """(b,) Tr(P - P+) over the cells ``roi`` (bool mask) of each look alone.

        With S = H P H^T + R, the reduction is sum over ROI columns r of (H P)_r^T S^-1 (H P)_r
        = sum(S^-1 * H Q H^T) with Q = P[:, roi] P[roi, :]: one product over the whole map, then
        each look reads its own few cells of P and Q.
        """
        n = cov.shape[0]
        if getattr(self, "_n", None) != n:
            self._n, self._flat = n, self.cells[:, :, None] * n + self.cells[:, None, :]
        P_roi = cov[:, roi]
        Q = P_roi @ P_roi.T
        Wt = self.W.transpose(0, 2, 1)
        S = self.W @ cov.ravel()[self._flat] @ Wt
        idx = np.arange(S.shape[1])
        S[:, idx, idx] += self.var
        return (np.linalg.inv(S) * (self.W @ Q.ravel()[self._flat] @ Wt)).sum(axis=(1, 2))


class OraclePlanner(GreedyPlanner):
    """Greedy on the true ROI, with the nodes above it as far targets (reference: reads the ground
    truth's ROI mask, nothing else of it)."""

    name = "oracle"
    Config = OracleConfig
    reads_truth = True

    def reset(self, view, seed: int) -> None:
        view.require_dense_belief(self.name, "its far targets' look gains need the full covariance with the "
                                  "ROI (LookBatch, n x n)")
        super().reset(view, seed)
        self._set_targets(view.true_roi())

    def _set_targets(self, roi: np.ndarray) -> None:
        """The nodes above a true ROI cell and their looks (built once per ROI)."""
        view, rm = self.view, self.view.roadmap
        self._roi = roi
        g = view.config.grid
        cols = np.clip((rm.positions[:, 0] // g.resolution).astype(np.int64), 0, g.cols - 1)
        rows = np.clip((rm.positions[:, 1] // g.resolution).astype(np.int64), 0, g.rows - 1)
        above = self._roi[rows * g.cols + cols]
        looks = [(i, view.sensor.observe(rm.positions[i])) for i in np.flatnonzero(above)]
        looks = [(i, o) for i, o in looks if o is not None]
        self._targets = np.array([i for i, _ in looks], dtype=np.int64)
        self._looks = LookBatch([o for _, o in looks]) if looks else None

    def roi(self) -> np.ndarray:
        return self._roi

    def act(self, obs):
        roi = self.view.true_roi()
        if not np.array_equal(roi, self._roi):  # the view's episode changed under the planner
            self._set_targets(roi)
        scores = self.scores(obs)
        if self._looks is None:
            return first_best(scores)
        return far_move(self.view, obs, scores, self._targets,
                        lambda: self._looks.trace_reductions(self.view.belief.cov, self._roi))
