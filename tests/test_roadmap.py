"""Roadmap structure: nodes on cell centres, balanced k-NN edges, travel-time costs, Laplacian encoding."""

import numpy as np
import pytest

from ipp_bench.core.config import GraphConfig, GridConfig
from ipp_bench.core.roadmap import Roadmap, laplacian_encoding


@pytest.fixture(scope="module")
def roadmap():
    return Roadmap.build(GridConfig(15, 15, 2.5), GraphConfig(), 2.0)


def test_grid_roadmap_has_450_nodes_on_cell_centres(roadmap):
    assert roadmap.n_nodes == 450 and roadmap.k == 20
    # node index = level * 225 + r * 15 + c
    np.testing.assert_allclose(roadmap.positions[0], [1.25, 1.25, 8.0])
    np.testing.assert_allclose(roadmap.positions[225 + 2 * 15 + 2], [6.25, 6.25, 14.0])
    assert set(np.unique(roadmap.positions[:, 2])) == {8.0, 14.0}


def test_knn_balanced_per_level_and_nearest(roadmap):
    lv = roadmap.levels[roadmap.neighbours]
    assert np.all((lv == 0).sum(axis=1) == 10) and np.all((lv == 1).sum(axis=1) == 10)
    assert not np.any(roadmap.neighbours == np.arange(450)[:, None])  # no self loops
    assert all(len(set(row)) == 20 for row in roadmap.neighbours)
    # brute force: the 10 chosen on each level are the 10 nearest on that level
    P = roadmap.positions
    for i in (0, 112, 300, 449):
        for lvl in (0, 1):
            members = np.flatnonzero((roadmap.levels == lvl) & (np.arange(450) != i))
            d = np.sort(np.linalg.norm(P[members] - P[i], axis=1))
            chosen = roadmap.neighbours[i][lv[i] == lvl]
            dc = np.sort(np.linalg.norm(P[chosen] - P[i], axis=1))
            np.testing.assert_allclose(dc, d[:10])


def test_edge_cost_is_travel_time(roadmap):
    d = np.linalg.norm(roadmap.positions[roadmap.neighbours] - roadmap.positions[:, None], axis=2)
    np.testing.assert_allclose(roadmap.costs, d / 2.0)
    assert np.all(np.diff(roadmap.costs, axis=1) >= -1e-12)  # nearest first


def test_uniform_prm_sampling():
    rm = Roadmap.build(GridConfig(15, 15), GraphConfig(sampling="uniform", n_samples=300, roadmap_seed=4), 2.0)
    assert rm.n_nodes == 300
    assert np.all(rm.positions[:, :2] >= 0) and np.all(rm.positions[:, :2] <= 37.5)
    lv = rm.levels[rm.neighbours]
    assert np.all((lv == 0).sum(axis=1) == 10)
    rm2 = Roadmap.build(GridConfig(15, 15), GraphConfig(sampling="uniform", n_samples=300, roadmap_seed=5), 2.0)
    assert not np.allclose(rm.positions, rm2.positions)


def test_laplacian_encoding_is_eigenvectors_with_fixed_sign(roadmap):
    pe = roadmap.pos_encoding
    assert pe.shape == (450, 32) and pe.dtype == np.float32
    nb = roadmap.neighbours
    A = np.zeros((450, 450))
    A[np.repeat(np.arange(450), 20), nb.ravel()] = 1
    A = np.maximum(A, A.T)
    d = 1 / np.sqrt(A.sum(1))
    L = np.eye(450) - d[:, None] * A * d[None]
    v = pe.astype(np.float64)
    lam = np.einsum("ij,ij->j", v, L @ v)
    np.testing.assert_allclose(L @ v, v * lam, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(v, axis=0), 1.0, atol=1e-5)
    assert np.all(lam > 1e-8)  # the trivial eigenvector is dropped
    # sign convention: first entry of largest magnitude is positive
    for j in range(32):
        col = v[:, j]
        i = np.argmax(np.abs(col) >= np.abs(col).max() - 1e-6)
        assert col[i] > 0
    np.testing.assert_array_equal(laplacian_encoding(nb, 32), pe)  # deterministic


