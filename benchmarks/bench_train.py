"""Where the training time of ``ipp-bench train`` goes (printed, never pass/fail).

Usage::

    python benchmarks/bench_train.py                                   # Grid15Train-v1, ~1 minute
    python benchmarks/bench_train.py --task ipp_bench/Grid30Train-v1 --gain-feature

Runs the PPO phase of ``ipp-bench train`` (the same ``MaskablePPO`` + ``AttentionPolicy`` + vec
env as the command) for a few rollouts and splits the wall time by wrapping, in this process only:

- ``env``: ``GraphIPPEnv.step`` and ``reset`` in total, of which ``belief update``
  (``Mission.fly_to``: the Kalman updates of a leg) and ``observation`` (node features, mask);
- ``feature``: the look-gain node feature (``--gain-feature`` only);
- ``forward``: the rest of the rollout (policy forward pass per vec step, SB3 buffers);
- ``update``: ``MaskablePPO.train`` (forward + backward + Adam over the rollout, n_epochs times).

Also the warm start's two parts: greedy-labelled episodes (expert + env) and the fit.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections import defaultdict

import numpy as np


def _timed(owner, name: str, bucket: str, acc: dict) -> None:
    fn = getattr(owner, name)

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[bucket] += time.perf_counter() - t

    setattr(owner, name, wrapper)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="ipp_bench/Grid15Train-v1")
    p.add_argument("--gain-feature", action="store_true")
    p.add_argument("--n-envs", type=int, default=8)
    p.add_argument("--n-steps", type=int, default=128)
    p.add_argument("--n-epochs", type=int, default=4)
    p.add_argument("--batch-size", type=int, default=256)
    p.add_argument("--rollouts", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--bc-episodes", type=int, default=3)
    args = p.parse_args()

    import torch
    from sb3_contrib import MaskablePPO

    from ipp_bench.envs.graph import GraphIPPEnv
    from ipp_bench.mission import Mission
    from ipp_bench.policies import features
    from ipp_bench.policies.sb3 import AttentionPolicy
    from ipp_bench.policies.train import TrainArgs, _vec_env, make_train_env, set_threads
    from ipp_bench.policies.warmstart import BCDataset, collect_episodes, fit_bc, make_expert

    set_threads(args.threads)
    print(f"python {platform.python_version()}, torch {torch.__version__}, "
          f"{len(os.sched_getaffinity(0))} CPUs available, {args.threads} torch thread(s), "
          f"load average {os.getloadavg()[0]:.1f}")
    acc: dict[str, float] = defaultdict(float)
    _timed(GraphIPPEnv, "step", "env", acc)
    _timed(GraphIPPEnv, "reset", "env", acc)
    _timed(Mission, "fly_to", "belief update", acc)
    _timed(GraphIPPEnv, "_observation", "observation", acc)
    _timed(features.LookGain, "__call__", "feature", acc)
    cfg = TrainArgs(task=args.task, gain_feature=args.gain_feature, n_envs=args.n_envs, n_steps=args.n_steps,
                    n_epochs=args.n_epochs, batch_size=args.batch_size)
    venv = _vec_env(cfg)
    model = MaskablePPO(AttentionPolicy, venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
                        n_epochs=cfg.n_epochs, learning_rate=3e-5, gae_lambda=0.95, seed=0, device="cpu",
                        policy_kwargs={"net_config": cfg.net_config().to_dict()})
    _timed(model, "train", "update", acc)
    per_rollout = cfg.n_envs * cfg.n_steps
    model.learn(per_rollout)  # warm-up
    acc.clear()
    t = time.perf_counter()
    model.learn(per_rollout * args.rollouts, reset_num_timesteps=False)
    wall = time.perf_counter() - t
    steps = per_rollout * args.rollouts
    env = acc["env"] + acc["feature"]
    forward = wall - acc["update"] - env
    print(f"\n{args.task}{' + look-gain feature' if args.gain_feature else ''}: PPO {cfg.n_envs} envs x "
          f"{cfg.n_steps} steps, {cfg.n_epochs} epochs, batch {cfg.batch_size}: {steps} steps in {wall:.1f} s = "
          f"{steps / wall:.0f} env-steps/s")
    print("| part | seconds | share | per env step |")
    print("|---|---|---|---|")
    rows = [("env step + reset (total)", acc["env"]), ("  of which belief update (Mission.fly_to)", acc["belief update"]),
            ("  of which observation", acc["observation"]), ("look-gain feature", acc["feature"]),
            ("policy forward in rollouts (+ SB3 buffers)", forward), ("PPO update (forward + backward + Adam)", acc["update"])]
    for name, sec in rows:
        print(f"| {name} | {sec:.2f} | {100 * sec / wall:.0f}% | {1e3 * sec / steps:.2f} ms |")
    venv.close()

    env1 = make_train_env(cfg)
    data = BCDataset()
    rng = np.random.default_rng(0)
    acc.clear()
    t = time.perf_counter()
    collect_episodes(env1, make_expert("greedy"), None, args.bc_episodes, 1.0, data, 0.99, rng, 0,
                     torch.device("cpu"))
    dt = time.perf_counter() - t
    print(f"\nwarm start: {len(data)} greedy-labelled env steps in {dt:.1f} s = {len(data) / dt:.0f}/s "
          f"(env {acc['env']:.1f} s, the rest greedy's scores)")
    from ipp_bench.policies.network import AttentionNet

    net = AttentionNet(cfg.net_config())
    t = time.perf_counter()
    fit_bc(net, data, 1, 3e-4, cfg.batch_size, rng, torch.device("cpu"))
    dt = time.perf_counter() - t
    print(f"warm start fit: {len(data) / dt:.0f} samples/s (one epoch, batch {cfg.batch_size})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
