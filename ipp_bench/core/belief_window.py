"""A GP belief for large grids: the covariance kept within a window, updated locally.

The dense :class:`~ipp_bench.core.belief.GPBelief` stores the n x n covariance P: 2 GB at 128 x 128
cells, and a Kalman update costs O(n m q). The Matern 3/2 prior decays with distance (at 3.6
length scales the correlation is 3 %, at 5 it is 0.4 %), and conditioning on measurements makes
posterior correlations decay faster still. :class:`WindowBelief` keeps the same model, the same
prior and the same Kalman update (paper eqs. 2-3, :func:`~ipp_bench.core.belief.gain_factor`'s
symbols), with one approximation: P is stored only between cells at most ``window`` cells apart
along both axes (a (2w + 1) x (2w + 1) stencil around every cell); entries beyond it are taken as
0 in an update and never written.

Storage: ``band[r, c, i, j] = P[(r, c), (r + i - w, c + j - w)]`` (zero where the partner cell is
off the map), n (2w + 1)^2 float64: 82 MB at 128 x 128 with w = 12. Every pair is stored twice
(once from each end), so the symmetric update writes both.

An update with read-out rows W on cells ``cells`` (H = W on those columns) touches only the
rectangle N of cells within w of the rows' bounding box:

    C = P[N, cells] W^T          (|N|, m)   from the band; entries beyond the window are 0
    S = W P[cells, cells] W^T + R,  L L^T = S
    mean[N] += C S^-1 (z - W mean[cells])
    P[a, b] -= A_a . A_b  for a, b in N, |a - b| <= w,   A = C L^-T

so its cost depends on the footprint and w, not on the map (n). A batch of read-outs spread
over the map (a leg, or a lawnmower row) is split into groups of rows whose cells fit in a
``group_span`` x ``group_span`` box and fused one group after the other; for the exact GP the
sequential and the batch update are equal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import as_strided
from scipy.linalg import cho_solve, solve_triangular

from .belief import GPBelief, LegBatch, _as_cov, matern32

WINDOW_LENGTH_SCALES = 4.0  # [-] the window covers this many length scales (prior correlation 0.8 % there;
# why four: docs/decisions/window-belief.md)
DEFAULT_GROUP_SPAN = 8  # [cells] largest bounding box side of the rows fused in one update
MASK_CACHE = 32  # window masks kept (one per rectangle shape; 0.6 MB each at w = 12)


def window_for(length_scale: float, resolution: float) -> int:
    """The default window [cells]: ceil(4 length scales / cell side); 12 for the v2 prior at 2.5 m, 14 for v1."""
    return max(1, math.ceil(WINDOW_LENGTH_SCALES * length_scale / resolution - 1e-9))


def task_window(grid, gp) -> int:
    """The window [cells] of a task's window belief: ``gp.belief_window``, or when 0 :func:`window_for`
    its length scale and cell side."""
    return int(gp.belief_window) if gp.belief_window else window_for(gp.length_scale, grid.resolution)


def prior_belief(grid, gp) -> GPBelief | WindowBelief:
    """The prior a task's belief starts from, by ``gp.belief``: the dense :class:`~ipp_bench.core.belief.GPBelief`
    (``"dense"``) or the :class:`WindowBelief` (``"window"``). The one place the choice is made."""
    if gp.belief == "window":
        return WindowBelief.prior(grid, gp)
    return GPBelief.prior(grid, gp)


class WindowBelief:
    """Mean and windowed covariance of the field at the cell centres of a rows x cols grid.

    Attributes:
        mean: (n,) posterior mean, row-major cells.
        band: (rows, cols, 2w + 1, 2w + 1) covariance of every cell with the cells of its window.
        shape: (rows, cols).
        window: w [cells].
    """

    def __init__(self, mean: np.ndarray, band: np.ndarray, window: int,
                 group_span: int = DEFAULT_GROUP_SPAN):
        rows, cols = band.shape[:2]
        side = 2 * int(window) + 1
        if band.shape != (rows, cols, side, side):
            raise ValueError(f"band has shape {band.shape}: expected (rows, cols, {side}, {side}) for window {window}")
        self.mean = np.array(mean, dtype=np.float64).reshape(-1)
        if self.mean.shape != (rows * cols,):
            raise ValueError(f"mean has shape {self.mean.shape}: expected ({rows * cols},) for a {rows} x {cols} grid")
        if int(group_span) < 1:
            raise ValueError(f"group_span = {group_span} is invalid: expected an integer >= 1 [cells]")
        self.band = np.ascontiguousarray(band, dtype=np.float64)
        self.shape = (rows, cols)
        self.window = int(window)
        self.group_span = int(group_span)
        self._masks: dict[tuple[int, int], np.ndarray] = {}
        self._buf: np.ndarray | None = None  # scratch of the downdate

    @classmethod
    def from_grid(cls, shape: tuple[int, int] = (15, 15), resolution: float = 2.5,
                  length_scale: float = 3.67, signal_variance: float = 1.82,
                  prior_mean: float = 0.5, nugget: float = 0.0,
                  window: int | None = None, group_span: int = DEFAULT_GROUP_SPAN) -> WindowBelief:
        """The prior of :meth:`GPBelief.from_grid <ipp_bench.core.belief.GPBelief.from_grid>` (Matern 3/2
        plus ``nugget`` on the diagonal) within the window ``window`` [cells] (default
        :func:`window_for` the length scale)."""
        rows, cols = (int(s) for s in shape)
        w = window_for(length_scale, resolution) if window is None else int(window)
        if w < 1:
            raise ValueError(f"window = {window} is invalid: expected an integer >= 1 [cells]")
        offsets = np.arange(-w, w + 1)
        dist = resolution * np.hypot(offsets[:, None], offsets[None, :])
        stencil = matern32(dist, length_scale, signal_variance)
        stencil[w, w] += nugget
        inside_r = _inside(rows, w)  # (rows, 2w+1): partner row on the map
        inside_c = _inside(cols, w)
        band = stencil[None, None] * (inside_r[:, None, :, None] & inside_c[None, :, None, :])
        return cls(np.full(rows * cols, float(prior_mean)), band, w, group_span)

    @classmethod
    def prior(cls, grid, gp, window: int | None = None) -> WindowBelief:
        """The prior of a :class:`~ipp_bench.core.config.GridConfig` and :class:`~ipp_bench.core.config.GPConfig`,
        within ``window`` [cells] (default: :func:`task_window`, the config's)."""
        return cls.from_grid((grid.rows, grid.cols), grid.resolution, gp.length_scale,
                             gp.signal_variance, gp.prior_mean, gp.nugget,
                             task_window(grid, gp) if window is None else window)

    @property
    def n(self) -> int:
        return self.mean.shape[0]

    @property
    def nbytes(self) -> int:
        """Memory of the belief [bytes]: its arrays, the update's scratch and the cached masks."""
        scratch = 0 if self._buf is None else self._buf.nbytes
        return self.mean.nbytes + self.band.nbytes + scratch + sum(m.nbytes for m in self._masks.values())

    @property
    def variance(self) -> np.ndarray:
        """Posterior marginal variances (n,), clipped at 0 against round-off."""
        return np.maximum(self.band[:, :, self.window, self.window].reshape(-1), 0.0)

    def copy(self) -> WindowBelief:
        other = WindowBelief.__new__(WindowBelief)
        other.mean = self.mean.copy()
        other.band = self.band.copy()
        other.shape, other.window, other.group_span = self.shape, self.window, self.group_span
        other._masks = self._masks  # read-only masks, shared
        other._buf = None
        return other

    def covariance(self, cells_a: np.ndarray, cells_b: np.ndarray) -> np.ndarray:
        """P[cells_a, cells_b] as stored: 0 for pairs farther apart than the window."""
        cells_a, cells_b = np.asarray(cells_a), np.asarray(cells_b)
        cols, w = self.shape[1], self.window
        ra, ca = np.divmod(cells_a, cols)
        rb, cb = np.divmod(cells_b, cols)
        di = rb[None, :] - ra[:, None] + w
        dj = cb[None, :] - ca[:, None] + w
        ok = (di >= 0) & (di <= 2 * w) & (dj >= 0) & (dj <= 2 * w)
        out = self.band[ra[:, None], ca[:, None], np.clip(di, 0, 2 * w), np.clip(dj, 0, 2 * w)]
        return np.where(ok, out, 0.0)

    # -- the update ----------------------------------------------------------------------------
    def update_local(self, cells: np.ndarray, W: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        """Kalman update with ``z = W f[cells] + v``, ``v ~ N(0, R)`` (as :meth:`GPBelief.update_local
        <ipp_bench.core.belief.GPBelief.update_local>`).

        Args:
            cells: (q,) flat indices of the cells the rows touch.
            W: (m, q) rows of H on those cells.
            z: (m,) measurements.
            R: (m,) noise variances, or an (m, m) covariance (then the rows are fused as one batch).

        Raises:
            ValueError: shapes that do not match, or cells off the grid.
        """
        cells, W, z, R = self._checked(cells, W, z, R)
        if R.ndim == 2:
            self._update_group(cells, W, z, R)
            return
        for rows in self._groups(cells, W):
            used = np.flatnonzero(np.any(W[rows] != 0.0, axis=0))
            self._update_group(cells[used], W[np.ix_(rows, used)], z[rows], np.diag(R[rows]))

    def _update_group(self, cells, W, z, R) -> None:
        (r0, r1, c0, c1), N, C, L, A = self._gain(cells, W, R)
        innovation = z - W @ self.mean[cells]
        self.mean[N] += C @ cho_solve((L, True), innovation)
        self._downdate(r0, r1, c0, c1, A)

    def _gain(self, cells, W, R):
        """The window N around ``cells`` and the gain's factors there: (rect, N, C, L, A), C = P[N, cells] W^T."""
        rect = self._rect(cells)
        r0, r1, c0, c1 = rect
        cols = self.shape[1]
        PN = self._columns(cells, rect)  # (|N|, q)
        rr, cc = np.divmod(cells, cols)
        pos = (rr - r0) * (c1 - c0) + (cc - c0)  # the cells' rows in N (row-major rectangle)
        C = PN @ W.T
        S = W @ C[pos, :] + R
        try:
            L = np.linalg.cholesky(0.5 * (S + S.T))
        except np.linalg.LinAlgError:
            raise np.linalg.LinAlgError(
                f"the innovation covariance of {W.shape[0]} rows is not positive definite: the covariance "
                f"kept within window = {self.window} cells lost definiteness; use a larger window") from None
        A = solve_triangular(L, C.T, lower=True, check_finite=False).T
        N = ((np.arange(r0, r1) * cols)[:, None] + np.arange(c0, c1)[None, :]).ravel()
        return rect, N, C, L, A

    def _columns(self, cells, rect) -> np.ndarray:
        """P[N, cells] (|N|, q) for the rectangle N = ``rect``: each cell's stencil, cut to N (0 beyond)."""
        r0, r1, c0, c1 = rect
        cols, w, side = self.shape[1], self.window, 2 * self.window + 1
        out = np.zeros((cells.size, r1 - r0, c1 - c0))
        rr, cc = np.divmod(cells, cols)
        for k, (r, c) in enumerate(zip(rr.tolist(), cc.tolist())):
            i0, j0 = r0 - r + w, c0 - c + w  # stencil index of N's first row and column
            ia, ib = max(0, i0), min(side, i0 + r1 - r0)
            ja, jb = max(0, j0), min(side, j0 + c1 - c0)
            out[k, ia - i0:ib - i0, ja - j0:jb - j0] = self.band[r, c, ia:ib, ja:jb]
        return out.reshape(cells.size, -1).T

    def _downdate(self, r0, r1, c0, c1, A) -> None:
        """band[a, b - a] -= A_a . A_b for every pair a, b of the rectangle within the window."""
        nr, nc, w = r1 - r0, c1 - c0, self.window
        q = nr * nc
        margin = w * nc + w
        size = q * q + 2 * margin
        if self._buf is None or self._buf.size < size:
            self._buf = np.empty(size)  # reused: the view reads the margins only where masked out
        buf = self._buf
        G = buf[margin:margin + q * q].reshape(q, q)
        np.matmul(A, A.T, out=G)
        step = buf.strides[0]
        # view[r, c, i, j] = G[a, a + (i - w) nc + (j - w)], a = r nc + c: the partner (r + i - w, c + j - w)
        view = as_strided(buf[margin - w * nc - w:], shape=(nr, nc, 2 * w + 1, 2 * w + 1),
                          strides=(nc * (q + 1) * step, (q + 1) * step, nc * step, step), writeable=False)
        target = self.band[r0:r1, c0:c1]
        np.subtract(target, view, out=target, where=self._mask(nr, nc))

    def _mask(self, nr: int, nc: int) -> np.ndarray:
        """(nr, nc, 2w + 1, 2w + 1): the partner lies inside the nr x nc rectangle."""
        mask = self._masks.get((nr, nc))
        if mask is None:
            w = self.window
            mask = _inside(nr, w)[:, None, :, None] & _inside(nc, w)[None, :, None, :]
            mask.flags.writeable = False
            if len(self._masks) >= MASK_CACHE:
                self._masks.clear()
            self._masks[(nr, nc)] = mask
        return mask

    def _rect(self, cells) -> tuple[int, int, int, int]:
        """[r0, r1) x [c0, c1): the cells within the window of the bounding box of ``cells``, on the map."""
        rows, cols = self.shape
        r, c = np.divmod(cells, cols)
        w = self.window
        return (max(0, int(r.min()) - w), min(rows, int(r.max()) + w + 1),
                max(0, int(c.min()) - w), min(cols, int(c.max()) + w + 1))

    def _groups(self, cells, W) -> list[np.ndarray]:
        """Consecutive rows whose cells fit in a ``group_span`` box: the updates a batch is fused in."""
        cols, span = self.shape[1], self.group_span
        r, c = np.divmod(cells, cols)
        nz = W != 0.0
        big = np.iinfo(np.int64).max
        lo_r = np.where(nz, r, big).min(axis=1)
        hi_r = np.where(nz, r, -1).max(axis=1)
        lo_c = np.where(nz, c, big).min(axis=1)
        hi_c = np.where(nz, c, -1).max(axis=1)
        groups, start = [], 0
        box = None
        for i in range(W.shape[0]):
            row_box = (lo_r[i], hi_r[i], lo_c[i], hi_c[i])
            if box is not None:
                merged = (min(box[0], row_box[0]), max(box[1], row_box[1]),
                          min(box[2], row_box[2]), max(box[3], row_box[3]))
                if merged[1] - merged[0] < span and merged[3] - merged[2] < span:
                    box = merged
                    continue
                groups.append(np.arange(start, i))
                start = i
            box = row_box
        groups.append(np.arange(start, W.shape[0]))
        return groups

    def _checked(self, cells, W, z, R):
        cells = np.asarray(cells).reshape(-1)
        W = np.atleast_2d(np.asarray(W, dtype=np.float64))
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        if not np.issubdtype(cells.dtype, np.integer):
            raise ValueError(f"cells has dtype {cells.dtype}: expected integer flat cell indices")
        if W.ndim != 2 or W.shape[1] != cells.size:
            raise ValueError(f"W has shape {W.shape}: expected (m, {cells.size}), one column per cell of cells")
        if z.shape[0] != W.shape[0]:
            raise ValueError(f"z has {z.shape[0]} values but W has {W.shape[0]} rows")
        if cells.size == 0 or W.shape[0] == 0:
            raise ValueError(f"an update needs at least one row and one cell: W has shape {W.shape}")
        if cells.min() < 0 or cells.max() >= self.n:
            raise ValueError(f"cells must lie in [0, {self.n}): got [{cells.min()}, {cells.max()}]")
        if np.any(np.all(W == 0.0, axis=1)):
            raise ValueError("W has a row of zeros: every measurement row must touch a cell")
        R = _as_cov(R, W.shape[0])  # (m, m); rows with independent noise can be fused in groups
        return cells, W, z, np.diag(R).copy() if _is_diagonal(R) else R

    # -- look-ahead ----------------------------------------------------------------------------
    def predict_variance_local(self, cells: np.ndarray, W: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Posterior marginal variances (n,) after measuring with (cells, W, R); the belief is unchanged.

        The rows are fused as one batch (as the look-ahead of :class:`GPBelief` does).
        """
        cells, W, _, R = self._checked(cells, W, np.zeros(np.atleast_2d(W).shape[0]), R)
        _, N, _, _, A = self._gain(cells, W, np.diag(R) if R.ndim == 1 else R)
        var = self.variance
        var[N] = np.maximum(var[N] - np.einsum("ij,ij->i", A, A), 0.0)
        return var

    def trace_reductions(self, legs, roi: np.ndarray) -> np.ndarray:
        """For every leg: Tr(P - P+) over the cells ``roi`` (bool mask (n,)), each leg's rows fused as
        one batch; 0 for legs that see nothing. :func:`ipp_bench.core.belief.trace_reductions` on the
        windowed covariance.

        Args:
            legs: a :class:`~ipp_bench.core.belief.LegBatch`, or a sequence of ``(cells, W, var)`` or None
                per leg (what ``LegBatch`` is built from: on a large map the batch's padded
                (legs, rows, union of cells) weights grow with the union, the list does not).
            roi: (n,) bool.
        """
        roi = np.asarray(roi, dtype=bool).reshape(-1)
        if roi.shape != (self.n,):
            raise ValueError(f"roi has shape {roi.shape}: expected ({self.n},) booleans")
        per_leg = _batch_legs(legs) if isinstance(legs, LegBatch) else list(legs)
        out = np.zeros(len(per_leg))
        for i, leg in enumerate(per_leg):
            if leg is None:
                continue
            cells, W, _, var = self._checked(leg[0], leg[1], np.zeros(np.atleast_2d(leg[1]).shape[0]), leg[2])
            _, N, _, _, A = self._gain(cells, W, np.diag(var) if var.ndim == 1 else var)
            sel = roi[N]
            out[i] = np.einsum("ij,ij->", A[sel], A[sel])
        return out


def _batch_legs(batch: LegBatch) -> list:
    """The legs of a LegBatch as ``(cells, W, var)`` or None, its padding rows and columns dropped."""
    legs: list = [None] * batch.size
    for j, i in enumerate(batch.index):
        Wj = batch.W[j]
        rows = np.flatnonzero(np.any(Wj != 0.0, axis=1))
        used = np.flatnonzero(np.any(Wj[rows] != 0.0, axis=0))
        legs[i] = (batch.cells[used], Wj[np.ix_(rows, used)], batch.var[j, rows])
    return legs


def _inside(size: int, w: int) -> np.ndarray:
    """(size, 2w + 1) booleans: index + offset (offset in [-w, w]) lies in [0, size)."""
    partner = np.arange(size)[:, None] + np.arange(-w, w + 1)[None, :]
    return (partner >= 0) & (partner < size)


def _is_diagonal(R: np.ndarray) -> bool:
    return not np.any(R - np.diag(np.diag(R)))


__all__ = ["DEFAULT_GROUP_SPAN", "WINDOW_LENGTH_SCALES", "WindowBelief", "prior_belief", "task_window", "window_for"]
