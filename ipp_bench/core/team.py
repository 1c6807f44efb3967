"""A team of UAVs mapping one field into one shared belief.

Each UAV has its own clock, position, flight budget, camera noise stream and platform (a
:class:`MemberMission`); all of them read and feed one belief, fused centrally. Decisions are
asynchronous: a UAV decides when its leg ends. A leg's read-outs are taken along the leg, so when a
UAV decides at time t its teammates may be halfway through theirs: what they have read up to t is in
the belief, what they will read after t is not yet (it is *pending*). :class:`TeamMission` keeps the
pending read-outs and fuses them in time order (:meth:`TeamMission.fuse_until`), so the belief at any
time holds exactly the read-outs taken by then, whatever order the legs were decided in, and the
metrics at the report times are exact as for one UAV.

The GP covariance does not depend on the values read, so a planner may fuse its teammates' pending
read-outs into a copy of the covariance in advance (:meth:`TeamMission.pending_observations`): the
variance it predicts is the one the belief will have, exactly. Their values stay hidden until taken.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .config import TIME_TOL_S, IPPConfig, check_integer, invalid, quoted
from .mission import Mission, Platform, Record, cell_to_xyz
from .sensor import Observation

#: the most UAVs a team task may have
MAX_TEAM = 16


@dataclass(frozen=True)
class TeamConfig:
    """A team task's ``[team]`` table.

    Attributes:
        size: number of UAVs (1..:data:`MAX_TEAM`).
        starts: one (col, row, altitude [m]) per UAV, or None: the mission's ``start`` for UAV 0 and
            random roadmap nodes for the others (drawn from the episode seed).
        budgets_s: [s] each UAV's own flight budget, or None: the mission's ``budget_s`` for every UAV.
        share_nodes: whether two UAVs may stand on, or fly to, the same roadmap node.
    """

    size: int = 2
    starts: tuple[tuple[float, float, float], ...] | None = None
    budgets_s: tuple[float, ...] | None = None
    share_nodes: bool = False

    @classmethod
    def from_dict(cls, data: Any) -> TeamConfig:
        """The ``[team]`` table of a task file (or overrides); unknown keys are refused."""
        if not isinstance(data, dict):
            invalid("team", data, "a [team] table: size, starts, budgets_s, share_nodes")
        names = {"size", "starts", "budgets_s", "share_nodes"}
        unknown = sorted(map(str, set(data) - names))
        if unknown:
            raise ValueError(f"unknown fields {unknown} in section 'team': valid are {sorted(names)}")
        values = dict(data)
        if isinstance(values.get("starts"), list):
            values["starts"] = tuple(tuple(s) if isinstance(s, list) else s for s in values["starts"])
        if isinstance(values.get("budgets_s"), list):
            values["budgets_s"] = tuple(values["budgets_s"])
        return cls(**values)

    def __post_init__(self) -> None:
        size = check_integer("team.size", self.size, 1, MAX_TEAM)
        if self.starts is not None:
            if not isinstance(self.starts, (list, tuple)) or len(self.starts) != size:
                invalid("team.starts", self.starts, f"{size} positions (col, row, altitude [m]), one per UAV "
                                                    "(team.size), or none")
            for s in self.starts:
                if (not isinstance(s, (list, tuple)) or len(s) != 3
                        or not all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
                                   for v in s)):
                    invalid("team.starts", self.starts, "positions (col, row, altitude [m]) of three finite numbers")
            object.__setattr__(self, "starts", tuple(tuple(float(v) for v in s) for s in self.starts))
        if self.budgets_s is not None:
            if not isinstance(self.budgets_s, (list, tuple)) or len(self.budgets_s) != size:
                invalid("team.budgets_s", self.budgets_s, f"{size} budgets [s], one per UAV (team.size), or none")
            for b in self.budgets_s:
                if isinstance(b, bool) or not isinstance(b, numbers.Real) or not math.isfinite(b) or b <= 0:
                    invalid("team.budgets_s", self.budgets_s, "budgets > 0 [s]")
            object.__setattr__(self, "budgets_s", tuple(float(b) for b in self.budgets_s))
        if not isinstance(self.share_nodes, bool):
            invalid("team.share_nodes", self.share_nodes, "true or false")

    def check(self, config: IPPConfig) -> None:
        """Refuse, in one line, a team that does not fit the task's map and flight envelope."""
        g = config.grid
        low, high = config.altitude_range
        for i, (c, r, h) in enumerate(self.starts or ()):
            if not (0 <= c <= g.cols - 1 and 0 <= r <= g.rows - 1 and low <= h <= high):
                invalid(f"team.starts[{i}]", (c, r, h), f"(col in [0, {g.cols - 1}], row in [0, {g.rows - 1}], "
                        f"altitude in [{low:g}, {high:g}] m, the range of graph.altitudes)")

    def budget(self, config: IPPConfig, uav: int) -> float:
        """[s] UAV ``uav``'s flight budget."""
        return self.budgets_s[uav] if self.budgets_s is not None else config.mission.budget_s

    def member_config(self, config: IPPConfig, uav: int) -> IPPConfig:
        """The task's config as UAV ``uav`` flies it: its own budget and start."""
        over: dict[str, Any] = {"budget_s": self.budget(config, uav)}
        if self.starts is not None:
            over["start"] = self.starts[uav]
        return config.replace(**over)

    def team_config(self, config: IPPConfig) -> IPPConfig:
        """The config of the shared world: the longest budget (the report times within it)."""
        return config.replace(budget_s=max(self.budget(config, i) for i in range(self.size)))

    def start_xyz(self, config: IPPConfig, uav: int) -> np.ndarray | None:
        """[m] UAV ``uav``'s configured start, or None (the env draws one)."""
        if self.starts is not None:
            return cell_to_xyz(config, *self.starts[uav])
        if uav == 0 and config.mission.start is not None:
            return cell_to_xyz(config, *config.mission.start)
        return None

    def to_dict(self) -> dict[str, Any]:
        return {"size": self.size, "starts": None if self.starts is None else [list(s) for s in self.starts],
                "budgets_s": None if self.budgets_s is None else list(self.budgets_s),
                "share_nodes": self.share_nodes}


