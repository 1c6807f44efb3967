"""PPO training throughput of this tree against a baseline commit, and the evidence that both train the same
MDP (printed figures, never pass/fail timings).

Usage::

    python benchmarks/bench_train.py                      # both mixes, 2 alternations, a few minutes on 2 cores
    python benchmarks/bench_train.py --repeats 4 --rollouts 8   # longer, steadier
    python benchmarks/bench_train.py --skip-equality      # throughput only
    python benchmarks/bench_train.py --skip-throughput    # the equality checks only
    python benchmarks/bench_train.py --tiny               # smoke test: a few steps of the 15 x 15 mix

Throughput: ``ipp-bench train``'s own PPO phase (``ipp_bench.train.run.execute``, so ``latest.zip`` and
the run state are written as in a real run) with the shipped recipe's PPO settings (``attention_v6``:
stage ``ppo30`` on the 30 x 30 mix ``Grid30Train-v1`` + ``Hotspots30Train-v2``, stage ``ppo15`` on the
15 x 15 mix; 16 environments x 64 steps, batch 128, one epoch, d 64 / ff 256, starting from
``attention_v6.pt``), for this tree and for the landed code of ``--base`` (a ``git worktree`` under
``runs/``, built if missing), each in a fresh process (``PYTHONPATH`` naming the tree), alternating old
and new so that both see the same machine load. ``--warmup`` rollouts are not timed, ``--rollouts`` are.

Where the time goes is measured from outside the trees' code (their files are never edited): timers
wrapped around SB3's ``collect_rollouts`` / ``train`` / ``save``, the policy's ``forward``, the
workers' ``DummyVecEnv.step_wait`` and ``multiprocessing.connection.Connection``'s ``send`` / ``recv``
(installed before the worker processes fork, so that they inherit them). Per env-step (one transition
of one environment), main process: policy forward (rollout), PPO update, ``latest.zip``, transfer
(pickling the actions, unpickling the results), waiting (blocked on the workers' pipes) and the rest;
worker processes (summed over workers, CPU-seconds per env-step): env step, forward, the PPO update's
second halves (``train.update``), sending results, idle.

Equality (``--skip-equality`` skips it): both trees fly the same episodes (greedy and the attention
planner on ``Grid30Train-v1``, ``Hotspots30Train-v2`` and ``Grid15Train-v1``) and their report metrics
must agree to 1e-9 relative; both trees' training environments (reward, invariant node features,
positional encoding dropped) step through the same seeded random actions, and their observations and
rewards must agree to 1e-9 relative; the trees' PPO policies with the shipped weights must give the
same logits, values, log-probabilities and gradients on those recorded observations to float rounding.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASE_REV = "4e9f32f"
MIXES = {"30": ("ppo30", "Grid30Train-v1 + Hotspots30Train-v2"), "15": ("ppo15", "Grid15Train-v1 + Hotspots15Train-v2")}
EPISODE_TASKS = ("ipp_bench/Grid30Train-v1", "ipp_bench/Hotspots30Train-v2", "ipp_bench/Grid15Train-v1")
EPISODE_PLANNERS = ("greedy", "attention")
RTOL = 1e-9
MAIN_PARTS = ("forward", "update", "save", "transfer", "waiting", "other")
WORKER_PARTS = ("env_step", "forward", "update", "send", "idle")


# -- child processes (run with PYTHONPATH = one tree) ----------------------------------------------------


def _child_measure(mix: str, warmup: int, rollouts: int, n_steps: int, out: Path) -> None:
    """One timed PPO run of the tree on ``PYTHONPATH``; writes its figures to ``out`` (JSON)."""
    import dataclasses
    import multiprocessing as mp
    import multiprocessing.connection as mpc
    from multiprocessing.reduction import ForkingPickler

    from sb3_contrib import MaskablePPO
    from sb3_contrib.common.maskable.policies import MaskableActorCriticPolicy
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import DummyVecEnv

    import ipp_bench
    from ipp_bench.train.recipe import load_recipe
    from ipp_bench.train.run import execute

    main_pid = os.getpid()
    shared = mp.Array("d", 5)  # workers: env_step, send, idle, forward, update half (summed), inherited by the workers
    main = dict.fromkeys(("forward", "update", "save", "send", "unpickle", "waiting", "env_step"), 0.0)
    depth = {"update": 0}  # inside the PPO update: a wait on a worker is the update's (train.update)
    clock = time.perf_counter

    def add(key: str, dt: float) -> None:
        if os.getpid() == main_pid:
            main[key] += dt
        else:
            with shared.get_lock():
                shared[{"env_step": 0, "send": 1, "waiting": 2, "forward": 3, "half": 4}[key]] += dt

    recv_orig, send_orig = mpc.Connection.recv, mpc.Connection.send

    def recv(self):
        self._check_closed()
        self._check_readable()
        t0 = clock()
        buf = self._recv_bytes()
        t1 = clock()
        obj = ForkingPickler.loads(buf.getbuffer())
        if not (os.getpid() == main_pid and depth["update"]):
            add("waiting", t1 - t0)
        if os.getpid() == main_pid:
            main["unpickle"] += clock() - t1
        return obj

    def send(self, obj):
        t0 = clock()
        send_orig(self, obj)
        add("send", clock() - t0)

    step_wait_orig = DummyVecEnv.step_wait

    def step_wait(self):
        t0 = clock()
        result = step_wait_orig(self)
        add("env_step", clock() - t0)
        return result

    mpc.Connection.recv, mpc.Connection.send, DummyVecEnv.step_wait = recv, send, step_wait
    del recv_orig

    def timed(cls, name: str, key: str) -> None:
        orig = getattr(cls, name)

        def wrapper(self, *args, **kwargs):
            depth[key] = depth.get(key, 0) + 1
            t0 = clock()
            try:
                return orig(self, *args, **kwargs)
            finally:
                depth[key] -= 1
                if not depth[key]:  # the outermost call (a subclass's update may call MaskablePPO's)
                    main[key] += clock() - t0

        setattr(cls, name, wrapper)

    timed(MaskablePPO, "train", "update")
    try:  # the tree's own PPO class, where it has its own update (the split update, train.update)
        from ipp_bench.train import rollout, update
    except ImportError:
        pass
    else:
        if "train" in vars(rollout.WorkerRolloutPPO):
            timed(rollout.WorkerRolloutPPO, "train", "update")
        half_orig = update.half_gradient

        def half_gradient(policy, data):
            t0 = clock()
            try:
                return half_orig(policy, data)
            finally:
                add("half", clock() - t0)

        update.half_gradient = half_gradient
    timed(BaseAlgorithm, "save", "save")
    forward_orig = MaskableActorCriticPolicy.forward

    def forward(self, *args, **kwargs):  # the rollout's forward pass, in the main process or in a worker
        t0 = clock()
        try:
            return forward_orig(self, *args, **kwargs)
        finally:
            add("forward", clock() - t0)

    MaskableActorCriticPolicy.forward = forward
    rollout_start = CallbackList.on_rollout_start
    window: dict[str, float] = {}
    count = [0]
    model = {}

    def on_rollout_start(self):  # every rollout starts here, whoever collects it (SB3's loop or the workers)
        if count[0] == warmup:
            for key in main:
                main[key] = 0.0
            with shared.get_lock():
                shared[:] = [0.0] * len(shared)
            window["t0"], window["steps0"] = clock(), self.model.num_timesteps
        if count[0] == warmup + rollouts:
            window["t1"], window["steps1"] = clock(), self.model.num_timesteps
            window["workers"] = list(shared[:])
            raise KeyboardInterrupt  # ipp-bench train's own way out: it saves its state and returns 130
        count[0] += 1
        model["m"] = self.model
        return rollout_start(self)

    CallbackList.on_rollout_start = on_rollout_start

    stage = load_recipe("attention_v6").stage(MIXES[mix][0])
    run = out.parent / f"run_{out.stem}"
    ckpt = Path(ipp_bench.__file__).parent / "policies" / "checkpoints" / "attention_v6.pt"
    cfg = stage.args(run.parent, init=str(ckpt))
    cfg = dataclasses.replace(cfg, out=str(run), total_steps=10**9, eval_every=10**9, checkpoint_every=10**9,
                              progress=False, n_steps=n_steps or cfg.n_steps,
                              batch_size=min(cfg.batch_size, cfg.n_envs * (n_steps or cfg.n_steps)))
    code = execute(cfg, run)
    if "t1" not in window:
        raise SystemExit(f"the PPO run ended (exit {code}) before the timed window")
    steps = window["steps1"] - window["steps0"]
    wall = window["t1"] - window["t0"]
    result = {"mix": mix, "code": ipp_bench.__file__, "steps": steps, "wall_s": wall,
              "steps_per_s": steps / wall, "algorithm": type(model["m"]).__name__,
              "n_envs": cfg.n_envs, "n_steps": cfg.n_steps, "main": dict(main), "workers": window["workers"],
              "load": os.getloadavg()[0]}
    out.write_text(json.dumps(result))


def _child_episodes(out: Path, seeds: int) -> None:
    """Episodes of greedy and the attention planner on :data:`EPISODE_TASKS`: their report metrics and paths."""
    from ipp_bench.envs.registry import make_env
    from ipp_bench.planners import make_planner
    from ipp_bench.planners.base import RobotView

    rows = []
    for task in EPISODE_TASKS:
        env = make_env(task)
        for spec in EPISODE_PLANNERS:
            planner = make_planner(spec)
            for seed in range(seeds):
                obs, _ = env.reset(seed=seed)
                planner.reset(RobotView(env.unwrapped), seed)
                done, nodes = False, []
                while not done:
                    obs, _, term, trunc, info = env.step(planner.act(obs))
                    nodes.append(int(info["node"]))
                    done = term or trunc
                mission = env.unwrapped.mission
                rows.append({"task": task, "planner": spec, "seed": seed, "nodes": nodes,
                             "report": mission.report(), "final": {k: float(v) for k, v in mission.metrics().items()}})
        env.close()
    out.write_text(json.dumps(rows))


def _child_transitions(out: Path, episodes: int) -> None:
    """The training environments of both mixes (environment 0 and 1 of each) stepped through seeded random
    valid actions: every observation, reward and done, in ``out`` (npz)."""
    from ipp_bench.train.recipe import load_recipe
    from ipp_bench.train.vec import DropPosEncoding, make_train_env

    arrays: dict[str, list] = {}
    for mix, (stage_name, _) in MIXES.items():
        cfg = load_recipe("attention_v6").stage(stage_name).args(Path(tempfile.gettempdir()))
        for i in range(2):
            env = DropPosEncoding(make_train_env(cfg, i))
            rng = np.random.default_rng(1000 + i)
            obs_list, rewards, actions = [], [], []
            for ep in range(episodes):
                obs, _ = env.reset(seed=100 * i + ep)
                done = False
                while not done:
                    a = int(rng.choice(np.flatnonzero(obs["action_mask"])))
                    obs_list.append(obs)
                    actions.append(a)
                    obs, r, term, trunc, _ = env.step(a)
                    rewards.append(r)
                    done = term or trunc
            key = f"{mix}_{i}"
            for k in obs_list[0]:
                arrays[f"{key}/{k}"] = np.stack([o[k] for o in obs_list])
            arrays[f"{key}/reward"] = np.array(rewards)
            arrays[f"{key}/action"] = np.array(actions)
            env.close()
    np.savez(out, **arrays)


def _child_parts(out: Path, reps: int) -> None:
    """The parts one idea each changed, timed alone in this tree (median over ``reps``, after one warm-up): the
    network's PPO minibatch (B 128: forward, backward, Adam) and rollout forward pass (B 16) at 450 and 1800
    nodes; a Kalman update of a 30 x 30 belief (eight beliefs in turn, as in a worker); building an episode's
    prior; one step of a training environment (eight 30 x 30 environments, random actions, resets included);
    pickling and unpickling one worker's step result."""
    from multiprocessing.reduction import ForkingPickler

    import torch
    from gymnasium import spaces
    from stable_baselines3.common.utils import obs_as_tensor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from ipp_bench.policies.checkpoint import load_checkpoint
    from ipp_bench.policies.sb3 import AttentionPolicy
    from ipp_bench.train.recipe import load_recipe
    from ipp_bench.train.vec import DropPosEncoding, make_train_env

    try:
        from ipp_bench.core.belief import GPBelief
    except ImportError:  # the tree before the core package
        from ipp_bench.belief import GPBelief
    try:
        from ipp_bench.core._threads import keep_freed_memory, limit_blas_threads
    except ImportError:
        from ipp_bench._threads import keep_freed_memory, limit_blas_threads
    torch.set_num_threads(1)
    keep_freed_memory()
    limit_blas_threads()
    clock = time.perf_counter

    def median_ms(fn, n: int = reps) -> float:
        fn()
        times = []
        for _ in range(n):
            t0 = clock()
            fn()
            times.append(clock() - t0)
        return 1000.0 * float(np.median(times))

    rng = np.random.default_rng(0)
    ckpt = Path(__import__("ipp_bench").__file__).parent / "policies" / "checkpoints" / "attention_v6.pt"
    net, _ = load_checkpoint(ckpt)
    result: dict[str, float] = {}
    for n_nodes in (450, 1800):
        k = 20
        space = spaces.Dict({"node_features": spaces.Box(-np.inf, np.inf, (n_nodes, 6), np.float32),
                             "current_node": spaces.Box(0, n_nodes - 1, (1,), np.int64),
                             "neighbours": spaces.Box(0, n_nodes - 1, (k,), np.int64),
                             "action_mask": spaces.Box(0, 1, (k,), np.int8),
                             "budget": spaces.Box(0, 1, (1,), np.float32)})
        pe = rng.normal(size=(n_nodes, 32)).astype(np.float32)
        policy = AttentionPolicy(space, spaces.Discrete(k), lambda _: 3e-5, net_config=net.cfg.to_dict(),
                                 pos_encoding=pe)
        policy.attention_net().load_state_dict(net.state_dict())
        for batch in (16, 128):
            obs = {"node_features": rng.normal(size=(batch, n_nodes, 6)).astype(np.float32),
                   "current_node": rng.integers(0, n_nodes, (batch, 1)),
                   "neighbours": rng.integers(0, n_nodes, (batch, k)),
                   "action_mask": (rng.random((batch, k)) > 0.3).astype(np.int8),
                   "budget": rng.random((batch, 1)).astype(np.float32)}
            masks = obs["action_mask"].astype(bool)
            obs_t = obs_as_tensor(obs, "cpu")
            if batch == 16:
                def rollout_forward():
                    with torch.no_grad():
                        policy(obs_t, action_masks=masks)
                result[f"rollout forward B 16, {n_nodes} nodes [ms]"] = median_ms(rollout_forward)
            else:
                actions = torch.as_tensor(rng.integers(0, k, batch))

                def minibatch():
                    values, log_prob, _ = policy.evaluate_actions(obs_t, actions, action_masks=masks)
                    policy.optimizer.zero_grad()
                    (values.mean() - log_prob.mean()).backward()
                    policy.optimizer.step()
                result[f"PPO minibatch B 128, {n_nodes} nodes [ms]"] = median_ms(minibatch, max(3, reps // 3))

    beliefs = [GPBelief.from_grid((30, 30), 2.5, 8.162, 0.0804, 0.5, 0.001959) for _ in range(8)]
    legs = []
    for _ in range(64):
        q = int(rng.integers(12, 40))
        cells = np.sort(rng.choice(900, size=q, replace=False))
        m = int(rng.integers(8, 30))
        legs.append((cells, rng.random((m, q)) / q, rng.normal(size=m), rng.uniform(0.002, 0.02, m)))
    turn = [0]

    def kalman():
        i = turn[0]
        turn[0] += 1
        beliefs[i % 8].update_local(*legs[i % 64])
    result["Kalman update, 30 x 30, m 8-30 [ms]"] = median_ms(kalman, 20 * reps)
    result["an episode's prior, 30 x 30 [ms]"] = median_ms(
        lambda: GPBelief.from_grid((30, 30), 2.5, 8.162, 0.0804, 0.5, 0.001959))

    cfg = load_recipe("attention_v6").stage("ppo30").args(Path(tempfile.gettempdir()))
    venv = DummyVecEnv([lambda i=i: DropPosEncoding(make_train_env(cfg, i)) for i in range(8)])
    venv.seed(0)
    obs = venv.reset()
    last = {}

    def env_step():
        actions = np.array([rng.choice(np.flatnonzero(m)) for m in last.get("obs", obs)["action_mask"]])
        last["obs"], rewards, dones, infos = venv.step(actions)
        last["payload"] = (last["obs"], rewards, dones, infos, venv.reset_infos)
    result["8 training envs, 30 x 30: one step each [ms]"] = median_ms(env_step, 20 * reps)
    blob = ForkingPickler.dumps(last["payload"])
    result["their step result: pickle [ms]"] = median_ms(lambda: ForkingPickler.dumps(last["payload"]), 10 * reps)
    result["their step result: unpickle [ms]"] = median_ms(lambda: ForkingPickler.loads(blob), 10 * reps)
    result["their step result: size [kB]"] = len(blob) / 1000.0
    out.write_text(json.dumps(result))


def _child_network(obs_file: Path, out: Path) -> None:
    """The tree's PPO policy with the shipped weights on recorded observations: logits, values,
    log-probabilities and the gradient of log-probability + value (npz)."""
    import torch
    from gymnasium import spaces
    from stable_baselines3.common.utils import obs_as_tensor

    from ipp_bench.policies.checkpoint import load_checkpoint
    from ipp_bench.policies.sb3 import AttentionPolicy

    torch.set_num_threads(1)
    ckpt = Path(__import__("ipp_bench").__file__).parent / "policies" / "checkpoints" / "attention_v6.pt"
    net, _ = load_checkpoint(ckpt)
    data = np.load(obs_file)
    results = {}
    for key in sorted({k.split("/")[0] for k in data.files}):
        obs = {k.split("/")[1]: data[k] for k in data.files if k.startswith(key + "/")}
        actions, _ = obs.pop("action"), obs.pop("reward")
        n, k = obs["neighbours"].shape
        space = spaces.Dict({name: spaces.Box(-np.inf, np.inf, v.shape[1:], np.float32) for name, v in obs.items()})
        from ipp_bench.envs.registry import make_env

        task = {"30": "ipp_bench/Grid30Train-v1", "15": "ipp_bench/Grid15Train-v1"}[key.split("_")[0]]
        pe = np.asarray(make_env(task).unwrapped.roadmap.pos_encoding, dtype=np.float32)
        policy = AttentionPolicy(space, spaces.Discrete(k), lambda _: 3e-5, net_config=net.cfg.to_dict(),
                                 pos_encoding=pe)
        policy.attention_net().load_state_dict(net.state_dict())
        for batch in (16, 128):
            sl = slice(0, min(batch, n))
            obs_t = obs_as_tensor({name: v[sl] for name, v in obs.items()}, "cpu")
            masks = obs["action_mask"][sl].astype(bool)
            with torch.no_grad():
                dist = policy.get_distribution(obs_t, action_masks=masks)
                results[f"{key}/{batch}/logits"] = dist.distribution.logits.numpy()
            policy.zero_grad()
            values, log_prob, _ = policy.evaluate_actions(obs_t, torch.as_tensor(actions[sl]), action_masks=masks)
            (log_prob.sum() + values.sum()).backward()
            results[f"{key}/{batch}/value"] = values.detach().numpy()
            results[f"{key}/{batch}/log_prob"] = log_prob.detach().numpy()
            results[f"{key}/{batch}/grad"] = torch.cat([p.grad.reshape(-1) for p in policy.parameters()
                                                         if p.grad is not None]).numpy()
    np.savez(out, **results)


# -- the parent: trees, alternation, report --------------------------------------------------------------


def ensure_base(base_dir: Path, rev: str) -> Path:
    """The worktree of ``rev`` at ``base_dir`` (``git worktree add``, detached, if missing)."""
    if not (base_dir / "ipp_bench" / "__init__.py").is_file():
        base_dir.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "worktree", "add", "--detach", str(base_dir), rev], cwd=ROOT, check=True,
                       capture_output=True, text=True)
    return base_dir


