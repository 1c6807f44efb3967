"""Gaussian-process belief over the grid, updated by a Kalman filter (paper eqs. 2-3).

The prior is a Matern 3/2 kernel over the cell centres in metres. Measurements are linear in the
cells (``z = H f + noise``); each sensor row touches only the cells of one footprint, so the update
works on those columns: with ``C = P[:, cells]`` and ``W = H[:, cells]`` the gain costs O(n m q)
and the covariance downdate ``P -= A A^T`` (``A = C W^T L^-T``, ``L L^T = S``) is symmetric by
construction, so a belief's update downdates the lower triangle only (BLAS syrk, half the work of the
whole product) and copies it onto the upper one when the whole matrix is read (:attr:`GPBelief.cov`).
Pure numpy/scipy, float64.

One module on purpose (over 400 lines): the prior, the one Kalman update every belief shares and
the camera-error belief built on it are one derivation; split, the update's invariants would span files.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas, cho_solve, solve_triangular
from scipy.spatial.distance import cdist

from .config import cell_centre


def matern32(dist: np.ndarray, length_scale: float, signal_variance: float) -> np.ndarray:
    """Matern nu = 3/2 kernel of distances ``dist`` [m]."""
    r = np.sqrt(3.0) * np.asarray(dist, dtype=np.float64) / length_scale
    return signal_variance * (1.0 + r) * np.exp(-r)


def cell_centres(shape: tuple[int, int], resolution: float) -> np.ndarray:
    """(rows*cols, 2) cell centres (x, y) [m] in row-major order."""
    rows, cols = shape
    r, c = np.divmod(np.arange(rows * cols), cols)
    return np.stack([cell_centre(c, resolution), cell_centre(r, resolution)], axis=1).astype(np.float64)


def prior_covariance(xy: np.ndarray, length_scale: float, signal_variance: float,
                     nugget: float = 0.0) -> np.ndarray:
    """Matern 3/2 kernel matrix over points ``xy`` [m], plus ``nugget`` on the diagonal."""
    cov = matern32(cdist(xy, xy), length_scale, signal_variance)
    if nugget:
        cov[np.diag_indices_from(cov)] += nugget
    return cov


_GRID_PRIORS: dict[tuple, np.ndarray] = {}
_GRID_PRIOR_MAX_BYTES = 64 << 20  # [B] kept per process: a 30 x 30 prior is 6.5 MB, a 64 x 64 one 134 MB (not kept)


def grid_prior_covariance(shape: tuple[int, int], resolution: float, length_scale: float, signal_variance: float,
                          nugget: float = 0.0) -> np.ndarray:
    """:func:`prior_covariance` over the cell centres of a rows x cols grid, read-only: built once per
    process and grid (every episode of a task starts from the same prior), while the priors kept stay
    under 64 MB; a grid too large to keep is built afresh."""
    key = (tuple(int(v) for v in shape), float(resolution), float(length_scale), float(signal_variance), float(nugget))
    cov = _GRID_PRIORS.get(key)
    if cov is None:
        cov = prior_covariance(cell_centres(key[0], key[1]), *key[2:])
        if cov.nbytes + sum(c.nbytes for c in _GRID_PRIORS.values()) <= _GRID_PRIOR_MAX_BYTES:
            cov.flags.writeable = False
            _GRID_PRIORS[key] = cov
    return cov


def gain_factor(cov: np.ndarray, cells: np.ndarray, W: np.ndarray, R: np.ndarray,
                columns: np.ndarray | None = None):
    """The Kalman update of ``cov`` for H = W on columns ``cells``, in factored form.

    Returns (A, L, C) with C = P H^T (n, m), L L^T = S = H P H^T + R and A = C L^-T, so that the
    posterior covariance is ``P - A A^T`` and the gain is ``K = C S^-1``. Every covariance update
    and prediction in ipp-bench goes through this one function. ``columns``: ``P[:, cells]`` where
    the caller has it (a :class:`GPBelief` whose upper triangle lags: :meth:`GPBelief.columns`).
    """
    C = (cov[:, cells] if columns is None else columns) @ W.T
    S = W @ C[cells, :] + _as_cov(R, W.shape[0])
    L = np.linalg.cholesky(0.5 * (S + S.T))
    A = solve_triangular(L, C.T, lower=True, check_finite=False).T
    return A, L, C


class LegBatch:
    """Several candidate measurement sets (one per action), padded for a batched Kalman gain.

    ``legs[i]`` is ``(cells, W, var)`` or None (nothing seen). Padding rows have W = 0 and unit
    variance, so they add nothing to the gain.
    """

    def __init__(self, legs):
        present = [i for i, leg in enumerate(legs) if leg is not None]
        self.index = np.array(present, dtype=np.int64)
        self.size = len(legs)
        if not present:
            self.cells = np.zeros(0, dtype=np.int64)
            return
        self.cells = np.unique(np.concatenate([legs[i][0] for i in present]))
        M = max(legs[i][1].shape[0] for i in present)
        self.W = np.zeros((len(present), M, self.cells.size))
        self.var = np.ones((len(present), M))
        for j, i in enumerate(present):
            cells, W, var = legs[i]
            self.W[j][:W.shape[0], np.searchsorted(self.cells, cells)] = W
            self.var[j, :W.shape[0]] = var


def trace_reductions(cov: np.ndarray, batch: LegBatch, roi: np.ndarray) -> np.ndarray:
    """For every leg of ``batch``: Tr(P - P+) over the cells ``roi`` (bool mask), in one batch.

    The batched form of :func:`gain_factor`: with S = H P H^T + R, the reduction is
    sum over ROI columns r of (H P)_r^T S^-1 (H P)_r. Legs that see nothing give 0. S is small
    (rows of one leg) and well conditioned (R >= the sensor's noise floor), so its inverse is used.
    """
    if batch.index.size == 0:
        return np.zeros(batch.size)
    return trace_reductions_of_rows(cov[batch.cells, :], batch, roi)


def trace_reductions_of_rows(rows: np.ndarray, batch: LegBatch, roi: np.ndarray) -> np.ndarray:
    """:func:`trace_reductions` from the covariance's rows of ``batch.cells`` only (``cov[batch.cells, :]``)."""
    out = np.zeros(batch.size)
    if batch.index.size == 0:
        return out
    HP = batch.W @ rows  # (b, M, n): H P per leg
    S = HP[:, :, batch.cells] @ batch.W.transpose(0, 2, 1)
    idx = np.arange(S.shape[1])
    S[:, idx, idx] += batch.var
    HP_roi = HP[:, :, roi]
    out[batch.index] = np.einsum("bmr,bmr->b", np.linalg.inv(S) @ HP_roi, HP_roi)
    return out


def downdate_inplace(cov: np.ndarray, A: np.ndarray) -> None:
    """``cov -= A A^T`` in place with one BLAS gemm (no n x n temporary)."""
    if not cov.flags.c_contiguous:
        raise ValueError("downdate_inplace needs a C-contiguous covariance")
    A = np.asfortranarray(A)
    blas.dgemm(-1.0, A, A, 1.0, cov.T, trans_b=True, overwrite_c=True)


def downdate_lower_inplace(cov: np.ndarray, A: np.ndarray) -> None:
    """The lower triangle of ``cov -= A A^T`` in place with one BLAS syrk (half of gemm's work); the strict
    upper triangle is left as it was (:func:`mirror_lower_inplace` copies the lower one over it)."""
    if not cov.flags.c_contiguous:
        raise ValueError("downdate_lower_inplace needs a C-contiguous covariance")
    # cov.T is the same memory in Fortran order, whose upper triangle is cov's lower one
    blas.dsyrk(-1.0, np.asfortranarray(A), beta=1.0, c=cov.T, lower=False, overwrite_c=True)


def mirror_lower_inplace(cov: np.ndarray, tile: int = 128) -> None:
    """Copy the lower triangle of ``cov`` onto its strict upper triangle, tile by tile: cov exactly symmetric."""
    n = cov.shape[0]
    for i in range(0, n, tile):
        cov[:i, i:i + tile] = cov[i:i + tile, :i].T
        block = cov[i:i + tile, i:i + tile]
        block[...] = np.tril(block) + np.tril(block, -1).T


def _as_cov(R: np.ndarray, m: int) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.ndim == 1:
        if R.shape != (m,):
            raise ValueError(f"R has shape {R.shape}: expected ({m},) variances or ({m}, {m})")
        return np.diag(R)
    if R.shape != (m, m):
        raise ValueError(f"R has shape {R.shape}: expected ({m},) variances or ({m}, {m})")
    return R


class GPBelief:
    """Mean and covariance of the field at the cell centres.

    Attributes:
        mean: (n,) posterior mean, row-major cells.
        cov: (n, n) posterior covariance (a property: see :attr:`cov`).
    """

    def __init__(self, mean: np.ndarray, cov: np.ndarray, shape: tuple[int, int] | None = None):
        self.mean = np.array(mean, dtype=np.float64)
        self._cov = np.array(cov, dtype=np.float64)
        self._upper_stale = False  # the strict upper triangle of _cov lags the lower one (see cov)
        n = self.mean.shape[0]
        if self.mean.shape != (n,) or self._cov.shape != (n, n):
            raise ValueError(f"mean {self.mean.shape} and cov {self._cov.shape} do not match: expected (n,) and (n, n)")
        self.shape = shape if shape is not None else (1, n)

    @property
    def cov(self) -> np.ndarray:
        """(n, n) posterior covariance, whole and exactly symmetric. An update downdates its lower triangle
        only; the first read after it copies that onto the upper one (:func:`mirror_lower_inplace`). The
        belief's own update, variances, look gains and predicted variances read the lower triangle and
        never pay for the copy (:meth:`columns`). Writing into the returned array changes the belief."""
        if self._upper_stale:
            mirror_lower_inplace(self._cov)
            self._upper_stale = False
        return self._cov

    @cov.setter
    def cov(self, value: np.ndarray) -> None:
        self._cov = np.asarray(value, dtype=np.float64)
        self._upper_stale = False

    def columns(self, cells: np.ndarray) -> np.ndarray:
        """(n, len(cells)): ``cov[:, cells]``, read from the lower triangle (no copy of the whole matrix)."""
        cov = self._cov
        cols = cov[:, cells]
        if self._upper_stale:  # P[i, c] for i < c lies above the diagonal: read it as P[c, i]
            for k, c in enumerate(np.asarray(cells).tolist()):
                cols[:c, k] = cov[c, :c]
        return cols

    @classmethod
    def from_grid(cls, shape: tuple[int, int] = (15, 15), resolution: float = 2.5,
                  length_scale: float = 3.67, signal_variance: float = 1.82,
                  prior_mean: float = 0.5, nugget: float = 0.0) -> GPBelief:
        """Prior over a rows x cols grid: mean ``prior_mean``, covariance the Matern 3/2 kernel
        plus ``nugget`` [field units^2] on the diagonal (independent per-cell variation)."""
        cov = grid_prior_covariance(shape, resolution, length_scale, signal_variance, nugget)  # copied by __init__
        return cls(np.full(cov.shape[0], float(prior_mean)), cov, shape=tuple(shape))

    @classmethod
    def prior(cls, grid, gp) -> GPBelief:
        """The prior of a :class:`~ipp_bench.core.config.GridConfig` and :class:`~ipp_bench.core.config.GPConfig`."""
        return cls.from_grid((grid.rows, grid.cols), grid.resolution, gp.length_scale,
                             gp.signal_variance, gp.prior_mean, gp.nugget)

    @property
    def n(self) -> int:
        return self.mean.shape[0]

    @property
    def variance(self) -> np.ndarray:
        """Posterior marginal variances, clipped at 0 against round-off."""
        return np.maximum(np.diag(self._cov), 0.0)

    def copy(self) -> GPBelief:
        other = GPBelief.__new__(GPBelief)
        other.mean = self.mean.copy()
        other._cov = self._cov.copy()
        other._upper_stale = self._upper_stale
        other.shape = self.shape
        return other

    @staticmethod
    def _local(H: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        H = np.atleast_2d(np.asarray(H, dtype=np.float64))
        if H.shape[1] != n:
            raise ValueError(f"H has shape {H.shape}: expected (m, {n})")
        cells = np.flatnonzero(np.any(H != 0.0, axis=0))
        return cells, H[:, cells]

    # -- public API -----------------------------------------------------------------------------
    def update(self, H: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        """Kalman update with measurements ``z = H f + v``, ``v ~ N(0, R)`` (paper eq. 3).

        Args:
            H: (m, n) measurement matrix.
            z: (m,) measurements.
            R: (m,) noise variances or (m, m) noise covariance.
        """
        cells, W = self._local(H, self.n)
        self.update_local(cells, W, z, R)

    def update_local(self, cells: np.ndarray, W: np.ndarray, z: np.ndarray, R: np.ndarray) -> None:
        """``update`` with H given by its non-zero columns ``cells`` and their weights W (m, q)."""
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        if z.shape[0] != W.shape[0]:
            raise ValueError(f"z has {z.shape[0]} values but H has {W.shape[0]} rows")
        A, L, C = gain_factor(self._cov, cells, W, R, columns=self.columns(cells))
        innovation = z - W @ self.mean[cells]
        self.mean += C @ cho_solve((L, True), innovation)
        downdate_lower_inplace(self._cov, A)
        self._upper_stale = True

    def predict_cov(self, H: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Posterior covariance after measuring with (H, R); the belief is unchanged.

        The covariance does not depend on the measured values, so look-ahead planners use this.
        """
        cells, W = self._local(H, self.n)
        A, _, _ = gain_factor(self.cov, cells, W, R)
        return self.cov - A @ A.T

    def predict_variance_local(self, cells: np.ndarray, W: np.ndarray, R: np.ndarray) -> np.ndarray:
        """Posterior marginal variances (n,) after a measurement; O(n m) beyond the gain."""
        A, _, _ = gain_factor(self._cov, cells, W, R, columns=self.columns(cells))
        return np.maximum(np.diag(self._cov) - np.einsum("ij,ij->i", A, A), 0.0)

    def trace_reductions(self, legs, roi: np.ndarray) -> np.ndarray:
        """For every leg: Tr(P - P+) over the cells ``roi`` (bool mask (n,)), each leg's rows fused as
        one batch; 0 for legs that see nothing: :func:`trace_reductions` on the covariance. The
        look-gain method both beliefs have (:meth:`WindowBelief.trace_reductions
        <ipp_bench.core.belief_window.WindowBelief.trace_reductions>`), so planners need not ask which.

        Args:
            legs: a :class:`LegBatch`, or a sequence of ``(cells, W, var)`` or None per leg (batched here).
            roi: (n,) bool.
        """
        batch = legs if isinstance(legs, LegBatch) else LegBatch(list(legs))
        if batch.index.size == 0:
            return np.zeros(batch.size)
        return trace_reductions_of_rows(self.columns(batch.cells).T, batch, roi)  # rows = columns: symmetric


class PredictedBelief:
    """A :class:`GPBelief` as it will be after read-outs not yet taken: its covariance after them, kept
    as the low-rank downdate P - A A^T of :func:`gain_factor` (the covariance does not depend on the
    values read, so this is exact), and its mean today's (the values are unknown). Rows of the
    covariance are formed on demand; the whole matrix only if asked for (:attr:`cov`).

    Args:
        belief: the belief now.
        observations: the read-outs to come (:class:`~ipp_bench.core.sensor.Observation`), at least one.
    """

    def __init__(self, belief: GPBelief, observations) -> None:
        from .sensor import stack

        cells, W, var = stack(list(observations))
        self.base = belief
        self.mean = belief.mean
        self.shape = belief.shape
        self.A = gain_factor(belief.cov, cells, W, var)[0]  # (n, m)
        self._cov: np.ndarray | None = None

    @property
    def n(self) -> int:
        return self.base.n

    def rows(self, cells: np.ndarray) -> np.ndarray:
        """(len(cells), n): the predicted covariance's rows ``cells``."""
        return self.base.cov[cells, :] - self.A[cells] @ self.A.T

    @property
    def cov(self) -> np.ndarray:
        """(n, n) the predicted covariance (formed once, on first use)."""
        if self._cov is None:
            self._cov = self.base.cov - self.A @ self.A.T
        return self._cov

    @property
    def variance(self) -> np.ndarray:
        return np.maximum(np.diag(self.base.cov) - np.einsum("ij,ij->i", self.A, self.A), 0.0)

    def trace_reductions(self, legs, roi: np.ndarray) -> np.ndarray:
        """:meth:`GPBelief.trace_reductions` on the predicted covariance, from its rows of the legs' cells."""
        batch = legs if isinstance(legs, LegBatch) else LegBatch(list(legs))
        if batch.index.size == 0:
            return np.zeros(batch.size)
        return trace_reductions_of_rows(self.rows(batch.cells), batch, roi)


def value_scale(t, floor: float) -> np.ndarray:
    """Variance factor k + (1 - k) 4 t (1 - t) of a camera error at field value ``t`` (clipped to [0, 1])."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return floor + (1.0 - floor) * 4.0 * t * (1.0 - t)


class PersistentErrorBelief:
    """A field belief whose camera repeats its error: the persistent per-cell error as extra states.

    Model: a read-out row w at resolution factor f measures ``z = w^T (x + e_f) + v``, where x (n,)
    is the field, e_f (n,) the camera's persistent per-cell error at factor f (the same texture seen
    again at that resolution is misread the same way) and v ~ N(0, r phi(z)) the look-to-look noise
    (r: the sensor's white variance ``noise_variance``). The error of cell c is
    ``e_f,c = sqrt(s_f phi(t_c)) u_f,c``: s_f its variance at t = 0.5 (``SensorConfig.persistent_var``,
    ``persistent_var_binned``), phi(t) = :func:`value_scale` (``noise_floor``, a cell with nothing to
    misread errs less), and u a unit-variance Gaussian field, independent of x, with
    ``corr(u_f,c, u_g,c') = C_cc' rho_fg``: C the spatial correlation r^(d^2) of
    :func:`~ipp_bench.core.sensor.persistent_correlation` (``persistent_neighbour_corr`` = r, so the cells of
    a binned block share much of their error; the identity for r = 0) and rho_fg = 1 for f = g, else
    ``persistent_corr``. t_c is plugged in from the data: the value of the row that first saw the cell.

    The state is ``[x, u_f1, u_f2, ...]`` (one block per factor with s_f > 0), its prior the field's
    and the u field's, both known from the start; a row's weights on it are ``[w, w * sd_f]`` over
    (x cells, u_f cells), sd_f,c = sqrt(s_f phi(t_c)) fixed once the cell is first seen, with
    R = r phi(z). The update is :meth:`GPBelief.update_local` on the augmented state (so
    :func:`gain_factor`, the one update) and exact for the model: equal to the batch GP posterior of x
    under the marginal covariance of z (``tests/test_belief.py``). After every update the field
    marginal (mean, covariance of x) is written into ``field``, the belief that planners, observations
    and metrics read. n (1 + factors) states: 675 on 15 x 15 with two factors.

    Args:
        field: the prior belief over the field (n cells, ``field.shape`` its grid); updated in place.
        sensor: the :class:`~ipp_bench.core.config.SensorConfig` with the camera's error constants.
    """

    def __init__(self, field: GPBelief, sensor):
        from .sensor import persistent_correlation

        self.field = field
        self.floor = float(sensor.noise_floor)
        n = field.n
        self.variances = {f: sensor.persistent(f) for f in sorted({1, int(sensor.binning)})}
        factors = [f for f, v in self.variances.items() if v > 0]
        self.offset = {f: n * (i + 1) for i, f in enumerate(factors)}
        self.corr = float(sensor.persistent_corr)
        N = n * (1 + len(factors))
        mean = np.zeros(N)
        mean[:n] = field.mean
        cov = np.zeros((N, N))
        cov[:n, :n] = field.cov
        rows, cols = np.divmod(np.arange(n), field.shape[1])
        C = persistent_correlation(rows, cols, float(sensor.persistent_neighbour_corr))
        for f, o in self.offset.items():
            for g, p in self.offset.items():
                cov[o:o + n, p:p + n] = C if f == g else self.corr * C
        self.state = GPBelief(mean, cov)
        self.sd = {f: np.zeros(n) for f in self.offset}  # sd_f,c, set when cell c is first seen
        self.seen = np.zeros(n, dtype=bool)

    def _rows(self, observations, zs) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The read-outs on the augmented state: (state columns, W over them, R, z), scales set first."""
        parts = []
        for o, z in zip(observations, zs):
            z = np.asarray(z, dtype=np.float64).reshape(-1)
            white = o.var if o.persistent is None else o.var - o.persistent
            if self.offset:
                self._set_scales(o, z)
            R = white * value_scale(z, self.floor)
            if o.factor in self.offset:
                cols = np.concatenate([o.cells, o.cells + self.offset[o.factor]])
                parts.append((cols, np.hstack([o.weights, o.weights * self.sd[o.factor][o.cells]]), R, z))
            else:
                parts.append((o.cells, o.weights, R, z))
        if len(parts) == 1:
            return parts[0]
        cols = np.unique(np.concatenate([p[0] for p in parts]))
        W = np.zeros((sum(p[1].shape[0] for p in parts), cols.size))
        row = 0
        for c, w, _, _ in parts:
            W[row:row + w.shape[0], np.searchsorted(cols, c)] = w
            row += w.shape[0]
        return cols, W, np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts])

    def _set_scales(self, obs, z: np.ndarray) -> None:
        """sd_f of the cells ``obs`` sees for the first time: sqrt(s_f phi(t)), t their row's value."""
        first = ~self.seen[obs.cells]
        if not first.any():
            return
        t = np.zeros(obs.cells.size)
        for w, value in zip(obs.weights, z):  # each cell lies in one row of a read-out
            t[w > 0] = value
        cells, scale = obs.cells[first], value_scale(t[first], self.floor)
        for f in self.offset:
            self.sd[f][cells] = np.sqrt(self.variances[f] * scale)
        self.seen[cells] = True

    def innovation(self, observations, zs) -> tuple[np.ndarray, np.ndarray]:
        """(nu, S) of a batch before its update: nu = z - H mu, S = H P H^T + R on the augmented state."""
        cols, W, R, z = self._rows(observations, zs)
        S = W @ self.state.cov[np.ix_(cols, cols)] @ W.T
        S[np.diag_indices_from(S)] += R
        return z - W @ self.state.mean[cols], S

    def normalised_innovation(self, observations, zs) -> tuple[float, int]:
        """NIS = nu^T S^-1 nu of a batch before its update (the augmented model's S), and its dof."""
        nu, S = self.innovation(observations, zs)
        return float(nu @ np.linalg.solve(S, nu)), int(nu.size)

    def update(self, observations, zs) -> None:
        """Kalman update with the read-outs ``observations`` and their values ``zs``, as one batch."""
        cols, W, R, z = self._rows(observations, zs)
        self.state.update_local(cols, W, z, R)
        n = self.field.n
        self.field.mean[:] = self.state.mean[:n]
        # the field's block of the state's covariance, its lower triangle current (GPBelief.cov)
        self.field._cov[:] = self.state._cov[:n, :n]
        self.field._upper_stale = self.state._upper_stale


def _nis(mu: np.ndarray, P: np.ndarray, W: np.ndarray, z: np.ndarray, var: np.ndarray) -> tuple[float, int]:
    nu = np.asarray(z, dtype=np.float64) - W @ mu
    S = W @ P @ W.T + np.diag(np.asarray(var, dtype=np.float64))
    return float(nu @ np.linalg.solve(S, nu)), int(nu.size)


def normalised_innovation(belief: GPBelief, cells: np.ndarray, W: np.ndarray, z: np.ndarray,
                          var: np.ndarray) -> tuple[float, int]:
    """NIS = nu^T S^-1 nu of a batch before its update, nu = z - H mu, S = H P H^T + R; and its dof (m).

    Under a consistent model NIS is chi-square with m degrees of freedom (mean m).
    """
    return _nis(belief.mean[cells], belief.cov[np.ix_(cells, cells)], W, z, var)


class WhiteNoiseBelief:
    """The field belief under independent (white) read-out noise, with the mission's one signature.

    ``update(observations, values)``: the read-outs stacked into one batch (``sensor.stack``) and
    :meth:`GPBelief.update_local` on ``field`` (so :func:`gain_factor`, the one update). The
    camera-error model (:class:`PersistentErrorBelief`) has the same two methods; a mission holds
    one of the two (:func:`belief_model`) and never asks which.
    """

    def __init__(self, field: GPBelief, sensor=None):
        del sensor  # the white noise rides on each read-out's own variance
        self.field = field

    def update(self, observations, zs) -> None:
        from .sensor import stack

        cells, W, var = stack(observations)
        self.field.update_local(cells, W, np.concatenate(zs), var)

    def normalised_innovation(self, observations, zs) -> tuple[float, int]:
        from .sensor import stack

        cells, W, var = stack(observations)
        return normalised_innovation(self.field, cells, W, np.concatenate(zs), var)


def belief_model(field: GPBelief, sensor) -> WhiteNoiseBelief | PersistentErrorBelief:
    """The belief a mission updates, for the sensor constants ``sensor`` (a ``SensorConfig``): the
    camera-error states where the sensor has them (``camera_error_states``), else white noise.
    Both keep ``field`` (the belief planners and metrics read) current."""
    cls = PersistentErrorBelief if sensor.camera_error_states else WhiteNoiseBelief
    return cls(field, sensor)


def error_states(mission) -> PersistentErrorBelief | None:
    """The belief model of ``mission`` (a :class:`~ipp_bench.core.mission.Mission`) if it carries the camera's
    repeated error as states (:class:`PersistentErrorBelief`: the deployment and its twin), else None
    (white read-out noise)."""
    model = getattr(mission, "belief_model", None)
    return model if isinstance(model, PersistentErrorBelief) else None


__all__ = ["GPBelief", "PersistentErrorBelief", "PredictedBelief", "WhiteNoiseBelief", "belief_model", "cell_centres",
           "error_states", "matern32", "normalised_innovation", "prior_covariance", "value_scale"]
