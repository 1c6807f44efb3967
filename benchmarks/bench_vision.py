"""The camera pipeline: the v0 hand-written per-pixel numpy code against OpenCV (printed figures).

Usage::

    python benchmarks/bench_vision.py                    # ~1 minute on 2 cores
    python benchmarks/bench_vision.py --frames 100 --sizes 320

Per frame, medians of 3 runs, over a weed field at 8 m (full resolution) and 14 m (2 x 2 binned
read-out in v1):

- ``v0 numpy``: the v0 HSV threshold (integer arithmetic per pixel) and projection (a ray per
  pixel, intersected with the ground, ``bincount`` per cell): ``ipp_bench.sim.vision_v0``, which
  the v0 task still uses;
- ``OpenCV``: ``cvtColor`` + ``inRange`` + closing, then ``getPerspectiveTransform`` /
  ``warpPerspective`` onto a ground raster and ``resize(INTER_AREA)`` to cells;
- ``image formation``: lens blur, binning, exposure / white balance, shot + read noise
  (``ipp_bench.sim.camera.form_image``);
- ``camera pipeline`` = image formation + OpenCV (target >= 200 frames/s at the chosen size);
- ``render``: MuJoCo's off-screen frame (Mesa llvmpipe), and with shadows on (cost of shadows);
- the two projections' per-cell fractions on the same masks (they agree to sampling error).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
from timing import per_frame  # noqa: E402  (benchmarks/timing.py)

from ipp_bench.core._threads import limit_blas_threads  # noqa: E402
from ipp_bench.core.config import GridConfig, SensorConfig  # noqa: E402
from ipp_bench.core.fields import make_field  # noqa: E402
from ipp_bench.sim.camera import form_image  # noqa: E402
from ipp_bench.sim.gl import mujoco  # noqa: E402
from ipp_bench.sim.render import SceneRenderer  # noqa: E402
from ipp_bench.sim.scene import SceneConfig, WeedScene  # noqa: E402
from ipp_bench.sim.vision_v0 import GroundProjector as V0Projector  # noqa: E402
from ipp_bench.sim.vision_v0 import HSVThreshold as V0Threshold  # noqa: E402
from ipp_bench.sim.world import SimConfig, WeedWorld  # noqa: E402


def fmt(t: float) -> str:
    return f"{1e3 * t:6.2f} ms ({1 / t:5.0f}/s)"


def bench(sizes: list[int], frames: int) -> None:
    grid, sensor = GridConfig(), SensorConfig()
    truth = make_field("weed_patches", grid, np.random.default_rng(0))
    print("\n## Per frame (median of 3 runs)")
    print(f"{'image':>9} {'alt':>4} {'f':>2} | {'v0 numpy':>19} | {'OpenCV':>19} | {'image formation':>19} | "
          f"{'camera pipeline':>19} | {'render':>19}")
    for size in sizes:
        cfg = SimConfig().with_image_size(size)
        world = WeedWorld(grid, sensor, cfg=cfg)
        world.begin_episode(truth, 1)
        cond = dataclasses.replace(world.conditions, exposure_gain=world.conditions.exposure_gain * world._exposure())
        rng = np.random.default_rng(0)
        for alt in (8.0, 14.0):
            f = world.binning_at(alt)
            world.flight.reset([18.75, 18.75, alt])
            world.flight.hover(0.3)
            raw = world.renderer.render(None, size, size)
            img = form_image(raw, cfg.camera, cond, rng, f)
            _, cam_pos, cam_mat = world.flight.estimated_camera_pose()
            s = size // f
            old_t, old_p = V0Threshold(), V0Projector(15, 15, 2.5, s, s)
            seg, proj = cfg.segmenter, world.projector(f)
            t_old = per_frame(lambda i: old_p.cell_fractions(old_t(img), cam_pos, cam_mat), frames)
            t_new = per_frame(lambda i: proj.cell_fractions(seg(img), cam_pos, cam_mat), frames)
            t_form = per_frame(lambda i: form_image(raw, cfg.camera, cond, rng, f), frames)
            t_pipe = per_frame(lambda i: proj.cell_fractions(seg(form_image(raw, cfg.camera, cond, rng, f)),
                                                             cam_pos, cam_mat), frames)
            t_render = per_frame(lambda i: world.renderer.render(None, size, size), frames)
            print(f"{size:>4}x{size:<4} {alt:3.0f}m {f:2d} | {fmt(t_old)} | {fmt(t_new)} | {fmt(t_form)} | "
                  f"{fmt(t_pipe)} | {fmt(t_render)}")
            # agreement of the two projections on the same (unsegmented-difference-free) mask
            mask = seg(img)
            a, sa, _ = proj.cell_fractions(mask, cam_pos, cam_mat)
            b, sb, _ = old_p.cell_fractions(mask.astype(bool), cam_pos, cam_mat)
            both = sa & sb
            print(f"{'':>19}   projections on the same mask: {both.sum()} cells, max |diff| "
                  f"{np.abs(a[both] - b[both]).max():.4f}, mean |diff| {np.abs(a[both] - b[both]).mean():.4f}")
        world.close()


def bench_shadows(size: int, frames: int) -> None:
    grid = GridConfig()
    print(f"\n## Shadows ({size} x {size}, 8 m): render time with and without a shadow map")
    for shadow in (0, 1024, 2048):
        scene = WeedScene(grid.rows, grid.cols, grid.resolution, cfg=SceneConfig())
        m = scene.model
        if shadow:
            m.vis.quality.shadowsize = shadow
            m.light_castshadow[scene.light_id] = 1
        r = SceneRenderer(scene)
        scene.reset([18.75, 18.75, 8.0])
        t = per_frame(lambda i: r.render(None, size, size), frames)
        print(f"shadow map {shadow:>5}: {fmt(t)}")
        r.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--sizes", type=int, nargs="+", default=[128, 320, 480])
    args = p.parse_args()
    limit_blas_threads()
    import cv2

    cv2.setNumThreads(1)  # as WeedWorld does

    print(f"# bench_vision: OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads), mujoco {mujoco.__version__}, "
          f"MUJOCO_GL={os.environ.get('MUJOCO_GL')}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    bench(args.sizes, args.frames)
    bench_shadows(320, args.frames)


if __name__ == "__main__":
    main()
