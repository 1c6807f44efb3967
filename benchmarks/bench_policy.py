"""Speed of the attention policy: per-decision time and training throughput (printed, never pass/fail).

Usage::

    python benchmarks/bench_policy.py                  # everything, a few minutes on 2 cores
    python benchmarks/bench_policy.py --skip-training  # decision times only
    python benchmarks/bench_policy.py --mcts-decisions 5
    python benchmarks/bench_policy.py --skip-training --env 'altitudes=[8,10,14]' --env k=21  # a third level

Figures:

- per-decision time of the ``attention`` planner (observation -> action: the look-gain feature
  where the checkpoint uses it, and one forward pass) on Grid15Eval-v1 (450 nodes), Grid20Eval-v1
  (800) and Grid30Eval-v1 (1800), one torch thread by default, median and p90 (``--env`` overrides
  the tasks' config as ``ipp-bench leaderboard --env`` does; the rows name the roadmap's node count);
- the same for ``greedy`` and MCTS (the leaderboard's ``mcts:simulations=24``, a few decisions)
  at 450 and 1800 nodes in the same run, and the ratio; MCTS's reference search
  (``mcts:simulations=24,search=reference``, a dense covariance per tree edge) on the same decision
  states, and how many times faster the default search is (``benchmarks/bench_search.py`` has the
  fuller comparison, CMA-ES's too);
- training throughput of ``ipp-bench train``'s PPO phase (environment steps per second, rollout
  and update together) with the shipped checkpoint's settings, and of the warm-start fit.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

TASKS = ("ipp_bench/Grid15Eval-v1", "ipp_bench/Grid20Eval-v1", "ipp_bench/Grid30Eval-v1")
MCTS_SPEC = "mcts:simulations=24,search=lowrank"  # the leaderboard's setting, low-rank search


def _decisions(planner_spec: str, task: str, n: int, seed: int = 0, env_overrides: dict | None = None) -> np.ndarray:
    """Seconds per ``act`` call over ``n`` decisions of real episodes (the planner flying them)."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners import make_planner
    from ipp_bench.planners.base import RobotView

    env = make_env(task, **(env_overrides or {}))
    planner = make_planner(planner_spec)
    times: list[float] = []
    ep = 0
    while len(times) < n:
        obs, _ = env.reset(seed=seed + ep)
        planner.reset(RobotView(env.unwrapped), seed + ep)
        done = False
        while not done and len(times) < n:
            t = time.perf_counter()
            a = planner.act(obs)
            times.append(time.perf_counter() - t)
            obs, _, term, trunc, _ = env.step(a)
            done = term or trunc
        ep += 1
    return np.asarray(times)


def _row(name: str, t: np.ndarray) -> dict:
    return {"what": name, "n": int(t.size), "median_ms": float(np.median(t) * 1e3),
            "p90_ms": float(np.percentile(t, 90) * 1e3)}


