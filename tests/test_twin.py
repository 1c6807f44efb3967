"""The graph twin's sensor draws the calibrated camera error: checked against the model's moments."""

import math

import gymnasium as gym
import numpy as np
import pytest

import ipp_bench.envs  # noqa: F401
from ipp_bench.core.belief import value_scale
from ipp_bench.core.legs import continuous_durations
from ipp_bench.core.mission import Mission, cell_to_xyz
from ipp_bench.core.twin import CameraErrorLegs

TASK = "ipp_bench/Weed15Twin-v1"


def _mission(seed: int, corr: float = 0.59, tilt_sd_deg: float = 0.0):
    """A twin mission; level camera by default (the error draws' tests), tilted as the deployment's if asked."""
    cfg = ipp_bench.envs.task_spec(TASK).config
    truth = np.random.default_rng(seed).random((15, 15))
    return Mission(cfg, truth, np.random.default_rng(seed + 1), cell_to_xyz(cfg, 2, 2, 14.0),
                   platform=CameraErrorLegs(corr, tilt_sd_deg=tilt_sd_deg))


def test_a_tilted_frame_misses_the_cells_at_its_edge_on_one_side():
    """A camera tilted about one axis looks away from where the thrust tilts: its frame moves by about
    h tan(tilt) on the ground, so the footprint's cells on the far side fall outside (seen < 50 %) and
    their rows are dropped, as the deployment's camera drops them; level, every footprint cell is seen."""
    m = _mission(0)
    p = cell_to_xyz(m.config, 7, 7, 14.0)
    cells = m.sensor.observe(p).cells
    level = m.platform._seen(m, p, np.zeros(2), cells)
    assert level[cells].all()
    tilted = m.platform._seen(m, p, np.array([math.radians(8.0), 0.0]), cells)  # body z toward +x
    missed = cells[~tilted[cells]]
    cols, edge = missed % m.config.grid.cols, cells.max() % m.config.grid.cols
    assert missed.size > 0 and cols.min() > 7  # the frame moved toward -x (by 14 tan 8 deg = 1.97 m)
    assert np.isin(cells[cells % m.config.grid.cols == edge], missed).all()  # the whole +x edge column
    # the deployment drops 25-34 % of the rows of its 14 m read-outs (docs/decisions/camera-error.md):
    # with the twin's tilt spread, about as many
    mt = _mission(0, tilt_sd_deg=4.6)
    rows = [(mt.sensor.observe(p).m, mt.platform._read(mt, [p], [0.0])[0][0]) for _ in range(200)]
    share = 1.0 - sum(0 if o is None else o.m for _, o in rows) / sum(n for n, _ in rows)
    assert 0.15 <= share <= 0.45, share


def test_persistent_errors_have_the_models_variance_and_correlations():
    cfg = ipp_bench.envs.task_spec(TASK).config.sensor
    e1, e2 = [], []
    for s in range(400):
        m = _mission(s)
        scale = value_scale(m._truth_flat, cfg.noise_floor)
        e1.append(m.platform.errors[1] / np.sqrt(cfg.persistent_var * scale))
        e2.append(m.platform.errors[2] / np.sqrt(cfg.persistent_var_binned * scale))
    e1, e2 = np.array(e1), np.array(e2)
    # unit variance after the model's scaling, the two factors correlated by persistent_corr,
    # edge-neighbours by neighbour_corr, cells two apart by neighbour_corr^4 (squared exponential)
    assert e1.var() == pytest.approx(1.0, abs=0.03) and e2.var() == pytest.approx(1.0, abs=0.03)
    assert np.mean(e1 * e2) == pytest.approx(cfg.persistent_corr, abs=0.02)
    c, right, two = 7 * 15 + 7, 7 * 15 + 8, 7 * 15 + 9
    assert np.mean(e2[:, c] * e2[:, right]) == pytest.approx(0.59, abs=0.08)
    assert np.mean(e2[:, c] * e2[:, two]) == pytest.approx(0.59 ** 4, abs=0.08)