def child(tree: Path, *args: str, timeout: float = 3600.0) -> None:
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONHASHSEED="0")
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", *args], cwd=tempfile.gettempdir(),
                          env=env, capture_output=True, text=True, timeout=timeout, check=False)
    if proc.returncode != 0:
        tail = (proc.stdout + proc.stderr)[-3000:]
        raise SystemExit(f"child {' '.join(args)} in {tree} exited {proc.returncode}:\n{tail}")


def measure(trees: dict[str, Path], mixes: list[str], args: argparse.Namespace, work: Path) -> dict:
    results: dict[tuple[str, str], list[dict]] = {}
    for rep in range(args.repeats):
        for mix in mixes:
            order = list(trees) if rep % 2 == 0 else list(trees)[::-1]
            for name in order:
                out = work / f"m_{name}_{mix}_{rep}.json"
                child(trees[name], "measure", "--mix", mix, "--warmup", str(args.warmup), "--rollouts",
                      str(args.rollouts), "--n-steps", str(args.n_steps), "--out", str(out))
                r = json.loads(out.read_text())
                results.setdefault((name, mix), []).append(r)
                print(f"  {name:5s} {mix} x {mix} rep {rep}: {r['steps_per_s']:7.1f} env-steps/s "
                      f"(load {r['load']:.2f})", flush=True)
    return results


