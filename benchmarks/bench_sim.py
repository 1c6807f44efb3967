"""Speed of the MuJoCo deployment (printed figures, never pass/fail).

Usage::

    python benchmarks/bench_sim.py                   # everything, ~1-2 minutes on 2 cores
    python benchmarks/bench_sim.py --frames 100 --seeds 1 --planners random

Figures:

- the v1 camera read-out per frame at 320 x 320 (render, image formation, OpenCV pipeline, sensor
  layout) at 8 m and 14 m (the pipeline alone against v0's numpy code: ``bench_vision.py``);
- physics: bare ``mj_step`` and controlled steps (estimator, wind, cascaded controller + ``mj_step``)
  per second;
- full missions of ``ipp_bench/MuJoCoWeed15-v1`` and ``-v0`` (200 s budget): wall time and how much
  faster than real time they run, with and without the planner's decision time (v1 target: >= 50x).

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
from timing import per_frame  # noqa: E402  (benchmarks/timing.py)

import ipp_bench.envs as envs  # noqa: E402
from ipp_bench.core._threads import limit_blas_threads  # noqa: E402
from ipp_bench.core.config import GridConfig, SensorConfig  # noqa: E402
from ipp_bench.core.fields import make_field  # noqa: E402
from ipp_bench.core.sensor import Sensor  # noqa: E402
from ipp_bench.sim.controller import ContinuousLeg  # noqa: E402
from ipp_bench.sim.gl import mujoco  # noqa: E402
from ipp_bench.sim.world import SimConfig, WeedWorld  # noqa: E402


def bench_camera(frames: int) -> None:
    """Whole read-out per frame in v1 (render, image formation, OpenCV pipeline, sensor layout)."""
    grid = GridConfig()
    cfg = envs.task_spec("ipp_bench/MuJoCoWeed15-v1").config
    truth = make_field("weed_patches", grid, np.random.default_rng(0))
    print("\n## v1 camera read-out per frame (median of 3 runs; render + formation + OpenCV + layout)")
    for size in (320,):
        world = WeedWorld(grid, cfg.sensor, cfg=SimConfig().with_image_size(size))
        world.begin_episode(truth, 1)
        sensor = Sensor(grid, cfg.sensor)
        rng = np.random.default_rng(0)
        xs = np.linspace(5.0, 32.5, 16)
        for alt in (8.0, 14.0):
            def place(i):
                world.scene.reset([xs[i % 16], xs[(5 * i) % 16], alt])

            def readout(i):
                place(i)
                world.read_camera(sensor, rng, truth)

            t = per_frame(readout, frames) - per_frame(place, frames)
            print(f"{size}x{size} {alt:4.0f} m: {1e3 * t:6.2f} ms ({1 / t:5.0f}/s)")
        world.close()


def bench_physics(steps: int) -> None:
    world = WeedWorld(GridConfig(), SensorConfig())  # v1 defaults: wind and state estimation on
    world.flight.disturbance_seed = 1
    m, d = world.scene.model, world.scene.data
    world.flight.reset([5.0, 5.0, 8.0])
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(m, d)
    bare = steps / (time.perf_counter() - t0)
    flight = world.flight
    flight.reset([5.0, 5.0, 8.0])
    leg = ContinuousLeg(flight.position, np.zeros(3), [30.0, 30.0, 14.0])
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


def bench_missions(task: str, planners: list[str], seeds: int) -> None:
    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.sim.video import make_sim_env

    print(f"\n## Full missions on {task} (200 s budget)")
    print(f"{'planner':>10} {'seed':>4} | {'reset s':>7} | {'mission s':>9} | {'wall s':>6} | {'planner s':>9} | "
          f"{'x real time':>11} | {'x w/o planner':>13} | {'legs':>4} | {'unc. red. %':>11}")
    env = make_sim_env(task)
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
    parser.add_argument("--tasks", nargs="+", default=["ipp_bench/MuJoCoWeed15-v1", "ipp_bench/MuJoCoWeed15-v0"])
    args = parser.parse_args()
    limit_blas_threads()
    print(f"# bench_sim: mujoco {mujoco.__version__}, MUJOCO_GL={os.environ.get('MUJOCO_GL')}, "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}")
    bench_camera(args.frames)
    bench_physics(args.steps)
    for task in args.tasks:
        bench_missions(task, args.planners, args.seeds)


if __name__ == "__main__":
    main()
