"""The MuJoCo platforms of a :class:`~ipp_bench.core.mission.Mission`: the simulated quadrotor and its camera.

The mission keeps its bookkeeping (clock, budget, metrics); what changes is the platform it
takes (:class:`ContinuousFlight`, v1, or :class:`StopAndGoFlight`, v0, both a
:class:`MuJoCoPlatform`). :class:`MuJoCoMission` is the core mission built with one of them, plus
read-only access to the platform's world and logs. Against the graph's straight legs:

* ``fly_to`` runs the MuJoCo physics under the cascaded controller, from the estimated state, in
  the episode's wind; distance is the path actually flown.
* Leg durations are the flight's own (:meth:`MuJoCoMission.leg_durations`, the mission's
  affordability oracle). v1 flies velocity-continuous legs (:class:`~ipp_bench.sim.controller.ContinuousLeg`):
  a leg takes exactly its reference duration, exact from the current position (the incoming
  velocity is known) and an upper bound, 2 ramp_s + length / speed, from any other start (the
  velocity there depends on the path to it). Mission time is that reference time, and
  ``position`` the reference's end, i.e. the waypoint the planner chose (the true and estimated
  positions are ``flight.position`` and ``flight.estimated_position()``). v0 (stop at every
  waypoint) keeps its rules: mission time is simulated time, ``position`` the drone's.
* The camera is read every ``measurement_spacing`` metres actually travelled (carried over between
  legs) and on arrival; a read-out is the rendered frame through image formation, segmentation
  and projection with the estimated pose (:meth:`WeedWorld.read_camera`), never the ground truth.
  The Kalman update is the core's (:meth:`Mission.assimilate`, through the mission's belief model;
  in v1 the camera's error states, :class:`~ipp_bench.core.belief.PersistentErrorBelief`); every
  update's normalised innovation squared is logged in ``nis_log`` (the belief's consistency
  check) by an update hook, with the S of the model the update uses.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ipp_bench.core.belief import GPBelief
from ipp_bench.core.config import IPPConfig
from ipp_bench.core.mission import LegOutcome, Mission, Record
from ipp_bench.core.sensor import Observation, Sensor
from ipp_bench.sim.world import WeedWorld

_TOL = 1e-9


def inside_map(mission: Mission, p) -> np.ndarray:
    """``p`` [m] clipped to the map (and above the ground): where a leg cut short by the budget ends."""
    width, height = mission.config.grid.size_m
    return np.array([min(max(p[0], 0.0), width), min(max(p[1], 0.0), height), max(p[2], 1e-3)])


class MuJoCoPlatform:
    """What the MuJoCo platforms share: the world, the episode's start, the camera read-outs, the logs.

    Args:
        world: the simulated world; its ground is repainted from the mission's truth at ``begin``.
        texture_seed: seed of the episode's texture (v0) or of everything drawn per episode (v1:
            texture, sun, exposure, white balance, pixel noise, wind, estimator errors).
    """

    def __init__(self, world: WeedWorld, texture_seed: int) -> None:
        self.world = world
        self.flight = world.flight
        self.texture_seed = int(texture_seed)
        #: called with the mission after every physics step (the demo grabs video frames here)
        self.step_hooks: list[Callable[[Mission], None]] = []
        #: (time [s], NIS, degrees of freedom) of every Kalman update
        self.nis_log: list[tuple[float, float, int]] = []
        #: (read-outs, values, time [s]) of every Kalman update, as fused (calibration replays them)
        self.update_log: list[tuple[list[Observation], list[np.ndarray], float]] = []
        #: (cells, the camera's fraction of each, resolution factor) of every read-out fused
        self.cell_log: list[tuple[np.ndarray, np.ndarray, int]] = []
        #: (time [s], true xyz, estimated xyz) of every camera read-out
        self.camera_log: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._mission: Mission | None = None

    # -- the platform protocol ------------------------------------------------------------------
    def begin(self, mission: Mission) -> None:
        self._paint(mission.truth)
        self.flight.reset(np.asarray(mission.position, dtype=np.float64))
        self._mission = mission
        mission.update_hooks.append(self._log_update)

    def leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        """Flight time [s] of legs from ``start_xyz`` to each of ``end_xyzs`` (K, 3), as flown here.

        From the current position: exact (v1: from the reference's velocity; v0: ramps included).
        From another start, v1 gives the upper bound over the unknown incoming velocity.
        """
        ends = np.asarray(end_xyzs, dtype=np.float64).reshape(-1, 3)
        start = np.asarray(start_xyz, dtype=np.float64).reshape(3)
        here = np.linalg.norm(start - mission.position) <= 1e-6
        return self.flight.leg_durations(ends, None if here else start)

    def static_leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        """Flight time [s] of legs from ``start_xyz`` to each of ``end_xyzs`` (K, 3) whatever the drone's
        state now (v1: the upper bound over the incoming velocity, also from the current position)."""
        del mission
        ends = np.asarray(end_xyzs, dtype=np.float64).reshape(-1, 3)
        return self.flight.leg_durations(ends, np.asarray(start_xyz, dtype=np.float64).reshape(3))

    def read_here(self, mission: Mission, time_s: float) -> list[Record]:
        del mission  # the drone is where it is
        return [self._read(float(time_s))]

    # -- shared parts ---------------------------------------------------------------------------
    def _paint(self, truth: np.ndarray) -> None:
        raise NotImplementedError

    def _odometer(self, mission: Mission, records: list[Record]):
        """The per-physics-step callback of a leg: distance flown, a read-out every spacing metres."""
        spacing = mission.config.mission.measurement_spacing
        data, adr = self.world.scene.data, self.world.scene.qpos_adr
        state = {"since": mission._since_measurement, "flown": 0.0, "last": tuple(data.qpos[adr: adr + 3])}
        hooks, budget = self.step_hooks, mission.budget_s

        def on_step(_flight) -> None:
            here = tuple(data.qpos[adr: adr + 3])
            step = math.dist(here, state["last"])
            state["last"] = here
            state["flown"] += step
            state["since"] += step
            if state["since"] >= spacing - _TOL:
                records.append(self._read(min(data.time, budget)))
                state["since"] = 0.0
            for hook in hooks:
                hook(mission)

        return on_step, state

    def _read(self, time_s: float) -> Record:
        mission = self._mission
        obs, z = self.world.read_camera(mission.sensor, mission.rng, mission.truth)
        mission.measurement_log.append((float(time_s), *map(float, self.flight.position)))
        reading = self.world.last_reading
        self.camera_log.append((float(time_s), reading.body_xyz, reading.estimated_xyz))
        if obs is not None:
            self.cell_log.append((obs.cells, reading.fraction[obs.cells], obs.factor))
        return obs, z, float(time_s)

    def _log_update(self, observations: list[Observation], zs: list[np.ndarray], time_s: float) -> None:
        """Update hook: the batch as fused, and its NIS under the model the update uses."""
        self.update_log.append((list(observations), list(zs), float(time_s)))
        self.nis_log.append((float(time_s), *self._mission.belief_model.normalised_innovation(observations, zs)))


class ContinuousFlight(MuJoCoPlatform):
    """v1: velocity-continuous legs through the waypoints; a leg takes exactly its reference duration.

    Mission time is that reference time and the mission's position the reference's end (the
    waypoint the planner chose); a leg the budget cuts short ends where the reference was then.
    """

    def _paint(self, truth: np.ndarray) -> None:
        self.world.begin_episode(truth, self.texture_seed)

    def fly(self, mission: Mission, target: np.ndarray, length_m: float) -> LegOutcome:
        del length_m
        records: list[Record] = []
        t0 = mission.time_s
        on_step, state = self._odometer(mission, records)
        leg = self.flight.follow(target, on_step=on_step, time_limit_s=mission.budget_s)
        end = self.flight.ref_time
        if end >= t0 + leg.duration - _TOL:  # the whole leg was flown
            records.append(self._read(min(end, mission.budget_s)))
            state["since"] = 0.0
            position = target
        else:  # out of budget on the way: the leg ends where the reference was
            position = inside_map(mission, self.flight.ref_pos)
        end_time = min(end, mission.budget_s)
        return LegOutcome(records, end_time, end_time - t0, state["flown"], position, state["since"])


class StopAndGoFlight(MuJoCoPlatform):
    """v0: ramp up, cruise, ramp down and settle at every waypoint; mission time is simulated time."""

    def _paint(self, truth: np.ndarray) -> None:
        self.world.load_field(truth, self.texture_seed)

    def fly(self, mission: Mission, target: np.ndarray, length_m: float) -> LegOutcome:
        del length_m
        records: list[Record] = []
        t0 = mission.time_s
        reference_s = mission.leg_time(target)
        on_step, state = self._odometer(mission, records)
        self.flight.fly_to(target, on_step=on_step, time_limit_s=mission.budget_s)
        end = self.flight.time_s
        if end - t0 >= reference_s - _TOL:  # settled, or out of budget with the reference at the target
            records.append(self._read(end))
            state["since"] = 0.0
        end_time = min(end, mission.budget_s)
        return LegOutcome(records, end_time, end_time - t0, state["flown"], inside_map(mission, self.flight.position),
                          state["since"])


def mujoco_platform(world: WeedWorld, texture_seed: int) -> MuJoCoPlatform:
    """The platform of the world's flight mode (``SimConfig.flight.mode``)."""
    cls = ContinuousFlight if world.cfg.flight.mode == "continuous" else StopAndGoFlight
    return cls(world, texture_seed)


class MuJoCoMission(Mission):
    """The core mission on a MuJoCo platform (:func:`mujoco_platform`), with its world and logs at hand.

    Args:
        config, truth, rng, start_xyz, belief, sensor: as :class:`~ipp_bench.core.mission.Mission`
            (``rng`` draws the v0 sensor noise and, in v1, the episode's seed).
        world: the simulated world; its ground is repainted from ``truth``.
        texture_seed: see :class:`MuJoCoPlatform`.

    Nothing of the core is overridden: the platform flies and reads, the core books.
    """

    def __init__(self, config: IPPConfig, truth: np.ndarray, rng: np.random.Generator, start_xyz,
                 world: WeedWorld, texture_seed: int, belief: GPBelief | None = None,
                 sensor: Sensor | None = None):
        super().__init__(config, truth, rng, start_xyz, belief, sensor, platform=mujoco_platform(world, texture_seed))

    # read-only access to the platform's parts and logs
    world = property(lambda self: self.platform.world)
    flight = property(lambda self: self.platform.flight)
    continuous = property(lambda self: isinstance(self.platform, ContinuousFlight))
    step_hooks = property(lambda self: self.platform.step_hooks)
    nis_log = property(lambda self: self.platform.nis_log)
    update_log = property(lambda self: self.platform.update_log)
    cell_log = property(lambda self: self.platform.cell_log)
    camera_log = property(lambda self: self.platform.camera_log)

    def can_reach(self, xyz) -> bool:
        """Whether the leg from here to ``xyz`` fits the remaining budget (the mission's oracle)."""
        return bool(self.affordable(np.asarray(xyz, dtype=np.float64).reshape(1, 3))[0])
