"""Ground texture, rendering, HSV threshold and ground projection: the camera as a weed sensor."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from ipp_bench.core.config import GridConfig, SensorConfig  # noqa: E402
from ipp_bench.core.fields import make_field  # noqa: E402
from ipp_bench.core.sensor import Sensor  # noqa: E402
from ipp_bench.sim import gl  # noqa: E402
from ipp_bench.sim.render import SceneRenderer  # noqa: E402
from ipp_bench.sim.texture import TexturePalette, weed_mask, weed_texture  # noqa: E402
from ipp_bench.sim.vision import GroundProjector, WeedSegmenter, rgb_to_hsv  # noqa: E402
from ipp_bench.sim.world import SimConfig, WeedWorld, restrict  # noqa: E402

GRID = GridConfig()


@pytest.fixture(scope="module")
def world():
    w = WeedWorld(GRID, SensorConfig(), cfg=SimConfig.v0())
    yield w
    w.close()


@pytest.fixture(scope="module")
def world_v1():
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
    seg = WeedSegmenter(open_px=0, close_px=0)
    hsv = rgb_to_hsv(img)
    ref = ((hsv[..., 0] >= seg.hue_min) & (hsv[..., 0] <= seg.hue_max)
           & (hsv[..., 1] >= seg.sat_min) & (hsv[..., 2] >= seg.val_min))
    # OpenCV's 8-bit HSV rounds hue to 2 deg and s, v to 1/255: only pixels on the range borders differ
    assert np.mean(seg(img).astype(bool) != ref) < 0.01
    texture, mask = weed_texture(make_field("weed_patches", GRID, rng), rng, 16, TexturePalette.v0())
    assert np.mean(seg(texture).astype(bool) == mask) > 0.97  # on the texels themselves: soil clutter stays out


def test_closing_fills_a_one_pixel_gap_and_keeps_a_blob():
    img = np.zeros((40, 40, 3), np.uint8)
    img[...] = (110, 80, 50)  # soil
    img[10:30, 10:30] = (60, 140, 40)  # a plant ...
    img[19, 10:30] = (110, 80, 50)  # ... with a one-pixel soil line through it
    closed = WeedSegmenter(open_px=0, close_px=3)(img)
    raw = WeedSegmenter(open_px=0, close_px=0)(img)
    assert raw[19, 20] == 0 and closed[19, 20] == 1
    assert closed[19, 11:29].all() and raw.sum() == 380
    assert 398 <= closed.sum() <= 400  # the gap's two ends open onto the soil: a closing may keep them


def _reference_fractions(mask, cam_pos, cam_mat, fovy=60.0, res=2.5, n=15):
    """Per-pixel ray casting onto z = 0 (the maths the homography must reproduce)."""
    h, w = mask.shape
    f = (h / 2) / np.tan(np.radians(fovy) / 2)
    u = (np.arange(w) + 0.5 - w / 2) / f
    v = (np.arange(h) + 0.5 - h / 2) / f
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([uu.ravel(), -vv.ravel(), -np.ones(uu.size)], 1) @ np.asarray(cam_mat).T
    t = -cam_pos[2] / rays[:, 2]
    x, y = cam_pos[0] + t * rays[:, 0], cam_pos[1] + t * rays[:, 1]
    c, r = np.floor(x / res).astype(int), np.floor(y / res).astype(int)
    ok = (c >= 0) & (c < n) & (r >= 0) & (r < n)
    idx = r[ok] * n + c[ok]
    counts = np.bincount(idx, minlength=n * n)
    hits = np.bincount(idx, weights=mask.ravel()[ok].astype(float), minlength=n * n)
    return hits / np.maximum(counts, 1), counts


def test_projection_straight_down_matches_the_footprint():
    proj = GroundProjector(15, 15, 2.5, 128, 128, 60.0)
    pos = np.array([18.75, 18.75, 8.0])
    ones = np.ones((128, 128), np.uint8)
    frac, seen, cover = proj.cell_fractions(ones, pos, np.eye(3))
    obs = Sensor(GRID, SensorConfig()).observe(pos)
    assert set(obs.cells) <= set(np.flatnonzero(seen))  # every cell of the nominal footprint is seen
    np.testing.assert_allclose(frac[seen], 1.0, atol=1e-5)
    centre = 7 * 15 + 7
    assert cover[centre] == pytest.approx(1.0, abs=1e-3)
    # footprint side 2 h tan(30 deg) = 9.24 m: the covered ground area equals the footprint's
    assert cover.sum() * 2.5 ** 2 == pytest.approx((2 * 8.0 * np.tan(np.radians(30))) ** 2, rel=0.02)
    # image column 0 is west (small x), row 0 is north (large y)
    west = np.zeros((128, 128), np.uint8)
    west[:, :64] = 1
    frac, seen, _ = proj.cell_fractions(west, pos, np.eye(3))
    assert frac[7 * 15 + 6] == pytest.approx(1.0, abs=1e-3) and frac[7 * 15 + 8] == pytest.approx(0.0, abs=1e-3)
    assert frac[centre] == pytest.approx(0.5, abs=0.02)  # the centre cell straddles x = 18.75
    north = np.zeros((128, 128), np.uint8)
    north[:64] = 1
    frac, _, _ = proj.cell_fractions(north, pos, np.eye(3))
    assert frac[8 * 15 + 7] == pytest.approx(1.0, abs=1e-3) and frac[6 * 15 + 7] == pytest.approx(0.0, abs=1e-3)


def test_homography_matches_per_pixel_ray_casting_for_a_tilted_camera():
    rng = np.random.default_rng(4)
    mask = (rng.random((16, 16)) > 0.5).astype(np.uint8).repeat(16, 0).repeat(16, 1)  # 256 x 256 blocks
    a, b = np.radians(12.0), np.radians(-7.0)  # roll about x, pitch about y
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    R = Rx @ Ry
    pos = np.array([17.0, 19.5, 10.0])
    proj = GroundProjector(15, 15, 2.5, 256, 256, 60.0)
    frac, seen, cover = proj.cell_fractions(mask, pos, R)
    ref, counts = _reference_fractions(mask, pos, R)
    full = cover > 0.95
    assert full.sum() >= 9
    np.testing.assert_allclose(frac[full], ref[full], atol=0.03)


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


def test_v1_camera_error_grows_from_8m_to_14m_binned(world_v1):
    """The realistic camera: error within reason, larger at 14 m read out 2 x 2 binned than at 8 m."""
    errs = {8.0: [], 14.0: []}
    for seed in (0, 1):
        truth = make_field("weed_patches", GRID, np.random.default_rng(50 + seed))
        world_v1.begin_episode(truth, 70 + seed)
        for x, y in [(6.25, 6.25), (18.75, 18.75), (31.25, 8.75), (11.25, 28.75), (26.25, 26.25)]:
            for h in errs:
                world_v1.flight.reset([x, y, h])
                r = world_v1.camera()
                assert r.binning == (2 if h > 10 else 1)
                errs[h].append(r.fraction[r.seen] - truth.reshape(-1)[r.seen])
    rmse = {h: float(np.sqrt(np.mean(np.concatenate(e) ** 2))) for h, e in errs.items()}
    assert 0.02 < rmse[8.0] < 0.15 and 0.02 < rmse[14.0] < 0.2
    assert rmse[14.0] > rmse[8.0]


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
    # v0 adds the sensor model's noise to the camera's values; v1 does not
    v0_residual = z - obs.weights @ world.last_reading.fraction[obs.cells]
    assert np.std(v0_residual) > 0.5 * np.sqrt(sensor.noise_variance(8.0))
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
    code = ("import sys, os, ipp_bench.eval.demo; assert 'mujoco' not in sys.modules; "
            "import ipp_bench.sim.scene; print(os.environ['MUJOCO_GL'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() in ("egl", "osmesa")


def test_v1_measurement_is_the_pipelines_estimate_without_added_noise(world_v1):
    truth = make_field("weed_patches", GRID, np.random.default_rng(9))
    world_v1.begin_episode(truth, 9)
    sensor = Sensor(GRID, SensorConfig())
    world_v1.flight.reset([18.75, 18.75, 14.0])
    obs, z = world_v1.read_camera(sensor, np.random.default_rng(0), truth)
    np.testing.assert_array_equal(z, obs.weights @ world_v1.last_reading.fraction[obs.cells])
    # the nominal footprint is placed at the estimated position, not the true one
    r = world_v1.last_reading
    assert not np.allclose(r.estimated_xyz, r.body_xyz)


def test_same_episode_seed_same_frames(world_v1):
    truth = make_field("weed_patches", GRID, np.random.default_rng(3))
    frames = []
    for seed in (11, 11, 12):
        world_v1.begin_episode(truth, seed)
        world_v1.flight.reset([12.0, 20.0, 8.0])
        world_v1.flight.hover(0.2)
        frames.append(world_v1.camera().frame)
    np.testing.assert_array_equal(frames[0], frames[1])
    assert not np.array_equal(frames[0], frames[2])
