"""The velocity-continuous reference leg of the deployment (v1), in the core: pure numpy.

:class:`ContinuousLeg` and :func:`continuous_durations` are the reference the MuJoCo drone flies
(``ipp_bench.sim.controller`` re-exports them; the flight follows them under the cascaded
controller) and the clock of the graph twin (:mod:`ipp_bench.core.twin`), which flies the same
reference without physics. No MuJoCo in here.
"""

from __future__ import annotations

import math

import numpy as np


def _blend_plan(start, v0, ends, speed: float, ramp_s: float, iters: int = 8):
    """Cruise direction, cruise speed, blend time and total duration of :class:`ContinuousLeg` s.

    Solves p0 + v0 T_r / 2 + v_c d (T_r / 2 + t_c) = end with T_r = ramp_s |v_c d - v0| / speed
    (a few fixed-point sweeps for d, then d is set so that the end is met exactly); legs too short
    for the cruise speed get the largest v_c with t_c >= 0 (bisection).

    Returns:
        (d (K, 3), v_c (K,), T_r (K,), t_c (K,)).
    """
    ends = np.asarray(ends, dtype=np.float64).reshape(-1, 3)
    v0 = np.asarray(v0, dtype=np.float64).reshape(1, 3)
    delta = ends - np.asarray(start, dtype=np.float64).reshape(1, 3)
    L = np.linalg.norm(delta, axis=1)
    d0 = delta / np.where(L > 0, L, 1.0)[:, None]

    def solve(vc):
        d = d0.copy()
        for _ in range(iters):
            Tr = ramp_s * np.linalg.norm(vc[:, None] * d - v0, axis=1) / speed
            q = delta - v0 * (0.5 * Tr)[:, None]
            qn = np.linalg.norm(q, axis=1)
            d = np.where(qn[:, None] > 1e-12, q / np.where(qn > 1e-12, qn, 1.0)[:, None], d0)
        Tr = ramp_s * np.linalg.norm(vc[:, None] * d - v0, axis=1) / speed
        q = delta - v0 * (0.5 * Tr)[:, None]
        qn = np.linalg.norm(q, axis=1)
        d = np.where(qn[:, None] > 1e-12, q / np.where(qn > 1e-12, qn, 1.0)[:, None], d0)
        return d, Tr, qn / vc - 0.5 * Tr

    vc = np.full(L.shape, float(speed))
    d, Tr, tc = solve(vc)
    short = tc < 0.0
    if short.any():
        lo, hi = np.zeros(int(short.sum())), np.full(int(short.sum()), float(speed))
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            ok = _sub_solve(solve, short, vc, mid)[2] >= 0.0
            lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
        vc[short] = np.maximum(lo, 1e-6)
        d, Tr, tc = solve(vc)
    return d, vc, Tr, np.maximum(tc, 0.0)


def _sub_solve(solve, rows, vc, values):
    full = vc.copy()
    full[rows] = np.maximum(values, 1e-6)
    d, Tr, tc = solve(full)
    return d[rows], Tr[rows], tc[rows]


