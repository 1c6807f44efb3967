"""Altitude-dependent downward camera (paper Section III-D; Popovic et al. 2020 lineage).

A square field of view of ``fov_deg`` pointing down sees a square footprint of side
``2 h tan(fov / 2)``; the cells whose centres fall inside it (clipped to the map) are observed.
Noise variance grows with altitude as ``a (1 - exp(-b h))``. Above ``binning_altitude`` the image
is read at a coarser resolution: each measurement averages a ``binning x binning`` block of the
footprint's cells (1/4 on each for 2 x 2; edge blocks average the cells they have), and its noise
variance is multiplied by ``f^e`` (f = ``binning``, e = ``binning_noise_exponent``: 0 in v0, 3 in
v1 as in the lineage's code).

A camera can also have a *persistent* error: a per-cell error e_c that every look at the same
resolution factor repeats (``SensorConfig.persistent_var``, ``persistent_var_binned``: its variance
s_f per cell, and the correlation of neighbouring cells' errors, ``persistent_neighbour_corr``). A
read-out row w then has error w^T e + v, and its variance for one look is
``var = f^e a (1 - exp(-b h)) + s_f w^T C w`` (what planners predict with; C the errors' correlation
over the row's cells, :func:`persistent_correlation`, so w^T C w = sum(w^2) for independent cells and
a binned 2 x 2 block keeps (1 + 2 r + r^2) / 4 of a cell's variance, 0.63 at r = 0.59); ``persistent`` is
the second term, which :class:`~ipp_bench.core.belief.PersistentErrorBelief` carries as states instead of
as noise, so that repeated looks are not taken as independent. :meth:`Sensor.measure` (the graph
tasks' simulated read-out) draws independent noise of variance ``var`` at every look: only the
MuJoCo camera repeats its error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .config import GridConfig, SensorConfig

_EPS = 1e-9  # [m] centres exactly on the footprint's edge are inside


@dataclass(frozen=True)
class Observation:
    """One camera read-out, H restricted to the cells it touches.

    Attributes:
        cells: (q,) flat indices of the observed cells, ascending.
        weights: (m, q) rows of H on those cells (each row sums to 1).
        var: (m,) noise variance of each measurement (one look: white + persistent).
        altitude: [m] altitude it was taken from.
        factor: resolution factor f of the read-out (1, or the sensor's binning).
        persistent: (m,) the part of ``var`` that every look at this factor repeats, s_f sum(w^2)
            (None: no persistent error).
    """

    cells: np.ndarray
    weights: np.ndarray
    var: np.ndarray
    altitude: float
    factor: int = 1
    persistent: np.ndarray | None = None

    @property
    def m(self) -> int:
        return self.weights.shape[0]

    def dense(self, n: int) -> np.ndarray:
        """The full (m, n) measurement matrix H."""
        H = np.zeros((self.m, n))
        H[:, self.cells] = self.weights
        return H


def persistent_correlation(rows: np.ndarray, cols: np.ndarray, r: float) -> np.ndarray:
    """(n, n) correlation of the persistent errors of the cells at (``rows``, ``cols``): r^(d^2), d their
    distance in cells (``SensorConfig.persistent_neighbour_corr``; the identity for r = 0)."""
    rows, cols = np.asarray(rows, dtype=np.float64), np.asarray(cols, dtype=np.float64)
    if r <= 0:
        return np.eye(rows.size)
    d2 = np.square(rows[:, None] - rows[None, :]) + np.square(cols[:, None] - cols[None, :])
    return np.power(float(r), d2)


def stack(observations: list[Observation]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Join several read-outs into one (cells, W, var) for a single batch update."""
    if len(observations) == 1:
        o = observations[0]
        return o.cells, o.weights, o.var
    cells = np.unique(np.concatenate([o.cells for o in observations]))
    m = sum(o.m for o in observations)
    W = np.zeros((m, cells.size))
    row = 0
    for o in observations:
        W[row:row + o.m, np.searchsorted(cells, o.cells)] = o.weights
        row += o.m
    return cells, W, np.concatenate([o.var for o in observations])


class Sensor:
    """Footprint, noise and measurement matrix of the camera over one grid."""

    def __init__(self, grid: GridConfig, cfg: SensorConfig | None = None):
        self.grid = grid
        self.cfg = cfg or SensorConfig()
        self._tan = math.tan(math.radians(self.cfg.fov_deg) / 2.0)
        self._cache: dict[tuple, Observation] = {}

    def footprint_side(self, altitude: float) -> float:
        """Side of the square footprint [m] at ``altitude`` [m]: 2 h tan(fov / 2)."""
        return 2.0 * float(altitude) * self._tan

    def noise_variance(self, altitude: float) -> float:
        """White noise variance f^e a (1 - exp(-b h)) of one read-out at ``altitude`` [m].

        f is the resolution factor (``binning`` when the read-out is binned, else 1).
        """
        cfg = self.cfg
        var = cfg.noise_a * (1.0 - math.exp(-cfg.noise_b * float(altitude)))
        if self.binned(altitude) and cfg.binning_noise_exponent:
            var *= float(cfg.binning) ** cfg.binning_noise_exponent
        return var

    def binned(self, altitude: float) -> bool:
        return float(altitude) > self.cfg.binning_altitude and self.cfg.binning > 1

    def footprint_ranges(self, xyz) -> tuple[int, int, int, int]:
        """Inclusive (r0, r1, c0, c1) of observed cells; r1 < r0 or c1 < c0 when none."""
        x, y, h = float(xyz[0]), float(xyz[1]), float(xyz[2])
        half = h * self._tan
        res = self.grid.resolution
        c0 = max(0, math.ceil((x - half - _EPS) / res - 0.5))
        c1 = min(self.grid.cols - 1, math.floor((x + half + _EPS) / res - 0.5))
        r0 = max(0, math.ceil((y - half - _EPS) / res - 0.5))
        r1 = min(self.grid.rows - 1, math.floor((y + half + _EPS) / res - 0.5))
        return r0, r1, c0, c1

    def observe(self, xyz) -> Observation | None:
        """The read-out from position ``xyz`` [m], or None when the footprint misses the map."""
        h = float(xyz[2])
        if h <= 0:
            raise ValueError(f"altitude {h} m is invalid: the camera must be above the ground (> 0 m)")
        r0, r1, c0, c1 = self.footprint_ranges(xyz)
        if r1 < r0 or c1 < c0:
            return None
        binned = self.binned(h)
        key = (r0, r1, c0, c1, binned)
        layout = self._cache.get(key)
        if layout is None:
            layout = self._layout(r0, r1, c0, c1, binned)
            if len(self._cache) > 65536:
                self._cache.clear()
            self._cache[key] = layout
        cells, W, share = layout
        factor = self.cfg.binning if binned else 1
        var = np.full(W.shape[0], self.noise_variance(h))
        s = self.cfg.persistent(factor)
        persistent = None
        if s > 0:
            persistent = s * share
            var += persistent
            persistent.flags.writeable = False
        var.flags.writeable = False
        return Observation(cells=cells, weights=W, var=var, altitude=h, factor=factor, persistent=persistent)

    def _layout(self, r0: int, r1: int, c0: int, c1: int,
                binned: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Observed cells, the rows of H over them and each row's share of the per-cell persistent
        variance, w^T C w with C the errors' correlation (:func:`persistent_correlation`; sum(w^2)
        for independent cells) (cached: they depend on the ranges only)."""
        rr, cc = np.meshgrid(np.arange(r0, r1 + 1), np.arange(c0, c1 + 1), indexing="ij")
        cells = (rr * self.grid.cols + cc).ravel()
        q = cells.size
        if binned:
            b = self.cfg.binning
            nbc = (c1 - c0) // b + 1
            block = (((rr - r0) // b) * nbc + (cc - c0) // b).ravel()
            _, block = np.unique(block, return_inverse=True)
            m = block.max() + 1
            W = np.zeros((m, q))
            W[block, np.arange(q)] = 1.0
            W /= W.sum(axis=1, keepdims=True)
        else:
            W = np.eye(q)
        r = self.cfg.persistent_neighbour_corr
        if r > 0 and binned:  # a block's cells share their error: w^T C w over the footprint's cells
            share = np.einsum("ij,jk,ik->i", W, persistent_correlation(rr.ravel(), cc.ravel(), r), W)
        else:  # one cell per row (C_cc = 1), or independent cells
            share = np.einsum("ij,ij->i", W, W)
        for a in (cells, W, share):
            a.flags.writeable = False
        return cells, W, share

    def matrix(self, xyz) -> np.ndarray:
        """Dense H (m, n) for a read-out at ``xyz``; (0, n) when the footprint misses the map."""
        obs = self.observe(xyz)
        n = self.grid.n_cells
        return np.zeros((0, n)) if obs is None else obs.dense(n)

    def noisy_from_cell_values(self, obs: Observation, cell_values: np.ndarray,
                               rng: np.random.Generator) -> np.ndarray:
        """z = H values + N(0, var): the read-out of per-cell values (truth, or a camera's estimate)."""
        values = np.asarray(cell_values, dtype=np.float64).reshape(-1)
        return obs.weights @ values[obs.cells] + rng.standard_normal(obs.m) * np.sqrt(obs.var)

    def measure(self, xyz, truth: np.ndarray, rng: np.random.Generator):
        """Simulated read-out of the ground truth: (Observation, z), or (None, None) off the map."""
        obs = self.observe(xyz)
        if obs is None:
            return None, None
        return obs, self.noisy_from_cell_values(obs, truth, rng)


def rays_on_ground(rays: np.ndarray, cam_pos, cam_mat) -> np.ndarray | None:
    """(K, 2) ground points (x, y) [m] where camera-frame ``rays`` (K, 3; looking along -z) from a camera at
    ``cam_pos`` with orientation ``cam_mat`` (columns: the camera's axes in the world) meet the plane z = 0;
    None when a ray misses the ground. The deployment's frame corners and the twin's tilted frame."""
    R = np.asarray(cam_mat, dtype=np.float64).reshape(3, 3)
    d = rays @ R.T
    pz = float(cam_pos[2])
    if pz <= 0.0 or np.any(d[:, 2] >= -1e-6):
        return None
    t = -pz / d[:, 2]
    return np.stack([cam_pos[0] + t * d[:, 0], cam_pos[1] + t * d[:, 1]], axis=1)


def restrict(obs: Observation, seen: np.ndarray) -> Observation | None:
    """``obs`` without the measurements (rows of H) that involve an unseen cell; None if none is left."""
    cell_seen = seen[obs.cells]
    if cell_seen.all():
        return obs
    rows = ~np.any((obs.weights > 0) & ~cell_seen[None, :], axis=1)
    if not rows.any():
        return None
    W = obs.weights[rows]
    cols = np.any(W > 0, axis=0)
    return Observation(cells=obs.cells[cols], weights=W[:, cols], var=obs.var[rows], altitude=obs.altitude,
                       factor=obs.factor, persistent=None if obs.persistent is None else obs.persistent[rows])
