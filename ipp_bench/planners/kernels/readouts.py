"""The camera's read-outs along a path as sparse rows, compiled, and what they predict against the belief.

:func:`leg_points` places the read-outs as the mission places them, :func:`camera_rows` turns them into the
camera's sparse rows (:meth:`~ipp_bench.core.sensor.Sensor.observe`'s, compiled) and :func:`fold_repeated_rows`
folds a footprint looked at twice into one row (both planners' fast forms); :func:`roi_product` is a
decision's B = P D P, and :func:`readout_blocks` the S and G of a batch of rows, whose ``Tr(S^-1 G)`` is its
predicted reduction of Tr(P) over the ROI D (CMA-ES, ``evaluation = "batched"``).
"""

from __future__ import annotations

import math

import numpy as np

from ...core.mission import leg_length, leg_samples
from ..base import MIN_LEG_M
from .jit import kernel


def leg_points(start, end, spacing: float) -> np.ndarray:
    """(K, 3) [m] where the mission reads the camera flying ``start -> end``: the positions of
    :meth:`~ipp_bench.planners.base.RobotView.leg_observations` (same spacing rule, same arithmetic)."""
    start = np.asarray(start, dtype=np.float64)
    delta = np.asarray(end, dtype=np.float64) - start
    dist = leg_length(start, end)
    if dist <= MIN_LEG_M:
        return np.zeros((0, 3))
    s = leg_samples(dist, 0.0, spacing)
    return start + np.outer(s / dist, delta)


def camera_args(sensor) -> tuple:
    """The constants of ``sensor`` (a :class:`~ipp_bench.core.sensor.Sensor`) that :func:`camera_rows` takes
    after the points, computed as the camera computes them."""
    cfg, grid = sensor.cfg, sensor.grid
    binned_scale = float(cfg.binning) ** cfg.binning_noise_exponent if cfg.binning_noise_exponent else 1.0
    tan = math.tan(math.radians(cfg.fov_deg) / 2.0)
    return (float(cfg.noise_a), float(cfg.noise_b), binned_scale, tan, float(grid.resolution), int(grid.rows),
            int(grid.cols), float(cfg.binning_altitude), int(cfg.binning), float(cfg.persistent(1)),
            float(cfg.persistent(cfg.binning)), float(cfg.persistent_neighbour_corr))


_EPS = 1e-9  # [m] as ipp_bench.core.sensor: centres exactly on the footprint's edge are inside


