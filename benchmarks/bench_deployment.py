"""Does the camera matter, and is the belief consistent with it? (printed figures, never pass/fail)

Usage::

    python benchmarks/bench_deployment.py                       # 3 planners x 6 seeds, ~3 minutes
    python benchmarks/bench_deployment.py --planners greedy --seeds 10
    python benchmarks/bench_deployment.py --planners random coverage greedy attention cmaes --seeds 10 --no-truth

For each planner and seed, the same ``ipp_bench/MuJoCoWeed15-v1`` episode is flown twice: with the
camera's values (the task) and with the ground truth in their place (``SimConfig(measurement=
"truth")``: same flight, wind, estimator and footprints; only z differs). Printed per planner:

- ROI uncertainty reduction and ROI RMSE reduction at 50 / 100 / 150 / 200 s, camera vs truth, and
  the paired difference of the final ROI RMSE (mean and a 95 % interval over the seeds);
- the normalised innovation squared of the Kalman updates (camera runs): NIS per degree of freedom
  pooled over the planner's missions (in [0.7, 1.4] is the consistency target) and per mission;
- the share of its read-outs (camera runs) taken above the binning altitude (binned, 14 m).

``--no-truth`` flies the camera runs only (NIS and the camera's metrics).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from ipp_bench.core._threads import limit_blas_threads  # noqa: E402

TASK = "ipp_bench/MuJoCoWeed15-v1"


def main() -> None:
    from ipp_bench.envs import make_env
    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.sim.world import SimConfig

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--planners", nargs="+", default=["coverage", "greedy", "random"])
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--no-truth", action="store_true", help="camera runs only")
    args = p.parse_args()
    limit_blas_threads()
    modes = ("camera",) if args.no_truth else ("camera", "truth")
    envs = {mode: make_env(TASK, sim=SimConfig(measurement=mode)) for mode in modes}
    times = envs["camera"].config.mission.report_times
    print(f"# bench_deployment: {TASK}, seeds 0..{args.seeds - 1}, load {os.getloadavg()[0]:.1f}")
    all_nis, all_dof = 0.0, 0
    for planner in args.planners:
        rows = {"camera": [], "truth": []}
        nis_per_mission, walls = [], []
        planner_nis, planner_dof = 0.0, 0
        reads, binned = 0, 0
        for seed in range(args.seeds):
            for mode, env in envs.items():
                t0 = time.perf_counter()
                fly_episode(env, planner, seed)
                walls.append(time.perf_counter() - t0)
                m = env.mission
                rows[mode].append([(m.metrics_at(t)["uncertainty_reduction_pct"], m.metrics_at(t)["rmse_reduction_pct"],
                                    m.metrics_at(t)["rmse_roi"]) for t in times])
                if mode == "camera":
                    nis = sum(x[1] for x in m.nis_log)
                    dof = sum(x[2] for x in m.nis_log)
                    nis_per_mission.append(nis / dof)
                    planner_nis, planner_dof = planner_nis + nis, planner_dof + dof
                    all_nis, all_dof = all_nis + nis, all_dof + dof
                    alts = np.array([r[3] for r in m.measurement_log])
                    reads += alts.size
                    binned += int(np.sum(alts > env.config.sensor.binning_altitude))
        print(f"\n## {planner} ({args.seeds} seeds, mean wall {np.mean(walls):.1f} s per episode)")
        for mode in modes:
            a = np.array(rows[mode])  # (seeds, times, 3)
            unc = " / ".join(f"{v:.1f}" for v in a[:, :, 0].mean(axis=0))
            rm = " / ".join(f"{v:.1f}" for v in a[:, :, 1].mean(axis=0))
            print(f"{mode:>7}: uncertainty reduction {unc} %   RMSE reduction {rm} %")
        if rows.get("truth"):
            diff = np.array(rows["camera"])[:, -1, 2] - np.array(rows["truth"])[:, -1, 2]
            half = 1.96 * diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else float("nan")
            print(f"final ROI RMSE, camera - truth: {diff.mean():+.4f} +- {half:.4f} (95 %), "
                  f"camera worse in {np.sum(diff > 0)}/{len(diff)} seeds")
        v = np.array(nis_per_mission)
        print(f"NIS per dof (camera): pooled {planner_nis / planner_dof:.3f} ({planner_dof} dof); per mission "
              + " ".join(f"{x:.2f}" for x in v) + f" (median {np.median(v):.2f})")
        print(f"read-outs (camera): {reads}, binned (above {envs['camera'].config.sensor.binning_altitude:g} m) "
              f"{100.0 * binned / max(reads, 1):.1f} %")
    print(f"\npooled NIS per degree of freedom over every camera mission: {all_nis / all_dof:.3f} ({all_dof} dof)")
    for env in envs.values():
        env.close()


if __name__ == "__main__":
    main()
