"""A team of UAVs on one roadmap and one shared belief, as a PettingZoo AEC environment.

Decisions are asynchronous: a UAV decides when its leg ends, so the UAV whose leg ends next acts
next (``agent_selection`` is the UAV with the earliest clock, ties to the lower index), and a UAV
whose leg is short acts again before a teammate on a long leg. Each UAV's observation is the
single-UAV task's, built by the same :class:`~ipp_bench.envs.observation.GraphObservation` the
single-UAV env holds (node features of the shared belief, its own node, neighbours, action mask and
budget fraction), so a single-UAV policy or planner flies any UAV of a team unchanged. The mask offers
the legs the UAV's own budget pays for and, unless the task lets UAVs share nodes, not a node another
UAV stands on or is flying to (where every affordable leg is taken by a teammate, the taken ones are
offered: a UAV never stops because a teammate is in the way).

The belief holds every read-out taken up to the acting UAV's clock (:class:`~ipp_bench.core.team.TeamMission`).
Rewards are the team's: after each leg, the shared belief's ROI trace reduction up to the next
decision (the single-UAV task's reward, eq. 9), given to every UAV. A UAV whose budget pays for no
further leg is terminated (stepped with None, then removed); the episode ends when every UAV is.

PettingZoo's conventions: :func:`raw_env` is the bare env of a team task (what
:func:`~ipp_bench.envs.make_env` returns), :func:`env` the same wrapped in PettingZoo's
``AssertOutOfBoundsWrapper`` (the actions are ``Discrete``) and ``OrderEnforcingWrapper``. There is
no parallel view, and ``metadata["is_parallelizable"]`` is False: PettingZoo's ``aec_to_parallel``
steps every live agent once per cycle in a fixed order, which this turn order is not (the wrapper
would fail the first time a UAV acts twice in a row), and a hand-written ``ParallelEnv`` would have
every UAV decide at once on one belief: a synchronous team, another task, whose UAVs would decide
before their legs end or wait for their teammates'. A UAV's own seat (:class:`UAVSeat`) is what its
planner reads through :class:`~ipp_bench.planners.base.TeamRobotView`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding
from pettingzoo import AECEnv
from pettingzoo.utils import wrappers

from ..core import metrics as M
from ..core.config import TIME_TOL_S, IPPConfig, invalid
from ..core.mission import cell_to_xyz
from ..core.team import MemberMission, TeamConfig, TeamMission
from .episode import check_render_mode, draw_episode, episode_seed, resolve_config
from .observation import GraphObservation
from .panels import render_mission

#: the team task :func:`env` and :func:`raw_env` make when none is named
DEFAULT_TASK = "ipp_bench/Hotspots30Team2Eval-v2"


class UAVSeat:
    """UAV ``index``'s seat in a team episode: its mission (a :class:`~ipp_bench.core.team.MemberMission`,
    whose belief is the team's), its node, its mask and its observation. The task's config, roadmap,
    camera and observation are the team env's, shared by every seat; the team env resets and steps it."""

    def __init__(self, team_env: TeamGraphEnv, index: int):
        self.team_env = team_env
        self.index = index
        self.observer: GraphObservation = team_env.observer
        self.mission: MemberMission | None = None
        self.current_node = 0
        self.off_roadmap = False  # flown to a waypoint off the roadmap (a continuous planner's UAV)

    @property
    def config(self) -> IPPConfig:
        return self.team_env.config

    @property
    def roadmap(self):
        return self.observer.roadmap

    @property
    def sensor(self):
        return self.observer.sensor

    @property
    def task_id(self) -> str | None:
        return self.team_env.task_id

    @property
    def episode_seed(self) -> int | None:
        return self.team_env.episode_seed

    @property
    def observation_space(self):
        return self.observer.observation_space

    @property
    def action_space(self):
        return self.observer.action_space

    def action_masks(self) -> np.ndarray:
        """(k,) bool: the neighbours this UAV may fly to now (:meth:`TeamGraphEnv.uav_mask`)."""
        return self.team_env.uav_mask(self.index)

    def observe(self, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """This UAV's observation (``mask``: :meth:`action_masks`, when already computed)."""
        return self.observer.observe(self.mission, self.current_node, self.action_masks() if mask is None else mask)


class TeamGraphEnv(AECEnv):
    """Several UAVs mapping one field into one belief (PettingZoo AEC).

    Args:
        config: the task's :class:`~ipp_bench.core.config.IPPConfig` (or a dict of its sections).
        team: the task's ``[team]`` table (:class:`~ipp_bench.core.team.TeamConfig` or a dict).
        render_mode: ``"rgb_array"`` or None.
        task_id: the task's id (tables, messages).
        **overrides: config fields by name (``budget_s=100``).

    Agents are ``uav_0 .. uav_{n-1}``; their observation and action spaces are the single-UAV task's.
    ``reset(seed=s)`` plays the task's episode seed as the single-UAV task does: the same field, the
    first UAV's start and camera noise as the single-UAV episode of that seed, so a team and one UAV
    are compared on the same fields. ``options={"start_nodes": [..]}`` sets every UAV's start node.
    """

    metadata = {"render_modes": ["rgb_array"], "name": "ipp_bench_team", "is_parallelizable": False,
                "render_fps": 4}

    def __init__(self, config: IPPConfig | dict | None = None, team: TeamConfig | dict | None = None,
                 render_mode: str | None = None, task_id: str | None = None, **overrides: Any):
        super().__init__()
        if team is None:
            team = TeamConfig()
        elif isinstance(team, dict):
            team = TeamConfig.from_dict(team)
        elif not isinstance(team, TeamConfig):
            invalid("team", team, "an ipp_bench.core.team.TeamConfig, a dict of the [team] table or None")
        self.config = resolve_config(config, overrides)
        check_render_mode(render_mode, self.metadata["render_modes"])
        team.check(self.config)
        self.team = team
        self.task_id = task_id
        self.render_mode = render_mode
        self.observer = GraphObservation.for_config(self.config)
        self.roadmap, self.sensor = self.observer.roadmap, self.observer.sensor
        if not team.share_nodes and team.size > self.roadmap.n_nodes:
            invalid("team.size", team.size, f"at most {self.roadmap.n_nodes} UAVs on this roadmap of "
                    f"{self.roadmap.n_nodes} nodes (team.share_nodes = false: one UAV per node)")
        if team.starts is not None and not team.share_nodes:
            nodes = [self.roadmap.nearest_node(cell_to_xyz(self.config, *s)) for s in team.starts]
            if len(set(nodes)) < len(nodes):
                invalid("team.starts", [list(s) for s in team.starts], "starts on different roadmap nodes "
                        "(team.share_nodes = false), or team.share_nodes = true")
        #: the shared world's config (the longest budget) and each UAV's (its own budget and start)
        self.world_config = team.team_config(self.config)
        self.member_configs = [team.member_config(self.config, i) for i in range(team.size)]
        self.possible_agents = [f"uav_{i}" for i in range(team.size)]
        self.seats = [UAVSeat(self, i) for i in range(team.size)]
        self.mission: TeamMission | None = None
        self.episode_seed: int | None = None
        self.agents: list[str] = []
        self.rewards, self._cumulative_rewards = {}, {}
        self.terminations, self.truncations, self.infos = {}, {}, {}
        self.agent_selection = self.possible_agents[0]
        self._roi: np.ndarray | None = None
        self._seed_rng = np.random.default_rng()  # draws the episode seed of reset(seed=None)

    # -- spaces ----------------------------------------------------------------------------------
    def observation_space(self, agent: str):
        return self.observer.observation_space

    def action_space(self, agent: str):
        return self.observer.action_space

    # -- reset -----------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        seed = episode_seed(self.config, seed, self._seed_rng.integers)
        self.episode_seed = seed
        rng, _ = seeding.np_random(seed)  # as GraphIPPEnv.reset: the same field, start and noise for UAV 0
        truth, start_seed, noise_seed = draw_episode(self.config, rng)
        nodes = self._start_nodes(start_seed, options)
        rngs = [np.random.default_rng(noise_seed)] + [np.random.default_rng([noise_seed, i])
                                                      for i in range(1, self.team.size)]
        starts = [self.roadmap.positions[n] for n in nodes]
        self.mission = self._make_mission(truth, starts, rngs)
        for seat, member, node in zip(self.seats, self.mission.members, nodes):
            seat.mission, seat.current_node, seat.off_roadmap = member, node, False
        self.agents = self.possible_agents[:]
        self.rewards = {a: 0.0 for a in self.agents}
        self._cumulative_rewards = {a: 0.0 for a in self.agents}
        self.terminations = {a: False for a in self.agents}
        self.truncations = {a: False for a in self.agents}
        for i, seat in enumerate(self.seats):
            if not seat.mission.affordable(self.roadmap.positions[self.roadmap.neighbours[seat.current_node]]).any():
                raise ValueError(f"the budget of UAV {i} ({seat.mission.budget_s:g} s) pays for no move from its "
                                 f"start node {seat.current_node}; raise budget_s or team.budgets_s")
        self.infos = {a: self._info(i) for i, a in enumerate(self.agents)}
        self._roi = self.mission.belief_roi()
        self.agent_selection = self._next()

    def _make_mission(self, truth: np.ndarray, starts: list[np.ndarray], rngs: list[np.random.Generator],
                      **platform: Any) -> TeamMission:
        """The episode's team mission; ``platform``: :class:`~ipp_bench.core.team.TeamMission`'s ``platform``
        and ``ahead`` (default: the graph's straight legs; a simulated team passes its drones')."""
        return TeamMission(self.world_config, self.team, truth, starts, rngs, self.member_configs,
                           sensor=self.sensor, **platform)

    def _fly_until(self, time_s: float | None) -> None:
        """Fly the committed legs up to ``time_s`` (None: to their ends). The graph's legs are flown
        whole when they are committed, so nothing is left to fly here; a simulated team flies here."""

    def _start_nodes(self, start_seed: int, options: dict | None) -> list[int]:
        n, size = self.roadmap.n_nodes, self.team.size
        if options and "start_nodes" in options:
            nodes = options["start_nodes"]
            if (not isinstance(nodes, (list, tuple)) or len(nodes) != size
                    or not all(isinstance(v, (int, np.integer)) and 0 <= v < n for v in nodes)
                    or (not self.team.share_nodes and len(set(nodes)) < size)):
                invalid("options['start_nodes']", nodes, f"{size} node indices in 0..{n - 1}"
                        + ("" if self.team.share_nodes else ", all different (team.share_nodes = false)"))
            return [int(v) for v in nodes]
        out: list[int] = []
        for i in range(size):
            xyz = self.team.start_xyz(self.config, i)
            if xyz is not None:
                out.append(self.roadmap.nearest_node(xyz))
                continue
            draw = np.random.default_rng(start_seed if i == 0 else [start_seed, i])
            node = int(draw.integers(n))
            while not self.team.share_nodes and node in out:
                node = int(draw.integers(n))
            out.append(node)
        return out

    # -- turn order and masks ------------------------------------------------------------------------
    def _next(self) -> str:
        """A terminated UAV first (to be stepped with None), else the live UAV with the earliest clock."""
        dead = [a for a in self.agents if self.terminations[a]]
        if dead:
            return dead[0]
        return min(self.agents, key=lambda a: (self.seats[self.uav_index(a)].mission.time_s, self.uav_index(a)))

    def uav_index(self, agent: str) -> int:
        """``"uav_3"`` -> 3."""
        return self.possible_agents.index(agent)

    def uav_mask(self, i: int) -> np.ndarray:
        """(k,) bool: UAV i's neighbours that its budget pays for and no teammate holds (see the module)."""
        seat = self.seats[i]
        nbrs = self.roadmap.neighbours[seat.current_node]
        mask = seat.mission.affordable(self.roadmap.positions[nbrs])
        if self.team.share_nodes or self.mission is None:
            return mask
        held = {s.current_node for j, s in enumerate(self.seats) if j != i and f"uav_{j}" in self.agents}
        free = mask & ~np.isin(nbrs, list(held))
        return free if free.any() else mask

    # -- AEC API ---------------------------------------------------------------------------------------
    def observe(self, agent: str) -> dict[str, np.ndarray]:
        seat = self.seats[self.uav_index(agent)]
        return seat.observe(self.uav_mask(seat.index))

    def step(self, action) -> None:
        if self.mission is None:
            raise RuntimeError("call reset() before step()")
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            if action is not None:
                raise ValueError(f"{agent} is done: the only valid action is None")
            self._remove(agent)
            return
        i = self.uav_index(agent)
        seat = self.seats[i]
        mask = self.uav_mask(i)
        a = self.observer.check_action(action, mask)
        self._cumulative_rewards[agent] = 0.0
        target = int(self.roadmap.neighbours[seat.current_node, a])
        seat.mission.fly_to(self.roadmap.positions[target])
        seat.current_node = target
        self._after_leg()

    def fly_waypoint(self, xyz) -> None:
        """Fly the acting UAV to ``xyz`` [m] off the roadmap (continuous planners); its node becomes
        the nearest roadmap node. ValueError as ``Mission.fly_to``."""
        agent = self.agent_selection
        if self.mission is None or self.terminations.get(agent, True):
            raise RuntimeError(f"{agent} cannot fly now (the episode is over or the UAV is done)")
        seat = self.seats[self.uav_index(agent)]
        self._cumulative_rewards[agent] = 0.0
        seat.mission.fly_to(xyz)
        seat.current_node = self.roadmap.nearest_node(seat.mission.position)
        seat.off_roadmap = True  # its planner, not the roadmap's mask, says when it is done (retire)
        self._after_leg()

    def retire(self) -> None:
        """End the acting UAV's flight (a continuous planner with no further waypoint)."""
        self.terminations[self.agent_selection] = True
        self._after_leg()

    def _after_leg(self) -> None:
        """Terminate the UAVs that can fly no more, fuse up to the next decision, pay the team's reward."""
        for a in self.agents:
            seat = self.seats[self.uav_index(a)]
            if self.terminations[a]:
                continue
            if seat.off_roadmap:
                done = seat.mission.remaining_s <= TIME_TOL_S
            else:
                nbrs = self.roadmap.positions[self.roadmap.neighbours[seat.current_node]]
                done = not seat.mission.affordable(nbrs).any()
            self.terminations[a] = done
        live = [a for a in self.agents if not self.terminations[a]]
        before = M.trace_roi(self.mission.belief.variance, self._roi)
        if live:
            now = min(self.seats[self.uav_index(a)].mission.time_s for a in live)
            self._fly_until(now)
            self.mission.fuse_until(now)
        else:
            self._fly_until(None)
            self.mission.finish()
        after = M.trace_roi(self.mission.belief.variance, self._roi)
        reward = M.info_gain_reward(before, after)
        self._roi = self.mission.belief_roi()
        for a in self.agents:
            self.rewards[a] = reward
        self._accumulate_rewards()
        for i, a in enumerate(self.possible_agents):
            if a in self.agents:
                self.infos[a] = self._info(i)
        self.agent_selection = self._next()

    def _remove(self, agent: str) -> None:
        for table in (self.terminations, self.truncations, self.rewards, self._cumulative_rewards, self.infos):
            del table[agent]
        self.agents.remove(agent)
        for a in self.agents:
            self.rewards[a] = 0.0
        if self.agents:
            self.agent_selection = self._next()

    def _info(self, i: int) -> dict[str, Any]:
        seat = self.seats[i]
        return {"node": seat.current_node, "time_s": seat.mission.time_s, "remaining_s": seat.mission.remaining_s,
                "team": self.mission.metrics(), "episode_seed": self.episode_seed}

    def render(self):
        if self.render_mode is None or self.mission is None:
            return None
        return render_mission(self.mission)

    def close(self) -> None:
        self.mission = None


def raw_env(task: str = DEFAULT_TASK, render_mode: str | None = None, **overrides: Any) -> TeamGraphEnv:
    """The team task ``task`` as PettingZoo's bare AEC env (what :func:`~ipp_bench.envs.make_env` returns:
    its own attributes and methods, :meth:`TeamGraphEnv.fly_waypoint` and :meth:`TeamGraphEnv.retire`
    included).

    Args:
        task: a team task's id (the ``ipp_bench/`` prefix optional) or task file.
        render_mode: ``"rgb_array"`` or None.
        **overrides: config fields by name, ``team={...}`` for fields of its ``[team]`` table.

    Raises:
        ValueError: a task that is not a team task, a render mode the env lacks, or a bad override.
    """
    from .registry import is_team_task, make_env, tagged

    if not is_team_task(task):
        raise ValueError(f"task {task!r} flies one UAV: a PettingZoo env is a team task's, valid are {tagged('team')}")
    check_render_mode(render_mode, TeamGraphEnv.metadata["render_modes"])
    return make_env(task, render=render_mode is not None, **overrides)


def env(task: str = DEFAULT_TASK, render_mode: str | None = None, **overrides: Any) -> AECEnv:
    """:func:`raw_env` in PettingZoo's standard wrappers: ``AssertOutOfBoundsWrapper`` (an action outside
    ``Discrete(k)`` fails before the env sees it) and ``OrderEnforcingWrapper`` (no step, observe or
    agent_iter before reset). Attributes pass through the wrappers; a continuous planner's
    :meth:`TeamGraphEnv.fly_waypoint` is no PettingZoo step, so fly those on :func:`raw_env`."""
    wrapped = wrappers.AssertOutOfBoundsWrapper(raw_env(task, render_mode=render_mode, **overrides))
    return wrappers.OrderEnforcingWrapper(wrapped)


__all__ = ["DEFAULT_TASK", "TeamGraphEnv", "UAVSeat", "env", "raw_env"]
