"""The Kalman update against the batch GP posterior (paper eqs. 2 and 3)."""

import numpy as np
import pytest

from ipp_bench.core.belief import GPBelief, cell_centres, matern32


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
    rng = np.random.default_rng(11)
    b = GPBelief.from_grid((8, 8))
    for i in range(96):
        cells = np.sort(rng.choice(64, size=4, replace=False))
        b.update_local(cells, np.full((1, 4), 0.25), rng.normal(size=1), np.array([0.04]))
        if i % 7 == 0:  # read whole now and then: exactly symmetric every time
            np.testing.assert_array_equal(b.cov, b.cov.T)
    np.testing.assert_array_equal(b.cov, b.cov.T)
    assert np.linalg.eigvalsh(b.cov).min() > -1e-12


def test_lower_triangle_updates_equal_the_whole_product_over_3000_updates():
    """The belief downdates only its lower triangle (syrk) and reads P[:, cells] from it: over 3000 updates
    of a 30 x 30 prior its covariance, variances and mean stay within 1e-12 (relative to the prior's
    variance) of the whole-matrix update (gemm, then (P + P^T) / 2 every 32 updates, as before), and the
    covariance stays positive definite."""
    from ipp_bench.core.belief import cho_solve, downdate_inplace, gain_factor

    rng = np.random.default_rng(3)
    b = GPBelief.from_grid((30, 30), 2.5, 8.162, 0.0804, 0.5, 0.001959)
    P, mu = b.cov.copy(), b.mean.copy()
    scale = P[0, 0]
    for i in range(3000):
        q = int(rng.integers(1, 40))
        cells = np.sort(rng.choice(900, size=q, replace=False))
        m = int(rng.integers(1, q + 1))
        W = rng.random((m, q)) * (rng.random((m, q)) < 0.5)
        W[np.arange(m), rng.integers(0, q, m)] += 0.1
        z, R = rng.normal(size=m), rng.uniform(0.001, 0.05, m)
        b.update_local(cells, W, z, R)
        A, L, C = gain_factor(P, cells, W, R)
        mu += C @ cho_solve((L, True), z - W @ mu[cells])
        downdate_inplace(P, A)
        if (i + 1) % 32 == 0:
            P[...] = (P + P.T) / 2
        if i % 500 == 499:
            assert np.abs(b.variance - np.maximum(np.diag(P), 0)).max() < 1e-12 * scale
    assert np.abs(b.mean - mu).max() < 1e-9
    assert np.abs(b.cov - P).max() < 1e-12 * scale
    assert np.array_equal(b.cov, b.cov.T)
    np.linalg.cholesky(b.cov)  # positive definite (nugget on the diagonal)


def test_columns_and_trace_reductions_read_the_lower_triangle_right():
    """Between updates the upper triangle lags; what the belief reads from the lower one equals the whole matrix's."""
    from ipp_bench.core.belief import LegBatch, trace_reductions

    rng = np.random.default_rng(5)
    b = GPBelief.from_grid((12, 12), 2.5, 6.0, 0.1, 0.5, 0.002)
    b.update_local(np.array([3, 4, 15, 16]), np.full((1, 4), 0.25), np.array([0.7]), np.array([0.01]))
    assert b._upper_stale
    cells = np.array([0, 5, 16, 80, 143])
    legs = [(np.array([1, 2, 13]), np.array([[0.5, 0.25, 0.25]]), np.array([0.02])), None,
            (np.array([100, 101]), np.eye(2), np.array([0.03, 0.03]))]
    roi = rng.random(144) > 0.5
    lazy_cols, lazy_red = b.columns(cells), b.trace_reductions(legs, roi)
    assert b._upper_stale
    whole = b.cov  # copies the lower triangle over
    assert not b._upper_stale
    np.testing.assert_array_equal(lazy_cols, whole[:, cells])
    np.testing.assert_array_equal(lazy_red, trace_reductions(whole, LegBatch(legs), roi))
    assert lazy_red[1] == 0 and lazy_red[0] > 0


def test_batched_trace_reductions_match_one_by_one():
    from ipp_bench.core.belief import LegBatch, gain_factor, trace_reductions

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


# -- the camera's persistent error as states (PersistentErrorBelief) ---------------------------------