@kernel
def camera_rows(points, noise_a, noise_b, binned_scale, tan, res, n_rows, n_cols, binning_altitude, binning,
                s_cell, s_binned, r_corr):
    """The camera's read-outs from each of ``points`` ((K, 3) [m]) in turn, as sparse rows: what
    :meth:`~ipp_bench.core.sensor.Sensor.observe` gives at each point (none where the footprint misses the map),
    row by row, compiled: the same footprint (``tan`` = tan(fov / 2); a ``n_rows`` x ``n_cols`` grid of
    ``res`` [m] cells), binning and weights, and the same noise variance, ``noise_a (1 - exp(-noise_b h))``
    (times ``binned_scale`` = f^e when binned) plus the persistent share ``s w^T C w`` (``s_cell``,
    ``s_binned``; C = ``r_corr``^(d^2) over a binned row's cells, summed in another order than the
    camera's: equal to rounding).

    Returns:
        (row_ptr (m + 1,), cells (nnz,), weights (nnz,), var (m,)): row a's nonzero weights ``weights`` on
        the map cells ``cells`` between ``row_ptr[a]`` and ``row_ptr[a + 1]``, and its noise variance.
    """
    K = points.shape[0]
    ranges = np.empty((K, 4), dtype=np.int64)
    m = 0
    nnz = 0
    for i in range(K):
        x, y, h = points[i, 0], points[i, 1], points[i, 2]
        half = h * tan
        c0 = max(0, int(np.ceil((x - half - _EPS) / res - 0.5)))
        c1 = min(n_cols - 1, int(np.floor((x + half + _EPS) / res - 0.5)))
        r0 = max(0, int(np.ceil((y - half - _EPS) / res - 0.5)))
        r1 = min(n_rows - 1, int(np.floor((y + half + _EPS) / res - 0.5)))
        ranges[i, 0], ranges[i, 1], ranges[i, 2], ranges[i, 3] = r0, r1, c0, c1
        if r1 < r0 or c1 < c0:
            continue
        cells = (r1 - r0 + 1) * (c1 - c0 + 1)
        nnz += cells
        if h > binning_altitude and binning > 1:
            m += ((r1 - r0) // binning + 1) * ((c1 - c0) // binning + 1)
        else:
            m += cells
    row_ptr = np.zeros(m + 1, dtype=np.int64)
    out_cells = np.empty(nnz, dtype=np.int64)
    weights = np.empty(nnz)
    var = np.empty(m)
    a = 0
    p = 0
    for i in range(K):
        r0, r1, c0, c1 = ranges[i, 0], ranges[i, 1], ranges[i, 2], ranges[i, 3]
        if r1 < r0 or c1 < c0:
            continue
        h = points[i, 2]
        white = noise_a * (1.0 - math.exp(-noise_b * h))
        if h > binning_altitude and binning > 1:
            white *= binned_scale
            for br in range(r0, r1 + 1, binning):
                for bc in range(c0, c1 + 1, binning):
                    re, ce = min(br + binning, r1 + 1), min(bc + binning, c1 + 1)
                    count = (re - br) * (ce - bc)
                    w = 1.0 / count
                    share = 0.0
                    for rr in range(br, re):
                        for cc in range(bc, ce):
                            out_cells[p] = rr * n_cols + cc
                            weights[p] = w
                            p += 1
                            if r_corr > 0:
                                for rr2 in range(br, re):
                                    for cc2 in range(bc, ce):
                                        share += w * w * r_corr ** ((rr - rr2) ** 2 + (cc - cc2) ** 2)
                            else:
                                share += w * w
                    var[a] = white + s_binned * share if s_binned > 0 else white
                    a += 1
                    row_ptr[a] = p
        else:
            for rr in range(r0, r1 + 1):
                for cc in range(c0, c1 + 1):
                    out_cells[p] = rr * n_cols + cc
                    weights[p] = 1.0
                    p += 1
                    var[a] = white + s_cell * 1.0 if s_cell > 0 else white
                    a += 1
                    row_ptr[a] = p
    return row_ptr, out_cells, weights, var


@kernel
def fold_repeated_rows(row_ptr, cells, weights, var):
    """The read-out rows of :func:`camera_rows` with repeated rows folded into one: a row with the same cells and
    weights as an earlier one (a look at the same footprint again) joins it, with the noise variance of
    both looks together, ``1 / (1 / r1 + 1 / r2)``. The same posterior covariance in exact arithmetic (two
    independent measurements of w^T x are one with their precisions added), with fewer rows.

    Returns (row_ptr, cells, weights, var) of the distinct rows, in the order of their first look.
    """
    m = var.size
    first = np.arange(m)
    for a in range(m):
        na = row_ptr[a + 1] - row_ptr[a]
        for c in range(a):
            if first[c] != c or row_ptr[c + 1] - row_ptr[c] != na:
                continue
            same = True
            for t in range(na):
                if cells[row_ptr[a] + t] != cells[row_ptr[c] + t] or weights[row_ptr[a] + t] != weights[row_ptr[c] + t]:
                    same = False
                    break
            if same:
                first[a] = c
                break
    precision = np.zeros(m)
    for a in range(m):
        precision[first[a]] += 1.0 / var[a]
    keep = 0
    nnz = 0
    for a in range(m):
        if first[a] == a:
            keep += 1
            nnz += row_ptr[a + 1] - row_ptr[a]
    out_ptr = np.zeros(keep + 1, dtype=np.int64)
    out_cells = np.empty(nnz, dtype=np.int64)
    out_w = np.empty(nnz)
    out_var = np.empty(keep)
    k = 0
    p = 0
    for a in range(m):
        if first[a] != a:
            continue
        for t in range(row_ptr[a], row_ptr[a + 1]):
            out_cells[p] = cells[t]
            out_w[p] = weights[t]
            p += 1
        out_var[k] = var[a] if precision[a] == 1.0 / var[a] else 1.0 / precision[a]
        k += 1
        out_ptr[k] = p
    return out_ptr, out_cells, out_w, out_var


def roi_product(cov: np.ndarray, roi: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """B = P D P (D: the diagonal mask ``roi``) as one (n, n) product, into ``out`` where it fits."""
    n = cov.shape[0]
    if out is None or out.shape != (n, n):
        out = np.empty((n, n))
    P_roi = cov if roi.all() else cov[:, roi]
    return np.matmul(P_roi, P_roi.T, out=out)


@kernel
def readout_blocks(P, B, row_ptr, cells, weights, var):
    """S = W P W^T + R and G = W B W^T of one batch of read-outs, W in sparse rows (row a's weights
    ``weights`` on the map cells ``cells`` between ``row_ptr[a]`` and ``row_ptr[a + 1]``; ``var`` (m,) the
    rows' noise variances; ``P`` and ``B`` = P D P, both (n, n); a row averages at most a binning block):
    the batch's predicted reduction of Tr(P) over the ROI D is ``Tr(S^-1 G)``."""
    m = var.size
    n = P.shape[0]
    seen = np.zeros(n, dtype=np.bool_)
    for p in range(cells.size):
        seen[cells[p]] = True
    union = np.flatnonzero(seen)  # the batch's cells, ascending (rows of P and B read in address order)
    q = union.size
    local = np.full(n, -1, dtype=np.int64)  # map cell -> its index among the batch's cells
    for y in range(q):
        local[union[y]] = y
    loc = np.empty(cells.size, dtype=np.int64)
    for p in range(cells.size):
        loc[p] = local[cells[p]]
    Pu = np.empty((q, q))  # P and B on the batch's cells
    Bu = np.empty((q, q))
    for x in range(q):
        rowP = P[union[x]]
        rowB = B[union[x]]
        for y in range(q):
            Pu[x, y] = rowP[union[y]]
            Bu[x, y] = rowB[union[y]]
    XP = np.zeros((m, q))  # W P[:, union]
    XB = np.zeros((m, q))  # W B[:, union]
    for a in range(m):
        for p in range(row_ptr[a], row_ptr[a + 1]):
            w = weights[p]
            x = loc[p]
            for y in range(q):
                XP[a, y] += w * Pu[x, y]
                XB[a, y] += w * Bu[x, y]
    S = np.empty((m, m))
    G = np.empty((m, m))
    for a in range(m):
        for c in range(a + 1):
            s = 0.0
            g = 0.0
            for t in range(row_ptr[c], row_ptr[c + 1]):
                y = loc[t]
                s += weights[t] * XP[a, y]
                g += weights[t] * XB[a, y]
            S[a, c] = s
            S[c, a] = s
            G[a, c] = g
            G[c, a] = g
        S[a, a] += var[a]
    return S, G
