"""Where the training time of ``ipp-bench train`` goes, and how fast it runs (printed, never pass/fail).

Usage::

    python benchmarks/bench_train.py                                  # Grid15Train-v1, the defaults
    python benchmarks/bench_train.py --gain-feature --embed-dim 64 --ff-dim 256   # the fast configuration
    python benchmarks/bench_train.py --task ipp_bench/Grid30Train-v1 --gain-feature
    python benchmarks/bench_train.py --n-epochs 4 --target-kl 0.02 --skip-profile  # any TrainArgs option

Builds the PPO phase exactly as ``ipp-bench train`` does (``MaskablePPO`` + ``AttentionPolicy``,
``policy_kwargs`` and the vec env of :mod:`ipp_bench.policies.train`; its options are
``TrainArgs``'s, with its defaults), then runs it twice, back to back, for ``--rollouts`` rollouts
each after one warm-up rollout:

1. **throughput**: as configured (``--vec-env subproc`` by default: environments in worker
   processes), nothing wrapped: env steps per second, and the CPU time per env step of the main
   process and of the worker processes (steadier than the wall time on a shared machine);
2. **profile**: with ``--vec-env dummy`` (environments in this process, so that they can be
   timed; same transitions), splitting the wall time by wrapping, in this process only:

   - ``env``: ``GraphIPPEnv.step`` and ``reset``, of which ``belief update`` (``Mission.fly_to``:
     the Kalman updates of a leg) and ``observation`` (node features, mask); the look-gain
     feature (``--gain-feature``) apart;
   - rollout ``forward``: ``policy.forward`` (one batched pass per vec step, no gradient);
     ``rollout rest``: SB3's buffers, observation stacking and conversion, GAE;
   - update ``forward`` (``policy.evaluate_actions``), ``backward`` (``Tensor.backward``),
     ``optimizer`` (``optimizer.step``), ``update rest`` (minibatch sampling, losses, gradient
     clipping).

Also the warm start's two parts: greedy-labelled episodes (expert + env) and the fit.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections import defaultdict
from dataclasses import fields
from pathlib import Path

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


def _model(cfg):
    from sb3_contrib import MaskablePPO

    from ipp_bench.policies.sb3 import AttentionPolicy
    from ipp_bench.policies.train import _vec_env, policy_kwargs

    venv = _vec_env(cfg)
    model = MaskablePPO(AttentionPolicy, venv, learning_rate=cfg.learning_rate, n_steps=cfg.n_steps,
                        batch_size=cfg.batch_size, n_epochs=cfg.n_epochs, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda,
                        clip_range=cfg.clip_range, ent_coef=cfg.ent_coef, vf_coef=cfg.vf_coef,
                        max_grad_norm=cfg.max_grad_norm, target_kl=cfg.target_kl or None,
                        policy_kwargs=policy_kwargs(cfg), seed=cfg.seed, device="cpu")
    return venv, model


def _worker_cpu_s(venv) -> float:
    """CPU seconds (user + system) used so far by the worker processes of a SubprocVecEnv (0 without)."""
    total = 0.0
    for proc in getattr(getattr(venv, "venv", venv), "processes", []):
        fields_ = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields_[11]) + int(fields_[12])) / os.sysconf("SC_CLK_TCK")
    return total


def _run(model, venv, cfg, rollouts: int) -> tuple[int, float, float, float]:
    """Steps, wall seconds, main-process and worker CPU seconds of ``rollouts`` rollouts."""
    per_rollout = cfg.n_envs * cfg.n_steps
    model.learn(per_rollout)  # warm-up: first reset, allocations
    t, c, w = time.perf_counter(), time.process_time(), _worker_cpu_s(venv)
    model.learn(per_rollout * rollouts, reset_num_timesteps=False)
    return (per_rollout * rollouts, time.perf_counter() - t, time.process_time() - c, _worker_cpu_s(venv) - w)


def main() -> int:
    import torch

    from ipp_bench.policies.train import TrainArgs, add_train_arguments, set_threads

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_train_arguments(p)  # every TrainArgs option, defaults as in `ipp-bench train`
    p.add_argument("--rollouts", type=int, default=3, help="timed rollouts (+ 1 warm-up) per part (default 3)")
    p.add_argument("--bc-probe-episodes", type=int, default=3, help="greedy episodes of the warm-start probe (0 = skip)")
    p.add_argument("--skip-profile", action="store_true", help="only the throughput run")
    p.add_argument("--default-malloc", action="store_true",
                   help="leave glibc's malloc as it is (ipp-bench train keeps freed memory for reuse)")
    args = p.parse_args()
    given = {f.name: getattr(args, f.name) for f in fields(TrainArgs) if getattr(args, f.name) is not None}
    given.setdefault("task", "ipp_bench/Grid15Train-v1")
    cfg = TrainArgs(**given)
    threads = set_threads(cfg.threads)
    from ipp_bench._threads import keep_freed_memory

    kept = not args.default_malloc and keep_freed_memory()

    from ipp_bench.envs.graph import GraphIPPEnv
    from ipp_bench.mission import Mission
    from ipp_bench.policies import features

    print(f"python {platform.python_version()}, torch {torch.__version__}, {len(os.sched_getaffinity(0))} CPUs "
          f"available, {threads} torch thread(s), freed memory {'kept' if kept else 'returned to the OS (glibc default)'}")
    what = (f"{cfg.task}{' + look-gain feature' if cfg.gain_feature else ''}: PPO {cfg.n_envs} envs x {cfg.n_steps} "
            f"steps, {cfg.n_epochs} epoch(s), batch {cfg.batch_size}, d {cfg.embed_dim} / ff {cfg.ff_dim}"
            f"{f', target KL {cfg.target_kl}' if cfg.target_kl else ''}")
    print(what)

    venv, model = _model(cfg)
    load0 = os.getloadavg()[0]
    steps, wall, cpu_main, cpu_workers = _run(model, venv, cfg, args.rollouts)
    venv.close()
    print(f"throughput ({cfg.vec_env} vec env): {steps} steps in {wall:.1f} s = **{steps / wall:.0f} env-steps/s** "
          f"(load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after); CPU per env step: main process "
          f"{1e3 * cpu_main / steps:.2f} ms, env workers {1e3 * cpu_workers / steps:.2f} ms")
    if args.skip_profile:
        return 0

    acc: dict[str, float] = defaultdict(float)
    _timed(GraphIPPEnv, "step", "env", acc)
    _timed(GraphIPPEnv, "reset", "env", acc)
    _timed(Mission, "fly_to", "belief update", acc)
    _timed(GraphIPPEnv, "_observation", "observation", acc)
    _timed(features.LookGain, "__call__", "feature", acc)
    pcfg = TrainArgs(**{**given, "vec_env": "dummy"})
    venv, model = _model(pcfg)
    policy = model.policy
    _timed(policy, "forward", "rollout forward", acc)
    _timed(policy, "evaluate_actions", "update forward", acc)
    _timed(policy.optimizer, "step", "optimizer", acc)
    _timed(torch.Tensor, "backward", "backward", acc)
    _timed(model, "train", "update", acc)
    per_rollout = pcfg.n_envs * pcfg.n_steps
    model.learn(per_rollout)
    acc.clear()
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    model.learn(per_rollout * args.rollouts, reset_num_timesteps=False)
    wall = time.perf_counter() - t
    venv.close()
    env = acc["env"] + acc["feature"]
    rollout = wall - acc["update"]
    print(f"\nprofile (dummy vec env, same transitions): {steps} steps in {wall:.1f} s = {steps / wall:.0f} env-steps/s "
          f"(load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after)")
    print("| part | seconds | share | per env step |")
    print("|---|---|---|---|")
    rows = [
        ("**rollout**", rollout),
        ("env step + reset", acc["env"]),
        ("  of which belief update (`Mission.fly_to`)", acc["belief update"]),
        ("  of which observation", acc["observation"]),
        ("look-gain feature", acc["feature"]),
        ("policy forward (no gradient)", acc["rollout forward"]),
        ("rollout rest (SB3 buffers, obs stacking, GAE)", rollout - env - acc["rollout forward"]),
        ("**PPO update**", acc["update"]),
        ("forward (`evaluate_actions`)", acc["update forward"]),
        ("backward", acc["backward"]),
        ("optimizer (Adam)", acc["optimizer"]),
        ("update rest (minibatches, losses, gradient clip)",
         acc["update"] - acc["update forward"] - acc["backward"] - acc["optimizer"]),
    ]
    for name, sec in rows:
        print(f"| {name} | {sec:.2f} | {100 * sec / wall:.0f}% | {1e3 * sec / steps:.2f} ms |")

    if args.bc_probe_episodes:
        from ipp_bench.policies.network import AttentionNet
        from ipp_bench.policies.train import make_train_env
        from ipp_bench.policies.warmstart import BCDataset, collect_episodes, fit_bc, make_expert

        env1 = make_train_env(cfg)
        data = BCDataset()
        rng = np.random.default_rng(0)
        acc.clear()
        t = time.perf_counter()
        collect_episodes(env1, make_expert("greedy"), None, args.bc_probe_episodes, 1.0, data, 0.99, rng, 0,
                         torch.device("cpu"))
        dt = time.perf_counter() - t
        print(f"\nwarm start: {len(data)} greedy-labelled env steps in {dt:.1f} s = {len(data) / dt:.0f}/s "
              f"(env {acc['env']:.1f} s, the rest greedy's scores)")
        net = AttentionNet(cfg.net_config())
        t = time.perf_counter()
        fit_bc(net, data, 1, 3e-4, cfg.batch_size, rng, torch.device("cpu"))
        dt = time.perf_counter() - t
        print(f"warm start fit: {len(data) / dt:.0f} samples/s (one epoch, batch {cfg.batch_size})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
