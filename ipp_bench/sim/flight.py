"""Flying the quadrotor in the scene: fixed-step physics under the cascaded controller.

:class:`Flight` owns the control loop. Every physics step (``SceneConfig.timestep``)
it reads the free joint's state, asks :class:`CascadedController` for rotor
thrusts, writes them to the actuators and calls ``mj_step``; time is MuJoCo's
simulated time. :meth:`Flight.fly_to` follows one :class:`Leg` to a waypoint and
reports every step to an optional callback (which the mission uses to measure
every few metres and the demo to grab video frames).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ipp_bench.sim.gl import mujoco

from ipp_bench.sim.controller import CascadedController, ControllerGains, Leg
from ipp_bench.sim.scene import WeedScene


class Flight:
    """The control loop around one :class:`WeedScene`.

    Args:
        scene: the compiled scene (its drone is flown).
        speed: cruise speed along legs [m/s].
        ramp_s: velocity ramp time at both ends of a leg [s].
        arrive_tol: a waypoint is reached within this distance [m] ...
        settle_speed: ... and below this speed [m/s], once the reference has arrived.
        max_extra_s: give up settling this long after the reference arrived [s].
        gains: controller bandwidths.
    """

    def __init__(self, scene: WeedScene, speed: float = 2.0, ramp_s: float = 1.0, arrive_tol: float = 0.15,
                 settle_speed: float = 0.3, max_extra_s: float = 5.0,
                 gains: ControllerGains = ControllerGains()) -> None:
        if speed <= 0.0 or ramp_s <= 0.0 or arrive_tol <= 0.0 or settle_speed <= 0.0 or max_extra_s < 0.0:
            raise ValueError("Flight: speed, ramp_s, arrive_tol and settle_speed must be > 0, max_extra_s >= 0")
        self.scene = scene
        self.speed, self.ramp_s = float(speed), float(ramp_s)
        self.arrive_tol, self.settle_speed = float(arrive_tol), float(settle_speed)
        self.max_extra_s = float(max_extra_s)
        self.controller = CascadedController(scene.quad, gains)
        self._m, self._d = scene.model, scene.data
        self._qp, self._qv = scene.qpos_adr, scene.qvel_adr
        self._act = scene.actuator_ids
        self.steps = 0

    @property
    def time_s(self) -> float:
        """Simulated time since :meth:`reset` [s]."""
        return float(self._d.time)

    @property
    def position(self) -> np.ndarray:
        return self._d.qpos[self._qp: self._qp + 3].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self._d.qvel[self._qv: self._qv + 3].copy()

    def reset(self, xyz, yaw: float = 0.0) -> None:
        """Drone at rest at ``xyz`` [m], time 0."""
        self.scene.reset(xyz, yaw)
        self.controller.yaw = float(yaw)
        self.steps = 0

    def leg_duration(self, target) -> float:
        """Reference duration of the leg from the current position to ``target`` [s]."""
        length = float(np.linalg.norm(np.asarray(target, dtype=np.float64) - self.position))
        return Leg.duration_for(length, self.speed, self.ramp_s)

    def step(self, ref_pos, ref_vel, ref_acc) -> None:
        """One physics step towards the reference."""
        d = self._d
        qp, qv = self._qp, self._qv
        q = d.qpos[qp: qp + 7].tolist()
        v = d.qvel[qv: qv + 6].tolist()
        d.ctrl[self._act] = self.controller.thrusts(q[:3], v[:3], q[3:], v[3:], ref_pos, ref_vel, ref_acc)
        mujoco.mj_step(self._m, d)
        self.steps += 1

    def hover(self, duration_s: float, at=None, on_step: Callable[["Flight"], bool | None] | None = None) -> None:
        """Holds position ``at`` (default: here) for ``duration_s`` seconds."""
        target = self.position if at is None else np.asarray(at, dtype=np.float64)
        target, zero = tuple(target.tolist()), (0.0, 0.0, 0.0)
        end = self.time_s + duration_s - 1e-9
        while self.time_s < end:
            self.step(target, zero, zero)
            if on_step is not None and on_step(self):
                return

    def fly_to(self, target, on_step: Callable[["Flight"], bool | None] | None = None,
               time_limit_s: float | None = None) -> bool:
        """Flies a straight leg from here to ``target`` and settles there.

        Args:
            target: waypoint (x, y, z) [m].
            on_step: called after every physics step; returning True stops the leg.
            time_limit_s: absolute simulated time at which to stop regardless [s].

        Returns:
            True when the drone settled at the target, False when stopped early
            (callback, time limit, or not settled ``max_extra_s`` after the reference arrived).
        """
        target = np.asarray(target, dtype=np.float64)
        leg = Leg(self.position, target, self.speed, self.ramp_s)
        t0 = self.time_s
        give_up = leg.duration + self.max_extra_s
        limit = np.inf if time_limit_s is None else float(time_limit_s)
        tol2, settle2 = self.arrive_tol ** 2, self.settle_speed ** 2
        d, qp, qv = self._d, self._qp, self._qv
        dt, lead = self._m.opt.timestep, self.controller.gains.feedforward_lead_s
        while True:
            t = d.time - t0
            self.step(*leg.sample(t + dt, lead))
            if on_step is not None and on_step(self):
                return False
            t = d.time - t0
            if t >= leg.duration:
                err = d.qpos[qp: qp + 3] - target
                vel = d.qvel[qv: qv + 3]
                if err @ err <= tol2 and vel @ vel <= settle2:
                    return True
                if t >= give_up:
                    return False
            if d.time >= limit - 1e-9:
                return False
