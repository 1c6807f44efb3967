"""A :class:`~ipp_bench.mission.Mission` flown by the simulated quadrotor and read by its camera.

Same world state, clock and metrics as the core mission, with three differences:

* ``fly_to`` runs the MuJoCo physics under the cascaded controller; mission time is simulated
  time (legs take their ramp-up and settling time, not only length / speed), distance is the
  path actually flown.
* the camera is read every ``measurement_spacing`` metres actually travelled (carried over
  between legs) and on arrival, at the drone's actual pose, tilt included;
* a read-out is the rendered frame through the HSV threshold and ground projection
  (:meth:`WeedWorld.read_camera`), never the ground truth; then the sensor's binning and noise,
  and the same Kalman update of the same ``GPBelief`` (:meth:`Mission.assimilate`).

A leg is refused, as in the core, when its duration by the mission's clock
(:meth:`MuJoCoMission.leg_durations`: the reference time, ramps included) exceeds the remaining
budget; action masks and planners ask the same clock, so they never offer such a leg. When the
flight itself runs out of budget (settling can take longer than the reference), the leg ends where the drone is at that moment (its arrival read-out is taken only
if the reference trajectory had reached the waypoint).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ipp_bench.belief import GPBelief
from ipp_bench.config import IPPConfig
from ipp_bench.mission import FlownLeg, Mission, leg_lengths
from ipp_bench.sensor import Observation, Sensor
from ipp_bench.sim.controller import Leg as Reference
from ipp_bench.sim.world import WeedWorld

_TOL = 1e-9


class MuJoCoMission(Mission):
    """Mission whose flights and measurements come from :class:`WeedWorld`.

    Args:
        config, truth, rng, start_xyz, belief: as :class:`~ipp_bench.mission.Mission`
            (``rng`` draws the sensor noise).
        world: the simulated world; its ground is repainted from ``truth``.
        texture_seed: seed of the ground texture (natural variation of the weeds and soil).
    """

    def __init__(self, config: IPPConfig, truth: np.ndarray, rng: np.random.Generator, start_xyz,
                 world: WeedWorld, texture_seed: int, belief: GPBelief | None = None,
                 sensor: Sensor | None = None):
        self.world = world
        self.flight = world.flight
        #: called with the mission after every physics step (the demo grabs video frames here)
        self.step_hooks: list[Callable[["MuJoCoMission"], None]] = []
        world.load_field(truth, texture_seed)
        world.flight.reset(np.asarray(start_xyz, dtype=np.float64))
        super().__init__(config, truth, rng, start_xyz, belief, sensor)

    # -- clock ------------------------------------------------------------------------------------
    def leg_durations(self, start_xyz, end_xyzs) -> np.ndarray:
        """(K,) reference flight times [s] of the legs ``start_xyz -> end_xyzs``: length / speed
        plus the velocity ramps (:meth:`Reference.duration_for`)."""
        speed, ramp = self.config.mission.speed, self.flight.ramp_s
        return np.array([Reference.duration_for(d, speed, ramp) for d in leg_lengths(start_xyz, end_xyzs)])

    # -- flight -----------------------------------------------------------------------------------
    def fly_to(self, xyz) -> FlownLeg:
        """Flies to ``xyz`` [m] in MuJoCo, reading the camera along the way and on arrival.

        Raises:
            BudgetExceededError: the leg's reference time (:meth:`leg_durations`) exceeds the remaining budget.
            ValueError: ``xyz`` is off the map or equals the current position.
        """
        target, dist = self.check_leg(xyz)
        spacing = self.config.mission.measurement_spacing
        flight, data, adr = self.flight, self.world.scene.data, self.world.scene.qpos_adr
        t0 = flight.time_s
        reference_s = self.leg_time(target)
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
                records.append(self._read(data.time))
                state["since"] = 0.0
            for hook in hooks:
                hook(self)

        flight.fly_to(target, on_step=on_step, time_limit_s=self.budget_s)
        end = flight.time_s
        if end - t0 >= reference_s - _TOL:  # settled, or out of budget with the reference at the target
            records.append(self._read(end))
            state["since"] = 0.0
        self.time_s = min(end, self.budget_s)
        self.distance_m += state["flown"]
        self.position = self._inside(flight.position)
        self._since_measurement = state["since"]
        self.path.append((self.time_s, *self.position))
        n = self.assimilate_records(records)
        return FlownLeg(self.time_s - t0, state["flown"], n, self.time_s)

    def _inside(self, p: np.ndarray) -> np.ndarray:
        width, height = self.config.grid.size_m
        return np.array([min(max(p[0], 0.0), width), min(max(p[1], 0.0), height), max(p[2], 1e-3)])

    # -- sensing ----------------------------------------------------------------------------------
    def _read(self, time_s: float) -> tuple[Observation | None, np.ndarray | None, float]:
        obs, z = self.world.read_camera(self.sensor, self.rng)
        self.measurement_log.append((float(time_s), *map(float, self.flight.position)))
        return obs, z, float(time_s)

    def _measure(self, points, times) -> int:
        """The core calls this once, for the read-out at the start: take it with the camera."""
        del points  # the drone is where it is
        return self.assimilate_records([self._read(float(t)) for t in times])

