"""Wind and state estimation: what separates the simulated drone from a perfect one.

* Wind (:class:`Wind`): a mean wind per episode (speed uniform in ``[0, wind_max]``, direction
  uniform) plus gusts, each horizontal component a first-order Gauss-Markov process (std
  ``gust_std``, correlation time ``gust_time_s``). It enters through MuJoCo's own ``opt.wind``
  (the inertia-box drag of ``opt.density`` is computed on the airspeed) and through an applied force
  ``rotor_drag * (wind - v)`` on the horizontal airspeed (``data.xfrc_applied``): the linear
  rotor (blade-flapping / induced) drag that dominates a multirotor's drag at these speeds.
* State estimation (:class:`StateEstimator`): the controller and the camera's georeferencing use
  the estimated pose, not the true one. Position error = a per-episode bias (GPS-like, separate
  horizontal and vertical std) plus a Gauss-Markov error (std ``pos_noise_std``, time
  ``pos_noise_time_s``); velocity error Gauss-Markov; attitude error = a per-episode bias plus a
  Gauss-Markov error, as a small rotation in the body frame.

Every process is updated at ``update_hz`` from a generator seeded per episode: the same seed gives
the same wind and the same estimates. Written on Python floats (called every few physics steps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DisturbanceConfig:
    """Wind and state-estimation errors (defaults: a breezy day, consumer GNSS + IMU)."""

    wind_max: float = 4.0  # [m/s] per-episode mean wind speed is uniform in [0, wind_max]
    gust_std: float = 0.7  # [m/s] std of each horizontal gust component
    gust_time_s: float = 2.0  # [s] correlation time of the gusts
    rotor_drag: float = 0.35  # [N s/m] linear rotor drag on the horizontal airspeed
    pos_bias_std: float = 0.25  # [m] per-episode horizontal position bias, each axis
    pos_bias_std_z: float = 0.2  # [m] per-episode vertical position bias
    pos_noise_std: float = 0.1  # [m] Gauss-Markov position error around the bias, each axis
    pos_noise_time_s: float = 1.0  # [s]
    vel_noise_std: float = 0.05  # [m/s] Gauss-Markov velocity error, each axis
    vel_noise_time_s: float = 0.3  # [s]
    att_bias_std_deg: float = 0.4  # [deg] per-episode attitude bias about each body axis
    att_noise_std_deg: float = 0.3  # [deg] Gauss-Markov attitude error about each body axis
    att_noise_time_s: float = 0.5  # [s]
    update_hz: float = 50.0  # [Hz] rate of the wind and estimator processes

    def __post_init__(self) -> None:
        for name in ("wind_max", "gust_std", "rotor_drag", "pos_bias_std", "pos_bias_std_z", "pos_noise_std",
                     "vel_noise_std", "att_bias_std_deg", "att_noise_std_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"DisturbanceConfig.{name} must be a finite number >= 0, got {v}")
        for name in ("gust_time_s", "pos_noise_time_s", "vel_noise_time_s", "att_noise_time_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"DisturbanceConfig.{name} must be a finite number > 0 [s], got {v}")
        if not 1.0 <= self.update_hz <= 1000.0:
            raise ValueError(f"DisturbanceConfig.update_hz must be in [1, 1000] Hz, got {self.update_hz}")

    @property
    def estimator_is_perfect(self) -> bool:
        return (self.pos_bias_std == 0 and self.pos_bias_std_z == 0 and self.pos_noise_std == 0
                and self.vel_noise_std == 0 and self.att_bias_std_deg == 0 and self.att_noise_std_deg == 0)

    @property
    def calm(self) -> bool:
        return self.wind_max == 0 and self.gust_std == 0

    @staticmethod
    def none() -> DisturbanceConfig:
        """No wind, perfect state (v0)."""
        return DisturbanceConfig(wind_max=0.0, gust_std=0.0, rotor_drag=0.0, pos_bias_std=0.0, pos_bias_std_z=0.0,
                                 pos_noise_std=0.0, vel_noise_std=0.0, att_bias_std_deg=0.0,
                                 att_noise_std_deg=0.0)


class _GaussMarkov:
    """First-order Gauss-Markov process x' = -x / tau + noise with stationary std ``std``, sampled at dt."""

    __slots__ = ("phi", "q", "x")

    def __init__(self, std: float, tau: float, dt: float, n: int, rng: np.random.Generator) -> None:
        self.phi = math.exp(-dt / tau)
        self.q = std * math.sqrt(1.0 - self.phi * self.phi)
        self.x = [float(v) for v in std * rng.standard_normal(n)]  # start in the stationary distribution

    def step(self, w) -> None:
        phi, q = self.phi, self.q
        self.x = [phi * x + q * wi for x, wi in zip(self.x, w)]


