"""WindowBelief (the belief for large grids) against the dense formula: exact where its window covers
the grid, the windowed model's own dense formula where it does not, and the dense GP within the
stated tolerances after a whole flight on 30 x 30 with the v1 and v2 priors."""

import numpy as np
import pytest

from ipp_bench.core.belief import GPBelief, LegBatch, trace_reductions
from ipp_bench.core.belief_window import WindowBelief, window_for
from ipp_bench.core.config import GridConfig, SensorConfig
from ipp_bench.core.sensor import Sensor, stack

# (length_scale [m], signal_variance, nugget, prior_mean) of tasks/grid30_eval_v1.toml and hotspots30_eval_v2.toml
PRIORS = {"v1": (8.162, 0.0804, 0.001959, 0.5), "v2": (6.931, 0.01789, 0.0006774, 0.03697)}
V1_CAMERA = SensorConfig(noise_a=0.05, noise_b=0.2, binning_altitude=10.0, binning=2, binning_noise_exponent=3.0)


def batch_posterior(mean0, K, H, z, R):
    """Batch GP posterior of f given z = H f + v, v ~ N(0, R): the textbook formula."""
    S = H @ K @ H.T + R
    G = K @ H.T @ np.linalg.inv(S)
    return mean0 + G @ (z - H @ mean0), K - G @ H @ K


def full_cov(b: WindowBelief) -> np.ndarray:
    cells = np.arange(b.n)
    return b.covariance(cells, cells)


def window_mask(shape, w) -> np.ndarray:
    r, c = np.divmod(np.arange(shape[0] * shape[1]), shape[1])
    return (np.abs(r[:, None] - r[None, :]) <= w) & (np.abs(c[:, None] - c[None, :]) <= w)


def flight(shape, n_looks, seed, per_batch=3):
    """A realistic read-out sequence: a random walk in 7.5 m steps at 8 or 14 m, looks in batches of 1-3."""
    rng = np.random.default_rng(seed)
    sensor = Sensor(GridConfig(rows=shape[0], cols=shape[1], resolution=2.5), V1_CAMERA)
    size = np.array([shape[1], shape[0]]) * 2.5
    xy = np.array([5.0, 5.0])
    looks = []
    for _ in range(n_looks):
        step = rng.normal(size=2)
        xy = np.clip(xy + 7.5 * step / np.linalg.norm(step), 1.0, size - 1.0)
        looks.append(sensor.observe((xy[0], xy[1], float(rng.choice([8.0, 14.0])))))
    batches = []
    while looks:
        k = int(rng.integers(1, per_batch + 1))
        cells, W, var = stack(looks[:k])
        batches.append((cells, W, var))
        looks = looks[k:]
    return batches


def values(rng, batch, mean):
    return mean + rng.normal(0.0, 0.3, batch[1].shape[0])


def test_prior_is_the_kernel_within_the_window():
    shape, w = (7, 9), 3
    dense = GPBelief.from_grid(shape, 2.5, 4.0, 1.3, 0.2, nugget=0.01)
    b = WindowBelief.from_grid(shape, 2.5, 4.0, 1.3, 0.2, nugget=0.01, window=w)
    mask = window_mask(shape, w)
    np.testing.assert_allclose(full_cov(b), np.where(mask, dense.cov, 0.0), rtol=1e-14, atol=0)
    np.testing.assert_allclose(b.variance, np.diag(dense.cov))
    assert b.mean.shape == (63,) and np.all(b.mean == 0.2)


def test_default_window_covers_four_length_scales():
    assert window_for(8.162, 2.5) == 14 and window_for(6.931, 2.5) == 12
    assert WindowBelief.from_grid((20, 20), 2.5, 6.931, 0.018).window == 12