def _camera_model(floor=0.3, corr=0.7, neighbour=0.0):
    from ipp_bench.core.config import GridConfig, SensorConfig
    from ipp_bench.core.sensor import Sensor

    grid = GridConfig(6, 7, 2.5)
    cfg = SensorConfig(noise_a=0.004, noise_b=0.1, binning_altitude=10.0, binning=2, binning_noise_exponent=-1.0,
                       persistent_var=0.01, persistent_var_binned=0.03, persistent_corr=corr, noise_floor=floor,
                       persistent_neighbour_corr=neighbour)
    return grid, cfg, Sensor(grid, cfg)


def _phi(t, k):
    t = min(max(t, 0.0), 1.0)
    return k + (1 - k) * 4 * t * (1 - t)


@pytest.mark.parametrize("neighbour", [0.0, 0.59])
@pytest.mark.parametrize("seed", range(4))
def test_persistent_error_states_equal_the_batch_posterior(seed, neighbour):
    """Sequential augmented updates = the batch GP posterior of the field under the marginal
    covariance of z = H x + E e + v, built here from the model's definition (not from the code):
    e_f,c = sqrt(s_f phi(t_c)) u_f,c, corr(u_f,c, u_g,c') = r^(d_cc'^2) (rho if f != g)."""
    from ipp_bench.core.belief import PersistentErrorBelief

    rng = np.random.default_rng(seed)
    grid, cfg, sensor = _camera_model(neighbour=neighbour)
    field = GPBelief.from_grid((grid.rows, grid.cols), grid.resolution, 6.0, 0.2, 0.5, 1e-4)
    mean0, K = field.mean.copy(), field.cov.copy()
    model = PersistentErrorBelief(field, cfg)
    n = field.n
    spots = [(rng.uniform(2, 15), rng.uniform(2, 13), h) for h in (8.0, 14.0) for _ in range(2)]
    rows = []  # (factor, cells, w, z, white)
    for _ in range(3):  # batches; positions repeat, so cells are re-read at both factors
        batch = [sensor.observe(spots[i]) for i in rng.choice(len(spots), 3)]
        zs = [rng.uniform(0.0, 1.0, o.m) for o in batch]
        model.update(batch, zs)
        for o, z in zip(batch, zs):
            white = cfg.noise_a * (1 - np.exp(-cfg.noise_b * o.altitude)) * (o.factor ** cfg.binning_noise_exponent
                                                                              if o.factor > 1 else 1.0)
            rows += [(o.factor, o.cells[w > 0], w[w > 0], zi, white) for w, zi in zip(o.weights, z)]
    # the model's definition: per-cell error prior from the value of the row that first saw the cell
    first = {}
    for _, cells, _, zi, _ in rows:
        for c in cells:
            first.setdefault(int(c), zi)
    m = len(rows)
    H, E = np.zeros((m, n)), np.zeros((m, 2 * n))  # E: rows on (e_1, e_2)
    z, R = np.zeros(m), np.zeros(m)
    for i, (f, cells, w, zi, white) in enumerate(rows):
        H[i, cells] = w
        E[i, cells + (0 if f == 1 else n)] = w
        z[i], R[i] = zi, white * _phi(zi, cfg.noise_floor)
    Se = np.zeros((2 * n, 2 * n))
    for c, t in first.items():
        for d, t2 in first.items():
            (rc, cc), (rd, cd) = divmod(c, grid.cols), divmod(d, grid.cols)
            space = neighbour ** ((rc - rd) ** 2 + (cc - cd) ** 2) if neighbour else float(c == d)
            for i, si in enumerate((cfg.persistent_var, cfg.persistent_var_binned)):
                for j, sj in enumerate((cfg.persistent_var, cfg.persistent_var_binned)):
                    rho = 1.0 if i == j else cfg.persistent_corr
                    Se[i * n + c, j * n + d] = rho * space * np.sqrt(si * _phi(t, cfg.noise_floor) * sj
                                                                     * _phi(t2, cfg.noise_floor))
    mean_b, cov_b = batch_posterior(mean0, K, H, z, E @ Se @ E.T + np.diag(R))
    np.testing.assert_allclose(field.mean, mean_b, rtol=0, atol=1e-9)
    np.testing.assert_allclose(field.cov, cov_b, rtol=0, atol=1e-10)