# -- the encoding at scale: dense for the suite's sizes, sparse above ----------------------
def _dense_encoding_reference(neighbours, dim):
    """the dense laplacian_encoding, verbatim: the reference of bit-identity."""
    from scipy.linalg import eigh

    N = neighbours.shape[0]
    A = np.zeros((N, N))
    A[np.repeat(np.arange(N), neighbours.shape[1]), neighbours.ravel()] = 1.0
    A = np.maximum(A, A.T)
    d = 1.0 / np.sqrt(A.sum(axis=1))
    L = np.eye(N) - d[:, None] * A * d[None, :]
    top = min(dim, N - 1)
    _, vecs = eigh(L, subset_by_index=[1, top], driver="evr")
    mag = np.abs(vecs)
    first_max = np.argmax(mag >= mag.max(axis=0, keepdims=True) - 1e-9, axis=0)
    signs = np.sign(vecs[first_max, np.arange(vecs.shape[1])])
    vecs = vecs * np.where(signs == 0, 1.0, signs)
    out = np.zeros((N, dim), dtype=np.float32)
    out[:, :top] = vecs
    return out


def _rayleigh(L, v):
    v = v.astype(np.float64)
    return np.einsum("ij,ij->j", v, L @ v) / np.einsum("ij,ij->j", v, v)


def _assert_same_eigenspace(neighbours, sparse, dim, tol=1e-6, signs=True):
    """Each eigenvalue cluster of the sparse encoding spans the dense eigenvectors of that cluster.

    Eigenvalues closer than ``tol`` form one cluster; its vectors are compared as a subspace
    (principal angles), since within a degenerate eigenvalue any orthonormal basis is right. The
    dense reference holds 4 extra vectors, so a cluster cut by ``dim`` is still covered. ``signs``:
    also check the sign convention on the float32 vectors (where ties of magnitude are clear).
    """
    from scipy.linalg import subspace_angles

    from ipp_bench.core.roadmap import sparse_laplacian

    L = sparse_laplacian(neighbours)
    dense = laplacian_encoding(neighbours, dim + 4, method="dense").astype(np.float64)
    lam_d, lam_s = _rayleigh(L, dense), _rayleigh(L, sparse)
    np.testing.assert_allclose(lam_s, lam_d[:dim], atol=tol / 10)  # the same dim smallest eigenvalues
    residual = L @ sparse - sparse * lam_s
    assert np.abs(residual).max() < 1e-5  # eigenvectors (to float32)
    for j in np.unique(np.round(lam_s / tol)):
        mine = np.flatnonzero(np.abs(lam_s - j * tol) <= tol)
        theirs = np.flatnonzero(np.abs(lam_d - lam_s[mine[0]]) <= 2 * tol)
        V, Q = sparse[:, mine].astype(np.float64), dense[:, theirs]
        assert np.linalg.norm(V - Q @ (Q.T @ V)) < 1e-5  # inside the dense cluster's span
        if len(theirs) == len(mine):  # a whole cluster: the same subspace
            assert subspace_angles(V, Q).max() < 1e-5
    for col in sparse.T if signs else ():  # sign convention: the first entry of largest magnitude is positive
        assert col[np.argmax(np.abs(col) >= np.abs(col).max() - 1e-6)] > 0


def test_every_task_keeps_its_dense_encoding_bit_for_bit():
    """Every registered task (15 x 15 to 30 x 30, at most 1 800 nodes) gets the dense encoding; the
    large tasks (tag ``large``, 128 x 128) are above the dense limit."""
    from ipp_bench.core.roadmap import DENSE_ENCODING_MAX_NODES
    from ipp_bench.envs import TASKS

    sizes = set()
    for spec in TASKS.values():
        if "large" in spec.tags:  # 128 x 128: the sparse encoding by design, no earlier encoding
            assert spec.config.grid.n_cells * len(spec.config.graph.altitudes) > DENSE_ENCODING_MAX_NODES
            continue
        c = spec.config
        rm = Roadmap.build(c.grid, c.graph, c.mission.speed)
        assert rm.n_nodes <= DENSE_ENCODING_MAX_NODES
        if (c.grid, c.graph) not in sizes:
            sizes.add((c.grid, c.graph))
            np.testing.assert_array_equal(rm.pos_encoding, _dense_encoding_reference(rm.neighbours, c.graph.pe_dim))
    assert {g.rows for g, _ in sizes} >= {15, 20, 30}


