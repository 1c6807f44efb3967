"""Ground texture, rendering, HSV threshold and ground projection: the camera as a weed sensor."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from ipp_bench.config import GridConfig, SensorConfig  # noqa: E402
from ipp_bench.fields import make_field  # noqa: E402
from ipp_bench.sensor import Sensor  # noqa: E402
from ipp_bench.sim import gl  # noqa: E402
from ipp_bench.sim.render import SceneRenderer  # noqa: E402
from ipp_bench.sim.texture import weed_mask, weed_texture  # noqa: E402
from ipp_bench.sim.vision import GroundProjector, HSVThreshold, rgb_to_hsv  # noqa: E402
from ipp_bench.sim.world import WeedWorld, restrict  # noqa: E402

GRID = GridConfig()


@pytest.fixture(scope="module")
def world():
    w = WeedWorld(GRID, SensorConfig())
    yield w
    w.close()


def test_texture_has_exact_cell_fractions_and_depends_on_the_seed():
    truth = make_field("weed_patches", GRID, np.random.default_rng(0))
    p = 16
    mask = weed_mask(truth, np.random.default_rng(1), p)
    per_cell = mask.reshape(15, p, 15, p).mean(axis=(1, 3))
    np.testing.assert_allclose(per_cell, np.rint(truth * p * p) / (p * p))
    a, _ = weed_texture(truth, np.random.default_rng(1), p)
    b, _ = weed_texture(truth, np.random.default_rng(1), p)
    c, _ = weed_texture(truth, np.random.default_rng(2), p)
    assert a.dtype == np.uint8 and a.shape == (15 * p, 15 * p, 3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    with pytest.raises(ValueError, match="values in"):
        weed_mask(truth * 2.0 + 0.1, np.random.default_rng(0), p)


def test_threshold_agrees_with_the_hsv_definition():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (200, 200, 3), dtype=np.uint8)
    th = HSVThreshold()
    hsv = rgb_to_hsv(img)
    ref = ((hsv[..., 0] >= th.hue_min) & (hsv[..., 0] <= th.hue_max)
           & (hsv[..., 1] >= th.sat_min) & (hsv[..., 2] >= th.val_min))
    # the threshold works in exact integer arithmetic; float HSV differs only on range borders
    assert np.mean(th(img) != ref) < 1e-3
    texture, mask = weed_texture(make_field("weed_patches", GRID, rng), rng, 16)
    assert np.mean(th(texture) == mask) > 0.97  # on the texels themselves: soil clutter stays out


def test_projection_straight_down_matches_the_footprint():
    proj = GroundProjector(15, 15, 2.5, 128, 128, 60.0)
    cells = proj.pixel_cells(np.array([18.75, 18.75, 8.0]), np.eye(3))
    sensor = Sensor(GRID, SensorConfig())
    obs = sensor.observe([18.75, 18.75, 8.0])
    hit = np.unique(cells[cells >= 0])
    assert set(obs.cells) <= set(hit)  # every cell of the nominal footprint is in the image
    counts = np.bincount(cells[cells >= 0], minlength=225)
    centre = 7 * 15 + 7
    assert counts[centre] == pytest.approx(proj.expected_pixels(8.0), rel=0.1)
    # image row 0 is north (+y), column 0 is west (x small)
    assert cells[0] // 15 > cells[-1] // 15 and cells[0] % 15 < cells[-1] % 15


def test_renderer_is_lazy_and_closes(world):
    r = SceneRenderer(world.scene)
    assert not r.is_open
    world.scene.reset([10.0, 10.0, 8.0])
    img = r.render(width=64, height=48)
    assert r.is_open and img.shape == (48, 64, 3) and img.dtype == np.uint8
    r.close()
    r.close()  # idempotent
    assert not r.is_open
    with pytest.raises(ValueError, match="max_render_size"):
        r.render(width=5000, height=10)


def test_missing_gl_error_names_the_apt_package():
    msg = str(gl.require_gl(OSError("libEGL.so.1: cannot open shared object file")))
    assert "apt-get install" in msg and ("libegl1" in msg or "libosmesa6" in msg)
    assert "MUJOCO_GL" in msg


def _rmse(world, truth, altitude, positions):
    errs = []
    for x, y in positions:
        world.scene.reset([x, y, altitude])
        reading = world.camera()
        seen = reading.seen
        assert seen.sum() >= 4
        errs.append(reading.fraction[seen] - truth.reshape(-1)[seen])
    e = np.concatenate(errs)
    return float(np.sqrt(np.mean(e * e)))


@pytest.mark.parametrize("seed", [0, 1])
def test_threshold_fractions_at_8m_have_rmse_below_0_1(world, seed):
    truth = make_field("weed_patches", GRID, np.random.default_rng(seed))
    world.load_field(truth, 100 + seed)
    positions = [(6.25, 6.25), (18.75, 18.75), (31.25, 8.75), (11.25, 28.75), (26.25, 26.25), (18.75, 6.25)]
    rmse = _rmse(world, truth, 8.0, positions)
    assert rmse < 0.1, rmse
    assert _rmse(world, truth, 14.0, positions[:3]) < 0.1


def test_new_field_is_uploaded_to_the_open_renderer(world):
    world.scene.reset([18.75, 18.75, 8.0])
    world.load_field(np.zeros((15, 15)), 0)
    bare = world.camera()
    assert bare.fraction[bare.seen].max() < 0.02
    world.load_field(np.ones((15, 15)), 0)
    full = world.camera()
    assert full.fraction[full.seen].mean() > 0.95  # a few yellowish plants fall below the hue range
    assert full.fraction[full.seen].min() > 0.85


def test_read_camera_uses_sensor_binning_and_drops_unseen_rows(world):
    truth = make_field("weed_patches", GRID, np.random.default_rng(3))
    world.load_field(truth, 3)
    sensor = Sensor(GRID, SensorConfig())
    rng = np.random.default_rng(0)
    world.scene.reset([18.75, 18.75, 8.0])
    obs, z = world.read_camera(sensor, rng)
    nominal = sensor.observe([18.75, 18.75, 8.0])
    assert obs.m == nominal.m and z.shape == (obs.m,)
    np.testing.assert_allclose(obs.var, sensor.noise_variance(8.0))
    world.scene.reset([18.75, 18.75, 14.0])
    obs, z = world.read_camera(sensor, rng)
    assert np.all(np.isclose(obs.weights[obs.weights > 0], 0.25) | np.isclose(obs.weights[obs.weights > 0], 0.5)
                  | np.isclose(obs.weights[obs.weights > 0], 1.0))  # 2 x 2 binning above 10 m
    seen = np.ones(225, bool)
    seen[nominal.cells[0]] = False
    cut = restrict(nominal, seen)
    assert cut.m == nominal.m - 1 and nominal.cells[0] not in cut.cells


def test_backend_is_chosen_before_mujoco_is_imported():
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    code = ("import sys, os, ipp_bench.sim.demo; assert 'mujoco' not in sys.modules; "
            "import ipp_bench.sim.scene; print(os.environ['MUJOCO_GL'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() in ("egl", "osmesa")