def test_without_persistent_error_the_camera_model_is_the_plain_update():
    from ipp_bench.core.belief import PersistentErrorBelief
    from ipp_bench.core.config import GridConfig, SensorConfig
    from ipp_bench.core.sensor import Sensor, stack

    grid = GridConfig(6, 7, 2.5)
    sensor = Sensor(grid, SensorConfig(noise_a=0.004, noise_b=0.1))
    a = GPBelief.from_grid((6, 7), 2.5)
    b = a.copy()
    model = PersistentErrorBelief(b, sensor.cfg)
    obs = [sensor.observe((5.0, 6.0, 8.0)), sensor.observe((9.0, 6.0, 14.0))]
    zs = [np.full(o.m, 0.3) for o in obs]
    model.update(obs, zs)
    cells, W, var = stack(obs)
    a.update_local(cells, W, np.concatenate(zs), var)
    np.testing.assert_allclose(b.mean, a.mean, atol=1e-12)
    np.testing.assert_allclose(b.cov, a.cov, atol=1e-12)


def test_nis_is_chi_square_with_the_error_states_and_not_without():
    """Errors that repeat at every look: with them as states, the summed NIS of all updates is
    chi-square (innovations are independent under the true model) and falls inside its two-sided
    99.9 % interval; treating the same variance as fresh noise per look (the v1 model before) it
    falls below it: the test can fail."""
    from scipy.stats import chi2

    from ipp_bench.core.belief import PersistentErrorBelief, normalised_innovation
    from ipp_bench.core.sensor import stack

    grid, cfg, sensor = _camera_model(floor=1.0, corr=0.7)
    rng = np.random.default_rng(7)
    spots = [(8.0, 7.0, 8.0), (10.0, 8.0, 8.0), (9.0, 7.5, 14.0)]
    totals = {"states": [0.0, 0], "white": [0.0, 0]}
    for _ in range(60):
        field = GPBelief.from_grid((grid.rows, grid.cols), grid.resolution, 6.0, 0.2, 0.5, 1e-4)
        x = rng.multivariate_normal(field.mean, field.cov)
        n = field.n
        s1, s2 = cfg.persistent_var, cfg.persistent_var_binned
        c = cfg.persistent_corr * np.sqrt(s1 * s2)
        e = rng.multivariate_normal([0, 0], [[s1, c], [c, s2]], size=n)  # (n, 2): per cell, both factors
        model, plain = PersistentErrorBelief(field, cfg), field.copy()
        for _ in range(6):  # the same spots again and again
            obs = [sensor.observe(p) for p in spots]
            zs = [o.weights @ (x[o.cells] + e[o.cells, 0 if o.factor == 1 else 1])
                  + rng.normal(0, np.sqrt(o.var - o.persistent)) for o in obs]
            nis, dof = model.normalised_innovation(obs, zs)
            totals["states"][0] += nis
            totals["states"][1] += dof
            model.update(obs, zs)
            cells, W, var = stack(obs)
            nis, dof = normalised_innovation(plain, cells, W, np.concatenate(zs), var)
            totals["white"][0] += nis
            totals["white"][1] += dof
            plain.update_local(cells, W, np.concatenate(zs), var)
    nis, dof = totals["states"]
    assert chi2.ppf(0.0005, dof) <= nis <= chi2.ppf(0.9995, dof), nis / dof
    nis, dof = totals["white"]
    assert nis < chi2.ppf(0.0005, dof), nis / dof  # repeated looks agree more than white noise would


def test_nis_is_chi_square_when_neighbouring_cells_share_their_error_and_not_if_taken_independent():
    """Errors drawn with neighbouring cells correlated (r = 0.59, the camera's measured value): the
    belief that models it gives a chi-square NIS (two-sided 99.9 %); the belief that takes the cells'
    errors as independent (r = 0) sees binned read-outs disagree more than it predicts, above it."""
    from scipy.stats import chi2

    from ipp_bench.core.belief import PersistentErrorBelief
    from ipp_bench.core.sensor import persistent_correlation

    r = 0.59
    grid, cfg, sensor = _camera_model(floor=1.0, corr=0.7, neighbour=r)
    _, cfg0, sensor0 = _camera_model(floor=1.0, corr=0.7, neighbour=0.0)
    rng = np.random.default_rng(11)
    spots = [(9.0, 7.5, 14.0), (6.0, 9.0, 14.0), (8.0, 7.0, 8.0)]
    rows, cols = np.divmod(np.arange(grid.n_cells), grid.cols)
    C = persistent_correlation(rows, cols, r)
    s1, s2 = cfg.persistent_var, cfg.persistent_var_binned
    c12 = cfg.persistent_corr * np.sqrt(s1 * s2)
    joint = np.block([[s1 * C, c12 * C], [c12 * C, s2 * C]])
    totals = {"modelled": [0.0, 0], "independent": [0.0, 0]}
    for _ in range(60):
        field = GPBelief.from_grid((grid.rows, grid.cols), grid.resolution, 6.0, 0.001, 0.5, 1e-5)  # errors dominate
        x = rng.multivariate_normal(field.mean, field.cov)
        n = field.n
        e = rng.multivariate_normal(np.zeros(2 * n), joint)
        models = {"modelled": (PersistentErrorBelief(field, cfg), sensor),
                  "independent": (PersistentErrorBelief(field.copy(), cfg0), sensor0)}
        for _ in range(4):
            obs = [sensor.observe(p) for p in spots]
            zs = [o.weights @ (x[o.cells] + e[o.cells + (0 if o.factor == 1 else n)])
                  + rng.normal(0, np.sqrt(o.var - o.persistent)) for o in obs]
            for name, (model, sens) in models.items():
                own = [sens.observe(p) for p in spots]  # each belief's own sensor model of the same read-outs
                nis, dof = model.normalised_innovation(own, zs)
                totals[name][0] += nis
                totals[name][1] += dof
                model.update(own, zs)
    nis, dof = totals["modelled"]
    assert chi2.ppf(0.0005, dof) <= nis <= chi2.ppf(0.9995, dof), nis / dof
    nis, dof = totals["independent"]
    assert nis > chi2.ppf(0.9995, dof), nis / dof