@pytest.mark.slow  # a dense eigh of 2 880 nodes (3.4 s); the suite sizes and the degenerate case run by default
def test_sparse_encoding_spans_the_dense_eigenspace_on_a_mid_size_map():
    rm = Roadmap.build(GridConfig(36, 40, 2.5), GraphConfig(), 2.0)  # 2 880 nodes: above the dense limit
    assert rm.n_nodes > 2048
    _assert_same_eigenspace(rm.neighbours, rm.pos_encoding.astype(np.float64), 32)
    np.testing.assert_array_equal(laplacian_encoding(rm.neighbours, 32, method="sparse"), rm.pos_encoding)


def test_sparse_encoding_on_the_suite_sizes_matches_dense_to_float32():
    """Where both are run on a task's roadmap (no degenerate eigenvalues), the vectors themselves agree."""
    rm = Roadmap.build(GridConfig(30, 30, 2.5), GraphConfig(), 2.0)
    sparse = laplacian_encoding(rm.neighbours, 32, method="sparse")
    np.testing.assert_allclose(sparse, rm.pos_encoding, atol=1e-6)
    _assert_same_eigenspace(rm.neighbours, sparse.astype(np.float64), 32)


def test_sparse_encoding_of_degenerate_eigenvalues_spans_each_eigenspace():
    """A cycle of 2 100 nodes: every eigenvalue but 0 is double, and dim = 31 cuts the last pair.

    No sign check here: a cycle's eigenvector (a sampled cosine) reaches its largest magnitude at
    many entries of both signs within float32 round-off, so which one comes first is not defined
    by the float32 encoding (the rule is applied in float64, with a 1e-9 tie tolerance).
    """
    n = 2100
    nb = np.stack([(np.arange(n) - 1) % n, (np.arange(n) + 1) % n], axis=1)
    sparse = laplacian_encoding(nb, 31, method="sparse")
    assert sparse.shape == (n, 31)
    _assert_same_eigenspace(nb, sparse.astype(np.float64), 31, signs=False)


def test_laplacian_encoding_refuses_an_unknown_method():
    expected = r"method = 'arpack' is invalid: expected one of \('auto', 'dense', 'sparse'\)"
    with pytest.raises(ValueError, match=expected):
        laplacian_encoding(np.zeros((4, 1), dtype=np.int64), 2, method="arpack")
    with pytest.raises(ValueError, match=r"method = 'sparse' needs more than dim \+ 1 = 33 nodes, the graph has 30"):
        laplacian_encoding(np.zeros((30, 1), dtype=np.int64), 32, method="sparse")


@pytest.mark.slow
def test_roadmap_and_encoding_of_128_by_128_cells():
    """The 128 x 128 size: 32 768 nodes, the k / n_levels rule kept, sparse eigenvectors with the fixed sign."""
    from ipp_bench.core.roadmap import sparse_laplacian

    rm = Roadmap.build(GridConfig(128, 128, 2.5), GraphConfig(), 2.0)
    assert rm.n_nodes == 32768 and rm.pos_encoding.shape == (32768, 32)
    lv = rm.levels[rm.neighbours]
    assert np.all((lv == 0).sum(axis=1) == 10) and np.all((lv == 1).sum(axis=1) == 10)
    v = rm.pos_encoding.astype(np.float64)
    L = sparse_laplacian(rm.neighbours)
    lam = _rayleigh(L, v)
    assert np.all(lam > 1e-8) and np.all(np.diff(lam) >= -1e-7)
    assert np.abs(L @ v - v * lam).max() < 1e-5
    np.testing.assert_allclose(v.T @ v, np.eye(32), atol=1e-5)
    for col in v.T:
        assert col[np.argmax(np.abs(col) >= np.abs(col).max() - 1e-6)] > 0