def breakdown(runs: list[dict]) -> tuple[dict, dict]:
    """Main-process and worker parts [ms per env-step], pooled over runs."""
    steps = sum(r["steps"] for r in runs)
    wall = sum(r["wall_s"] for r in runs)
    m = {k: sum(r["main"][k] for r in runs) for k in runs[0]["main"]}
    w = np.sum([r["workers"] for r in runs], axis=0)
    main = {"forward": m["forward"], "update": m["update"], "save": m["save"],
            "transfer": m["send"] + m["unpickle"], "waiting": m["waiting"]}
    main["other"] = wall - sum(main.values())
    workers = {"env_step": w[0], "forward": w[3], "update": w[4] if len(w) > 4 else 0.0, "send": w[1], "idle": w[2]}
    scale = 1000.0 / steps
    return {k: v * scale for k, v in main.items()}, {k: v * scale for k, v in workers.items()}


def report(results: dict, trees: dict[str, Path], mixes: list[str]) -> None:
    print("\nenv-steps/s (pooled over repeats; per run in brackets)")
    for mix in mixes:
        rates = {}
        for name in trees:
            runs = results[(name, mix)]
            rates[name] = sum(r["steps"] for r in runs) / sum(r["wall_s"] for r in runs)
            loads = [r["load"] for r in runs]
            print(f"{MIXES[mix][1]:36s} {name:5s} {rates[name]:7.1f}  "
                  "[" + ", ".join(f"{r['steps_per_s']:.1f}" for r in runs)
                  + f"]  load {min(loads):.1f}-{max(loads):.1f}")
        for name in rates:
            if name != "old":
                print(f"{MIXES[mix][1]:36s} {name} / old: {rates[name] / rates['old']:.2f}x")
    print("\nwhere the time goes [ms per env-step]; main process: "
          + ", ".join(MAIN_PARTS) + "; workers (CPU, summed): " + ", ".join(WORKER_PARTS))
    for mix in mixes:
        for name in trees:
            main, workers = breakdown(results[(name, mix)])
            total = sum(main.values())
            print(f"{mix} x {mix} {name:5s} main {total:6.3f} = "
                  + " + ".join(f"{k} {main[k]:.3f}" for k in MAIN_PARTS)
                  + " | workers " + ", ".join(f"{k} {workers[k]:.3f}" for k in WORKER_PARTS))


