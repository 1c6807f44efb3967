"""The graph twin's sensor: the deployment camera's error, drawn instead of rendered.

:class:`CameraErrorLegs` is a mission :class:`~ipp_bench.core.mission.Platform` that flies the
deployment's own reference legs (:class:`~ipp_bench.core.legs.ContinuousLeg`: velocity-continuous
through waypoints, the same clock as ``MuJoCoWeed15-v1``'s, without physics, wind or estimator) and
draws its read-outs from the error model that ``python -m ipp_bench.sim.calibrate`` fits to the
MuJoCo camera, so that planners and training see the deployment's sensor without MuJoCo. The
camera is read every ``measurement_spacing`` metres along the reference (followed in steps of
``step_s``, the deployment's physics step) and on arrival.

The error model:

* a persistent error per cell, resolution factor and episode, drawn once at the start:
  ``e_f,c = sqrt(s_f phi(x_c)) u_f,c`` with s_f the task's ``persistent_var`` /
  ``persistent_var_binned``, phi(t) = :func:`~ipp_bench.core.belief.value_scale` (``noise_floor``) at
  the cell's true value x_c (a cell with nothing to misread errs less), corr(u_1,c, u_2,c) =
  ``persistent_corr``, and each u_f a unit-variance Gaussian field over the cells with a squared-
  exponential correlation whose value between edge-neighbours is ``neighbour_corr`` (the task's
  ``persistent_neighbour_corr``, 0.59, measured between neighbouring cells of binned read-outs,
  ``benchmarks/RESULTS.md``, "What the camera gets wrong": the cells of a binned 2 x 2 block share
  much of their error);
* white noise on top: ``N(0, f^e a (1 - exp(-b h)) phi(w . x))`` per read-out row w;
* the frame's edge: at every read the camera is tilted by a fresh draw (each horizontal component
  N(0, ``tilt_sd_deg``), 4.6 deg: the deployment's median tilt at its reads is 5.4 deg), and the rows of
  the cells its frame covers less than half of are dropped (``restrict``, as the deployment's camera
  drops them: 25-34 % of the rows of a 14 m read-out, 2-6 % at 8 m).

A row measures ``z = w . (x + e_f) + v``. The belief is the task's (the deployment's model,
:class:`~ipp_bench.core.belief.PersistentErrorBelief`), which models the same correlation: on the twin the
belief is the sensor's own model, up to the value t at which each cell's error scale is plugged in.
"""

from __future__ import annotations

import math

import numpy as np

from .belief import value_scale
from .legs import ContinuousLeg, continuous_durations
from .mission import LegOutcome, Mission
from .sensor import persistent_correlation, rays_on_ground, restrict

NEIGHBOUR_CORR = 0.59  # [-] correlation of the persistent errors of edge-neighbouring cells (measured, f = 2)
#: [deg] sd of each horizontal component of the drone's tilt when the camera reads (MuJoCoWeed15-v1: median
#: tilt 5.4 deg over random's and greedy's reads, a Rayleigh median of 1.18 sd)
TILT_SD_DEG = 4.6


