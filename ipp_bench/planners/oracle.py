"""Oracle: greedy's rule scored on the true region of interest, a reference row that reads the truth.

Greedy scores each neighbour by the predicted reduction of the ROI trace per second of flight, with
the ROI the belief can compute (``mu + beta sigma >= mu_th``). The oracle scores it on the
*evaluation* ROI (the cells whose true value is at least ``mu_th``, the cells the metrics are
computed on), which it reads through a :class:`~ipp_bench.planners.base.TruthView`; everything else
(the covariance, the read-outs of a leg, the clock) is greedy's. Its row shows the room that
knowing where the region of interest lies opens above greedy: an indication, not an upper bound
(it is myopic; a planner that looks further ahead can beat it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .greedy import GreedyPlanner


@dataclass(frozen=True)
class OracleConfig:
    """No settings: score = (Tr_ROI(P) - Tr_ROI(P+)) / travel time over the true ROI."""


class OraclePlanner(GreedyPlanner):
    """Greedy on the true ROI (reference: reads the ground truth's ROI mask, nothing else of it)."""

    name = "oracle"
    Config = OracleConfig
    reads_truth = True

    def roi(self) -> np.ndarray:
        return self.view.true_roi()
