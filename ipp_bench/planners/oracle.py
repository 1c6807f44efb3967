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
to it along the roadmap (by the mission's clock; :class:`~ipp_bench.core.gains.LookBatch`,
:func:`~ipp_bench.core.gains.far_move`), and flies the first leg of that path when a target beats every
neighbour. It is the same criterion, gain per second of flight, over a larger
set of moves; it remains myopic (one look at the target, no plan beyond it), so its row indicates
the room that knowing where the ROI lies opens above greedy, not an upper bound.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.gains import LookBatch, far_move, first_best
from .greedy import GreedyPlanner


@dataclass(frozen=True)
class OracleConfig:
    """No settings: score = (Tr_ROI(P) - Tr_ROI(P+)) / flight time over the true ROI, for the
    neighbours' legs and for one look at every node above a true ROI cell."""


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
                        lambda: self._looks.trace_reductions(self.belief().cov, self._roi))
