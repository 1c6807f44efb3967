"""Camera model against the maths: footprint 2 h tan(30 deg), noise a(1 - e^{-bh}), binning."""

import math

import numpy as np
import pytest

from ipp_bench.core.config import GridConfig, SensorConfig
from ipp_bench.core.sensor import Sensor, stack


@pytest.fixture
def sensor():
    return Sensor(GridConfig(15, 15, 2.5), SensorConfig())


@pytest.mark.parametrize("h, side", [(8.0, 9.2376), (14.0, 16.1658)])
def test_footprint_side(sensor, h, side):
    assert sensor.footprint_side(h) == pytest.approx(2 * h * math.tan(math.radians(30)))
    assert sensor.footprint_side(h) == pytest.approx(side, abs=1e-4)


@pytest.mark.parametrize("h, var", [(8.0, 0.0399), (14.0, 0.0470)])
def test_noise_variance(sensor, h, var):
    assert sensor.noise_variance(h) == pytest.approx(0.05 * (1 - math.exp(-0.2 * h)))
    assert sensor.noise_variance(h) == pytest.approx(var, abs=1e-4)


def test_cells_inside_footprint_at_8m(sensor):
    # centre of cell (7, 7): half side 4.62 m covers centres at +-2.5 m, not +-5 m -> 3 x 3 cells
    obs = sensor.observe((18.75, 18.75, 8.0))
    assert obs.cells.size == 9 and obs.m == 9
    np.testing.assert_array_equal(obs.weights, np.eye(9))
    rows, cols = np.divmod(obs.cells, 15)
    assert set(rows) == {6, 7, 8} and set(cols) == {6, 7, 8}
    np.testing.assert_allclose(obs.var, sensor.noise_variance(8.0))


def test_binning_at_14m(sensor):
    # half side 8.08 m covers +-7.5 m -> 7 x 7 cells, read as 2 x 2 blocks -> 4 x 4 measurements
    obs = sensor.observe((18.75, 18.75, 14.0))
    assert obs.cells.size == 49 and obs.m == 16
    np.testing.assert_allclose(obs.weights.sum(axis=1), 1.0)
    full = obs.weights[0][obs.weights[0] > 0]
    np.testing.assert_allclose(full, 0.25)  # interior blocks hold 1/4 on each of 4 cells
    assert sorted((obs.weights > 0).sum(axis=1)) == [1] + [2] * 6 + [4] * 9
    # below the binning altitude there is no binning
    assert not sensor.binned(10.0) and sensor.binned(10.01)


def test_footprint_clipped_to_map(sensor):
    obs = sensor.observe((1.25, 1.25, 14.0))  # corner cell (0, 0)
    rows, cols = np.divmod(obs.cells, 15)
    assert rows.min() == 0 and cols.min() == 0 and rows.max() == 3 and cols.max() == 3
    assert sensor.observe((-50.0, -50.0, 8.0)) is None
    assert sensor.matrix((-50.0, -50.0, 8.0)).shape == (0, 225)


def test_dense_matrix_and_measurement_statistics(sensor):
    truth = np.linspace(0, 1, 225)
    H = sensor.matrix((18.75, 18.75, 14.0))
    assert H.shape == (16, 225)
    rng = np.random.default_rng(0)
    zs = np.array([sensor.measure((18.75, 18.75, 14.0), truth, rng)[1] for _ in range(4000)])
    np.testing.assert_allclose(zs.mean(axis=0), H @ truth, atol=0.02)  # 5 sigma of the mean
    np.testing.assert_allclose(zs.var(axis=0), sensor.noise_variance(14.0), rtol=0.1)


def test_stack_joins_observations(sensor):
    a = sensor.observe((18.75, 18.75, 8.0))
    b = sensor.observe((21.25, 18.75, 8.0))
    cells, W, var = stack([a, b])
    H = np.zeros((W.shape[0], 225))
    H[:, cells] = W
    np.testing.assert_array_equal(H, np.vstack([a.dense(225), b.dense(225)]))
    assert var.shape == (18,)


def test_nonpositive_altitude_is_an_error(sensor):
    with pytest.raises(ValueError, match="above the ground"):
        sensor.observe((5.0, 5.0, 0.0))


@pytest.mark.parametrize("e", [0.0, 3.0])
def test_binned_noise_is_f_to_the_e_times_the_altitude_law(e):
    """The lineage's law: a read-out at resolution factor f has variance f^e a (1 - e^{-bh})."""
    sensor = Sensor(GridConfig(15, 15, 2.5), SensorConfig(binning_noise_exponent=e))
    law = {h: 0.05 * (1 - math.exp(-0.2 * h)) for h in (8.0, 14.0)}
    assert sensor.noise_variance(8.0) == pytest.approx(law[8.0])  # f = 1 below 10 m
    assert sensor.noise_variance(14.0) == pytest.approx(2.0 ** e * law[14.0])
    if e == 3.0:  # the figures of REFERENCE.md: 0.040 at 8 m, 0.376 for a 14 m block mean
        assert sensor.noise_variance(8.0) == pytest.approx(0.0399, abs=1e-4)
        assert sensor.noise_variance(14.0) == pytest.approx(0.3757, abs=1e-4)
    obs = sensor.observe((18.75, 18.75, 14.0))
    np.testing.assert_allclose(obs.var, 2.0 ** e * law[14.0])
