"""Where the belief's NIS comes from: the camera's per-cell error in real missions (printed figures).

Usage::

    python benchmarks/bench_camera_error.py                              # 5 planners x 5 seeds, ~2 minutes
    python benchmarks/bench_camera_error.py --planners random greedy --seeds 3

Full missions of ``ipp_bench/MuJoCoWeed15-v1``; every camera read-out's per-cell weed fractions are
compared with the ground truth (error e = fraction - truth, per cell, f = the read-out's resolution
factor: 1 below the binning altitude, 2 above). Printed:

- per factor: mean error and mean squared error per cell;
- pairs of looks at the same cell: E[e1 e2] and the correlation, at the same factor and across the
  two factors, and the look-to-look part E[(e1 - e2)^2] / 2 (what repeated looks do not share);
- neighbouring cells of one read-out: correlation of their errors;
- error mean / sd by truth decile (heteroscedasticity);
- per planner, NIS per dof: of the missions (the task's model); of the same updates replayed with
  the camera's error taken as white noise of the same single-look variance (R = ``Observation.var``,
  the v1 model before the error states); and with the camera's values replaced by the truth plus
  fresh noise drawn from that R. If the last is about 1 and the second is not, the camera's error
  is what the white-noise model gets wrong.
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

from ipp_bench.core._threads import limit_blas_threads

TASK = "ipp_bench/MuJoCoWeed15-v1"


def main() -> None:
    from ipp_bench.core.belief import GPBelief, normalised_innovation
    from ipp_bench.core.sensor import stack
    from ipp_bench.envs import make_env
    from ipp_bench.planners.episode import fly_episode

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--planners", nargs="+", default=["random", "coverage", "greedy", "attention", "cmaes"])
    p.add_argument("--seeds", type=int, default=5)
    args = p.parse_args()
    limit_blas_threads()
    env = make_env(TASK)
    cfg = env.config
    print(f"# bench_camera_error: {TASK}, seeds 0..{args.seeds - 1}, load {os.getloadavg()[0]:.1f}")
    per_factor = defaultdict(list)
    pairs = defaultdict(list)
    neighbours = defaultdict(list)
    by_truth = defaultdict(list)
    nis_rows = []
    cols = cfg.grid.cols
    for planner in args.planners:
        camera, white = [0.0, 0], {"camera": [0.0, 0], "fresh": [0.0, 0]}
        for seed in range(args.seeds):
            fly_episode(env, planner, seed)
            m = env.mission
            truth = m.truth.reshape(-1)
            looks = defaultdict(list)
            for cells, fraction, factor in m.cell_log:
                e = fraction - truth[cells]
                per_factor[factor] += e.tolist()
                for c, ec in zip(cells, e):
                    looks[int(c)].append((factor, float(ec)))
                    by_truth[(factor, min(int(truth[c] * 10), 9))].append(float(ec))
                index = {int(c): i for i, c in enumerate(cells)}
                for c, i in index.items():
                    for d in (1, cols):
                        j = index.get(c + d)
                        if j is not None and (d == cols or (c + 1) % cols):
                            neighbours[factor].append((e[i], e[j]))
            for L in looks.values():
                for a in range(len(L)):
                    for b in range(a + 1, len(L)):
                        fa, fb = sorted((L[a][0], L[b][0]))
                        pairs[f"f={fa} & f={fb}"].append((L[a][1], L[b][1]))
            camera[0] += sum(x[1] for x in m.nis_log)
            camera[1] += sum(x[2] for x in m.nis_log)
            rng = np.random.default_rng(seed)
            plain = {"camera": GPBelief.prior(cfg.grid, cfg.gp), "fresh": GPBelief.prior(cfg.grid, cfg.gp)}
            for observations, zs, _ in m.update_log:
                cells, W, var = stack(observations)
                values = {"camera": np.concatenate(zs),
                          "fresh": W @ truth[cells] + rng.standard_normal(var.size) * np.sqrt(var)}
                for key, b in plain.items():
                    nis, dof = normalised_innovation(b, cells, W, values[key], var)
                    white[key][0] += nis
                    white[key][1] += dof
                    b.update_local(cells, W, values[key], var)
        nis_rows.append((planner, camera[0] / camera[1], white["camera"][0] / white["camera"][1],
                         white["fresh"][0] / white["fresh"][1], camera[1]))
    print("\n## per-cell error of the camera, by resolution factor")
    for f, v in sorted(per_factor.items()):
        v = np.asarray(v)
        print(f"f = {f}: {v.size} cell reads, mean {v.mean():+.4f}, mean square {np.mean(v ** 2):.5f}")
    print("\n## pairs of looks at one cell: E[e1 e2], correlation, look-to-look E[(e1 - e2)^2] / 2")
    for k, v in sorted(pairs.items()):
        v = np.asarray(v)
        print(f"{k}: {len(v)} pairs, E[e1 e2] {np.mean(v[:, 0] * v[:, 1]):.5f}, corr {np.corrcoef(v.T)[0, 1]:.3f}, "
              f"look-to-look {0.5 * np.mean((v[:, 0] - v[:, 1]) ** 2):.5f}")
    for f, v in sorted(neighbours.items()):
        v = np.asarray(v)
        print(f"neighbouring cells of one read-out, f = {f}: corr {np.corrcoef(v.T)[0, 1]:.3f}")
    print("\n## error mean / sd by truth decile")
    for f in sorted(per_factor):
        print(f"f = {f}: " + "  ".join(f"{d / 10:.1f}: {np.mean(by_truth[(f, d)]):+.3f}/{np.std(by_truth[(f, d)]):.3f}"
                                       for d in range(10) if by_truth[(f, d)]))
    print("\n## NIS per dof: task model | white-noise model, camera | white-noise model, truth + fresh noise")
    for planner, cam, wcam, fr, dof in nis_rows:
        print(f"{planner:>10}: {cam:.3f} | {wcam:.3f} | {fr:.3f}  ({dof} dof)")
    env.close()


if __name__ == "__main__":
    main()
