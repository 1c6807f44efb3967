"""Flying the quadrotor in the scene: fixed-step physics under the cascaded controller.

:class:`Flight` owns the control loop. Every physics step (``SceneConfig.timestep``) it reads the
free joint's state, passes it through the state estimator (:mod:`ipp_bench.sim.disturbance`:
position bias and noise, velocity and attitude noise), asks :class:`CascadedController` for rotor
thrusts from the *estimated* state, applies the wind (``opt.wind`` and the rotor drag as an applied
force), writes the thrusts and calls ``mj_step``; time is MuJoCo's simulated time.

Two ways to fly a leg (``FlightConfig.mode``):

* ``"continuous"`` (v1, :meth:`Flight.follow`): the reference is a :class:`ContinuousLeg` from
  the previous reference's end state, so the drone flies through waypoints at up to the cruise
  speed; a leg takes exactly its reference duration (:meth:`Flight.leg_durations`), whatever the
  wind does to the tracking error.
* ``"stop"`` (v0, :meth:`Flight.fly_to`): ramp up, cruise, ramp down, settle at every waypoint.

Both report every step to an optional callback (the mission measures every few metres there, the
demo grabs video frames).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ipp_bench.sim.controller import CascadedController, ContinuousLeg, ControllerGains, Leg, continuous_durations
from ipp_bench.sim.disturbance import DisturbanceConfig, Disturbances, perturb_quat, quat_to_mat
from ipp_bench.sim.gl import mujoco
from ipp_bench.sim.quadrotor import RotorSpeeds
from ipp_bench.sim.scene import WeedScene

FLIGHT_MODES = ("continuous", "stop")


@dataclass(frozen=True)
class FlightConfig:
    """How legs are flown (defaults: v1)."""

    mode: str = "continuous"  # "continuous": through waypoints (v1); "stop": settle at each (v0)
    ramp_s: float = 1.0  # [s] time to change the velocity by the full cruise speed (peak accel pi v / (2 ramp_s))
    arrive_tol: float = 0.15  # [m] "stop": waypoint reached within this distance ...
    settle_speed: float = 0.3  # [m/s] ... and below this speed
    max_extra_s: float = 5.0  # [s] "stop": give up settling this long after the reference arrived

    def __post_init__(self) -> None:
        if self.mode not in FLIGHT_MODES:
            raise ValueError(f"FlightConfig.mode must be one of {FLIGHT_MODES}, got {self.mode!r}")
        for name in ("ramp_s", "arrive_tol", "settle_speed"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"FlightConfig.{name} must be a finite number > 0, got {v}")
        if not self.max_extra_s >= 0.0:
            raise ValueError(f"FlightConfig.max_extra_s must be >= 0 [s], got {self.max_extra_s}")

    @staticmethod
    def v0() -> FlightConfig:
        return FlightConfig(mode="stop")


class Flight:
    """The control loop around one :class:`WeedScene`.

    Args:
        scene: the compiled scene (its drone is flown).
        speed: cruise speed along legs [m/s].
        cfg: how legs are flown.
        gains: controller bandwidths.
        disturbances: wind and state-estimation errors (drawn per episode from ``disturbance_seed``).
        drone: which drone of a team scene this loop flies (:attr:`WeedScene.drones_ids`).
        wind_owner: whether this loop's disturbances set the scene's wind (``opt.wind``). In a team
            scene the first drone's do; the others keep their own estimator errors and feel that
            same wind (:meth:`wind`).

    A team scene's drones are flown together (:func:`step_together`): each loop's :meth:`control`
    writes its drone's thrusts, then one ``mj_step`` advances them all.
    """

    def __init__(self, scene: WeedScene, speed: float = 2.0, cfg: FlightConfig = FlightConfig(),
                 gains: ControllerGains = ControllerGains(),  # noqa: B008 (frozen dataclasses)
                 disturbances: DisturbanceConfig = DisturbanceConfig.none(), drone: int = 0,  # noqa: B008
                 wind_owner: bool = True) -> None:
        if not speed > 0.0:
            raise ValueError(f"Flight speed must be > 0 [m/s], got {speed}")
        if not 0 <= drone < scene.drones:
            raise ValueError(f"drone = {drone} is invalid: the scene has {scene.drones} (0..{scene.drones - 1})")
        self.scene, self.cfg = scene, cfg
        self.drone, self.wind_owner = int(drone), bool(wind_owner)
        self.speed = float(speed)
        self.ramp_s = cfg.ramp_s
        self.controller = CascadedController(scene.quad, gains)
        self._m, self._d = scene.model, scene.data
        ids = scene.drones_ids[self.drone]
        self._qp, self._qv = ids.qpos_adr, ids.qvel_adr
        self._act = ids.actuator_ids
        self._body = ids.body_id
        self.camera_id = ids.camera_id
        #: rotor speeds of the "speed" rotor model (None: MuJoCo's thrust lag)
        self.rotors = RotorSpeeds(scene.quad, self._m.opt.timestep) if scene.quad.rotor_model == "speed" else None
        self.disturbance_cfg = disturbances
        self.disturbance_seed = 0
        self.disturbances: Disturbances | None = None
        self._every = max(1, int(round(1.0 / (disturbances.update_hz * self._m.opt.timestep))))
        self.steps = 0
        self.ref_pos = np.zeros(3)
        self.ref_vel = np.zeros(3)
        self.ref_time = 0.0  # [s] reference (mission) time: the exact sum of the legs' durations

    # -- state ------------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time since :meth:`reset` [s]."""
        return float(self._d.time)

    @property
    def position(self) -> np.ndarray:
        """True position [m]."""
        return self._d.qpos[self._qp: self._qp + 3].copy()

    @property
    def velocity(self) -> np.ndarray:
        """True world-frame velocity [m/s]."""
        return self._d.qvel[self._qv: self._qv + 3].copy()

    @property
    def angular_velocity(self) -> np.ndarray:
        """Body-frame angular velocity [rad/s]."""
        return self._d.qvel[self._qv + 3: self._qv + 6].copy()

    @property
    def wind(self) -> np.ndarray:
        """Current wind velocity [m/s] (zeros when calm)."""
        if not self.wind_owner:
            return np.array(self._m.opt.wind)
        return np.array(self.disturbances.wind) if self.disturbances is not None else np.zeros(3)

    def estimated_position(self) -> np.ndarray:
        p = self.position
        if self.disturbances is not None:
            p += self.disturbances.position_error()
        return p

    def estimated_camera_pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(estimated body position, camera position, camera orientation (3, 3)) used to georeference frames."""
        d, cam = self._d, self.camera_id
        if self.disturbances is None:
            return self.position, d.cam_xpos[cam].copy(), d.cam_xmat[cam].reshape(3, 3).copy()
        q = d.qpos[self._qp + 3: self._qp + 7].tolist()
        R = quat_to_mat(perturb_quat(q, self.disturbances.attitude_error()))
        p = self.estimated_position()
        return p, p + R @ np.array([0.0, 0.0, self.scene.quad.camera_offset_z]), R

    def reset(self, xyz, yaw: float = 0.0) -> None:
        """Drone at rest at ``xyz`` [m], time 0, the episode's disturbances from ``disturbance_seed``."""
        self.scene.reset(xyz, yaw)
        self.reset_state(xyz, yaw)

    def reset_state(self, xyz, yaw: float = 0.0) -> None:
        """This loop's state for a drone the scene has just put at rest at ``xyz`` (``WeedScene.reset_team``)."""
        if self.rotors is not None:
            self.rotors.reset(self.scene.quad.hover_thrust)
        self.controller.yaw = float(yaw)
        self.steps = 0
        cfg = self.disturbance_cfg
        perfect = cfg.calm and cfg.estimator_is_perfect
        self.disturbances = None if perfect else Disturbances(cfg, self.disturbance_seed)
        if self.wind_owner:
            self._m.opt.wind[:] = 0.0
        self._d.xfrc_applied[self._body] = 0.0
        self.ref_pos = np.asarray(xyz, dtype=np.float64).copy()
        self.ref_vel = np.zeros(3)
        self.ref_time = 0.0

    # -- affordability -----------------------------------------------------------------------------
    def leg_durations(self, ends, start=None) -> np.ndarray:
        """Durations [s] of legs to ``ends`` (K, 3) as this flight flies them.

        ``start=None``: from the current reference state (exact). Another start: from rest in "stop"
        mode; in "continuous" mode the upper bound over every incoming velocity (2 ramp_s + L / speed),
        since the velocity there is not known yet.
        """
        ends = np.asarray(ends, dtype=np.float64).reshape(-1, 3)
        if self.cfg.mode == "stop":
            p0 = self.position if start is None else np.asarray(start, dtype=np.float64)
            L = np.linalg.norm(ends - p0, axis=1)
            v = np.minimum(self.speed, L / self.ramp_s)
            return np.where(L > 0, L / np.where(v > 0, v, 1.0) + self.ramp_s, 0.0)
        if start is None:
            return continuous_durations(self.ref_pos, self.ref_vel, ends, self.speed, self.ramp_s)
        return continuous_durations(start, None, ends, self.speed, self.ramp_s)

    # -- control loop ------------------------------------------------------------------------------
    def step(self, ref_pos, ref_vel, ref_acc) -> None:
        """One physics step towards the reference, from the estimated state, in the current wind."""
        self.control(ref_pos, ref_vel, ref_acc)
        mujoco.mj_step(self._m, self._d)
        self.steps += 1

    def control(self, ref_pos, ref_vel, ref_acc) -> None:
        """The drone's thrusts (and wind forces) for the next physics step, from the estimated state;
        the caller steps the physics (:meth:`step` for one drone; a team steps once for all of them)."""
        d = self._d
        qp, qv = self._qp, self._qv
        q = d.qpos[qp: qp + 7].tolist()
        v = d.qvel[qv: qv + 6].tolist()
        dist = self.disturbances
        if dist is None:
            pos, vel, quat = q[:3], v[:3], q[3:]
        else:
            if self.steps % self._every == 0:
                dist.advance()
                if self.wind_owner:
                    self._m.opt.wind[:] = dist.wind
            ep, ev = dist.position_error(), dist.velocity_error()
            pos = (q[0] + ep[0], q[1] + ep[1], q[2] + ep[2])
            vel = (v[0] + ev[0], v[1] + ev[1], v[2] + ev[2])
            quat = perturb_quat(q[3:], dist.attitude_error())
            k = self.disturbance_cfg.rotor_drag
            if k > 0.0:
                wx, wy, _ = dist.wind if self.wind_owner else self._m.opt.wind
                d.xfrc_applied[self._body, 0] = k * (wx - v[0])
                d.xfrc_applied[self._body, 1] = k * (wy - v[1])
        thrusts = self.controller.thrusts(pos, vel, quat, v[3:], ref_pos, ref_vel, ref_acc)
        d.ctrl[self._act] = thrusts if self.rotors is None else self.rotors.step(thrusts)

    def hover(self, duration_s: float, at=None, on_step: Callable[[Flight], bool | None] | None = None) -> None:
        """Holds position ``at`` (default: here) for ``duration_s`` seconds."""
        target = self.position if at is None else np.asarray(at, dtype=np.float64)
        target, zero = tuple(target.tolist()), (0.0, 0.0, 0.0)
        end = self.time_s + duration_s - 1e-9
        while self.time_s < end:
            self.step(target, zero, zero)
            if on_step is not None and on_step(self):
                return

    def follow(self, target, on_step: Callable[[Flight], bool | None] | None = None,
               time_limit_s: float | None = None) -> ContinuousLeg:
        """Flies a velocity-continuous leg to ``target`` for exactly its reference duration.

        The reference starts from the previous reference's end (position, velocity, time), so
        consecutive legs join without a stop. ``on_step`` is called after every physics step
        (returning True stops the leg there); ``time_limit_s`` is an absolute reference time.

        Returns:
            The leg flown (its ``duration`` is what the leg took, unless stopped early).
        """
        leg = ContinuousLeg(self.ref_pos, self.ref_vel, target, self.speed, self.ramp_s)
        t0 = self.ref_time
        end = t0 + leg.duration
        limit = end if time_limit_s is None else min(end, float(time_limit_s))
        d = self._d
        dt, lead = self._m.opt.timestep, self.controller.gains.feedforward_lead_s
        stopped = False
        while d.time < limit - 1e-9:
            self.step(*leg.sample(d.time + dt - t0, lead))
            if on_step is not None and on_step(self):
                stopped = True
                break
        if stopped or limit < end:
            p, v, _ = leg.sample(d.time - t0)
            self.ref_pos, self.ref_vel, self.ref_time = np.array(p), np.array(v), float(d.time)
        else:
            self.ref_pos, self.ref_vel, self.ref_time = leg.end.copy(), leg.end_velocity(), end
        return leg

    def fly_to(self, target, on_step: Callable[[Flight], bool | None] | None = None,
               time_limit_s: float | None = None) -> bool:
        """Flies a straight leg from here to ``target`` and settles there ("stop" mode, v0).

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
        give_up = leg.duration + self.cfg.max_extra_s
        limit = np.inf if time_limit_s is None else float(time_limit_s)
        tol2, settle2 = self.cfg.arrive_tol ** 2, self.cfg.settle_speed ** 2
        d, qp, qv = self._d, self._qp, self._qv
        dt, lead = self._m.opt.timestep, self.controller.gains.feedforward_lead_s
        try:
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
        finally:
            self.ref_pos, self.ref_vel, self.ref_time = self.position, np.zeros(3), self.time_s


def step_together(flights: list[Flight], refs) -> None:
    """One physics step of a team scene: each drone's loop towards its reference ``(pos, vel, acc)``
    (the first drone's first: its disturbances set the wind the others feel), then one ``mj_step``."""
    for flight, ref in zip(flights, refs):
        flight.control(*ref)
    mujoco.mj_step(flights[0]._m, flights[0]._d)
    for flight in flights:
        flight.steps += 1
