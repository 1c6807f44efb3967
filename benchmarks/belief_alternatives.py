"""The beliefs issue 20 measured against :class:`ipp_bench.belief_window.WindowBelief` and did not choose.

Kept with the benchmarks (not in the package) so that ``bench_belief_scale.py --alternatives``
can repeat the measurements of ``RESULTS_issue20.md``.

:class:`TaperedSparseBelief`: a compactly supported kernel and a sparse covariance (Furrer, Genton
and Nychka 2006; covariance localisation as in ensemble Kalman filters). The prior is the Matern
3/2 kernel times the Wendland taper phi_{3,1}(d / theta) = (1 - d / theta)_+^4 (4 d / theta + 1)
(positive definite in up to 3 dimensions, so the product is a valid covariance that is 0 beyond
theta). P is a scipy CSR matrix on that support; an update computes the gain from the sparse
columns P[:, cells] and subtracts T o (A A^T) on the support (the Schur product with the taper keeps
the sparsity). It is not the dense belief's model: the prior's covariances are damped at every
distance below theta.

:class:`InformationGMRFCost`: the cost side of a sparse-precision belief in information form,
measured as what one update with exact marginal variances needs: refactorising the sparse
precision Q + H^T R^-1 H (SuperLU, scipy's only sparse factorisation) and solving for the
variances of the footprint's neighbourhood. Matern 3/2 in 2D has no exact sparse precision
(the SPDE's alpha = nu + d/2 = 5/2 is not an integer), so the precision is the alpha = 2 (nu = 1)
SPDE stencil: the same kind of model, not the same one; this class measures cost only.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_solve, solve_triangular
from scipy.sparse.linalg import splu

from ipp_bench.belief import _as_cov, matern32


def wendland31(dist: np.ndarray, theta: float) -> np.ndarray:
    """Wendland phi_{3,1} taper: (1 - d/theta)_+^4 (4 d/theta + 1); 1 at 0, 0 from theta on."""
    t = np.clip(np.asarray(dist, dtype=np.float64) / theta, 0.0, 1.0)
    return (1.0 - t) ** 4 * (4.0 * t + 1.0)


def _pairs(shape, resolution: float, radius: float):
    """All (i, j, distance) of cells of the grid closer than ``radius`` [m], i and j flat indices."""
    rows, cols = shape
    w = int(np.ceil(radius / resolution))
    r, c = np.divmod(np.arange(rows * cols), cols)
    I, J, D = [], [], []
    for di in range(-w, w + 1):
        for dj in range(-w, w + 1):
            d = resolution * np.hypot(di, dj)
            if d >= radius:
                continue
            rr, cc = r + di, c + dj
            ok = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            I.append(np.flatnonzero(ok))
            J.append((rr * cols + cc)[ok])
            D.append(np.full(int(ok.sum()), d))
    return np.concatenate(I), np.concatenate(J), np.concatenate(D)


class TaperedSparseBelief:
    """Matern 3/2 times a Wendland taper of range ``theta`` [m], covariance in CSR, localised update."""

    def __init__(self, shape, resolution, length_scale, signal_variance, prior_mean, nugget, theta):
        self.shape = tuple(shape)
        n = shape[0] * shape[1]
        I, J, D = _pairs(shape, resolution, theta)
        taper = wendland31(D, theta)
        values = matern32(D, length_scale, signal_variance) * taper + nugget * (I == J)
        P = sp.csr_matrix((values, (I, J)), shape=(n, n))
        P.sort_indices()
        T = sp.csr_matrix((taper, (I, J)), shape=(n, n))
        T.sort_indices()
        assert np.array_equal(P.indices, T.indices) and np.array_equal(P.indptr, T.indptr)
        self.cov, self._taper = P, T.data
        self.mean = np.full(n, float(prior_mean))
        self._where = np.full(n, -1, dtype=np.int64)

    @property
    def n(self) -> int:
        return self.mean.shape[0]

    @property
    def nbytes(self) -> int:
        P = self.cov
        return self.mean.nbytes + P.data.nbytes + P.indices.nbytes + P.indptr.nbytes + self._taper.nbytes

    @property
    def variance(self) -> np.ndarray:
        return np.maximum(self.cov.diagonal(), 0.0)

    def copy(self):
        other = TaperedSparseBelief.__new__(TaperedSparseBelief)
        other.shape, other.cov, other._taper = self.shape, self.cov.copy(), self._taper
        other.mean, other._where = self.mean.copy(), np.full(self.n, -1, dtype=np.int64)
        return other

    def update_local(self, cells, W, z, R) -> None:
        cells = np.asarray(cells)
        W = np.atleast_2d(np.asarray(W, dtype=np.float64))
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        if W.shape[1] != cells.size or z.shape[0] != W.shape[0]:
            raise ValueError(f"W {W.shape}, cells {cells.shape} and z {z.shape} do not match")
        P = self.cov
        rows = P[cells]  # (q, n) sparse; P is symmetric, so these are the columns
        N = np.unique(rows.indices)
        PN = rows[:, N].toarray().T  # (|N|, q)
        where = self._where
        where[N] = np.arange(N.size)
        C = PN @ W.T
        S = W @ C[where[cells], :] + _as_cov(R, W.shape[0])
        L = np.linalg.cholesky(0.5 * (S + S.T))
        A = solve_triangular(L, C.T, lower=True, check_finite=False).T
        self.mean[N] += C @ cho_solve((L, True), z - W @ self.mean[cells])
        # the entries of rows N whose column is in N: data -= taper * (A A^T)
        starts, stops = P.indptr[N], P.indptr[N + 1]
        lengths = stops - starts
        idx = np.repeat(stops - np.cumsum(lengths), lengths) + np.arange(lengths.sum())
        rowpos = np.repeat(np.arange(N.size), lengths)
        colpos = where[P.indices[idx]]
        keep = colpos >= 0
        idx, rowpos, colpos = idx[keep], rowpos[keep], colpos[keep]
        G = A @ A.T
        P.data[idx] -= self._taper[idx] * G[rowpos, colpos]
        where[N] = -1


class InformationGMRFCost:
    """The per-update cost of an information-form GMRF with exact variances near the update.

    State: the field f on n cells with precision Q0 = (kappa^2 I - Laplacian)^2 / c (the alpha = 2
    SPDE on the grid) plus a nugget handled as measurement noise. An update adds H^T R^-1 H to Q and
    H^T R^-1 z to the information vector; the mean and the variances of ``probe`` cells need a fresh
    sparse factorisation of Q (SuperLU with COLAMD ordering) and one solve per probed variance.
    """

    def __init__(self, shape, resolution, length_scale, signal_variance):
        rows, cols = shape
        n = rows * cols
        kappa = np.sqrt(8.0 * 1.0) / length_scale  # nu = 1: rho = sqrt(8 nu) / kappa
        lap1 = lambda k: sp.diags([np.ones(k - 1), -2.0 * np.ones(k), np.ones(k - 1)], [-1, 0, 1]) / resolution**2
        Lap = sp.kron(sp.identity(rows), lap1(cols)) + sp.kron(lap1(rows), sp.identity(cols))
        Kop = kappa**2 * sp.identity(n) - Lap
        tau = 4.0 * np.pi * kappa**2 * signal_variance  # marginal variance 1 / (4 pi kappa^2 tau) -> signal_variance
        self.Q = (tau * (Kop @ Kop) * resolution**2).tocsc()
        self.b = np.zeros(n)
        self.shape = shape

    @property
    def nbytes(self) -> int:
        return self.Q.data.nbytes + self.Q.indices.nbytes + self.Q.indptr.nbytes + self.b.nbytes

    def update_and_variances(self, cells, W, z, R, probe) -> np.ndarray:
        """Add the read-out's information, refactorise, return the mean and the variances at ``probe``."""
        n = self.Q.shape[0]
        H = sp.csr_matrix((W.ravel(), (np.repeat(np.arange(W.shape[0]), W.shape[1]), np.tile(cells, W.shape[0]))),
                          shape=(W.shape[0], n))
        Rinv = sp.diags(1.0 / np.asarray(R))
        self.Q = (self.Q + (H.T @ Rinv @ H)).tocsc()
        self.b += H.T @ (np.asarray(z) / np.asarray(R))
        lu = splu(self.Q, permc_spec="COLAMD")
        mean = lu.solve(self.b)
        E = np.zeros((n, len(probe)))
        E[probe, np.arange(len(probe))] = 1.0
        var = np.einsum("ij,ij->j", E, lu.solve(E))
        return mean, var