def bench_decisions(args) -> list[dict]:
    rows = []
    ckpt = f",checkpoint={args.checkpoint}" if args.checkpoint else ""
    env, tasks = args.env_overrides, args.tasks
    for threads in args.decision_threads:
        spec = f"attention:threads={threads}{ckpt}"
        for task, nodes in tasks:
            _decisions(spec, task, 20, env_overrides=env)  # warm-up
            t = _decisions(spec, task, args.decisions, env_overrides=env)
            rows.append(_row(f"attention, {nodes} nodes, {threads} thread(s)", t))
            print(_fmt(rows[-1]), flush=True)
    for task, nodes in tasks[:: len(tasks) - 1]:
        t = _decisions("greedy", task, args.decisions, env_overrides=env)
        rows.append(_row(f"greedy, {nodes} nodes", t))
        print(_fmt(rows[-1]), flush=True)
    if args.mcts_decisions > 0:
        for task, nodes in tasks[:: len(tasks) - 1]:
            t_new, t_ref = _paired_mcts(MCTS_SPEC, task, args.mcts_decisions, env)
            for name, t in ((MCTS_SPEC, t_new), (MCTS_SPEC.replace("search=lowrank", "search=reference"), t_ref)):
                rows.append(_row(f"{name}, {nodes} nodes (same states)", t))
                print(_fmt(rows[-1]), flush=True)
            print(f"{MCTS_SPEC}: {np.median(t_ref) / np.median(t_new):.1f}x faster than its reference search at "
                  f"{nodes} nodes (median per decision, same states; {_load()})", flush=True)
        for spec in args.mcts:
            for task, nodes in tasks[:: len(tasks) - 1]:
                try:
                    t = _decisions(spec, task, args.mcts_decisions, env_overrides=env)
                except (ValueError, ImportError, ModuleNotFoundError) as err:
                    print(f"{spec} not measured: {err}")
                    continue
                rows.append(_row(f"{spec}, {nodes} nodes", t))
                print(_fmt(rows[-1]), flush=True)
                att_name = f"attention, {nodes} nodes, {args.decision_threads[0]} thread(s)"
                att = next(r for r in rows if r["what"] == att_name)
                print(f"{spec} / attention median per-decision time at {nodes} nodes: "
                      f"{rows[-1]['median_ms'] / att['median_ms']:.0f}x", flush=True)
    return rows