@pytest.mark.parametrize("seed", range(3))
def test_exact_when_the_window_covers_the_grid(seed):
    """w >= the grid: no truncation, so sequential grouped updates equal the batch GP posterior."""
    rng = np.random.default_rng(seed)
    shape = (6, 8)
    b = WindowBelief.from_grid(shape, 2.5, 3.67, 1.82, 0.5, nugget=0.02, window=8, group_span=2)
    mean0, K = b.mean.copy(), full_cov(b)
    Hs, zs, Rs = [], [], []
    for _ in range(5):
        m = int(rng.integers(1, 6))
        cells = np.sort(rng.choice(b.n, size=int(rng.integers(m, 9)), replace=False))
        W = rng.uniform(0.1, 1.0, (m, cells.size)) * (rng.random((m, cells.size)) < 0.6)
        W[np.arange(m), rng.integers(0, cells.size, m)] = 0.5  # no empty row
        used = np.any(W != 0, axis=0)
        cells, W = cells[used], W[:, used]
        z, R = rng.normal(0.5, 0.5, m), rng.uniform(0.01, 0.1, m)
        b.update_local(cells, W, z, R)
        H = np.zeros((m, b.n))
        H[:, cells] = W
        Hs.append(H), zs.append(z), Rs.append(R)
    mean_b, cov_b = batch_posterior(mean0, K, np.vstack(Hs), np.concatenate(zs), np.diag(np.concatenate(Rs)))
    np.testing.assert_allclose(b.mean, mean_b, rtol=0, atol=1e-10)
    np.testing.assert_allclose(full_cov(b), cov_b, rtol=0, atol=1e-10)


