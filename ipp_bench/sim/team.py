"""A team task deployed in MuJoCo: several quadrotors in one dm_control scene, one shared belief.

The team's PettingZoo environment (:class:`~ipp_bench.envs.team.TeamGraphEnv`: the UAV whose leg ends
next acts, one observation and mask per UAV, the team's reward) over a simulated world: every UAV is a
quadrotor of one :class:`~ipp_bench.sim.world.WeedWorld` (``drones`` = the team's size), flown by its
own cascaded controller from its own state estimate, in the one wind of the episode; its camera is its
sensor (rendered, formed, segmented and projected as for one drone, :meth:`WeedWorld.read_camera`).

The drones share one physics, so their legs are flown together, as time goes on: when a UAV commits a
leg (a velocity-continuous reference, :class:`~ipp_bench.sim.controller.ContinuousLeg`, whose duration
is exact at commit), the physics runs, every drone following its own reference, until the next leg
ends; that UAV decides next. A camera read-out (every ``measurement_spacing`` metres each drone
actually flies, and on arrival) goes to the team as it is taken and is fused in time order
(:class:`~ipp_bench.core.team.TeamMission`), so the belief a UAV decides on holds every read-out taken by
then. What a teammate's committed leg will still read is predicted from its reference (the sensor
model's footprint every spacing metres along it): a team-aware planner fuses those predicted read-outs
into its covariance in advance (``teammates_pending``). The drones do not collide with each other
(:mod:`ipp_bench.sim.scene`).

Only the velocity-continuous flight (v1) flies a team: stop-and-go legs (v0) have no duration known
at commit.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ipp_bench.core.config import IPPConfig, invalid
from ipp_bench.core.mission import LegOutcome, Mission, Record
from ipp_bench.core.sensor import Observation
from ipp_bench.core.team import TeamConfig, TeamMission
from ipp_bench.envs.panels import render_mission
from ipp_bench.envs.team import TeamGraphEnv
from ipp_bench.sim.controller import ContinuousLeg
from ipp_bench.sim.flight import step_together
from ipp_bench.sim.mission import inside_map
from ipp_bench.sim.render import azimuth_to_centre, chase_camera
from ipp_bench.sim.world import SimConfig, WeedWorld, split_sim_settings

_TOL = 1e-9
_AHEAD_DT = 0.05  # [s] step along a committed reference when predicting its read-outs


class _CommittedLeg:
    """A drone's leg in flight: its reference, start and end [s], and whether the budget lets it finish."""

    __slots__ = ("leg", "t0", "limit", "whole")

    def __init__(self, leg: ContinuousLeg, t0: float, limit: float, whole: bool):
        self.leg, self.t0, self.limit, self.whole = leg, t0, limit, whole