class Disturbances:
    """Wind and estimator errors of one episode (see the module docstring).

    Args:
        cfg: the settings.
        seed: the episode's seed for these processes.
    """

    def __init__(self, cfg: DisturbanceConfig, seed: int) -> None:
        self.cfg = cfg
        rng = np.random.default_rng(int(seed))
        self._rng = rng
        dt = 1.0 / cfg.update_hz
        self.dt = dt
        speed = cfg.wind_max * rng.uniform()
        heading = rng.uniform(0.0, 2.0 * math.pi)
        self.wind_mean = (speed * math.cos(heading), speed * math.sin(heading))
        self.pos_bias = (cfg.pos_bias_std * rng.standard_normal(), cfg.pos_bias_std * rng.standard_normal(),
                         cfg.pos_bias_std_z * rng.standard_normal())
        deg = math.pi / 180.0
        self.att_bias = tuple(float(v) for v in cfg.att_bias_std_deg * deg * rng.standard_normal(3))
        self._gust = _GaussMarkov(cfg.gust_std, cfg.gust_time_s, dt, 2, rng)
        self._pos = _GaussMarkov(cfg.pos_noise_std, cfg.pos_noise_time_s, dt, 3, rng)
        self._vel = _GaussMarkov(cfg.vel_noise_std, cfg.vel_noise_time_s, dt, 3, rng)
        self._att = _GaussMarkov(cfg.att_noise_std_deg * deg, cfg.att_noise_time_s, dt, 3, rng)

    def advance(self) -> None:
        """One update period of every process."""
        w = self._rng.standard_normal(11).tolist()
        self._gust.step(w[0:2])
        self._pos.step(w[2:5])
        self._vel.step(w[5:8])
        self._att.step(w[8:11])

    @property
    def wind(self) -> tuple[float, float, float]:
        """Current wind velocity (world frame) [m/s]."""
        g = self._gust.x
        return self.wind_mean[0] + g[0], self.wind_mean[1] + g[1], 0.0

    def position_error(self) -> tuple[float, float, float]:
        b, e = self.pos_bias, self._pos.x
        return b[0] + e[0], b[1] + e[1], b[2] + e[2]

    def velocity_error(self) -> tuple[float, float, float]:
        e = self._vel.x
        return e[0], e[1], e[2]

    def attitude_error(self) -> tuple[float, float, float]:
        """Small rotation (body frame) [rad] from the true to the estimated attitude."""
        b, e = self.att_bias, self._att.x
        return b[0] + e[0], b[1] + e[1], b[2] + e[2]


def perturb_quat(q, rotvec) -> tuple[float, float, float, float]:
    """q * exp(rotvec / 2): the attitude ``q`` (w, x, y, z) rotated by the small body-frame rotation ``rotvec``."""
    rx, ry, rz = rotvec
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < 1e-12:
        return float(q[0]), float(q[1]), float(q[2]), float(q[3])
    s = math.sin(angle / 2.0) / angle
    bw, bx, by, bz = math.cos(angle / 2.0), rx * s, ry * s, rz * s
    aw, ax, ay, az = q[0], q[1], q[2], q[3]
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def quat_to_mat(q) -> np.ndarray:
    """(3, 3) rotation matrix (columns: body axes in the world) of the unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