def test_windowed_model_equals_its_dense_formula():
    """w < the grid: the update equals, to round-off, the dense Kalman update of the covariance
    masked to the window (gain from the masked P, downdate masked to the window)."""
    shape, w = (16, 13), 4
    rng = np.random.default_rng(11)
    b = WindowBelief.from_grid(shape, 2.5, 5.0, 0.08, 0.5, nugget=0.002, window=w, group_span=100)
    M = window_mask(shape, w)
    mean, P = b.mean.copy(), full_cov(b)
    for cells, W, var in flight(shape, 12, seed=5, per_batch=1):
        z = values(rng, (cells, W, var), 0.5)
        b.update_local(cells, W, z, var)
        H = np.zeros((W.shape[0], b.n))
        H[:, cells] = W
        C = P @ H.T
        S = H @ C + np.diag(var)
        mean = mean + C @ np.linalg.solve(S, z - H @ mean)
        A = C @ np.linalg.inv(np.linalg.cholesky(S)).T
        P = np.where(M, P - A @ A.T, 0.0)
    np.testing.assert_allclose(b.mean, mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(full_cov(b), P, rtol=0, atol=1e-12)


def _flown_pair(prior, rng, n_looks, seed):
    """The dense and the window belief of a 30 x 30 prior after the same flight and the same values."""
    ls, sv, nugget, mu = PRIORS[prior]
    dense = GPBelief.from_grid((30, 30), 2.5, ls, sv, mu, nugget)
    win = WindowBelief.from_grid((30, 30), 2.5, ls, sv, mu, nugget)
    for cells, W, var in flight((30, 30), n_looks, seed=seed):
        z = values(rng, (cells, W, var), mu)
        dense.update_local(cells, W, z, var)
        win.update_local(cells, W, z, var)
    return dense, win


@pytest.mark.parametrize("prior", ["v1", "v2"])
def test_agrees_with_dense_gp_after_a_whole_flight(prior):
    """On 30 x 30, variances within 2 % (relative) and means within 0.01 of the dense GP."""
    _, sv, _, mu = PRIORS[prior]
    dense, win = _flown_pair(prior, np.random.default_rng(3), n_looks=80, seed=1)
    assert dense.variance.min() < 0.2 * sv  # the flight did measure: many cells well below the prior
    rel = np.abs(win.variance / dense.variance - 1.0)
    assert rel.max() <= 0.02, f"max relative variance error {rel.max():.4f}"
    assert np.abs(win.mean - dense.mean).max() <= 0.01
    # and the agreement is not the prior's: the mean moved by more than the tolerance
    assert np.abs(dense.mean - mu).max() > 0.05


def _legs(sensor, rng, n_legs):
    legs = []
    for _ in range(n_legs):
        a = rng.uniform(2, 73, 2)
        h = float(rng.choice([8.0, 14.0]))
        b = np.clip(a + rng.normal(0, 8, 2), 1, 74)
        looks = [sensor.observe((*(a + t * (b - a)), h)) for t in (0.0, 0.5, 1.0)]
        legs.append(stack(looks))
    return legs + [None]


@pytest.mark.parametrize("prior", ["v1", "v2"])
def test_trace_reductions_agree_with_dense(prior):
    rng = np.random.default_rng(4)
    dense, win = _flown_pair(prior, rng, n_looks=40, seed=2)
    sensor = Sensor(GridConfig(rows=30, cols=30, resolution=2.5), V1_CAMERA)
    legs = _legs(sensor, rng, 12)
    batch = LegBatch(legs)
    roi = rng.random(900) < 0.5
    ref = trace_reductions(dense.cov, batch, roi)
    got = win.trace_reductions(batch, roi)
    np.testing.assert_allclose(win.trace_reductions(legs, roi), got, rtol=1e-12)  # the list form
    assert got[-1] == 0.0 and ref[-1] == 0.0
    np.testing.assert_allclose(got[:-1], ref[:-1], rtol=0.02)
    assert np.argmax(got) == np.argmax(ref)


def test_predict_variance_local_matches_the_update_and_changes_nothing():
    b = WindowBelief.from_grid((20, 20), 2.5, 6.931, 0.01789, 0.03697, 0.0006774)
    cells, W, var = flight((20, 20), 1, seed=3)[0]
    before_mean, before_band = b.mean.copy(), b.band.copy()
    predicted = b.predict_variance_local(cells, W, var)
    assert np.array_equal(b.mean, before_mean) and np.array_equal(b.band, before_band)
    b.update_local(cells, W, np.zeros(W.shape[0]), var)
    np.testing.assert_allclose(predicted, b.variance, rtol=1e-10, atol=1e-15)
    assert predicted.min() < 0.5 * before_band[..., b.window, b.window].min()


def test_copy_is_independent():
    b = WindowBelief.from_grid((12, 12), 2.5, 6.931, 0.01789, 0.03697, 0.0006774)
    c = b.copy()
    cells, W, var = flight((12, 12), 1, seed=4)[0]
    c.update_local(cells, W, np.full(W.shape[0], 0.4), var)
    fresh = WindowBelief.from_grid((12, 12), 2.5, 6.931, 0.01789, 0.03697, 0.0006774)
    assert np.array_equal(b.mean, fresh.mean) and np.array_equal(b.band, fresh.band)
    assert not np.array_equal(c.variance, b.variance) and not np.array_equal(c.mean, b.mean)


@pytest.mark.parametrize("bad, match", [
    (dict(W=np.ones((2, 3))), r"W has shape \(2, 3\): expected \(m, 4\)"),
    (dict(z=np.zeros(3)), r"z has 3 values but W has 2 rows"),
    (dict(R=np.ones(3)), r"R has shape \(3,\)"),
    (dict(cells=np.array([0, 1, 2, 400])), r"cells must lie in \[0, 144\)"),
    (dict(W=np.array([[1.0, 0, 0, 0], [0, 0, 0, 0]])), r"row of zeros"),
])
def test_bad_input_is_one_clear_value_error(bad, match):
    b = WindowBelief.from_grid((12, 12), 2.5, 6.931, 0.01789)
    args = dict(cells=np.array([0, 1, 12, 13]), W=np.full((2, 4), 0.25), z=np.zeros(2), R=np.full(2, 0.04))
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        b.update_local(args["cells"], args["W"], args["z"], args["R"])
    with pytest.raises(ValueError, match="window = 0 is invalid"):
        WindowBelief.from_grid((12, 12), 2.5, 6.931, 0.01789, window=0)


def test_a_mission_runs_on_the_window_belief():
    """The mission's interface (``update_local`` through its belief model, ``mean``, ``variance``):
    the same flight with the same noise gives the dense belief's report within the tolerances."""
    from ipp_bench.core.mission import Mission
    from ipp_bench.envs import task_config

    cfg = task_config("ipp_bench/Hotspots30Eval-v2")
    g, gp = cfg.grid, cfg.gp
    truth = np.clip(np.random.default_rng(0).normal(0.05, 0.2, (g.rows, g.cols)), 0.0, 1.0)
    missions = [Mission(cfg, truth, np.random.default_rng(1), (5.0, 5.0, 14.0), belief=belief)
                for belief in (GPBelief.prior(g, gp), WindowBelief.prior(g, gp))]
    for x, y, h in [(70, 5, 8), (70, 20, 14), (5, 20, 14), (5, 40, 8), (70, 60, 8)]:
        for m in missions:
            m.fly_to((float(x), float(y), float(h)))
    dense, win = (m.belief for m in missions)
    assert missions[0].n_measurements == missions[1].n_measurements > 300
    assert np.abs(win.variance / dense.variance - 1).max() <= 0.02
    assert np.abs(win.mean - dense.mean).max() <= 0.01
    for a, b in zip(missions[0].report(), missions[1].report()):
        assert a.keys() == b.keys()
        for key in a:
            assert b[key] == pytest.approx(a[key], rel=1e-3, abs=1e-2), key