def parts(trees: dict[str, Path], work: Path, reps: int, repeats: int) -> None:
    """The parts each idea changed, per tree (alternating, ``repeats`` times; the median of the runs' medians)."""
    runs: dict[str, list[dict]] = {name: [] for name in trees}
    for rep in range(repeats):
        for name in (list(trees) if rep % 2 == 0 else list(trees)[::-1]):
            out = work / f"parts_{name}_{rep}.json"
            child(trees[name], "parts", "--part-reps", str(reps), "--out", str(out))
            runs[name].append(json.loads(out.read_text()))
    print(f"\nparts alone, one process each (load {os.getloadavg()[0]:.2f}): old / new, median of {repeats} run(s)")
    for key in runs["old"][0]:
        old = float(np.median([r[key] for r in runs["old"]]))
        new = float(np.median([r[key] for r in runs["new"]]))
        print(f"  {key:48s} {old:9.3f} {new:9.3f}  {old / new if new else float('inf'):5.2f}x")


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        return float("inf")
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300)
    diff = np.abs(a - b)
    both_inf = (a == b)
    return float(np.max(np.where(both_inf, 0.0, diff / scale), initial=0.0))


def equality(trees: dict[str, Path], work: Path, seeds: int, episodes: int) -> None:
    print("\nequality of the MDP and the network (old = " + str(trees["old"]) + ")")
    for name, tree in trees.items():
        child(tree, "episodes", "--seeds", str(seeds), "--out", str(work / f"ep_{name}.json"))
    old, new = (json.loads((work / f"ep_{n}.json").read_text()) for n in ("old", "new"))
    worst = 0.0
    for a, b in zip(old, new, strict=True):
        same_path = a["nodes"] == b["nodes"]
        keys = list(a["final"])
        rel = max(_rel([r[k] for r in a["report"] for k in r], [r[k] for r in b["report"] for k in r]),
                  _rel([a["final"][k] for k in keys], [b["final"][k] for k in keys]))
        worst = max(worst, rel if same_path else float("inf"))
        print(f"  episode {a['task']:30s} {a['planner']:9s} seed {a['seed']}: {len(a['nodes'])} legs, "
              f"same path {same_path}, metrics max rel. diff {rel:.2e}")
    print(f"episodes: {len(old)}, metrics max rel. diff {worst:.2e} ({'equal' if worst <= RTOL else 'DIFFERENT'} "
          f"to {RTOL:g})")

    for name, tree in trees.items():
        child(tree, "transitions", "--episodes", str(episodes), "--out", str(work / f"tr_{name}.npz"))
    a, b = np.load(work / "tr_old.npz"), np.load(work / "tr_new.npz")
    worst = max(_rel(a[k], b[k]) for k in a.files) if set(a.files) == set(b.files) else float("inf")
    n = sum(a[k].shape[0] for k in a.files if k.endswith("/reward"))
    print(f"training transitions: {n}, observations and rewards max rel. diff {worst:.2e} "
          f"({'equal' if worst <= RTOL else 'DIFFERENT'} to {RTOL:g})")

    for name, tree in trees.items():
        child(tree, "network", "--obs", str(work / "tr_old.npz"), "--out", str(work / f"net_{name}.npz"))
    a, b = np.load(work / "net_old.npz"), np.load(work / "net_new.npz")
    for what in ("logits", "value", "log_prob", "grad"):
        keys = [k for k in a.files if k.endswith("/" + what)]
        old_v = np.concatenate([a[k].reshape(-1) for k in keys]).astype(np.float64)
        new_v = np.concatenate([b[k].reshape(-1) for k in keys]).astype(np.float64)
        if what == "logits":  # masked neighbours hold -1e8 in both
            old_v, new_v = old_v[np.abs(old_v) < 1e7], new_v[np.abs(old_v) < 1e7]
        diff = np.abs(old_v - new_v)
        scale = float(np.abs(old_v).max())
        print(f"network {what:8s}: max |old - new| {diff.max():.2e}, relative to max |old| ({scale:.2e}) "
              f"{diff.max() / scale:.1e} ({'float32 rounding' if diff.max() <= 1e-5 * scale else 'DIFFERENT'})")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mixes", nargs="+", default=["30", "15"], choices=list(MIXES))
    p.add_argument("--warmup", type=int, default=1, help="untimed rollouts of each run")
    p.add_argument("--rollouts", type=int, default=3, help="timed rollouts (16 x n_steps env-steps each) per run")
    p.add_argument("--repeats", type=int, default=2, help="alternations of old and new per mix")
    p.add_argument("--n-steps", type=int, default=0, help="steps per env per rollout (0: the recipe's, 64)")
    p.add_argument("--base", default=BASE_REV, help="the baseline commit")
    p.add_argument("--base-dir", type=Path, default=ROOT / "runs" / "bench_base", help="its worktree")
    p.add_argument("--skip-throughput", action="store_true")
    p.add_argument("--skip-equality", action="store_true")
    p.add_argument("--seeds", type=int, default=2, help="episodes per task and planner in the equality check")
    p.add_argument("--episodes", type=int, default=2, help="episodes per training env in the transitions check")
    p.add_argument("--tiny", action="store_true", help="smoke test: 15 x 15, 8 steps per env, one repeat")
    p.add_argument("--child", nargs="?", choices=["measure", "episodes", "transitions", "network", "parts"])
    p.add_argument("--parts", action="store_true", help="also time the parts each idea changed, alone, per tree")
    p.add_argument("--part-reps", type=int, default=15, help="repetitions of each part's timing (--parts)")
    p.add_argument("--mix", choices=list(MIXES))
    p.add_argument("--obs", type=Path)
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    if args.child == "measure":
        _child_measure(args.mix, args.warmup, args.rollouts, args.n_steps, args.out)
        return 0
    if args.child == "episodes":
        _child_episodes(args.out, args.seeds)
        return 0
    if args.child == "transitions":
        _child_transitions(args.out, args.episodes)
        return 0
    if args.child == "network":
        _child_network(args.obs, args.out)
        return 0
    if args.child == "parts":
        _child_parts(args.out, args.part_reps)
        return 0
    if args.tiny:
        args.mixes, args.n_steps, args.repeats, args.rollouts, args.seeds, args.episodes = ["15"], 8, 1, 1, 1, 1

    trees = {"old": ensure_base(args.base_dir, args.base), "new": ROOT}
    print(f"old: {args.base} ({trees['old']}), new: {ROOT}; {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f} "
          f"at start")
    with tempfile.TemporaryDirectory(prefix="bench_train_") as tmp:
        work = Path(tmp)
        if not args.skip_throughput:
            results = measure(trees, args.mixes, args, work)
            report(results, trees, args.mixes)
        if args.parts:
            parts(trees, work, args.part_reps, args.repeats)
        if not args.skip_equality:
            equality(trees, work, args.seeds, args.episodes)
    print(f"load at the end {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
