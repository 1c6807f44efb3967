"""A :class:`~ipp_bench.mission.Mission` flown by the simulated quadrotor and read by its camera.

Same world state, clock and metrics as the core mission, with these differences:

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
  The Kalman update is the core's (:meth:`Mission.assimilate`; in v1 through the camera's error
  model, :class:`~ipp_bench.belief.PersistentErrorBelief`); every update's normalised innovation
  squared is logged in ``nis_log`` (the belief's consistency check), with the S of the model the
  update uses.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ipp_bench.belief import GPBelief, normalised_innovation
from ipp_bench.config import IPPConfig
from ipp_bench.mission import FlownLeg, Mission, fits_budget
from ipp_bench.sensor import Observation, Sensor, stack
from ipp_bench.sim.world import WeedWorld

_TOL = 1e-9


class MuJoCoMission(Mission):
    """Mission whose flights and measurements come from :class:`WeedWorld`.

    Args:
        config, truth, rng, start_xyz, belief: as :class:`~ipp_bench.mission.Mission`
            (``rng`` draws the v0 sensor noise and, in v1, the episode's seed).
        world: the simulated world; its ground is repainted from ``truth``.
        texture_seed: seed of the episode's texture (v0) or of everything drawn per episode (v1:
            texture, sun, exposure, white balance, pixel noise, wind, estimator errors).
    """

    def __init__(self, config: IPPConfig, truth: np.ndarray, rng: np.random.Generator, start_xyz,
                 world: WeedWorld, texture_seed: int, belief: GPBelief | None = None,
                 sensor: Sensor | None = None):
        self.world = world
        self.flight = world.flight
        self.continuous = world.cfg.flight.mode == "continuous"
        #: called with the mission after every physics step (the demo grabs video frames here)
        self.step_hooks: list[Callable[["MuJoCoMission"], None]] = []
        #: (time [s], NIS, degrees of freedom) of every Kalman update
        self.nis_log: list[tuple[float, float, int]] = []
        #: (read-outs, values, time [s]) of every Kalman update, as fused (calibration replays them)
        self.update_log: list[tuple[list[Observation], list[np.ndarray], float]] = []
        #: (cells, the camera's fraction of each, resolution factor) of every read-out fused
        self.cell_log: list[tuple[np.ndarray, np.ndarray, int]] = []
        #: (time [s], true xyz, estimated xyz) of every camera read-out
        self.camera_log: list[tuple[float, np.ndarray, np.ndarray]] = []
        if self.continuous:
            world.begin_episode(truth, texture_seed)
        else:
            world.load_field(truth, texture_seed)
        world.flight.reset(np.asarray(start_xyz, dtype=np.float64))
        super().__init__(config, truth, rng, start_xyz, belief, sensor)

    # -- clock: the affordability oracle ----------------------------------------------------------
    def leg_durations(self, start_xyz, end_xyzs) -> np.ndarray:
        """Flight time [s] of legs from ``start_xyz`` to each of ``end_xyzs`` (K, 3), as flown here.

        From the current position: exact (v1: from the reference's velocity; v0: ramps included).
        From another start, v1 gives the upper bound over the unknown incoming velocity.
        """
        ends = np.asarray(end_xyzs, dtype=np.float64).reshape(-1, 3)
        start = np.asarray(start_xyz, dtype=np.float64).reshape(3)
        here = np.linalg.norm(start - self.position) <= 1e-6
        return self.flight.leg_durations(ends, None if here else start)

    def leg_time(self, xyz) -> float:
        """Flight time [s] from here to ``xyz``."""
        return float(self.leg_durations(self.position, np.asarray(xyz, dtype=np.float64).reshape(1, 3))[0])

    def leg_times(self, distances: np.ndarray) -> np.ndarray:
        """v0 only: leg times for leg lengths ``distances`` [m] (stop mode, from rest)."""
        d = np.asarray(distances, dtype=np.float64)
        ramp = self.flight.ramp_s
        v = np.minimum(self.config.mission.speed, d / ramp)
        return np.where(d > 0, d / np.where(v > 0, v, 1.0) + ramp, 0.0)

    def affordable(self, end_xyzs) -> np.ndarray:
        """(K,) bool: legs from here that end within the remaining budget."""
        return fits_budget(self.leg_durations(self.position, end_xyzs), self.remaining_s)

    def can_reach(self, xyz) -> bool:
        return bool(self.affordable(np.asarray(xyz, dtype=np.float64).reshape(1, 3))[0])

    # -- flight -----------------------------------------------------------------------------------
    def fly_to(self, xyz) -> FlownLeg:
        """Flies to ``xyz`` [m] in MuJoCo, reading the camera along the way and on arrival.

        A leg is refused, as in the core, when its nominal time (length / speed) exceeds the remaining
        budget. Graph tasks only offer legs that the oracle (:meth:`leg_durations`) says fit; a
        continuous planner that plans with nominal times may ask for one that does not: it is flown
        until the budget runs out and ends where the drone is then (v0 did the same).

        Raises:
            BudgetExceededError: the leg's nominal time exceeds the remaining budget.
            ValueError: ``xyz`` is off the map or equals the current position.
        """
        target, _ = self.check_leg(xyz)
        spacing = self.config.mission.measurement_spacing
        flight, data, adr = self.flight, self.world.scene.data, self.world.scene.qpos_adr
        t0 = self.time_s
        records: list[tuple[Observation | None, np.ndarray | None, float]] = []
        state = {"since": self._since_measurement, "flown": 0.0, "last": tuple(data.qpos[adr: adr + 3])}
        hooks = self.step_hooks

        def on_step(_flight) -> None:
            here = tuple(data.qpos[adr: adr + 3])
            step = math.dist(here, state["last"])
            state["last"] = here
            state["flown"] += step
            state["since"] += step
            if state["since"] >= spacing - _TOL:
                records.append(self._read(min(data.time, self.budget_s)))
                state["since"] = 0.0
            for hook in hooks:
                hook(self)

        if self.continuous:
            leg = flight.follow(target, on_step=on_step, time_limit_s=self.budget_s)
            end = flight.ref_time
            if end >= t0 + leg.duration - _TOL:  # the whole leg was flown
                records.append(self._read(min(end, self.budget_s)))
                state["since"] = 0.0
                self.position = target
            else:  # out of budget on the way: the leg ends where the reference was
                self.position = self._inside(flight.ref_pos.copy())
        else:
            reference_s = self.leg_time(target)
            flight.fly_to(target, on_step=on_step, time_limit_s=self.budget_s)
            end = flight.time_s
            if end - t0 >= reference_s - _TOL:  # settled, or out of budget with the reference at the target
                records.append(self._read(end))
                state["since"] = 0.0
            self.position = self._inside(flight.position)
        self.time_s = min(end, self.budget_s)
        self.distance_m += state["flown"]
        self._since_measurement = state["since"]
        self.path.append((self.time_s, *self.position))
        n = self.assimilate_records(records)
        return FlownLeg(self.time_s - t0, state["flown"], n, self.time_s)

    def _inside(self, p: np.ndarray) -> np.ndarray:
        width, height = self.config.grid.size_m
        return np.array([min(max(p[0], 0.0), width), min(max(p[1], 0.0), height), max(p[2], 1e-3)])

    # -- sensing ----------------------------------------------------------------------------------
    def _read(self, time_s: float) -> tuple[Observation | None, np.ndarray | None, float]:
        obs, z = self.world.read_camera(self.sensor, self.rng, self.truth)
        self.measurement_log.append((float(time_s), *map(float, self.flight.position)))
        reading = self.world.last_reading
        self.camera_log.append((float(time_s), reading.body_xyz, reading.estimated_xyz))
        if obs is not None:
            self.cell_log.append((obs.cells, reading.fraction[obs.cells], obs.factor))
        return obs, z, float(time_s)

    def _measure(self, points, times) -> int:
        """The core calls this once, for the read-out at the start: take it with the camera."""
        del points  # the drone is where it is
        return self.assimilate_records([self._read(float(t)) for t in times])

    def assimilate(self, observations: list[Observation], zs: list[np.ndarray], time_s: float) -> int:
        """The core's Kalman update, with the normalised innovation squared of the batch logged first."""
        if observations:
            self.update_log.append((list(observations), list(zs), float(time_s)))
        if observations and self.camera_errors is not None:
            self.nis_log.append((float(time_s), *self.camera_errors.normalised_innovation(observations, zs)))
        elif observations:
            cells, W, var = stack(observations)
            z = np.concatenate(zs)
            self.nis_log.append((float(time_s), *normalised_innovation(self.belief, cells, W, z, var)))
        return super().assimilate(observations, zs, time_s)
