"""The MCTS planner's settings (:class:`MCTSConfig`, ``mcts:simulations=24,...``)."""

from __future__ import annotations

from dataclasses import dataclass

from ..core.config import check_integer, check_number
from ..core.mission import TIME_TOL_S

#: the most simulations per decision (a decision of 10^5 is already far longer than a leg's flight)
MAX_SIMULATIONS = 100_000
#: how the gains are computed: the low-rank factor (the default) or the dense reference
SEARCHES = ("lowrank", "reference")


@dataclass(frozen=True)
class MCTSConfig:
    """MCTS settings; the defaults are what the leaderboard flies.

    Attributes:
        simulations: simulations per decision.
        time_limit_s: optional wall-clock limit per decision [s] (None: simulations only).
        horizon_s: flight time looked ahead, tree and rollout together [s].
        gamma: discount per ``discount_period_s`` of flight.
        discount_period_s: flight time over which ``gamma`` applies once [s].
        exploration: UCT constant c in Q + c sqrt(ln N / n) (rewards are in units of the best
            one-step gain at the root).
        pw_k, pw_alpha: progressive widening, children while |C| <= pw_k N^pw_alpha.
        rollout_lambda: sharpness of the cost-benefit rollout.
        search: the gains model: ``"lowrank"`` (the gains from a low-rank factor of the covariance updates,
            :mod:`~ipp_bench.planners.mcts_lowrank`) or ``"reference"`` (a dense covariance copied and downdated
            per tree edge, :mod:`~ipp_bench.planners.mcts_reference`): the same search and gains, up to rounding.
    """

    simulations: int = 24
    time_limit_s: float | None = None  # [s]
    horizon_s: float = 12.0  # [s]
    gamma: float = 0.95
    discount_period_s: float = 2.0  # [s]
    exploration: float = 0.5
    pw_k: float = 2.0
    pw_alpha: float = 0.5
    rollout_lambda: float = 8.0
    search: str = "lowrank"

    def __post_init__(self):
        check_integer("mcts.simulations", self.simulations, 1, MAX_SIMULATIONS)
        if self.time_limit_s is not None:
            check_number("mcts.time_limit_s", self.time_limit_s, 0.0, low_open=True, unit="s")
        # at or below the clock's tolerance the root counts as already at the horizon and no leg is scored
        check_number("mcts.horizon_s", self.horizon_s, TIME_TOL_S, low_open=True, unit="s")
        check_number("mcts.gamma", self.gamma, 0.0, 1.0, low_open=True)
        check_number("mcts.discount_period_s", self.discount_period_s, 0.0, low_open=True, unit="s")
        check_number("mcts.exploration", self.exploration, 0.0)
        check_number("mcts.pw_k", self.pw_k, 1.0)
        check_number("mcts.pw_alpha", self.pw_alpha, 0.0, 1.0)
        check_number("mcts.rollout_lambda", self.rollout_lambda, 0.0)
        if self.search not in SEARCHES:
            raise ValueError(f"mcts.search = {self.search!r} is invalid: expected one of {list(SEARCHES)}")
