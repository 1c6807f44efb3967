"""Planners for UAV teams, and the team episode loop.

A team task (:class:`~ipp_bench.envs.team.TeamGraphEnv`) is flown by one planner per UAV, all built
from one spec:

- any single-UAV planner (``greedy``, ``attention``, ``mcts``, ...) flies each UAV on its own, on the
  shared belief (*independent*): it sees what its teammates have read so far, not where they are going;
- ``team-greedy`` scores its legs as greedy does, on the belief with its teammates' committed legs
  fused into the covariance in advance (:meth:`~ipp_bench.planners.base.TeamRobotView.belief_ahead`:
  exact, since the covariance does not depend on the values read), so it does not plan to look where
  a teammate is about to look;
- ``team-coverage``: the lawnmower with the map split into one band of rows per UAV;
- ``team-oracle``: the ``oracle`` reference (greedy on the true ROI, with far targets) with the
  teammates' committed legs fused in advance.

:func:`~ipp_bench.planners.episode.fly_team_episode` is the team's episode loop (``fly_episode`` hands a
team env to it); it returns the single-UAV loop's :class:`~ipp_bench.planners.episode.EpisodeResult`
(the team's report on the shared belief).
"""

from __future__ import annotations

from dataclasses import dataclass

from .greedy import GreedyPlanner
from .oracle import OraclePlanner
from .simple import CoverageConfig, CoveragePlanner


@dataclass(frozen=True)
class TeamGreedyConfig:
    """No settings: greedy's score, (Tr_ROI(P) - Tr_ROI(P+)) / flight time, with P the covariance after
    the teammates' committed read-outs."""


class _TeamAware:
    """Scores on :meth:`~ipp_bench.planners.base.TeamRobotView.belief_ahead`, computed once per decision."""

    team = True

    def act(self, obs):
        self._ahead = self.view.belief_ahead()
        return super().act(obs)

    def belief(self):
        return self._ahead


class TeamGreedyPlanner(_TeamAware, GreedyPlanner):
    """Greedy for a UAV of a team: its legs scored on the covariance its teammates' committed legs will leave."""

    name = "team-greedy"
    Config = TeamGreedyConfig

    def reset(self, view, seed: int) -> None:
        view.require_dense_belief(self.name, "the teammates' read-outs are fused into the full covariance")
        super().reset(view, seed)


class TeamOraclePlanner(_TeamAware, OraclePlanner):
    """The ``oracle`` reference for a UAV of a team: greedy on the true ROI, far targets included, on the
    covariance its teammates' committed legs will leave."""

    name = "team-oracle"


class TeamCoveragePlanner(CoveragePlanner):
    """The lawnmower for UAV i of n: lanes over the i-th of n equal bands of the map's y extent."""

    name = "team-coverage"
    Config = CoverageConfig
    team = True

    def band(self, view) -> tuple[float, float]:
        height = view.config.grid.size_m[1]
        return view.uav * height / view.team_size, (view.uav + 1) * height / view.team_size


__all__ = ["TeamCoveragePlanner", "TeamGreedyPlanner", "TeamOraclePlanner"]
