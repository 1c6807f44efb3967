"""The dense GP belief and the windowed one side by side at growing map sizes.

Prints figures, never pass/fail. Run: ``python benchmarks/bench_belief_scale.py [--sizes 15 30 50 128]
[--task ipp_bench/Hotspots30Eval-v2] [--agreement] [--seeds 3] [--flight 3000]``.

* Speed and memory (every size): the median of a measurement update of one read-out at 8 m and at
  14 m (successive read-outs at random places, so the belief changes), the median of one greedy
  look-gain call (``trace_reductions`` of 20 candidate legs of 3 read-outs each) and the belief's
  memory. The dense belief runs where its covariance is at most ``--dense-max-gb``.
* ``--agreement``: the whole read-out sequence of greedy and coverage episodes of
  ``Grid30Eval-v1`` and ``Hotspots30Eval-v2`` replayed into both beliefs (max relative variance
  error, max |mean difference|), greedy's decisions scored with both beliefs (share identical), and
  a random mixed-altitude flight on 50 x 50.
* ``--flight N``: N looks of a random-walk flight on 128 x 128 (update, variances and ROI trace after
  each; the process's peak memory at the end).
The task gives the prior (length scale, variances), the camera and the grid's cell side.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import time

import numpy as np

from ipp_bench.core import metrics as M
from ipp_bench.core._threads import limit_blas_threads
from ipp_bench.core.belief import GPBelief, LegBatch, trace_reductions
from ipp_bench.core.belief_window import WindowBelief
from ipp_bench.core.config import GridConfig
from ipp_bench.core.mission import Mission
from ipp_bench.core.sensor import Sensor, stack
from ipp_bench.envs import make_env, task_config

AGREEMENT_TASKS = ("ipp_bench/Grid30Eval-v1", "ipp_bench/Hotspots30Eval-v2")


def _looks(sensor: Sensor, size: int, h: float, count: int, rng) -> list:
    span = size * sensor.grid.resolution
    return [sensor.observe((*rng.uniform(0.1 * span, 0.9 * span, 2), h)) for _ in range(count)]


def _legs(sensor: Sensor, size: int, rng, k: int = 20) -> LegBatch:
    """k candidate legs from the map's centre (3 read-outs each, 8 or 14 m), as greedy scores them."""
    res = sensor.grid.resolution
    start = np.full(2, size * res / 2)
    legs = []
    for i in range(k):
        end = start + rng.normal(0.0, 8.0, 2)
        h = 8.0 if i % 2 else 14.0
        legs.append(stack([sensor.observe((*(start + t * (end - start)), h)) for t in (1 / 3, 2 / 3, 1.0)]))
    return LegBatch(legs)


