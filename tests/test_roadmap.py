"""Roadmap structure: nodes on cell centres, balanced k-NN edges, travel-time costs, Laplacian encoding."""

import numpy as np
import pytest

from ipp_bench.config import GraphConfig, GridConfig
from ipp_bench.roadmap import Roadmap, laplacian_encoding


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