class SimTeam:
    """The drones of one team episode, flown together in the world's physics.

    Args:
        world: the simulated world (one drone per UAV).
        starts: (3,) [m] start of each UAV.
        texture_seed: seed of everything the world draws per episode (texture, sun, exposure, wind,
            estimator errors; :meth:`WeedWorld.begin_episode`).
    """

    def __init__(self, world: WeedWorld, starts: list[np.ndarray], texture_seed: int):
        if len(starts) != world.scene.drones:
            raise ValueError(f"a scene of {world.scene.drones} drones flies {world.scene.drones} UAVs, got "
                             f"{len(starts)} starts")
        self.world = world
        self.flights = world.flights
        self.starts = [np.asarray(s, dtype=np.float64) for s in starts]
        self.texture_seed = int(texture_seed)
        self.members: list[Mission | None] = [None] * len(starts)
        self.team: TeamMission | None = None
        self.legs: list[_CommittedLeg | None] = [None] * len(starts)
        self._since = [0.0] * len(starts)  # [m] each drone has flown since its last read-out
        self._last = [s.copy() for s in self.starts]  # each drone's true position after the last step
        #: called with the team mission after every physics step (the demo grabs video frames here)
        self.step_hooks: list[Callable[[TeamMission], None]] = []

    # -- the platform of UAV i -------------------------------------------------------------------------
    def begin(self, uav: int, mission: Mission) -> None:
        """UAV ``uav``'s mission starts; the first paints the field and puts every drone at its start."""
        self.members[uav] = mission
        if uav == 0:
            self.world.begin_episode(mission.truth, self.texture_seed)
            self.world.scene.reset_team(self.starts)
            for flight, start in zip(self.flights, self.starts):
                flight.reset_state(start)
            self._last = [f.position for f in self.flights]

    def leg_durations(self, uav: int, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        ends = np.asarray(end_xyzs, dtype=np.float64).reshape(-1, 3)
        start = np.asarray(start_xyz, dtype=np.float64).reshape(3)
        here = np.linalg.norm(start - mission.position) <= 1e-6
        return self.flights[uav].leg_durations(ends, None if here else start)

    def static_leg_durations(self, uav: int, start_xyz, end_xyzs) -> np.ndarray:
        ends = np.asarray(end_xyzs, dtype=np.float64).reshape(-1, 3)
        return self.flights[uav].leg_durations(ends, np.asarray(start_xyz, dtype=np.float64).reshape(3))

    def commit(self, uav: int, mission: Mission, target: np.ndarray) -> LegOutcome:
        """UAV ``uav`` commits a leg to ``target``: its reference is set (the physics flies it later,
        :meth:`fly_until`); the mission books its end (exact: the reference's duration, or the budget)."""
        f = self.flights[uav]
        leg = ContinuousLeg(f.ref_pos, f.ref_vel, target, f.speed, f.ramp_s)
        t0 = f.ref_time
        end = t0 + leg.duration
        limit = min(end, mission.budget_s)
        whole = end <= mission.budget_s + _TOL
        if whole:
            f.ref_pos, f.ref_vel, f.ref_time = leg.end.copy(), leg.end_velocity(), end
            position = np.asarray(target, dtype=np.float64)
        else:  # out of budget on the way: the leg ends where the reference is then
            p, v, _ = leg.sample(limit - t0)
            f.ref_pos, f.ref_vel, f.ref_time = np.array(p), np.array(v), limit
            position = inside_map(mission, p)
        self.legs[uav] = _CommittedLeg(leg, t0, limit, whole)
        return LegOutcome([], limit, limit - t0, 0.0, position, mission._since_measurement)

    def read(self, uav: int, time_s: float) -> Record:
        """UAV ``uav``'s camera read-out now, stamped ``time_s``."""
        m = self.members[uav]
        obs, z = self.world.read_camera(m.sensor, m.rng, m.truth, drone=uav)
        m.measurement_log.append((float(time_s), *map(float, self.flights[uav].position)))
        return obs, z, float(time_s)

    # -- flying ----------------------------------------------------------------------------------------
    def fly_until(self, time_s: float | None) -> None:
        """Run the physics, every drone on its committed leg (a drone without one holds its position),
        until ``time_s`` [s] (None: until every committed leg has ended); read-outs go to the team."""
        d = self.world.scene.data
        if time_s is None:
            time_s = max([leg.limit for leg in self.legs if leg is not None], default=float(d.time))
        dt = self.world.scene.model.opt.timestep
        zero = (0.0, 0.0, 0.0)
        while d.time < time_s - _TOL:
            refs = []
            for f, c in zip(self.flights, self.legs):
                if c is None:
                    refs.append((tuple(f.ref_pos.tolist()), zero, zero))
                else:
                    refs.append(c.leg.sample(d.time + dt - c.t0, f.controller.gains.feedforward_lead_s))
            step_together(self.flights, refs)
            for uav, c in enumerate(self.legs):
                if c is not None:
                    self._odometer(uav, c)
                else:
                    self._last[uav] = self.flights[uav].position
            for hook in self.step_hooks:
                hook(self.team)

    def _odometer(self, uav: int, c: _CommittedLeg) -> None:
        """Distance flown this step, a read-out every spacing metres, the arrival read-out at the leg's end."""
        m = self.members[uav]
        here = self.flights[uav].position
        step = math.dist(here, self._last[uav])
        self._last[uav] = here
        m.distance_m += step
        self._since[uav] += step
        d = self.world.scene.data
        if self._since[uav] >= m.config.mission.measurement_spacing - _TOL:
            self.team.take(uav, [self.read(uav, min(float(d.time), m.budget_s))])
            self._since[uav] = 0.0
        if d.time >= c.limit - _TOL:
            if c.whole:
                self.team.take(uav, [self.read(uav, min(c.limit, m.budget_s))])
                self._since[uav] = 0.0
            self.legs[uav] = None
            m._since_measurement = self._since[uav]

    # -- what the teammates' legs will read ------------------------------------------------------------
    def ahead(self, uav: int) -> list[Observation]:
        """The read-outs UAV ``uav``'s committed leg will still take, predicted: the sensor model's
        footprint at each of :meth:`ahead_points`."""
        sensor = self.members[uav].sensor
        out = []
        for p in self.ahead_points(uav):
            obs = sensor.observe(p)
            if obs is not None:
                out.append(obs)
        return out

    def ahead_points(self, uav: int) -> list[np.ndarray]:
        """Where UAV ``uav``'s committed leg will still read its camera: every spacing metres along the rest
        of its reference (counted from its last read-out), and at its end if the budget lets it get there."""
        c = self.legs[uav]
        if c is None:
            return []
        m = self.members[uav]
        spacing = m.config.mission.measurement_spacing
        now = float(self.world.scene.data.time)
        since = self._since[uav]
        last = np.asarray(self._last[uav])
        points = []
        for t in np.arange(now + _AHEAD_DT, c.limit, _AHEAD_DT):
            p = np.asarray(c.leg.sample(t - c.t0)[0])
            since += float(np.linalg.norm(p - last))
            last = p
            if since >= spacing - _TOL:
                points.append(p)
                since = 0.0
        if c.whole:
            points.append(np.asarray(c.leg.end, dtype=np.float64))
        return points


class DronePlatform:
    """UAV ``uav``'s :class:`~ipp_bench.core.mission.Platform` in a simulated team: its drone of the shared
    scene. Legs are committed here and flown by :meth:`SimTeam.fly_until`."""

    def __init__(self, team: SimTeam, uav: int):
        self.team, self.uav = team, uav

    def begin(self, mission: Mission) -> None:
        self.team.begin(self.uav, mission)

    def leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        return self.team.leg_durations(self.uav, mission, start_xyz, end_xyzs)

    def static_leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        del mission
        return self.team.static_leg_durations(self.uav, start_xyz, end_xyzs)

    def fly(self, mission: Mission, target: np.ndarray, length_m: float) -> LegOutcome:
        del length_m
        return self.team.commit(self.uav, mission, target)

    def read_here(self, mission: Mission, time_s: float) -> list[Record]:
        del mission
        return [self.team.read(self.uav, time_s)]


class MuJoCoTeamEnv(TeamGraphEnv):
    """A team task deployed in MuJoCo: one quadrotor per UAV in one scene, one shared belief (PettingZoo AEC).

    Args:
        config, team, render_mode, task_id: as :class:`~ipp_bench.envs.team.TeamGraphEnv`.
        sim: the deployment's settings (default: ``sim_section``, the task file's ``[sim]`` table).
        sim_section: the task file's ``[sim]`` table.
        airframe: a PyMJCF quadrotor to fly instead of the shipped one (every UAV flies a copy).
        **overrides: config fields and ``[sim]`` leaf fields by name.

    ``world`` is the simulated world (``world.flights[i]`` flies UAV i); ``render()`` shows a chase
    view of every drone above the truth / mean / std panels with every path.
    """

    metadata = {"render_modes": ["rgb_array"], "name": "ipp_bench_team_mujoco", "is_parallelizable": False,
                "render_fps": 4}

    def __init__(self, config: IPPConfig | dict | None = None, team: TeamConfig | dict | None = None,
                 render_mode: str | None = None, task_id: str | None = None, sim: SimConfig | None = None,
                 sim_section: dict | None = None, airframe=None, **overrides: Any):
        sim = split_sim_settings(
            lambda rest: super(MuJoCoTeamEnv, self).__init__(config, team=team, render_mode=render_mode,
                                                             task_id=task_id, **rest),
            overrides, sim, sim_section)
        if sim.flight.mode != "continuous":
            invalid("sim.flight.mode", sim.flight.mode, "'continuous' (a team's drones fly their legs together, "
                    "each leg's duration known when it is committed; stop-and-go legs have none)")
        self.sim_config = sim
        self.world = WeedWorld(self.config.grid, self.config.sensor, self.config.mission.speed, sim,
                               airframe=airframe, drones=self.team.size)
        self._chase = [chase_camera(self.world.scene, drone=i) for i in range(self.team.size)]
        self.sim_team: SimTeam | None = None

    def _make_mission(self, truth: np.ndarray, starts: list[np.ndarray],
                      rngs: list[np.random.Generator]) -> TeamMission:
        # drawn from a copy of the first UAV's noise stream, as the single-drone task draws it: the same
        # seed paints the same field under the same sun and wind
        texture_seed = int(copy.deepcopy(rngs[0]).integers(2**63 - 1))
        sim = SimTeam(self.world, starts, texture_seed)
        self.sim_team = sim
        mission = super()._make_mission(truth, starts, rngs, platform=lambda i: DronePlatform(sim, i),
                                        ahead=sim.ahead)
        sim.team = mission
        return mission

    def _fly_until(self, time_s: float | None) -> None:
        self.sim_team.fly_until(time_s)

    def render(self):
        """(H, W, 3) uint8: a chase view of every drone above the truth / mean / std panels (every path)."""
        if self.render_mode is None or self.mission is None:
            return None
        panels = render_mission(self.mission)
        n = self.team.size
        width = (panels.shape[1] - 4 * (n - 1)) // n
        views = []
        for i, cam in enumerate(self._chase):
            cam.azimuth = azimuth_to_centre(self.world.scene, drone=i)
            views.append(self.world.renderer.render(cam, width, min(width, panels.shape[0])))
            if i < n - 1:
                views.append(np.full((views[-1].shape[0], 4, 3), 255, np.uint8))
        top = np.concatenate(views, axis=1)
        pad = panels.shape[1] - top.shape[1]
        if pad:
            top = np.concatenate([top, np.full((top.shape[0], pad, 3), 255, np.uint8)], axis=1)
        return np.ascontiguousarray(np.concatenate([top, np.full((4, top.shape[1], 3), 255, np.uint8), panels]))

    def close(self) -> None:
        self.world.close()
        super().close()


__all__ = ["DronePlatform", "MuJoCoTeamEnv", "SimTeam"]
