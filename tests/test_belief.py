"""The Kalman update against the batch GP posterior (paper eqs. 2 and 3)."""

import numpy as np
import pytest

from ipp_bench.belief import GPBelief, cell_centres, matern32


def batch_posterior(mean0, K, H, z, R):
    """Batch GP posterior of f given z = H f + v, v ~ N(0, R): the textbook formula."""
    S = H @ K @ H.T + R
    G = K @ H.T @ np.linalg.inv(S)
    return mean0 + G @ (z - H @ mean0), K - G @ H @ K


def test_prior_is_matern32_kernel():
    b = GPBelief.from_grid((3, 4), resolution=2.0, length_scale=3.0, signal_variance=1.5, prior_mean=0.2)
    assert b.mean.shape == (12,) and b.cov.shape == (12, 12)
    np.testing.assert_allclose(b.mean, 0.2)
    # cells 0 and 1 are 2 m apart: k = s2 (1 + sqrt3 d / l) exp(-sqrt3 d / l)
    r = np.sqrt(3) * 2.0 / 3.0
    assert b.cov[0, 1] == pytest.approx(1.5 * (1 + r) * np.exp(-r), rel=1e-12)
    assert b.cov[0, 0] == pytest.approx(1.5)
    # row-major: cell 4 is (row 1, col 0), directly above cell 0
    xy = cell_centres((3, 4), 2.0)
    np.testing.assert_allclose(xy[4], [1.0, 3.0])
    assert b.cov[0, 4] == pytest.approx(b.cov[0, 1])


def test_matern32_at_zero_and_decay():
    assert matern32(0.0, 3.67, 1.82) == pytest.approx(1.82)
    d = np.linspace(0, 20, 50)
    assert np.all(np.diff(matern32(d, 3.67, 1.82)) < 0)


@pytest.mark.parametrize("seed", range(5))
def test_sequential_updates_equal_batch_posterior(seed):
    rng = np.random.default_rng(seed)
    belief = GPBelief.from_grid((6, 7), resolution=2.5)
    mean0, K = belief.mean.copy(), belief.cov.copy()
    n = belief.n
    Hs, zs, Rs = [], [], []
    for _ in range(6):
        m = int(rng.integers(1, 5))
        H = np.zeros((m, n))
        for row in range(m):  # sparse random rows, like footprints
            cols = rng.choice(n, size=int(rng.integers(1, 6)), replace=False)
            H[row, cols] = rng.uniform(0.1, 1.0, cols.size)
        z = rng.normal(0.5, 0.5, m)
        R = rng.uniform(0.01, 0.1, m)
        belief.update(H, z, R)
        Hs.append(H), zs.append(z), Rs.append(R)
    H, z, R = np.vstack(Hs), np.concatenate(zs), np.diag(np.concatenate(Rs))
    mean_b, cov_b = batch_posterior(mean0, K, H, z, R)
    scale_m = np.max(np.abs(mean_b))
    scale_c = np.max(np.abs(cov_b))
    assert np.max(np.abs(belief.mean - mean_b)) <= 1e-8 * scale_m
    assert np.max(np.abs(belief.cov - cov_b)) <= 1e-8 * scale_c


def test_full_covariance_R_and_dense_random_H():
    rng = np.random.default_rng(7)
    belief = GPBelief.from_grid((4, 4))
    mean0, K = belief.mean.copy(), belief.cov.copy()
    H = rng.normal(size=(3, 16))
    A = rng.normal(size=(3, 3))
    R = A @ A.T * 0.01 + 0.05 * np.eye(3)
    z = rng.normal(size=3)
    belief.update(H, z, R)
    mean_b, cov_b = batch_posterior(mean0, K, H, z, R)
    np.testing.assert_allclose(belief.mean, mean_b, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(belief.cov, cov_b, rtol=1e-8, atol=1e-10)


def test_predict_cov_does_not_change_belief_and_matches_update():
    rng = np.random.default_rng(3)
    belief = GPBelief.from_grid((5, 5))
    H = np.zeros((2, 25))
    H[0, [0, 1, 5, 6]] = 0.25
    H[1, 12] = 1.0
    R = np.array([0.04, 0.04])
    before = belief.cov.copy()
    pred = belief.predict_cov(H, R)
    np.testing.assert_array_equal(belief.cov, before)
    belief.update(H, rng.normal(size=2), R)
    np.testing.assert_allclose(pred, belief.cov, rtol=1e-12, atol=1e-14)


def test_predict_variance_local_is_diag_of_predict_cov():
    belief = GPBelief.from_grid((5, 5))
    cells = np.array([3, 4, 8])
    W = np.array([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]])
    R = np.array([0.04, 0.05])
    H = np.zeros((2, 25))
    H[:, cells] = W
    np.testing.assert_allclose(belief.predict_variance_local(cells, W, R),
                               np.diag(belief.predict_cov(H, R)), rtol=1e-12, atol=1e-14)


def test_copy_is_independent():
    b = GPBelief.from_grid((3, 3))
    c = b.copy()
    c.update(np.eye(9)[:1], np.array([1.0]), np.array([0.01]))
    assert b.mean[0] == 0.5 and c.mean[0] != 0.5


def test_bad_shapes_raise_clear_errors():
    b = GPBelief.from_grid((3, 3))
    with pytest.raises(ValueError, match=r"expected \(m, 9\)"):
        b.update(np.ones((1, 4)), np.ones(1), np.ones(1))
    with pytest.raises(ValueError, match="variances"):
        b.update(np.eye(9)[:2], np.ones(2), np.ones(3))
    with pytest.raises(ValueError, match="rows"):
        b.update(np.eye(9)[:2], np.ones(3), np.ones(2))


def test_covariance_stays_symmetric_psd_over_many_updates():
    from ipp_bench.belief import RESYMMETRISE_EVERY

    rng = np.random.default_rng(11)
    b = GPBelief.from_grid((8, 8))
    for i in range(3 * RESYMMETRISE_EVERY):
        cells = np.sort(rng.choice(64, size=4, replace=False))
        b.update_local(cells, np.full((1, 4), 0.25), rng.normal(size=1), np.array([0.04]))
    np.testing.assert_array_equal(b.cov, b.cov.T)  # just re-symmetrised
    assert np.linalg.eigvalsh(b.cov).min() > -1e-12


def test_batched_trace_reductions_match_one_by_one():
    from ipp_bench.belief import LegBatch, gain_factor, trace_reductions

    rng = np.random.default_rng(5)
    b = GPBelief.from_grid((6, 6))
    b.update(np.eye(36)[:3], rng.normal(size=3), np.full(3, 0.04))
    legs = []
    for m in (1, 4, 2):
        cells = np.sort(rng.choice(36, size=5, replace=False))
        legs.append((cells, rng.uniform(0, 1, (m, 5)), rng.uniform(0.01, 0.1, m)))
    legs.insert(1, None)
    roi = rng.random(36) < 0.5
    got = trace_reductions(b.cov, LegBatch(legs), roi)
    for leg, g in zip(legs, got):
        if leg is None:
            assert g == 0.0
            continue
        A = gain_factor(b.cov, *leg)[0]
        assert g == pytest.approx(np.sum(A[roi] ** 2), rel=1e-10)
