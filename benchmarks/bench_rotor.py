"""What the rotor-speed model changes (printed figures, never pass/fail).

Usage::

    python benchmarks/bench_rotor.py                        # ~2-3 minutes on 2 cores
    python benchmarks/bench_rotor.py --seeds 2 --planners greedy

Both rotor models of ``QuadrotorParams.rotor_model`` ("thrust": first-order lag on thrust, the v1
default; "speed": rotor speed state with a first-order lag, thrust k_f omega^2), same everything else:

- tracking error [m] (true position - reference) over a standard leg sequence flown velocity-
  continuously (square at 8 m, climb to 14 m, diagonal, a turn straight back, descent), calm and
  with the v1 wind + estimator of one seed: RMS, 95th percentile and maximum;
- physics speed: controlled steps per second (x real time);
- full missions of ``ipp_bench/MuJoCoWeed15-v1`` per planner and seed: ROI uncertainty and RMSE
  reduction at 200 s, NIS per dof, wall time per mission (x real time).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from ipp_bench.core._threads import limit_blas_threads  # noqa: E402

TASK = "ipp_bench/MuJoCoWeed15-v1"
LEGS = [(28.0, 8.0, 8.0), (28.0, 28.0, 8.0), (8.0, 28.0, 8.0), (8.0, 8.0, 8.0), (8.0, 8.0, 14.0),
        (30.0, 30.0, 14.0), (12.0, 12.0, 14.0), (30.0, 30.0, 14.0), (30.0, 30.0, 8.0), (18.0, 18.0, 8.0)]


def tracking(rotor_model: str, disturbed: bool) -> tuple[np.ndarray, float]:
    """Tracking errors [m] of every physics step over LEGS, and controlled steps per second."""
    from ipp_bench.sim.controller import ContinuousLeg
    from ipp_bench.sim.disturbance import DisturbanceConfig
    from ipp_bench.sim.flight import Flight
    from ipp_bench.sim.quadrotor import QuadrotorParams
    from ipp_bench.sim.scene import WeedScene

    scene = WeedScene(15, 15, 2.5, QuadrotorParams(rotor_model=rotor_model))
    flight = Flight(scene, disturbances=DisturbanceConfig() if disturbed else DisturbanceConfig.none())
    flight.disturbance_seed = 3
    flight.reset(np.array([8.0, 8.0, 8.0]))
    errors = []
    state = {}

    def on_step(f):
        errors.append(np.linalg.norm(f.position - state["leg"].sample(f.time_s - state["t0"])[0]))

    t0 = time.perf_counter()
    for target in LEGS:
        state["leg"] = ContinuousLeg(flight.ref_pos, flight.ref_vel, np.array(target), flight.speed, flight.ramp_s)
        state["t0"] = flight.ref_time
        flight.follow(np.array(target), on_step=on_step)
    return np.array(errors), len(errors) / (time.perf_counter() - t0)


def missions(rotor_model: str, planners: list[str], seeds: int) -> dict:
    from ipp_bench.envs import make_env
    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.sim.world import SimConfig

    env = make_env(TASK, sim=SimConfig(rotor_model=rotor_model))
    out = {}
    for planner in planners:
        for seed in range(seeds):
            t0 = time.perf_counter()
            fly_episode(env, planner, seed)
            wall = time.perf_counter() - t0
            m = env.mission
            at = m.metrics_at(m.budget_s)
            nis = sum(x[1] for x in m.nis_log) / sum(x[2] for x in m.nis_log)
            out[(planner, seed)] = (at["uncertainty_reduction_pct"], at["rmse_reduction_pct"], nis, wall,
                                    m.budget_s / wall, m.distance_m)
    env.close()
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--planners", nargs="+", default=["coverage", "greedy", "random"])
    p.add_argument("--seeds", type=int, default=3)
    args = p.parse_args()
    limit_blas_threads()
    print(f"# bench_rotor: load {os.getloadavg()[0]:.1f}")
    print("\n## tracking error over the standard leg sequence [m]: RMS / p95 / max, and controlled steps/s")
    for disturbed in (False, True):
        for model in ("thrust", "speed"):
            e, rate = tracking(model, disturbed)
            print(f"{'wind + estimator' if disturbed else 'calm':>16} {model:>6}: {np.sqrt(np.mean(e ** 2)):.4f} / "
                  f"{np.percentile(e, 95):.4f} / {e.max():.4f} m over {len(e)} steps; {rate:.0f} steps/s")
    print(f"\n## full missions of {TASK} at 200 s: uncertainty red. / RMSE red. [%], NIS per dof, "
          "wall [s] (x real time),"
          " distance [m]")
    res = {model: missions(model, args.planners, args.seeds) for model in ("thrust", "speed")}
    for key in res["thrust"]:
        a, b = res["thrust"][key], res["speed"][key]
        print(f"{key[0]:>9} seed {key[1]}: thrust {a[0]:.2f} / {a[1]:.2f} / {a[2]:.3f} / {a[3]:.2f} s ({a[4]:.0f}x) / "
              f"{a[5]:.1f} m;  speed {b[0]:.2f} / {b[1]:.2f} / {b[2]:.3f} / {b[3]:.2f} s ({b[4]:.0f}x) / {b[5]:.1f} m")
    for model in ("thrust", "speed"):
        v = np.array(list(res[model].values()))
        print(f"mean {model:>6}: uncertainty red. {v[:, 0].mean():.2f} %, RMSE red. {v[:, 1].mean():.2f} %, "
              f"{v[:, 4].mean():.0f}x real time")
    print(f"# load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