class ContinuousLeg:
    """Velocity-continuous reference from ``start`` (velocity ``v0``) to ``end``, leaving at cruise speed.

    The velocity blends from ``v0`` to the cruise velocity v_c d with a raised cosine over
    T_r = ramp_s |v_c d - v0| / speed (continuous acceleration, zero at both ends, peak
    pi speed / (2 ramp_s)), then holds it until ``end``; the cruise direction d is the one that
    makes the blend plus the cruise land exactly on ``end``. A blend of two velocities of at most
    ``speed`` never exceeds ``speed``. The drone flies through a waypoint without stopping and
    slows down only where the next leg turns away (to zero where it turns straight back).
    Duration T_r + t_c (:func:`continuous_durations`).
    """

    def __init__(self, start, v0, end, speed: float = 2.0, ramp_s: float = 1.0) -> None:
        if speed <= 0.0 or ramp_s <= 0.0:
            raise ValueError(f"ContinuousLeg speed and ramp_s must be > 0, got {speed}, {ramp_s}")
        self.start = np.asarray(start, dtype=np.float64).copy()
        self.end = np.asarray(end, dtype=np.float64).copy()
        self.v0 = np.asarray(v0, dtype=np.float64).copy()
        if np.linalg.norm(self.end - self.start) <= 0.0:
            raise ValueError("ContinuousLeg: start and end coincide")
        d, vc, Tr, tc = _blend_plan(self.start, self.v0, self.end[None], float(speed), float(ramp_s))
        self.direction, self.cruise_speed = d[0], float(vc[0])
        self.ramp_time, self.cruise_time = float(Tr[0]), float(tc[0])
        self.duration = self.ramp_time + self.cruise_time
        self._dv = tuple((self.cruise_speed * self.direction - self.v0).tolist())
        self._vc = tuple((self.cruise_speed * self.direction).tolist())
        self._start, self._v = tuple(self.start.tolist()), tuple(self.v0.tolist())
        Tr2 = 0.5 * self.ramp_time
        self._blend_end = tuple((self.start + (self.v0 + self.cruise_speed * self.direction) * Tr2).tolist())

    def end_velocity(self) -> np.ndarray:
        return self.cruise_speed * self.direction

    def sample(self, t: float, lead_s: float = 0.0) -> tuple[tuple, tuple, tuple]:
        """Reference position [m], velocity [m/s] at leg time t [s] and acceleration [m/s^2] at t + lead_s.

        Before the leg (t < 0) the incoming velocity is extrapolated; after it, the cruise.
        """
        (x0, y0, z0), (ux, uy, uz), (gx, gy, gz) = self._start, self._v, self._dv
        Tr = self.ramp_time
        if t < 0.0:
            return (x0 + ux * t, y0 + uy * t, z0 + uz * t), self._v, (0.0, 0.0, 0.0)
        if t < Tr:
            w = math.pi / Tr
            sig = 0.5 * (1.0 - math.cos(w * t))
            Sig = 0.5 * (t - math.sin(w * t) / w)
            pos = (x0 + ux * t + gx * Sig, y0 + uy * t + gy * Sig, z0 + uz * t + gz * Sig)
            vel = (ux + gx * sig, uy + gy * sig, uz + gz * sig)
        else:
            (bx, by, bz), (cx, cy, cz) = self._blend_end, self._vc
            c = t - Tr
            pos = (bx + cx * c, by + cy * c, bz + cz * c)
            vel = self._vc
        ta = t + lead_s
        if 0.0 <= ta < Tr:
            w = math.pi / Tr
            k = 0.5 * w * math.sin(w * ta)
            acc = (gx * k, gy * k, gz * k)
        else:
            acc = (0.0, 0.0, 0.0)
        return pos, vel, acc


def continuous_durations(start, v0, ends, speed: float = 2.0, ramp_s: float = 1.0) -> np.ndarray:
    """Durations [s] of :class:`ContinuousLeg` from ``start`` with velocity ``v0`` to each of ``ends`` (K, 3).

    ``v0=None`` gives an upper bound over every incoming velocity of magnitude <= ``speed``:
    2 ramp_s + L / speed, the duration when the leg turns straight back at full speed (checked
    against random incoming velocities in the tests). Zero-length legs take 0 s.
    """
    ends = np.asarray(ends, dtype=np.float64).reshape(-1, 3)
    L = np.linalg.norm(ends - np.asarray(start, dtype=np.float64).reshape(1, 3), axis=1)
    if v0 is None:
        return np.where(L > 0.0, 2.0 * ramp_s + L / speed, 0.0)
    _, _, Tr, tc = _blend_plan(start, v0, ends, speed, ramp_s)
    return np.where(L > 0.0, Tr + tc, 0.0)