class MemberMission(Mission):
    """One UAV of a team: a :class:`~ipp_bench.core.mission.Mission` whose clock, position, budget, noise
    stream and platform are its own, whose belief is the team's, and whose read-outs go to the team
    (:meth:`TeamMission.take`) instead of into the belief. Its own ``history`` is never updated:
    the team's metrics are the :class:`TeamMission`'s."""

    def __init__(self, team: TeamMission, index: int, config: IPPConfig, start_xyz, rng: np.random.Generator,
                 platform: Platform | None = None):
        self.team = team  # set before Mission.__init__: its start read-out already goes to the team
        self.index = index
        super().__init__(config, team.truth, rng, start_xyz, belief=team.belief, sensor=team.sensor,
                         platform=platform)
        self.belief_model = team.world.belief_model
        team.world.measurement_log.extend(self.measurement_log)  # one log, every UAV's read-outs
        self.measurement_log = team.world.measurement_log

    def assimilate_records(self, records: list[Record]) -> int:
        self.team.take(self.index, records)
        return sum(o.m for o, _, _ in records if o is not None)


class TeamMission:
    """The shared world of a team episode: truth, one belief, the metrics, and the UAVs.

    Args:
        config: the task (its ``budget_s`` the longest of the UAVs': the report times within it).
        team: the team's settings.
        truth: (rows, cols) ground truth.
        starts: (3,) [m] start of each UAV.
        rngs: one sensor-noise generator per UAV.
        member_configs: each UAV's config (its own budget); default: ``team.member_config``.
        sensor: the camera model (default: built from ``config``).
        platform: a factory ``platform(uav)`` of each UAV's platform (default: straight legs).
        ahead: for platforms whose legs are flown as time goes on (a simulated team, which cannot fly a
            leg before its teammates reach its time): ``ahead(uav)`` predicts the read-outs UAV
            ``uav``'s committed leg will still take; :meth:`pending_observations` adds them.
    """

    def __init__(self, config: IPPConfig, team: TeamConfig, truth: np.ndarray, starts: Sequence,
                 rngs: Sequence[np.random.Generator], member_configs: Sequence[IPPConfig] | None = None,
                 sensor=None, platform: Callable[[int], Platform] | None = None,
                 ahead: Callable[[int], list[Observation]] | None = None):
        if len(starts) != team.size or len(rngs) != team.size:
            raise ValueError(f"a team of {team.size} needs {team.size} starts and noise generators: got "
                             f"{len(starts)} and {len(rngs)}")
        self.config = config
        self.team_config = team
        # the world: belief, truth, metrics; it never flies (no start read-out of its own)
        world_cfg = config.replace(measure_at_start=False)
        self.world = Mission(world_cfg, truth, np.random.default_rng(0), starts[0], sensor=sensor)
        self.truth = self.world.truth
        self.sensor = self.world.sensor
        self.belief = self.world.belief
        self._pending: list[tuple[float, int, int, Record]] = []  # (time, uav, order taken, record)
        self._taken = 0
        self._ahead = ahead
        self.fused_s = 0.0  # [s] the belief holds every read-out taken up to this time
        configs = member_configs or [team.member_config(config, i) for i in range(team.size)]
        self.members: list[MemberMission] = []
        for i in range(team.size):
            self.members.append(MemberMission(self, i, configs[i], starts[i], rngs[i],
                                              platform(i) if platform is not None else None))
        self.fuse_until(0.0)

    # -- read-outs ---------------------------------------------------------------------------------
    def take(self, uav: int, records: list[Record]) -> None:
        """Keep UAV ``uav``'s read-outs until the belief reaches their times."""
        for record in records:
            self._pending.append((float(record[2]), uav, self._taken, record))
            self._taken += 1

    def fuse_until(self, time_s: float) -> int:
        """Fuse every pending read-out taken at or before ``time_s``, in time order (ties: by UAV, then
        in the order taken), split at the report times as one UAV's are; returns the measurements fused."""
        due = sorted(p for p in self._pending if p[0] <= time_s + TIME_TOL_S)
        if due:
            self._pending = [p for p in self._pending if p[0] > time_s + TIME_TOL_S]
            n = self.world.assimilate_records([p[3] for p in due])
        else:
            n = 0
        self.fused_s = max(self.fused_s, float(time_s))
        self.world.time_s = self.fused_s
        return n

    def finish(self) -> int:
        """Fuse what is still pending (the team's flights are over)."""
        return self.fuse_until(max([self.fused_s] + [p[0] for p in self._pending]))

    def pending_observations(self, exclude: int | None = None) -> list[Observation]:
        """The observations (where and how noisy; not the values) of the read-outs taken but not yet
        fused, of every UAV but ``exclude``: a teammate's committed leg, which a planner may fuse into
        its predicted covariance in advance. With an ``ahead`` predictor, the read-outs the teammates'
        committed legs will still take are added as predicted."""
        out = [p[3][0] for p in sorted(self._pending) if p[1] != exclude and p[3][0] is not None]
        if self._ahead is not None:
            for uav in range(len(self.members)):
                if uav != exclude:
                    out.extend(self._ahead(uav))
        return out

    # -- clock and metrics ---------------------------------------------------------------------------
    @property
    def eval_roi(self) -> np.ndarray:
        return self.world.eval_roi

    @property
    def budget_s(self) -> float:
        """[s] the longest of the UAVs' budgets."""
        return self.world.budget_s

    @property
    def paths(self) -> list[list[tuple[float, float, float, float]]]:
        """Each UAV's waypoints (t, x, y, z)."""
        return [m.path for m in self.members]

    @property
    def history(self):
        return self.world.history

    def report(self) -> list[dict[str, float]]:
        """The team's report: the shared belief's metrics at each report time within the longest budget."""
        return self.world.report()

    def metrics_at(self, time_s: float) -> dict[str, float]:
        return self.world.metrics_at(time_s)

    def metrics(self) -> dict[str, float]:
        """The latest metrics; ``distance_m`` the team's, ``remaining_s`` the UAVs' sum."""
        out = self.world.metrics()
        out.update(distance_m=sum(m.distance_m for m in self.members),
                   remaining_s=sum(m.remaining_s for m in self.members))
        return out

    def belief_roi(self) -> np.ndarray:
        return self.world.belief_roi()

    def __repr__(self) -> str:
        return (f"TeamMission({self.team_config.size} UAVs, fused to {self.fused_s:.2f} s, "
                f"{len(self._pending)} read-outs pending, budgets {[quoted(m.budget_s) for m in self.members]})")


__all__ = ["MAX_TEAM", "MemberMission", "TeamConfig", "TeamMission"]