def _load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def _paired_mcts(spec: str, task: str, n: int, env_overrides: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Seconds per decision of ``spec`` and of its reference search, both from the same ``n`` states of a real
    episode (the reference flying it) with the same random state, each planner in its own copy of the env."""
    from ipp_bench.envs import make_env
    from ipp_bench.planners import make_planner
    from ipp_bench.planners.base import RobotView

    envs = [make_env(task, **(env_overrides or {})) for _ in range(2)]
    planners = [make_planner(spec), make_planner(spec.replace("search=lowrank", "search=reference"))]
    obs = [e.reset(seed=0)[0] for e in envs]
    for p, e in zip(planners, envs):
        p.reset(RobotView(e.unwrapped), 0)
    times: list[list[float]] = [[], []]
    for i in range(n):
        planners[0].rng.bit_generator.state = planners[1].rng.bit_generator.state
        moves = [0, 0]
        for k in ((0, 1) if i % 2 else (1, 0)):  # alternate which goes first
            t = time.perf_counter()
            moves[k] = planners[k].act(obs[k])
            times[k].append(time.perf_counter() - t)
        done = False
        for k, e in enumerate(envs):
            obs[k], _, term, trunc, _ = e.step(moves[1])
            done = done or term or trunc
        if done:
            break
    return np.asarray(times[0]), np.asarray(times[1])


def bench_training(args) -> list[dict]:
    import torch
    from sb3_contrib import MaskablePPO

    from ipp_bench.policies.network import AttentionNet
    from ipp_bench.policies.sb3 import AttentionPolicy
    from ipp_bench.train.args import TrainArgs
    from ipp_bench.train.bc import BCDataset, fit_bc
    from ipp_bench.train.ppo import make_ppo_vec_env, policy_kwargs
    from ipp_bench.train.vec import make_train_env
    from ipp_bench.train.warmstart import collect_episodes, make_expert

    cfg = TrainArgs(n_envs=5, n_steps=128, n_epochs=args.n_epochs, batch_size=128)
    venv = make_ppo_vec_env(cfg)
    model = MaskablePPO(AttentionPolicy, venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                        n_epochs=cfg.n_epochs, learning_rate=2e-5, seed=0, device="cpu",
                        policy_kwargs=policy_kwargs(cfg))
    rows = []
    for threads in args.train_threads:
        torch.set_num_threads(threads)
        model.learn(cfg.n_envs * cfg.n_steps, reset_num_timesteps=False)  # warm-up
        steps = cfg.n_envs * cfg.n_steps * args.ppo_rollouts
        t = time.perf_counter()
        model.learn(steps, reset_num_timesteps=False)
        dt = time.perf_counter() - t
        rows.append({"what": f"PPO env-steps/s (5 envs x 128 steps, {cfg.n_epochs} epochs, batch 128, "
                             f"{threads} thread(s))", "steps": steps, "seconds": dt, "steps_per_s": steps / dt})
        print(f"{rows[-1]['what']}: {rows[-1]['steps_per_s']:.1f} over {steps} steps", flush=True)
    torch.set_num_threads(args.train_threads[0])

    env = make_train_env(cfg, 0)
    data = BCDataset()
    rng = np.random.default_rng(0)
    t = time.perf_counter()
    collect_episodes(env, make_expert("greedy"), None, 5, 1.0, data, 0.99, rng, 0, torch.device("cpu"),
                     net_config=cfg.net_config())
    dt = time.perf_counter() - t
    rows.append({"what": "warm start: greedy-labelled env-steps/s", "steps": len(data), "seconds": dt,
                 "steps_per_s": len(data) / dt})
    print(f"{rows[-1]['what']}: {rows[-1]['steps_per_s']:.1f}", flush=True)
    net = AttentionNet(cfg.net_config())  # the training env's node features (look gain included)
    t = time.perf_counter()
    fit_bc(net, data, 1, 3e-4, 128, rng, torch.device("cpu"))
    dt = time.perf_counter() - t
    rows.append({"what": "warm start: fit samples/s (one epoch, batch 128)", "steps": len(data), "seconds": dt,
                 "steps_per_s": len(data) / dt})
    print(f"{rows[-1]['what']}: {rows[-1]['steps_per_s']:.1f}", flush=True)
    venv.close()
    return rows


def _fmt(r: dict) -> str:
    return f"{r['what']}: median {r['median_ms']:.2f} ms, p90 {r['p90_ms']:.2f} ms over {r['n']} decisions"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--decisions", type=int, default=300, help="decisions timed per setting")
    p.add_argument("--mcts-decisions", type=int, default=5, help="MCTS decisions timed (0: skip)")
    p.add_argument("--mcts", nargs="+", default=["mcts:simulations=24"],
                   help="MCTS specs timed (default: the leaderboard's mcts:simulations=24)")
    p.add_argument("--checkpoint", default="", help="attention checkpoint to time (default: the shipped one)")
    p.add_argument("--decision-threads", type=int, nargs="+", default=[1],
                   help="torch threads for the decision times (default 1, the planner's default)")
    p.add_argument("--train-threads", type=int, nargs="+", default=[1, 2],
                   help="torch threads for the training figures (each measured; the first for the warm start)")
    p.add_argument("--n-epochs", type=int, default=4, help="PPO epochs in the throughput figure")
    p.add_argument("--ppo-rollouts", type=int, default=3, help="PPO rollouts (of 640 steps) timed")
    p.add_argument("--skip-training", action="store_true")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE",
                   help="override a field of the timed tasks' config, as ipp-bench leaderboard --env (e.g. "
                        "--env altitudes=[8,10,14] --env k=21: a third flight level); decision times only")
    p.add_argument("--json", help="also write the figures to this file")
    args = p.parse_args()
    from ipp_bench.envs import make_env, parse_overrides

    try:
        args.env_overrides = parse_overrides(args.env)
        # (task, its roadmap's node count); a bad override is refused here, before anything is timed
        args.tasks = [(task, int(make_env(task, **args.env_overrides).unwrapped.roadmap.n_nodes)) for task in TASKS]
    except ValueError as e:
        p.error(str(e))

    from ipp_bench.core._threads import limit_blas_threads

    limit_blas_threads()
    import torch

    cpu = platform.processor() or platform.machine()
    print(f"python {platform.python_version()}, torch {torch.__version__}, {cpu}, "
          f"{len(os.sched_getaffinity(0))} CPUs available; {_load()}")
    rows = bench_decisions(args)
    if not args.skip_training:
        rows += bench_training(args)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