def test_predicted_belief_is_the_covariance_after_the_read_outs_without_forming_it():
    """PredictedBelief = a copy updated with the read-outs (any values): covariance, rows, variances
    and the legs' trace reductions; the mean stays today's."""
    from ipp_bench.core.belief import LegBatch, PredictedBelief
    from ipp_bench.core.config import GridConfig, SensorConfig
    from ipp_bench.core.sensor import Sensor, stack

    belief = GPBelief.from_grid((12, 12), 2.5, 6.0, 0.05, 0.1, 0.001)
    sensor = Sensor(GridConfig(rows=12, cols=12, resolution=2.5), SensorConfig())
    coming = [sensor.observe(np.array(p)) for p in ([5.0, 5.0, 8.0], [12.0, 9.0, 14.0], [20.0, 20.0, 8.0])]
    predicted = PredictedBelief(belief, coming)
    updated = belief.copy()
    cells, W, var = stack(coming)
    updated.update_local(cells, W, np.full(W.shape[0], 0.7), var)
    np.testing.assert_allclose(predicted.cov, updated.cov, atol=1e-14)
    np.testing.assert_allclose(predicted.rows(np.array([3, 40])), updated.cov[[3, 40], :], atol=1e-14)
    np.testing.assert_allclose(predicted.variance, updated.variance, atol=1e-14)
    np.testing.assert_array_equal(predicted.mean, belief.mean)
    legs = [(o.cells, o.weights, o.var) for o in (sensor.observe(np.array(p)) for p in
                                                ([7.5, 5.0, 8.0], [2.0, 25.0, 14.0]))] + [None]
    roi = np.arange(belief.n) % 3 == 0
    np.testing.assert_allclose(predicted.trace_reductions(LegBatch(legs), roi),
                               updated.trace_reductions(LegBatch(legs), roi), rtol=1e-10, atol=1e-15)


def test_cached_prior_equals_a_fresh_build_and_is_never_written():
    """Every episode's prior is a writable copy of one read-only covariance, equal bit for bit to the
    kernel built afresh; updating a belief leaves the kept prior and the next episode's belief as built."""
    from ipp_bench.core.belief import grid_prior_covariance, prior_covariance

    args = ((30, 30), 2.5, 8.162, 0.0804, 0.001959)
    fresh = prior_covariance(cell_centres((30, 30), 2.5), 8.162, 0.0804, 0.001959)
    kept = grid_prior_covariance(*args)
    assert np.array_equal(kept, fresh) and not kept.flags.writeable
    assert grid_prior_covariance(*args) is kept
    a = GPBelief.from_grid((30, 30), 2.5, 8.162, 0.0804, 0.5, 0.001959)
    assert a.cov.flags.writeable and not np.shares_memory(a.cov, kept)
    a.update(np.eye(900)[:3], np.ones(3), np.full(3, 0.01))
    b = GPBelief.from_grid((30, 30), 2.5, 8.162, 0.0804, 0.5, 0.001959)
    assert np.array_equal(b.cov, fresh) and np.array_equal(kept, fresh)
    assert not np.array_equal(a.cov, fresh)
