"""3D probabilistic roadmap: candidate measurement positions and their k-NN edges.

Nodes sit on the grid's cell centres at every altitude level (``sampling="grid"``: 15 x 15 x 2 =
450 nodes), or are drawn uniformly over the map on each level (``sampling="uniform"``, a PRM).
Each node links to its k nearest neighbours, k / n_levels from every level (paper Section IV-A),
so that every decision can change altitude. Edge cost is travel time at the mission speed. The
positional encoding holds the eigenvectors of the normalised graph Laplacian with the smallest
non-zero eigenvalues, each signed so that its largest-magnitude entry is positive.

Two eigensolvers give the encoding: the dense ``scipy.linalg.eigh`` for roadmaps of at
most :data:`DENSE_ENCODING_MAX_NODES` nodes, which keeps every task of the suite (at most 30 x 30 x 2
= 1 800 nodes) bit for bit what its committed results were computed with, and above it a sparse
shift-invert Lanczos (``scipy.sparse.linalg.eigsh`` on a sparse LU of L - sigma I), which builds the
encoding of a 128 x 128 x 2 roadmap (32 768 nodes) in seconds and ~0.2 GB where the dense Laplacian
alone would need 8 GiB. Both span the same eigenspace; within a degenerate eigenvalue the basis
they pick differs, so the switch is by size, never a fallback.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import eigh
from scipy.sparse.linalg import LinearOperator, eigsh, splu
from scipy.spatial import cKDTree

from .belief import cell_centres
from .config import GraphConfig, GridConfig

_CACHE: dict[tuple, Roadmap] = {}

#: [-] the most nodes whose encoding the dense eigensolver computes: the suite's largest roadmap
#: (30 x 30 cells x 2 levels = 1 800 nodes) rounded up to 2^11, a dense Laplacian of 32 MiB and
#: ~1 s of ``eigh``; above it the sparse solver is faster (0.1 s at 1 800 nodes) and the dense one
#: grows as N^3 (14 s at 5 000 nodes)
DENSE_ENCODING_MAX_NODES = 2048
#: the shift of the sparse solver's shift-invert: just below the Laplacian's spectrum [0, 2], so
#: that (L - sigma I) is positive definite and its smallest eigenvalues are the largest of the inverse
ENCODING_SHIFT = -1e-3
ENCODING_METHODS = ("auto", "dense", "sparse")


@dataclass(frozen=True, eq=False)
class Roadmap:
    """An immutable roadmap; build it with :meth:`Roadmap.build`.

    Attributes:
        positions: (N, 3) node positions [m].
        levels: (N,) altitude level index of each node.
        neighbours: (N, k) neighbour node indices, nearest first.
        costs: (N, k) nominal travel time [s] to each neighbour (length / speed). Not the clock:
            what a leg costs an episode is the mission's ``leg_durations`` (the MuJoCo task adds
            its velocity ramps); masks and planners ask the mission. On the core mission the two
            are equal bit for bit (tests/envs/test_graph.py).
        pos_encoding: (N, pe_dim) float32 Laplacian eigenvector encoding.
    """

    positions: np.ndarray
    levels: np.ndarray
    neighbours: np.ndarray
    costs: np.ndarray
    pos_encoding: np.ndarray
    grid: GridConfig
    graph: GraphConfig
    speed: float

    @property
    def n_nodes(self) -> int:
        return self.positions.shape[0]

    @property
    def k(self) -> int:
        return self.neighbours.shape[1]

    def nearest_node(self, xyz) -> int:
        """Index of the node closest to ``xyz`` [m]."""
        d = np.linalg.norm(self.positions - np.asarray(xyz, dtype=np.float64), axis=1)
        return int(np.argmin(d))

    @classmethod
    def build(cls, grid: GridConfig, graph: GraphConfig, speed: float) -> Roadmap:
        """Build (or fetch from the per-process cache) the roadmap of a configuration."""
        key = (grid, graph, float(speed))
        cached = _CACHE.get(key)
        if cached is not None:
            return cached
        positions, levels = _sample_nodes(grid, graph)
        neighbours, dist = _balanced_knn(positions, levels, graph)
        pe = laplacian_encoding(neighbours, graph.pe_dim)
        for a in (positions, levels, neighbours, dist, pe):
            a.flags.writeable = False
        costs = dist / float(speed)
        costs.flags.writeable = False
        roadmap = cls(positions, levels, neighbours, costs, pe, grid, graph, float(speed))
        _CACHE[key] = roadmap
        return roadmap


def _sample_nodes(grid: GridConfig, graph: GraphConfig) -> tuple[np.ndarray, np.ndarray]:
    width, height = grid.size_m
    parts, levels = [], []
    if graph.sampling == "grid":
        xy = cell_centres((grid.rows, grid.cols), grid.resolution)
        per_level = [xy] * len(graph.altitudes)
    else:
        rng = np.random.default_rng(graph.roadmap_seed)
        n = graph.n_samples // len(graph.altitudes)
        per_level = [rng.uniform([0.0, 0.0], [width, height], size=(n, 2)) for _ in graph.altitudes]
    for i, (alt, xy) in enumerate(zip(graph.altitudes, per_level)):
        parts.append(np.column_stack([xy, np.full(len(xy), alt)]))
        levels.append(np.full(len(xy), i, dtype=np.int64))
    return np.concatenate(parts).astype(np.float64), np.concatenate(levels)


def _balanced_knn(positions: np.ndarray, levels: np.ndarray, graph: GraphConfig):
    """k nearest neighbours per node, k / n_levels from each level, ties broken by index."""
    n_levels = len(graph.altitudes)
    per = graph.k // n_levels
    N = positions.shape[0]
    idx_parts, dist_parts = [], []
    for lvl in range(n_levels):
        members = np.flatnonzero(levels == lvl)
        if members.size < per + 1:
            raise ValueError(
                f"graph.k = {graph.k} needs at least {per + 1} nodes per level, level {lvl} has {members.size}")
        q = min(members.size, per + 9)
        dist, local = cKDTree(positions[members]).query(positions, k=q)
        cand = members[local]
        dist = np.where(cand == np.arange(N)[:, None], np.inf, dist)  # no self-loops
        order = np.lexsort((cand, np.round(dist, 9)), axis=1)[:, :per]
        idx_parts.append(np.take_along_axis(cand, order, 1))
        dist_parts.append(np.take_along_axis(dist, order, 1))
    idx = np.concatenate(idx_parts, axis=1)
    dist = np.concatenate(dist_parts, axis=1)
    order = np.lexsort((idx, np.round(dist, 9)), axis=1)
    return np.take_along_axis(idx, order, 1).astype(np.int64), np.take_along_axis(dist, order, 1)


def laplacian_encoding(neighbours: np.ndarray, dim: int, method: str = "auto") -> np.ndarray:
    """(N, dim) eigenvectors of the normalised Laplacian of the symmetrised k-NN graph.

    The trivial eigenvector is dropped; each vector is signed so that its first entry of largest
    magnitude is positive, which fixes the encoding for a given roadmap. Missing dimensions (tiny
    graphs) are zero.

    Args:
        neighbours: (N, k) neighbour indices of each node.
        dim: eigenvectors kept.
        method: ``"dense"`` (``scipy.linalg.eigh``), ``"sparse"`` (shift-invert ``eigsh``) or
            ``"auto"``: dense for at most :data:`DENSE_ENCODING_MAX_NODES` nodes, else sparse.

    Raises:
        ValueError: an unknown ``method``, or ``"sparse"`` on a graph of at most dim + 1 nodes.
    """
    if method not in ENCODING_METHODS:
        raise ValueError(f"method = {method!r} is invalid: expected one of {ENCODING_METHODS}")
    N = neighbours.shape[0]
    top = min(dim, N - 1)
    if method == "sparse" and N <= dim + 1:
        raise ValueError(f"method = 'sparse' needs more than dim + 1 = {dim + 1} nodes, the graph has {N}: "
                         "use 'dense' (or 'auto')")
    if method == "dense" or (method == "auto" and N <= DENSE_ENCODING_MAX_NODES):
        vecs = _dense_eigenvectors(neighbours, top)
    else:
        vecs = _sparse_eigenvectors(neighbours, top)
    mag = np.abs(vecs)
    first_max = np.argmax(mag >= mag.max(axis=0, keepdims=True) - 1e-9, axis=0)
    signs = np.sign(vecs[first_max, np.arange(vecs.shape[1])])
    vecs = vecs * np.where(signs == 0, 1.0, signs)
    out = np.zeros((N, dim), dtype=np.float32)
    out[:, :top] = vecs
    return out


def _dense_eigenvectors(neighbours: np.ndarray, top: int) -> np.ndarray:
    """Eigenvectors 1..top (ascending eigenvalues) of the dense normalised Laplacian."""
    N = neighbours.shape[0]
    A = np.zeros((N, N))
    A[np.repeat(np.arange(N), neighbours.shape[1]), neighbours.ravel()] = 1.0
    A = np.maximum(A, A.T)
    d = 1.0 / np.sqrt(A.sum(axis=1))
    L = np.eye(N) - d[:, None] * A * d[None, :]
    _, vecs = eigh(L, subset_by_index=[1, top], driver="evr")
    return vecs


def sparse_laplacian(neighbours: np.ndarray) -> sp.csc_matrix:
    """The normalised Laplacian I - D^-1/2 A D^-1/2 of the symmetrised k-NN graph, sparse."""
    N, k = neighbours.shape
    A = sp.csr_matrix((np.ones(N * k), (np.repeat(np.arange(N), k), neighbours.ravel())), shape=(N, N))
    A = ((A + A.T) > 0).astype(np.float64)
    d = 1.0 / np.sqrt(np.asarray(A.sum(axis=1)).ravel())
    return (sp.identity(N, format="csc") - sp.diags(d) @ A @ sp.diags(d)).tocsc()


def _sparse_eigenvectors(neighbours: np.ndarray, top: int) -> np.ndarray:
    """Eigenvectors 1..top (ascending eigenvalues) by shift-invert Lanczos.

    L - sigma I (sigma = :data:`ENCODING_SHIFT` < 0) is symmetric positive definite, so its LU
    needs no pivoting: SuperLU in symmetric mode with a minimum-degree ordering of A + A^T (on
    128 x 128 x 2 nodes ~9.5 M factor entries, against 15 M with COLAMD). ARPACK then finds the
    top + 1 largest eigenvalues of (L - sigma I)^-1 from a seeded start vector, so the result is
    the same on every build.
    """
    N = neighbours.shape[0]
    L = sparse_laplacian(neighbours)
    lu = splu((L - ENCODING_SHIFT * sp.identity(N, format="csc")).tocsc(), permc_spec="MMD_AT_PLUS_A",
              diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    inverse = LinearOperator((N, N), matvec=lu.solve, dtype=np.float64)
    v0 = np.random.default_rng(0).standard_normal(N)
    vals, vecs = eigsh(L, k=top + 1, sigma=ENCODING_SHIFT, OPinv=inverse, which="LM", v0=v0)
    order = np.argsort(vals, kind="stable")[1:]
    return vecs[:, order]