def test_a_repeated_look_repeats_the_persistent_error_and_a_binned_block_is_no_better_than_its_cells():
    m = _mission(0)
    p = cell_to_xyz(m.config, 7, 7, 14.0)
    obs = m.sensor.observe(p)
    (o, z1, _), = m.platform._read(m, [p], [0.0])
    (_, z2, _), = m.platform._read(m, [p], [0.0])
    clean = o.weights @ m._truth_flat[o.cells]
    shared = o.weights @ m.platform.errors[o.factor][o.cells]
    white_sd = np.sqrt((obs.var - obs.persistent) * value_scale(clean, m.sensor.cfg.noise_floor))
    # what the two looks have in common is the persistent error; they differ by white noise only
    assert np.abs((z1 + z2) / 2 - clean - shared).max() < 4 * white_sd.max()
    assert np.abs(z1 - z2).max() < 6 * white_sd.max()
    # a binned block (2 x 2, edge-neighbours 0.59, diagonal 0.59^2) keeps (4 + 8 * 0.59 + 4 * 0.59^2) / 16
    # = 0.63 of its cells' persistent variance, where independent errors would keep 1/4
    cfg = m.sensor.cfg
    block = o.weights[0] > 0
    means = []
    for s in range(400):
        mm = _mission(s)
        u = mm.platform.errors[2] / np.sqrt(cfg.persistent_var_binned * value_scale(mm._truth_flat, cfg.noise_floor))
        means.append(u[o.cells[block]].mean())
    expected = (4 + 8 * 0.59 + 4 * 0.59 ** 2) / 16
    assert block.sum() == 4 and np.var(means) == pytest.approx(expected, abs=0.1)


def test_the_twin_flies_the_deployments_clock():
    m = _mission(3)
    ends = np.array([cell_to_xyz(m.config, 6, 2, 14.0), cell_to_xyz(m.config, 2, 6, 8.0)])
    np.testing.assert_array_equal(m.leg_durations(m.position, ends),
                                  continuous_durations(m.position, np.zeros(3), ends, 2.0, 1.0))
    leg = m.fly_to(ends[0])
    assert leg.duration_s == pytest.approx(continuous_durations(cell_to_xyz(m.config, 2, 2, 14.0), np.zeros(3),
                                                                ends[:1], 2.0, 1.0)[0])
    # turning straight back costs the 2 s of the ramps, as in MuJoCo (v1)
    back = m.leg_durations(m.position, cell_to_xyz(m.config, 2, 2, 14.0))[0]
    assert back == pytest.approx(2.0 * 1.0 + 10.0 / 2.0, abs=1e-6)
    assert m.n_measurements > 0 and math.isclose(m.time_s, leg.duration_s)


def test_the_twin_task_is_registered_and_bad_neighbour_corr_is_one_line():
    env = gym.make(TASK).unwrapped
    assert "twin" in ipp_bench.envs.task_spec(TASK).tags
    assert ipp_bench.envs.task_spec(TASK).config == ipp_bench.envs.task_spec("MuJoCoWeed15-v1").config
    assert TASK not in ipp_bench.envs.tagged("benchmark")
    env.reset(seed=0)
    assert type(env.mission.platform) is CameraErrorLegs
    with pytest.raises(ValueError, match=r"neighbour_corr = 1.5 is invalid: expected a number in \[0, 1\)"):
        gym.make(TASK, neighbour_corr=1.5)


@pytest.mark.parametrize("kwargs, message", [
    ({"tilt_sd_deg": -1.0}, r"tilt_sd_deg = -1.0 is invalid: expected a number in \[0, 30\) degrees"),
    ({"min_coverage": 0.0}, r"min_coverage = 0.0 is invalid: expected a number in \(0, 1\]"),
])
def test_bad_frame_settings_are_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CameraErrorLegs(**kwargs)
