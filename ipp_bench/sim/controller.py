"""Cascaded flight control: reference trajectory -> position -> attitude -> rotor thrusts.

* :class:`Leg` is the reference for one straight waypoint-to-waypoint leg: a
  cruise at up to ``speed`` (2 m/s) with raised-cosine velocity ramps, so the
  commanded acceleration (and the attitude it implies) is continuous.
* :class:`ContinuousLeg` is the v1 reference: velocity-continuous through waypoints (the drone
  does not stop at a node; it slows down only where the next leg turns away), with
  :func:`continuous_durations` its exact duration for the mission's affordability oracle.
* :class:`CascadedController` closes a PD position loop with acceleration
  feed-forward, turns the desired acceleration into a thrust vector (tilt
  limited) and a desired attitude at fixed yaw, runs a geometric attitude loop
  on SO(3) (Lee, Leok & McClamroch 2010) for the body torques, and inverts the
  rotor allocation for the four thrusts (clipped to the rotor limits).

No MuJoCo in here: the state comes in as arrays, the thrusts go out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the v1 reference lives in the core (the graph twin flies it too); re-exported here
from ipp_bench.core.legs import ContinuousLeg, _blend_plan, continuous_durations  # noqa: F401
from ipp_bench.sim.quadrotor import GRAVITY, QuadrotorParams


@dataclass(frozen=True)
class ControllerGains:
    """Loop bandwidths; gains follow as k_p = w^2, k_d = 2 zeta w (times inertia for attitude)."""

    pos_omega_xy: float = 2.6  # [rad/s]
    pos_omega_z: float = 3.2  # [rad/s]
    pos_zeta: float = 0.95
    att_omega: float = 16.0  # [rad/s]
    att_zeta: float = 0.85
    yaw_omega: float = 6.0  # [rad/s]
    max_tilt_deg: float = 35.0  # [deg]
    max_accel: float = 6.0  # [m/s^2] bound on the commanded acceleration (each axis group)
    feedforward_lead_s: float = 0.1  # [s] acceleration feed-forward taken this far ahead (attitude + rotor lag)

    def __post_init__(self) -> None:
        for name in ("pos_omega_xy", "pos_omega_z", "pos_zeta", "att_omega", "att_zeta", "yaw_omega", "max_accel"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"ControllerGains.{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.feedforward_lead_s <= 0.5:
            raise ValueError(f"ControllerGains.feedforward_lead_s must be in [0, 0.5], got {self.feedforward_lead_s}")
        if not 0.0 < self.max_tilt_deg < 80.0:
            raise ValueError(f"ControllerGains.max_tilt_deg must be in (0, 80), got {self.max_tilt_deg}")


class Leg:
    """Straight-line reference from ``start`` to ``end`` at up to ``speed``.

    Velocity ramps up (and down) over ``ramp_s`` seconds along v(t) = v_c (1 - cos(pi t / ramp_s)) / 2;
    legs too short to reach ``speed`` cruise at ``length / ramp_s``. Duration = length / v_c + ramp_s.
    """

    def __init__(self, start, end, speed: float = 2.0, ramp_s: float = 1.0) -> None:
        if speed <= 0.0 or ramp_s <= 0.0:
            raise ValueError(f"Leg speed and ramp_s must be > 0, got {speed}, {ramp_s}")
        self.start = np.asarray(start, dtype=np.float64).copy()
        self.end = np.asarray(end, dtype=np.float64).copy()
        delta = self.end - self.start
        self.length = float(np.linalg.norm(delta))
        self.direction = delta / self.length if self.length > 0.0 else np.zeros(3)
        self.ramp_s = float(ramp_s)
        self.cruise_speed = min(float(speed), self.length / self.ramp_s)
        self.duration = (self.length / self.cruise_speed + self.ramp_s) if self.length > 0.0 else 0.0
        self._dir, self._start = tuple(self.direction.tolist()), tuple(self.start.tolist())

    @staticmethod
    def duration_for(length: float, speed: float = 2.0, ramp_s: float = 1.0) -> float:
        """Reference duration of a leg of ``length`` metres [s] (0 for a zero-length leg)."""
        if length <= 0.0:
            return 0.0
        return length / min(speed, length / ramp_s) + ramp_s

    def _along(self, t: float) -> tuple[float, float, float]:
        """Distance, speed and acceleration along the leg at time t."""
        vc, ta, T = self.cruise_speed, self.ramp_s, self.duration
        if self.length == 0.0 or t >= T:
            return self.length, 0.0, 0.0
        if t <= 0.0:
            return 0.0, 0.0, 0.0
        w = math.pi / ta
        if t < ta:  # accelerate
            s, c = math.sin(w * t), math.cos(w * t)
            return 0.5 * vc * (t - s / w), 0.5 * vc * (1 - c), 0.5 * vc * w * s
        if t <= T - ta:  # cruise
            return 0.5 * vc * ta + vc * (t - ta), vc, 0.0
        u = T - t  # decelerate: mirror image of the ramp
        s, c = math.sin(w * u), math.cos(w * u)
        return self.length - 0.5 * vc * (u - s / w), 0.5 * vc * (1 - c), -0.5 * vc * w * s

    def sample(self, t: float, lead_s: float = 0.0) -> tuple[tuple, tuple, tuple]:
        """Reference position [m], velocity [m/s] at leg time t [s], and acceleration [m/s^2] at t + lead_s.

        The lead lets the acceleration feed-forward anticipate the attitude and rotor lag.
        """
        s, v, a = self._along(t)
        if lead_s:
            a = self._along(t + lead_s)[2]
        (dx, dy, dz), (x0, y0, z0) = self._dir, self._start
        return (x0 + s * dx, y0 + s * dy, z0 + s * dz), (v * dx, v * dy, v * dz), (a * dx, a * dy, a * dz)


class CascadedController:
    """Position -> attitude -> rotor-thrust controller for :class:`QuadrotorParams`.

    Written on Python floats: at 3-vectors numpy's per-call overhead would cost
    more than the physics step itself.
    """

    def __init__(self, params: QuadrotorParams = QuadrotorParams(),  # noqa: B008 (frozen dataclasses)
                 gains: ControllerGains = ControllerGains(), yaw: float = 0.0) -> None:
        self.params, self.gains = params, gains
        self.yaw = float(yaw)
        g = gains
        self.kp = (g.pos_omega_xy ** 2, g.pos_omega_xy ** 2, g.pos_omega_z ** 2)
        kd_xy, kd_z = 2.0 * g.pos_zeta * g.pos_omega_xy, 2.0 * g.pos_zeta * g.pos_omega_z
        self.kd = (kd_xy, kd_xy, kd_z)
        self.inertia = tuple(float(i) for i in params.inertia)
        omegas = (g.att_omega, g.att_omega, g.yaw_omega)
        self.kR = tuple(i * w * w for i, w in zip(self.inertia, omegas))
        self.kw = tuple(i * 2.0 * g.att_zeta * w for i, w in zip(self.inertia, omegas))
        self.cos_max_tilt = math.cos(math.radians(g.max_tilt_deg))
        self.sin_max_tilt = math.sin(math.radians(g.max_tilt_deg))
        self.mixer = tuple(tuple(float(v) for v in row) for row in params.mixer)
        self.max_thrust = float(params.max_thrust)
        self.mass = float(params.mass)

    @property
    def yaw(self) -> float:
        return self._yaw

    @yaw.setter
    def yaw(self, value: float) -> None:
        self._yaw = float(value)
        self._b1c = (math.cos(self._yaw), math.sin(self._yaw))

    def desired_acceleration(self, pos, vel, ref_pos, ref_vel, ref_acc) -> tuple[float, float, float]:
        """Position loop: PD on the tracking error plus the reference acceleration [m/s^2]."""
        kp, kd, amax = self.kp, self.kd, self.gains.max_accel
        ax = ref_acc[0] + kp[0] * (ref_pos[0] - pos[0]) + kd[0] * (ref_vel[0] - vel[0])
        ay = ref_acc[1] + kp[1] * (ref_pos[1] - pos[1]) + kd[1] * (ref_vel[1] - vel[1])
        az = ref_acc[2] + kp[2] * (ref_pos[2] - pos[2]) + kd[2] * (ref_vel[2] - vel[2])
        nxy = math.hypot(ax, ay)
        if nxy > amax:
            ax, ay = ax * amax / nxy, ay * amax / nxy
        az = min(max(az, -0.8 * GRAVITY), amax)
        return ax, ay, az

    def thrusts(self, pos, vel, quat, omega_body, ref_pos, ref_vel, ref_acc) -> list[float]:
        """Rotor thrusts [N] (4,) for the state and reference.

        Args:
            pos, vel: world position [m] and velocity [m/s].
            quat: body orientation (w, x, y, z), body to world.
            omega_body: angular velocity in the body frame [rad/s].
            ref_pos, ref_vel, ref_acc: reference from :meth:`Leg.sample`.
        """
        ax, ay, az = self.desired_acceleration(pos, vel, ref_pos, ref_vel, ref_acc)
        m = self.mass
        fx, fy, fz = m * ax, m * ay, m * (az + GRAVITY)
        fn = math.sqrt(fx * fx + fy * fy + fz * fz)
        b3x, b3y, b3z = fx / fn, fy / fn, fz / fn
        if b3z < self.cos_max_tilt:  # limit the tilt, keep the heading of the horizontal part
            h = math.hypot(b3x, b3y)
            b3x, b3y, b3z = b3x / h * self.sin_max_tilt, b3y / h * self.sin_max_tilt, self.cos_max_tilt
        # body rotation matrix R (columns: body axes in world)
        w, x, y, z = quat[0], quat[1], quat[2], quat[3]
        r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
        r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
        r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
        collective = fx * r02 + fy * r12 + fz * r22
        # desired attitude: b3d, heading yaw; b2d = b3d x b1c / |.|, b1d = b2d x b3d
        c1x, c1y = self._b1c
        b2x, b2y, b2z = -b3z * c1y, b3z * c1x, b3x * c1y - b3y * c1x
        n2 = math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z)
        b2x, b2y, b2z = b2x / n2, b2y / n2, b2z / n2
        b1x, b1y, b1z = b2y * b3z - b2z * b3y, b2z * b3x - b2x * b3z, b2x * b3y - b2y * b3x
        # E = Rd^T R; e_R = vee(0.5 (E - E^T))
        e10 = b2x * r00 + b2y * r10 + b2z * r20
        e01 = b1x * r01 + b1y * r11 + b1z * r21
        e20 = b3x * r00 + b3y * r10 + b3z * r20
        e02 = b1x * r02 + b1y * r12 + b1z * r22
        e21 = b3x * r01 + b3y * r11 + b3z * r21
        e12 = b2x * r02 + b2y * r12 + b2z * r22
        erx, ery, erz = 0.5 * (e21 - e12), 0.5 * (e02 - e20), 0.5 * (e10 - e01)
        wx, wy, wz = omega_body[0], omega_body[1], omega_body[2]
        (Ix, Iy, Iz), kR, kw = self.inertia, self.kR, self.kw
        tx = -kR[0] * erx - kw[0] * wx + (wy * Iz * wz - wz * Iy * wy)
        ty = -kR[1] * ery - kw[1] * wy + (wz * Ix * wx - wx * Iz * wz)
        tz = -kR[2] * erz - kw[2] * wz + (wx * Iy * wy - wy * Ix * wx)
        fmax = self.max_thrust
        out = []
        for row in self.mixer:
            f = row[0] * collective + row[1] * tx + row[2] * ty + row[3] * tz
            out.append(0.0 if f < 0.0 else (fmax if f > fmax else f))
        return out