class CameraErrorLegs:
    """The deployment's reference legs, read by the calibrated camera-error model (module docstring).

    Args:
        neighbour_corr: correlation of the persistent errors of two edge-neighbouring cells, in [0, 1).
        ramp_s: velocity-ramp time of the reference legs [s] (the deployment's ``FlightConfig.ramp_s``).
        step_s: step along the reference [s] at which the distance travelled is counted.
    """

    def __init__(self, neighbour_corr: float = NEIGHBOUR_CORR, ramp_s: float = 1.0, step_s: float = 0.005,
                 tilt_sd_deg: float = TILT_SD_DEG, min_coverage: float = 0.5) -> None:
        if not (isinstance(neighbour_corr, (int, float)) and 0.0 <= neighbour_corr < 1.0):
            raise ValueError(f"neighbour_corr = {neighbour_corr!r} is invalid: expected a number in [0, 1)")
        if not (ramp_s > 0.0 and 0.0 < step_s <= 0.1):
            raise ValueError(f"ramp_s = {ramp_s}, step_s = {step_s} are invalid: expected ramp_s > 0, "
                             "step_s in (0, 0.1] s")
        self.neighbour_corr, self.ramp_s, self.step_s = float(neighbour_corr), float(ramp_s), float(step_s)
        if not (isinstance(tilt_sd_deg, (int, float)) and 0.0 <= tilt_sd_deg < 30.0):
            raise ValueError(f"tilt_sd_deg = {tilt_sd_deg!r} is invalid: expected a number in [0, 30) degrees")
        if not (isinstance(min_coverage, (int, float)) and 0.0 < min_coverage <= 1.0):
            raise ValueError(f"min_coverage = {min_coverage!r} is invalid: expected a number in (0, 1]")
        self.tilt_sd, self.min_coverage = math.radians(float(tilt_sd_deg)), float(min_coverage)
        self.errors: dict[int, np.ndarray] = {}
        self.ref_pos = np.zeros(3)
        self.ref_vel = np.zeros(3)

    def begin(self, mission: Mission) -> None:
        """Draws the episode's persistent errors from ``mission.rng`` (before any read-out); at rest."""
        cfg, grid = mission.sensor.cfg, mission.config.grid
        n = grid.n_cells
        if self.neighbour_corr > 0.0:  # the belief's own correlation (PersistentErrorBelief)
            rows, cols = np.divmod(np.arange(n), grid.cols)
            L = np.linalg.cholesky(persistent_correlation(rows, cols, self.neighbour_corr) + 1e-9 * np.eye(n))
        else:
            L = np.eye(n)
        rho = float(cfg.persistent_corr)
        z1, z2 = mission.rng.standard_normal((2, n))
        u = {1: L @ z1, int(cfg.binning): L @ (rho * z1 + math.sqrt(max(1.0 - rho * rho, 0.0)) * z2)}
        scale = value_scale(mission._truth_flat, cfg.noise_floor)
        self.errors = {f: np.sqrt(cfg.persistent(f) * scale) * uf for f, uf in u.items()}
        self.ref_pos = np.array(mission.position, dtype=np.float64)
        self.ref_vel = np.zeros(3)

    def leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        """Exact from the current position (the reference's velocity is known); from another start the
        upper bound over incoming velocities, as the deployment's oracle."""
        speed = mission.config.mission.speed
        start = np.asarray(start_xyz, dtype=np.float64).reshape(3)
        if np.linalg.norm(start - mission.position) <= 1e-6:
            return continuous_durations(self.ref_pos, self.ref_vel, end_xyzs, speed, self.ramp_s)
        return continuous_durations(start, None, end_xyzs, speed, self.ramp_s)

    def static_leg_durations(self, mission: Mission, start_xyz, end_xyzs) -> np.ndarray:
        """The upper bound over incoming velocities from ``start_xyz``, also from the current position."""
        start = np.asarray(start_xyz, dtype=np.float64).reshape(3)
        return continuous_durations(start, None, end_xyzs, mission.config.mission.speed, self.ramp_s)

    def fly(self, mission: Mission, target: np.ndarray, length_m: float) -> LegOutcome:
        del length_m
        speed, spacing = mission.config.mission.speed, mission.config.mission.measurement_spacing
        leg = ContinuousLeg(self.ref_pos, self.ref_vel, target, speed, self.ramp_s)
        t0, budget = mission.time_s, mission.budget_s
        end = t0 + leg.duration
        limit = min(end, budget)
        records: list = []
        since, flown = mission._since_measurement, 0.0
        last = tuple(self.ref_pos.tolist())
        dt, k = self.step_s, 1
        while t0 + k * dt < limit - 1e-9:
            here = leg.sample(k * dt)[0]
            step = math.dist(here, last)
            last = here
            flown += step
            since += step
            if since >= spacing - 1e-9:
                records.extend(self._read(mission, [here], [min(t0 + k * dt, budget)]))
                since = 0.0
            k += 1
        if limit >= end - 1e-12:  # the whole leg: read on arrival
            flown += math.dist(tuple(np.asarray(target, dtype=np.float64).tolist()), last)
            records.extend(self._read(mission, [target], [limit]))
            self.ref_pos, self.ref_vel = leg.end.copy(), leg.end_velocity()
            return LegOutcome(records, limit, limit - t0, flown, np.asarray(target, dtype=np.float64), 0.0)
        p, v, _ = leg.sample(limit - t0)  # out of budget on the way: the leg ends where the reference was
        self.ref_pos, self.ref_vel = np.array(p), np.array(v)
        return LegOutcome(records, limit, limit - t0, flown, self.ref_pos.copy(), since)

    def _seen(self, mission: Mission, p: np.ndarray, tilt: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """(n,) bool: the cells the frame of a camera tilted by ``tilt`` (about x and y, [rad]) covers to
        ``min_coverage`` (a 4 x 4 grid of points per cell inside the frame's ground quadrilateral), as the
        deployment's camera reports the cells at its frame's edge unseen and drops their rows."""
        seen = np.ones(mission.config.grid.n_cells, dtype=bool)
        body_z = np.array([math.tan(tilt[0]), math.tan(tilt[1]), 1.0])
        body_z /= np.linalg.norm(body_z)
        axis = np.cross([0.0, 0.0, 1.0], body_z)
        s_ang = float(np.linalg.norm(axis))
        if s_ang < 1e-12:
            return seen
        k = axis / s_ang
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        R = np.eye(3) + s_ang * K + (1.0 - body_z[2]) * (K @ K)
        tan = math.tan(math.radians(mission.sensor.cfg.fov_deg) / 2.0)
        corners = np.array([[-tan, -tan, -1.0], [tan, -tan, -1.0], [tan, tan, -1.0], [-tan, tan, -1.0]])
        quad = rays_on_ground(corners, p, R)  # counter-clockwise on the ground
        if quad is None:
            return ~seen
        res, ncols = mission.config.grid.resolution, mission.config.grid.cols
        offs = (np.arange(4) + 0.5) / 4.0
        rr, cc = np.divmod(np.asarray(cells), ncols)
        px, py = np.broadcast_arrays((cc[:, None, None] + offs[None, None, :]) * res,
                                     (rr[:, None, None] + offs[None, :, None]) * res)
        inside = np.ones(px.shape, dtype=bool)
        for j in range(4):  # counter-clockwise corners: inside is left of every edge
            (x0, y0), (x1, y1) = quad[j], quad[(j + 1) % 4]
            inside &= (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0) >= 0.0
        seen[cells] = inside.reshape(len(cells), -1).mean(axis=1) >= self.min_coverage
        return seen

    def read_here(self, mission: Mission, time_s: float) -> list:
        return self._read(mission, [mission.position], [time_s])

    def _read(self, mission: Mission, points, times) -> list:
        truth, floor = mission._truth_flat, mission.sensor.cfg.noise_floor
        records = []
        for p, t in zip(points, times):
            p = np.asarray(p, dtype=np.float64)
            obs = mission.sensor.observe(p)
            mission.measurement_log.append((float(t), *map(float, p)))
            if obs is not None and self.tilt_sd > 0.0:
                obs = restrict(obs, self._seen(mission, p, mission.rng.normal(0.0, self.tilt_sd, 2), obs.cells))
            if obs is None:
                records.append((None, None, float(t)))
                continue
            W = obs.weights
            clean = W @ truth[obs.cells]
            white = (obs.var if obs.persistent is None else obs.var - obs.persistent) * value_scale(clean, floor)
            z = clean + W @ self.errors[obs.factor][obs.cells] + np.sqrt(white) * mission.rng.standard_normal(obs.m)
            records.append((obs, z, float(t)))
        return records
