"""Speed of the MuJoCo deployment (printed figures, never pass/fail).

Usage::

    python benchmarks/bench_sim.py                   # everything, ~1-2 minutes on 2 cores
    python benchmarks/bench_sim.py --frames 100 --seeds 1 --planners random

Figures:

- downward camera at 128 x 128 and 256 x 256: time per frame of rendering alone, of render +
  HSV threshold, and of the whole read-out (render, threshold, projection to the grid, sensor
  binning and noise), at 8 m and 14 m over a weed field (target: >= 100 frames/s at 128 x 128);
- accuracy of the camera's per-cell weed fractions against the ground truth (RMSE, bias);
- physics: bare ``mj_step`` and controlled steps (cascaded controller + ``mj_step``) per second;
- full missions of ``ipp_bench/MuJoCoWeed15-v0`` (200 s budget): wall time and how much faster than
  real time they run, with and without the planner's decision time (target: >= 5x).

Medians over repetitions; the machine is shared and noisy, so compare ratios from one run.
MUJOCO_GL defaults to egl (Mesa llvmpipe renders without a GPU).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import ipp_bench.envs  # noqa: E402, F401
from ipp_bench._threads import limit_blas_threads  # noqa: E402
from ipp_bench.config import GridConfig, SensorConfig  # noqa: E402
from ipp_bench.fields import make_field  # noqa: E402
from ipp_bench.sensor import Sensor  # noqa: E402
from ipp_bench.sim.controller import Leg  # noqa: E402
from ipp_bench.sim.gl import mujoco  # noqa: E402
from ipp_bench.sim.world import SimConfig, WeedWorld  # noqa: E402


def per_frame(fn, n: int, repeat: int = 3) -> float:
    """Median over ``repeat`` runs of the mean time of ``n`` calls [s]."""
    fn(0)  # warm-up (GL context, caches)
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for i in range(n):
            fn(i)
        runs.append((time.perf_counter() - t0) / n)
    return float(np.median(runs))


def bench_camera(frames: int) -> None:
    grid, sensor_cfg = GridConfig(), SensorConfig()
    truth = make_field("weed_patches", grid, np.random.default_rng(0))
    print("\n## Downward camera: time per frame (median of 3 runs)")
    print(f"{'size':>9} {'alt':>5} | {'render':>14} | {'render+HSV':>14} | {'full read-out':>14}")
    for size in (128, 256):
        world = WeedWorld(grid, sensor_cfg, cfg=SimConfig(image_size=size))
        world.load_field(truth, 1)
        sensor = Sensor(grid, sensor_cfg)
        rng = np.random.default_rng(0)
        xs = np.linspace(5.0, 32.5, 16)
        for alt in (8.0, 14.0):
            def place(i):
                world.scene.reset([xs[i % 16], xs[(5 * i) % 16], alt])

            def render(i):
                place(i)
                world.renderer.render(None, size, size)

            def render_threshold(i):
                place(i)
                world.cfg.threshold(world.renderer.render(None, size, size))

            def readout(i):
                place(i)
                world.read_camera(sensor, rng)

            t_place = per_frame(place, frames)
            t = [per_frame(f, frames) - t_place for f in (render, render_threshold, readout)]
            cells = [f"{1e3 * x:6.2f} ms {1 / x:5.0f}/s" for x in t]
            print(f"{size:>4}x{size:<4} {alt:4.0f}m | " + " | ".join(cells))
        world.close()


def bench_accuracy(fields: int) -> None:
    grid, sensor_cfg = GridConfig(), SensorConfig()
    print(f"\n## Camera weed fractions against the ground truth ({fields} weed_patches fields x 25 positions)")
    print(f"{'size':>9} {'alt':>5} | {'cells':>6} | {'RMSE':>6} | {'bias':>7} | {'max |err|':>9}")
    xs = np.arange(3.75, 37.5, 7.5)
    for size in (128, 256):
        world = WeedWorld(grid, sensor_cfg, cfg=SimConfig(image_size=size))
        for alt in (8.0, 14.0):
            errs = []
            for seed in range(fields):
                truth = make_field("weed_patches", grid, np.random.default_rng(seed))
                world.load_field(truth, 1000 + seed)
                for x in xs:
                    for y in xs:
                        world.scene.reset([x, y, alt])
                        r = world.camera()
                        errs.append(r.fraction[r.seen] - truth.reshape(-1)[r.seen])
            e = np.concatenate(errs)
            print(f"{size:>4}x{size:<4} {alt:4.0f}m | {e.size:6d} | {np.sqrt(np.mean(e * e)):6.3f} | "
                  f"{e.mean():+7.3f} | {np.abs(e).max():9.3f}")
        world.close()


def bench_physics(steps: int) -> None:
    world = WeedWorld(GridConfig(), SensorConfig())
    m, d = world.scene.model, world.scene.data
    world.flight.reset([5.0, 5.0, 8.0])
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(m, d)
    bare = steps / (time.perf_counter() - t0)
    flight = world.flight
    flight.reset([5.0, 5.0, 8.0])
    leg = Leg(flight.position, [30.0, 30.0, 14.0])
    t0 = time.perf_counter()
    n = 0
    while n < steps:
        flight.step(*leg.sample(flight.time_s + m.opt.timestep, flight.controller.gains.feedforward_lead_s))
        n += 1
    controlled = steps / (time.perf_counter() - t0)
    dt = m.opt.timestep
    print(f"\n## Physics (timestep {dt * 1e3:.0f} ms)")
    print(f"bare mj_step:                  {bare:9.0f} steps/s  ({bare * dt:6.0f}x real time)")
    print(f"controller + mj_step (flight): {controlled:9.0f} steps/s  ({controlled * dt:6.0f}x real time)")
    world.close()


def bench_missions(planners: list[str], seeds: int) -> None:
    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.sim.demo import make_sim_env

    print("\n## Full missions on ipp_bench/MuJoCoWeed15-v0 (200 s budget)")
    print(f"{'planner':>10} {'seed':>4} | {'reset s':>7} | {'mission s':>9} | {'wall s':>6} | {'planner s':>9} | "
          f"{'x real time':>11} | {'x w/o planner':>13} | {'legs':>4} | {'unc. red. %':>11}")
    env = make_sim_env("ipp_bench/MuJoCoWeed15-v0")
    rows = []
    for planner in planners:
        for seed in range(seeds):
            t0 = time.perf_counter()
            env.reset(seed=seed)  # texture and camera warm-up, timed apart
            reset_s = time.perf_counter() - t0
            log = fly_episode(env, planner, seed)
            mission_s = log.final["time_s"]
            wall = log.episode_wall_s
            sim_wall = wall - sum(log.decision_times_s)
            rows.append((planner, mission_s / wall, mission_s / sim_wall))
            print(f"{planner:>10} {seed:>4} | {reset_s:7.2f} | {mission_s:9.1f} | {wall:6.2f} | "
                  f"{sum(log.decision_times_s):9.2f} | {mission_s / wall:10.1f}x | {mission_s / sim_wall:12.1f}x | "
                  f"{log.decisions:>4} | {log.final['uncertainty_reduction_pct']:11.1f}")
    env.close()
    for planner in planners:
        r = [x for x in rows if x[0] == planner]
        print(f"{planner}: median {np.median([x[1] for x in r]):.1f}x real time, "
              f"{np.median([x[2] for x in r]):.1f}x without the planner's decisions")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200, help="frames per camera measurement")
    parser.add_argument("--steps", type=int, default=20000, help="physics steps per physics measurement")
    parser.add_argument("--planners", nargs="+", default=["random", "coverage", "greedy"],
                        help="planners flown for the real-time factor")
    parser.add_argument("--seeds", type=int, default=2, help="missions per planner")
    parser.add_argument("--fields", type=int, default=4, help="fields for the threshold accuracy")
    args = parser.parse_args()
    limit_blas_threads()
    print(f"# bench_sim: mujoco {mujoco.__version__}, MUJOCO_GL={os.environ.get('MUJOCO_GL')}, "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    bench_camera(args.frames)
    bench_accuracy(args.fields)
    bench_physics(args.steps)
    bench_missions(args.planners, args.seeds)


if __name__ == "__main__":
    main()