def _median_ms(fn, items) -> float:
    ts = []
    for it in items:
        t0 = time.perf_counter()
        fn(it)
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def bench_belief(make, size: int, sensor: Sensor, mu: float, looks: int, gain=None) -> dict:
    """Update medians at 8 m and 14 m, look-gain median and memory of the belief ``make()``."""
    rng = np.random.default_rng(size)
    t0 = time.perf_counter()
    b = make()
    out = {"build_s": time.perf_counter() - t0}
    for h in (8.0, 14.0):
        obs = _looks(sensor, size, h, looks, rng)
        out[f"upd{int(h)}_ms"] = _median_ms(
            lambda o: b.update_local(o.cells, o.weights, mu + rng.normal(0, 0.1, o.m), o.var), obs)
    batch = _legs(sensor, size, rng)
    roi = rng.random(b.n) < 0.5
    gain = gain or (lambda bel, bt, r: bel.trace_reductions(bt, r))
    out["gain_ms"] = _median_ms(lambda _: gain(b, batch, roi), range(max(5, looks // 10)))
    out["mem_mb"] = (b.nbytes if hasattr(b, "nbytes") else b.mean.nbytes + b.cov.nbytes) / 1e6
    return out


def speed(args, cfg) -> None:
    gp, res = cfg.gp, cfg.grid.resolution
    print(f"prior of {args.task}: length scale {gp.length_scale} m, signal variance {gp.signal_variance}, "
          f"nugget {gp.nugget}; cells of {res} m")
    print(f"{'grid':>8} {'belief':<22} {'build s':>8} {'upd 8m ms':>10} {'upd 14m ms':>11} "
          f"{'gain ms':>8} {'memory MB':>10}")
    for size in args.sizes:
        sensor = Sensor(GridConfig(rows=size, cols=size, resolution=res), cfg.sensor)
        n = size * size
        rows = []
        dense_gb = n * n * 8 / 1e9
        if dense_gb <= args.dense_max_gb:
            rows.append(("dense GPBelief", lambda size=size: GPBelief.from_grid(
                (size, size), res, gp.length_scale, gp.signal_variance, gp.prior_mean, gp.nugget),
                lambda bel, bt, r: trace_reductions(bel.cov, bt, r)))
        else:
            print(f"{size:>3}x{size:<4} {'dense GPBelief':<22} skipped: its covariance needs {dense_gb:.1f} GB")
        prior = (res, gp.length_scale, gp.signal_variance, gp.prior_mean, gp.nugget)
        window = WindowBelief.from_grid((2, 2), *prior).window
        rows.append((f"WindowBelief w={window}", lambda size=size, prior=prior: WindowBelief.from_grid(
            (size, size), *prior), None))
        for name, make, gain in rows:
            r = bench_belief(make, size, sensor, gp.prior_mean, args.looks, gain)
            print(f"{size:>3}x{size:<4} {name:<22} {r['build_s']:>8.2f} {r['upd8_ms']:>10.3f} "
                  f"{r['upd14_ms']:>11.3f} {r['gain_ms']:>8.3f} {r['mem_mb']:>10.1f}", flush=True)


# -- agreement with the dense belief ----------------------------------------------------------
def record_episode(task: str, planner: str, seed: int, compare_decisions: bool):
    """The batches (cells, W, var, z) of one episode and, for greedy, the share of its decisions that
    the windowed belief (kept in step with the dense one) would have made the same."""
    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.planners.greedy import GreedyPlanner, leg_batch

    env = make_env(task)
    cfg = env.config
    gp = cfg.gp
    win = WindowBelief.from_grid((cfg.grid.rows, cfg.grid.cols), cfg.grid.resolution, gp.length_scale,
                                 gp.signal_variance, gp.prior_mean, gp.nugget)
    batches, same = [], []

    class Recording(GPBelief):
        """The mission's dense belief, passing every update on to the windowed one (the start's too,
        which the mission fuses before an update hook could be attached)."""

        def update_local(self, cells, W, z, R):
            batches.append((cells, W, R, z))
            win.update_local(cells, W, z, R)
            super().update_local(cells, W, z, R)

    def make_mission(truth, rng, start_xyz):
        return Mission(cfg, truth, rng, start_xyz, sensor=env.sensor, belief=Recording.prior(cfg.grid, gp))

    env._make_mission = make_mission  # this env's episodes only

    class Compared(GreedyPlanner):
        def scores(self, obs):
            ref = super().scores(obs)
            view, node = self.view, int(obs["current_node"][0])
            roi = M.belief_roi(win.mean, win.variance, cfg.mission.mu_th, cfg.mission.beta)
            got = win.trace_reductions(leg_batch(view, node), roi) / view.neighbour_durations(node, view.position)
            got = np.where(obs["action_mask"].astype(bool), got, -np.inf)
            same.append(int(np.argmax(got)) == int(np.argmax(ref)))
            return ref

    agent = Compared() if (planner == "greedy" and compare_decisions) else planner
    fly_episode(env, agent, seed)
    del env._make_mission  # the closure refers to env: no cycle keeps its roadmap and leg caches alive
    return batches, same, (env.mission.belief, win)


def replay(batches, shape, res, gp, window):
    """Replay ``batches`` into a fresh WindowBelief of ``window`` cells."""
    b = WindowBelief.from_grid(shape, res, gp.length_scale, gp.signal_variance, gp.prior_mean, gp.nugget, window)
    for cells, W, var, z in batches:
        b.update_local(cells, W, z, var)
    return b


def errors(b, dense) -> tuple[float, float]:
    return (100.0 * float(np.max(np.abs(b.variance / dense.variance - 1.0))),
            float(np.max(np.abs(b.mean - dense.mean))))


def agreement(args) -> None:
    print("\nagreement with the dense GPBelief after whole episodes (max over cells and seeds): "
          "variance error [% relative], |mean difference|")
    windows = [None] + list(args.windows)  # None: the default window, in step with the episode
    for task in AGREEMENT_TASKS:
        cfg = task_config(task)
        shape, res, gp = (cfg.grid.rows, cfg.grid.cols), cfg.grid.resolution, cfg.gp
        for planner in ("greedy", "coverage"):
            worst: dict = {}
            same_all: list = []
            for seed in range(args.seeds):
                batches, same, (dense, win) = record_episode(task, planner, seed, compare_decisions=True)
                same_all += same
                for p in windows:
                    # None: the default window, updated during the episode in step with the dense belief
                    b = win if p is None else replay(batches, shape, res, gp, p)
                    label = f"window w={b.window}" + (" (default)" if p is None else "")
                    v, m = errors(b, dense)
                    old = worst.get(label, (0.0, 0.0))
                    worst[label] = (max(old[0], v), max(old[1], m))
            for label, (v, m) in worst.items():
                print(f"  {task.split('/')[-1]:<18} {planner:<8} {label:<22} var {v:7.3f} %  mean {m:.5f}")
            if same_all:
                print(f"  {task.split('/')[-1]:<18} {planner:<8} greedy's decision identical with the window "
                      f"belief in {100 * np.mean(same_all):.1f} % of {len(same_all)} decisions")
    _agreement_50(args)


def _agreement_50(args) -> None:
    cfg = task_config("ipp_bench/Grid30Eval-v1")
    res = cfg.grid.resolution
    for task in AGREEMENT_TASKS:
        gp = task_config(task).gp
        sensor = Sensor(GridConfig(rows=50, cols=50, resolution=res), cfg.sensor)
        rng = np.random.default_rng(0)
        dense = GPBelief.from_grid((50, 50), res, gp.length_scale, gp.signal_variance, gp.prior_mean, gp.nugget)
        win = WindowBelief.from_grid((50, 50), res, gp.length_scale, gp.signal_variance, gp.prior_mean, gp.nugget)
        xy, looks = np.array([5.0, 5.0]), []
        for _ in range(240):  # a random walk of 7.5 m steps at 8 or 14 m, 1 800 m of flight
            step = rng.normal(size=2)
            xy = np.clip(xy + 7.5 * step / np.linalg.norm(step), 1.0, 124.0)
            looks.append(sensor.observe((*xy, float(rng.choice([8.0, 14.0])))))
        for i in range(0, len(looks), 3):
            cells, W, var = stack(looks[i:i + 3])
            z = gp.prior_mean + rng.normal(0, np.sqrt(gp.signal_variance), W.shape[0])
            dense.update_local(cells, W, z, var)
            win.update_local(cells, W, z, var)
        v, m = errors(win, dense)
        print(f"  50 x 50, {task.split('/')[-1]} prior, random flight of 240 looks: window w={win.window} "
              f"var {v:.3f} %  mean {m:.5f}")


def long_flight(args, cfg) -> None:
    """A whole large-map episode's belief work: ``--flight`` looks of a random walk (7.5 m steps, 8 or
    14 m) over the 128 x 128 map, each fused and followed by what the mission computes after an
    update (the variances and the ROI trace); revisits are many, as in a long flight."""
    gp, res, size = cfg.gp, cfg.grid.resolution, 128
    sensor = Sensor(GridConfig(rows=size, cols=size, resolution=res), cfg.sensor)
    rng = np.random.default_rng(1)
    b = WindowBelief.from_grid((size, size), res, gp.length_scale, gp.signal_variance, gp.prior_mean, gp.nugget)
    roi = rng.random(b.n) < 0.1
    xy, span = np.full(2, size * res / 2), size * res
    upd, post = [], []
    t_all = time.perf_counter()
    for _ in range(args.flight):
        step = rng.normal(size=2)
        xy = np.clip(xy + 7.5 * step / np.linalg.norm(step), 1.0, span - 1.0)
        o = sensor.observe((*xy, float(rng.choice([8.0, 14.0]))))
        t0 = time.perf_counter()
        b.update_local(o.cells, o.weights, gp.prior_mean + rng.normal(0, 0.1, o.m), o.var)
        t1 = time.perf_counter()
        M.trace_roi(b.variance, roi)
        post.append(time.perf_counter() - t1)
        upd.append(t1 - t0)
    total = time.perf_counter() - t_all
    var = b.variance
    print(f"\n128 x 128, {args.task.split('/')[-1]} prior, window w={b.window}: a random-walk flight of {args.flight} "
          f"looks: update median {1e3 * np.median(upd):.2f} ms (p90 {1e3 * np.percentile(upd, 90):.2f}, "
          f"max {1e3 * np.max(upd):.2f}), variances + ROI trace after it {1e3 * np.median(post):.2f} ms, "
          f"total {total:.1f} s; belief {b.nbytes / 1e6:.0f} MB; least variance {var.min() / gp.signal_variance:.3f} "
          f"of the prior's, {100 * np.mean(var < 0.5 * gp.signal_variance):.0f} % of the cells below half of it")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[15, 30, 50, 128])
    parser.add_argument("--task", default="ipp_bench/Hotspots30Eval-v2", help="task whose prior and camera are used")
    parser.add_argument("--looks", type=int, default=100, help="updates timed per altitude")
    parser.add_argument("--dense-max-gb", type=float, default=1.0, help="largest dense covariance to time [GB]")
    parser.add_argument("--agreement", action="store_true", help="accuracy against the dense belief")
    parser.add_argument("--windows", type=int, nargs="*", default=[], help="more windows [cells] for --agreement")
    parser.add_argument("--seeds", type=int, default=3, help="episodes per task and planner for --agreement")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed table")
    parser.add_argument("--flight", type=int, default=0, help="looks of a long random flight on 128 x 128 (0: none)")
    args = parser.parse_args()
    limit_blas_threads()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, numpy {np.__version__}, BLAS threads 1, "
          f"load {os.getloadavg()[0]:.2f}")
    if not args.no_speed:
        speed(args, task_config(args.task))
    if args.flight:
        long_flight(args, task_config(args.task))
    if args.agreement:
        agreement(args)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak memory: {peak:.0f} MB")


if __name__ == "__main__":
    main()
