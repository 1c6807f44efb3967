"""``ipp-bench train``: train the attention policy (behaviour-cloning warm start + MaskablePPO).

Two phases, both resumable, in one run folder:

1. **Warm start** (``--warm-start greedy``, optional): DAgger-style behaviour cloning from a planner
   of the registry. Round 0 flies the expert; later rounds fly the student (the expert's action
   taken with probability 0.5^round) and label every visited state with the expert's choice. The
   network is fitted to the labels (cross-entropy) and its value head to the discounted returns
   observed, so that PPO starts from a policy near the expert and a critic that knows its scale.
2. **PPO** (sb3-contrib ``MaskablePPO`` with :class:`~ipp_bench.policies.sb3.AttentionPolicy`)
   for ``--total-steps`` environment steps, validating the deterministic policy every
   ``--eval-every`` steps on fixed episodes of the training task (never the evaluation tasks).

Defaults are the paper's PPO settings (Adam, lr 1e-5, 8 epochs per batch, batch 128, gamma 0.99,
one-step TD advantages = GAE lambda 0, 5 parallel instances) and no warm start; see
``ipp_bench/policies/checkpoints/README.md`` for the settings of the shipped checkpoint and why
they differ.

Run folder (``--out DIR``, default ``runs/<task>__attention__<seed>__<time>``)::

    config.json      the arguments and the exact command
    state.json       phase bookkeeping (warm start done, steps trained)
    progress.csv     SB3 training log (appended across resumes), validation included
    tb/              TensorBoard logs
    warmstart/       bc.pt (warm-start weights), bc_log.csv
    checkpoints/     latest.zip (after every PPO update), step_<n>.zip, best.zip (validation)
    export.pt        best validated policy in the shipped checkpoint format (+ export.json)
    last.pt          final policy in the same format

``--resume`` continues a run from ``latest.zip``: a checkpoint is written after every PPO update,
so an interrupted run (Ctrl-C, SIGTERM) loses at most the rollout being collected, which was not
trained on yet; the step counter continues from the checkpoint.

Episodes (validation, warm-start collection) go through the suite's one episode loop,
:func:`ipp_bench.planners.episode.fly_episode`, and validation decides through the leaderboard's
:class:`~ipp_bench.policies.planner.AttentionPlanner`. Why this module is over 400 lines: it holds
the whole training script (arguments, warm start, PPO callbacks, run folder); issue 11 rewrites
and splits it.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import shlex
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ipp_bench._threads import available_cpus
from ipp_bench.envs.registry import parse_overrides
from ipp_bench.planners.base import GraphPlanner, softmax
from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from ipp_bench.policies.network import MASKED_LOGIT, AttentionNet, NetConfig

VAL_SEED0 = 10_000_000  # validation episodes use seeds VAL_SEED0 + i (training uses --seed onwards)


@dataclass
class TrainArgs:
    """Every option of ``ipp-bench train`` with its default (the paper's values where it has one)."""

    task: str = "ipp_bench/Grid15-v0"
    env: list[str] = field(default_factory=list)  # KEY=VALUE overrides of the task config (budget_s=200)
    total_steps: int = 200_000  # PPO environment steps (the warm start comes on top)
    n_envs: int = 5  # paper: five parallel instances
    n_steps: int = 128  # steps per env per PPO rollout: 5 x 128 = 640 samples = 5 batches
    batch_size: int = 128  # paper
    n_epochs: int = 8  # paper: eight PPO iterations per batch
    learning_rate: float = 1e-5  # paper
    gamma: float = 0.99  # paper
    gae_lambda: float = 0.0  # paper: one-step TD error
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.0  # 0 = off
    embed_dim: int = 128  # CAtNIPP / paper
    n_heads: int = 4
    ff_dim: int = 512
    warm_start: str = "none"  # planner to imitate first ("greedy"), or "none"
    bc_episodes: int = 100  # expert episodes of round 0
    bc_rounds: int = 2  # DAgger rounds after round 0
    bc_round_episodes: int = 50  # student episodes per DAgger round
    bc_epochs: int = 8  # passes over the data after each round
    bc_lr: float = 3e-4
    bc_temperature: float = 0.1  # soft targets from the expert's scores; 0 = one-hot on its action
    val_task: str = ""  # task of the validation episodes; "" = the training task
    eval_every: int = 20_000  # [steps] validation period (also after the warm start)
    eval_episodes: int = 16
    checkpoint_every: int = 20_000  # [steps] keep checkpoints/step_<n>.zip
    seed: int = 0
    device: str = "auto"  # auto | cpu | cuda
    threads: int = 0  # torch threads; 0 = half the CPUs available to this process, at least 1
    out: str = ""  # run folder
    progress: bool = True

    def net_config(self) -> NetConfig:
        return NetConfig(embed_dim=self.embed_dim, n_heads=self.n_heads, ff_dim=self.ff_dim)


# Options that may change when resuming a run; all others must match the saved config.
_RESUMABLE = {"total_steps", "device", "threads", "progress", "out"}


def add_train_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of ``ipp-bench train`` to ``parser`` (defaults documented in the help)."""
    d = TrainArgs()
    a = parser.add_argument
    a("--task", default=None, help=f"gymnasium task id to train on (default {d.task})")
    a("--env", metavar="KEY=VALUE", action="append", default=None,
      help="override a field of the task config for training, e.g. --env budget_s=200 (repeatable; "
           "values are read as JSON where they parse)")
    a("--total-steps", type=int, default=None, help=f"PPO environment steps (default {d.total_steps})")
    a("--n-envs", type=int, default=None, help=f"parallel environments (default {d.n_envs}, the paper's 5)")
    a("--device", default=None, help="torch device: auto, cpu or cuda (default auto)")
    a("--out", default=None, help="run folder (default runs/<task>__attention__<seed>__<time>)")
    a("--resume", action="store_true", help="continue the run in --out from its latest checkpoint")
    a("--seed", type=int, default=None, help=f"seed (default {d.seed})")
    a("--threads", type=int, default=None,
      help="torch intra-op threads (default: half the CPUs available, at least 1; 1 on a 2-core machine)")
    g = parser.add_argument_group("PPO (paper values as defaults)")
    g.add_argument("--learning-rate", type=float, default=None, help=f"Adam learning rate (default {d.learning_rate})")
    g.add_argument("--n-epochs", type=int, default=None, help=f"epochs per rollout (default {d.n_epochs})")
    g.add_argument("--batch-size", type=int, default=None, help=f"minibatch size (default {d.batch_size})")
    g.add_argument("--n-steps", type=int, default=None, help=f"steps per env per rollout (default {d.n_steps})")
    g.add_argument("--gamma", type=float, default=None, help=f"discount (default {d.gamma})")
    g.add_argument("--gae-lambda", type=float, default=None,
                   help=f"GAE lambda (default {d.gae_lambda}: the paper's one-step TD advantage)")
    g.add_argument("--clip-range", type=float, default=None, help=f"PPO clip (default {d.clip_range})")
    g.add_argument("--ent-coef", type=float, default=None, help=f"entropy bonus (default {d.ent_coef})")
    g.add_argument("--vf-coef", type=float, default=None, help=f"value loss weight (default {d.vf_coef})")
    g.add_argument("--max-grad-norm", type=float, default=None, help=f"gradient clip (default {d.max_grad_norm})")
    g.add_argument("--target-kl", type=float, default=None, help="early-stop an update past this KL (default off)")
    n = parser.add_argument_group("network")
    n.add_argument("--embed-dim", type=int, default=None, help=f"d (default {d.embed_dim})")
    n.add_argument("--n-heads", type=int, default=None, help=f"attention heads (default {d.n_heads})")
    n.add_argument("--ff-dim", type=int, default=None, help=f"feed-forward width (default {d.ff_dim})")
    w = parser.add_argument_group("warm start (behaviour cloning / DAgger)")
    w.add_argument("--warm-start", default=None,
                   help="planner to imitate before PPO, e.g. greedy; 'none' to skip (default none)")
    w.add_argument("--bc-episodes", type=int, default=None, help=f"expert episodes (default {d.bc_episodes})")
    w.add_argument("--bc-rounds", type=int, default=None, help=f"DAgger rounds (default {d.bc_rounds})")
    w.add_argument("--bc-round-episodes", type=int, default=None,
                   help=f"student episodes per DAgger round (default {d.bc_round_episodes})")
    w.add_argument("--bc-epochs", type=int, default=None, help=f"epochs after each round (default {d.bc_epochs})")
    w.add_argument("--bc-lr", type=float, default=None, help=f"warm-start learning rate (default {d.bc_lr})")
    w.add_argument("--bc-temperature", type=float, default=None,
                   help="soft imitation targets p ~ exp((score/best - 1)/T) from the expert's scores; 0 = one-hot "
                        f"(default {d.bc_temperature})")
    v = parser.add_argument_group("validation and checkpoints")
    v.add_argument("--val-task", default=None,
                   help="task of the validation episodes (seeds 10,000,000 onwards, disjoint from the "
                        "leaderboard's); default: the training task")
    v.add_argument("--eval-every", type=int, default=None, help=f"validation period in steps (default {d.eval_every})")
    v.add_argument("--eval-episodes", type=int, default=None, help=f"validation episodes (default {d.eval_episodes})")
    v.add_argument("--checkpoint-every", type=int, default=None,
                   help=f"keep a numbered checkpoint every this many steps (default {d.checkpoint_every})")
    v.add_argument("--no-progress", dest="progress", action="store_false", default=None,
                   help="no progress bar")
    parser.add_argument("--export", metavar="ZIP", default=None,
                        help="only convert an SB3 checkpoint (.zip) of a run to the shipped .pt format and exit")
    return parser


def _explicit(ns: argparse.Namespace) -> dict[str, Any]:
    names = {f.name for f in fields(TrainArgs)}
    return {k: v for k, v in vars(ns).items() if k in names and v is not None}


def command_line(cfg: TrainArgs) -> str:
    """The exact ``ipp-bench train`` command for ``cfg`` (every option spelled out)."""
    parts = ["ipp-bench", "train"]
    for f in fields(TrainArgs):
        val = getattr(cfg, f.name)
        if f.name == "progress":
            if not val:
                parts.append("--no-progress")
            continue
        if f.name in ("out", "device", "threads"):
            continue
        if f.name == "env":
            for item in val:
                parts += ["--env", item]
            continue
        parts += [f"--{f.name.replace('_', '-')}", str(val)]
    return shlex.join(parts)


def _check(cfg: TrainArgs) -> None:
    positive = ("total_steps", "n_envs", "n_steps", "batch_size", "n_epochs", "eval_episodes",
                "checkpoint_every", "eval_every", "embed_dim", "n_heads", "ff_dim")
    for name in positive:
        if getattr(cfg, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} = {getattr(cfg, name)} is invalid: expected an integer >= 1")
    for name in ("bc_episodes", "bc_rounds", "bc_round_episodes", "bc_epochs", "threads"):
        if getattr(cfg, name) < 0:
            raise ValueError(f"--{name.replace('_', '-')} = {getattr(cfg, name)} is invalid: expected an integer >= 0")
    if cfg.bc_temperature < 0:
        raise ValueError(f"--bc-temperature = {cfg.bc_temperature} is invalid: expected >= 0 (0 = one-hot targets)")
    if not 0 < cfg.learning_rate < 1 or not 0 < cfg.bc_lr < 1:
        raise ValueError("--learning-rate and --bc-lr must lie in (0, 1)")
    if not 0 <= cfg.gamma <= 1 or not 0 <= cfg.gae_lambda <= 1:
        raise ValueError("--gamma and --gae-lambda must lie in [0, 1]")
    if cfg.device not in ("auto", "cpu") and not cfg.device.startswith("cuda"):
        raise ValueError(f"--device {cfg.device!r} is invalid: expected auto, cpu, cuda or cuda:<n>")
    if cfg.device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"--device {cfg.device} asked for but torch sees no CUDA device; use --device cpu")
    cfg.net_config()  # validates the network sizes
    import gymnasium as gym

    import ipp_bench.envs  # noqa: F401 - registers the tasks

    if cfg.task not in gym.registry:
        valid = sorted(t for t in gym.registry if t.startswith("ipp_bench/"))
        raise ValueError(f"--task {cfg.task!r} is not a registered task: valid are {valid}")
    if cfg.val_task and cfg.val_task not in gym.registry:
        raise ValueError(f"--val-task {cfg.val_task!r} is not a registered task")
    try:
        make_train_env(cfg).close()  # a bad override fails now, with the config's message
    except (ValueError, TypeError) as err:
        raise ValueError(f"--task {cfg.task} with --env {cfg.env}: {err}") from None


def _resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def set_threads(n: int = 0) -> int:
    """Torch intra-op threads: ``n``, or half the CPUs available to this process (at least 1).

    Measured on the 2-core development machine while other jobs ran (load average about 3): PPO
    made 145 env-steps/s with one torch thread and 7 with two, and a 450-node forward pass took
    1.5 ms with one thread and 200 ms with two (OpenMP threads waiting on each other whenever one
    is descheduled). Half the CPUs leaves room for the environments and for other processes.
    """
    n = n or max(1, available_cpus() // 2)
    torch.set_num_threads(n)
    return n


# ------------------------------------------------------------------------------------------------
# Environments and experts
# ------------------------------------------------------------------------------------------------
def make_env(task: str, **overrides: Any):
    import gymnasium as gym

    import ipp_bench.envs  # noqa: F401 - registers the tasks

    return gym.make(task, **overrides)


def make_train_env(cfg: TrainArgs):
    """The training task with the run's ``--env`` overrides."""
    return make_env(cfg.task, **parse_overrides(cfg.env))


def _validation(net: AttentionNet, cfg: TrainArgs, device: torch.device) -> dict[str, float]:
    if cfg.val_task:
        return evaluate_net(net, cfg.val_task, cfg.eval_episodes, device)
    return evaluate_net(net, cfg.task, cfg.eval_episodes, device, overrides=parse_overrides(cfg.env))


def make_expert(name: str) -> _PlannerExpert:
    """``expert(obs) -> (action index, scores)`` from the planner registry (``greedy``, ``mcts``, ...)."""
    try:
        from ipp_bench.planners import make_planner
    except ImportError as err:
        raise ValueError(f"--warm-start {name}: the planner registry is not available ({err})") from None
    planner = make_planner(name)
    if getattr(planner, "kind", None) != "graph":
        raise ValueError(f"--warm-start {name}: a roadmap planner (kind 'graph') is needed to label neighbours")
    return _PlannerExpert(planner)


class _PlannerExpert:
    """A registry planner as ``expert(obs) -> (action, scores)``; the episode loop resets it."""

    def __init__(self, planner: Any) -> None:
        self.planner = planner

    def __call__(self, obs: dict) -> tuple[int, np.ndarray | None]:
        """The expert's action and, where the planner exposes them, its scores per neighbour."""
        if hasattr(self.planner, "scores"):
            scores = np.asarray(self.planner.scores(obs), dtype=np.float64)
            return int(np.argmax(scores)), scores
        return int(self.planner.act(obs)), None


def soft_target(action: int, scores: np.ndarray | None, k: int, temperature: float) -> np.ndarray:
    """Imitation target over the k neighbours.

    With expert scores (e.g. greedy's predicted gain per second), neighbours scoring close to the
    best share the probability: ``p ~ exp((s / s_max - 1) / temperature)`` over the valid ones, so
    near-ties are not forced apart. Without scores (or ``temperature = 0``): one-hot on the action.
    """
    target = np.zeros(k, dtype=np.float32)
    if scores is None or temperature <= 0:
        target[action] = 1.0
        return target
    valid = np.isfinite(scores)
    best = scores[action]
    if best <= 0 or not valid.any():
        target[action] = 1.0
        return target
    z = np.where(valid, (scores / best - 1.0) / temperature, -np.inf)
    return softmax(z).astype(np.float32)


def obs_batch(obs_list: list[dict], device: torch.device) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(np.stack([o[k] for o in obs_list])).to(device) for k in obs_list[0]}


@torch.no_grad()
def net_action(net: AttentionNet, obs: dict, device: torch.device, deterministic: bool = True,
               rng: np.random.Generator | None = None) -> int:
    logits, _ = net.forward_obs(obs_batch([obs], device))
    logits = logits[0].cpu().numpy().astype(np.float64)
    if deterministic:
        return int(np.argmax(logits))
    return int((rng or np.random.default_rng()).choice(logits.size, p=softmax(logits)))


def evaluate_net(net: AttentionNet, task: str, episodes: int, device: torch.device,
                 seed0: int = VAL_SEED0, overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """Deterministic (argmax) episodes of ``task`` on fixed seeds, through the episode loop and the
    planner class the leaderboard uses (:class:`~ipp_bench.policies.planner.AttentionPlanner`).

    Every second episode starts at the node nearest the default start of
    :class:`~ipp_bench.config.MissionConfig` (above cell (2, 2) at 14 m) instead of the task's own
    start rule, so that a policy which is good from random starts but, say, oscillates between
    two nodes from the standard start does not pass validation.

    Returns:
        ``val/score`` (mean ROI uncertainty reduction over the report times within the budget, or
        at the end of the budget if none is), ``val/unc_red_<t>s`` per report time, ``val/return``.
    """
    from ipp_bench.config import MissionConfig
    from ipp_bench.mission import cell_to_xyz
    from ipp_bench.planners.episode import fly_episode
    from ipp_bench.policies.planner import AttentionPlanner

    base = make_env(task, **(overrides or {})).unwrapped
    times = base.config.mission.report_times_in_budget or (base.config.mission.budget_s,)
    start = MissionConfig().start
    std_node = base.roadmap.nearest_node(cell_to_xyz(base.config, *start)) if start is not None else None
    planner = AttentionPlanner.from_net(net, device)
    red, ret = [], []
    was_training = net.training
    net.eval()
    for i in range(episodes):
        options = {"start_node": std_node} if (i % 2 and std_node is not None) else None
        result = fly_episode(base, planner, seed0 + i, options=options)
        red.append([base.mission.metrics_at(t)["uncertainty_reduction_pct"] for t in times])
        ret.append(result.total_reward)
    net.train(was_training)
    red_arr = np.asarray(red)
    out = {"val/score": float(red_arr.mean()), "val/return": float(np.mean(ret))}
    for j, t in enumerate(times):
        out[f"val/unc_red_{int(t)}s"] = float(red_arr[:, j].mean())
    return out


# ------------------------------------------------------------------------------------------------
# Warm start: behaviour cloning with DAgger
# ------------------------------------------------------------------------------------------------
class BCDataset:
    """States visited, expert labels and discounted returns (positional encodings stored once)."""

    def __init__(self) -> None:
        self.nf: list[np.ndarray] = []
        self.small: list[np.ndarray] = []  # [current, neighbours (k), mask (k), budget]
        self.pe_id: list[int] = []
        self.action: list[int] = []
        self.target: list[np.ndarray] = []
        self.ret: list[float] = []
        self.pes: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self.action)

    def _pe_index(self, pe: np.ndarray) -> int:
        for i, p in enumerate(self.pes):
            if p.shape == pe.shape and np.array_equal(p, pe):
                return i
        self.pes.append(np.array(pe, dtype=np.float32))
        return len(self.pes) - 1

    def add_episode(self, obs_list: list[dict], actions: list[int], targets: list[np.ndarray], rewards: list[float],
                    gamma: float) -> None:
        g, rets = 0.0, []
        for r in reversed(rewards):
            g = r + gamma * g
            rets.append(g)
        rets.reverse()
        for o, a, tg, rt in zip(obs_list, actions, targets, rets):
            self.nf.append(o["node_features"].astype(np.float32))
            self.small.append(np.concatenate([o["current_node"].astype(np.float32), o["neighbours"].astype(np.float32),
                                              o["action_mask"].astype(np.float32), o["budget"].astype(np.float32)]))
            self.pe_id.append(self._pe_index(o["pos_encoding"]))
            self.action.append(int(a))
            self.target.append(tg)
            self.ret.append(float(rt))

    def batches(self, batch_size: int, rng: np.random.Generator, device: torch.device):
        order = rng.permutation(len(self))
        k = (self.small[0].size - 2) // 2
        pes = [torch.as_tensor(p) for p in self.pes]
        for s in range(0, len(order), batch_size):
            idx = order[s : s + batch_size]
            small = torch.as_tensor(np.stack([self.small[i] for i in idx]))
            obs = {
                "node_features": torch.as_tensor(np.stack([self.nf[i] for i in idx])),
                "pos_encoding": torch.stack([pes[self.pe_id[i]] for i in idx]),
                "current_node": small[:, :1],
                "neighbours": small[:, 1 : 1 + k],
                "action_mask": small[:, 1 + k : 1 + 2 * k],
                "budget": small[:, -1:],
            }
            obs = {key: t.to(device) for key, t in obs.items()}
            yield obs, torch.as_tensor(np.stack([self.target[i] for i in idx])).to(device), \
                torch.as_tensor(np.array([self.ret[i] for i in idx], dtype=np.float32)).to(device)


def collect_episodes(env, expert, net: AttentionNet | None, episodes: int, beta: float, data: BCDataset,
                     gamma: float, rng: np.random.Generator, seed0: int, device: torch.device,
                     temperature: float = 0.0) -> dict[str, float]:
    """Fly ``episodes`` episodes through the episode loop (:func:`~ipp_bench.planners.episode.fly_episode`);
    at each state the expert's action is executed with probability ``beta`` (else the student's,
    sampled); every state is labelled with the expert's action."""
    from ipp_bench.planners.episode import fly_episode

    red, steps = [], 0
    for e in range(episodes):
        dagger = _DaggerPlanner(expert, net, beta, rng, device, temperature)
        rews: list[float] = []
        result = fly_episode(env.unwrapped, dagger, seed0 + e, on_decision=lambda d: rews.append(d.reward))
        data.add_episode(dagger.obs_list, dagger.expert_actions, dagger.targets, rews, gamma)
        red.append(result.final["uncertainty_reduction_pct"])
        steps += len(dagger.expert_actions)
    return {"episodes": episodes, "steps": steps, "unc_red_final": float(np.mean(red)) if red else float("nan")}


class _DaggerPlanner(GraphPlanner):
    """DAgger's behaviour policy as a planner: labels every state with the expert's action and
    executes it with probability ``beta``, else the student's (sampled)."""

    name = "dagger"

    def __init__(self, expert, net, beta: float, rng: np.random.Generator, device: torch.device,
                 temperature: float) -> None:
        super().__init__(None)
        self.expert, self.net, self.beta, self.student_rng = expert, net, beta, rng
        self.device, self.temperature = device, temperature
        self.obs_list: list[dict] = []
        self.expert_actions: list[int] = []
        self.targets: list[np.ndarray] = []

    def reset(self, view, seed: int) -> None:
        super().reset(view, seed)
        self.expert.planner.reset(view, seed)

    def act(self, obs):
        a_exp, scores = self.expert(obs)
        self.targets.append(soft_target(a_exp, scores, len(obs["action_mask"]), self.temperature))
        a = a_exp
        if self.net is not None and self.student_rng.random() >= self.beta:
            a = net_action(self.net, obs, self.device, deterministic=False, rng=self.student_rng)
        self.obs_list.append(obs)
        self.expert_actions.append(a_exp)
        return a


def fit_bc(net: AttentionNet, data: BCDataset, epochs: int, lr: float, batch_size: int, rng: np.random.Generator,
           device: torch.device, vf_coef: float = 0.5, log: Callable[[dict], None] | None = None) -> None:
    """Cross-entropy to the expert's targets + ``vf_coef`` x Huber loss of the value to the returns.

    Logged: the losses, ``acc`` (argmax = the expert's best) and ``target_p`` (the target probability
    of the student's argmax, 1 = as good as the expert's choice by the expert's own scores)."""
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    for epoch in range(epochs):
        tot = {"loss_pi": 0.0, "loss_v": 0.0, "acc": 0.0, "target_p": 0.0, "n": 0}
        for obs, target, ret in data.batches(batch_size, rng, device):
            logits, value = net.forward_obs(obs)
            logits = logits.clamp_min(MASKED_LOGIT)
            loss_pi = -(target * torch.log_softmax(logits, -1)).sum(-1).mean()
            loss_v = F.smooth_l1_loss(value, ret)
            loss = loss_pi + vf_coef * loss_v
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            n = target.shape[0]
            tot["loss_pi"] += loss_pi.item() * n
            tot["loss_v"] += loss_v.item() * n
            choice = logits.argmax(-1, keepdim=True)
            tot["acc"] += (choice[:, 0] == target.argmax(-1)).float().sum().item()
            tot["target_p"] += (target.gather(1, choice) / target.max(-1, keepdim=True).values).sum().item()
            tot["n"] += n
        if log is not None:
            n = max(tot["n"], 1)
            log({"epoch": epoch, "loss_pi": tot["loss_pi"] / n, "loss_v": tot["loss_v"] / n, "acc": tot["acc"] / n,
                 "target_p": tot["target_p"] / n})
    net.eval()


def warm_start(cfg: TrainArgs, run: Path, device: torch.device, say: Callable[[str], None]
               ) -> tuple[AttentionNet, dict[str, float]]:
    """Behaviour cloning (DAgger) from ``cfg.warm_start``; writes ``warmstart/bc.pt``."""
    out = run / "warmstart"
    out.mkdir(exist_ok=True)
    env = make_train_env(cfg)
    expert = make_expert(cfg.warm_start)
    torch.manual_seed(cfg.seed)
    net = AttentionNet(cfg.net_config()).to(device)
    data = BCDataset()
    rng = np.random.default_rng(cfg.seed)
    log_path = out / "bc_log.csv"
    rows: list[dict] = []

    def log(row: dict) -> None:
        rows.append({"round": rnd, "samples": len(data), "wall_s": round(time.time() - t0, 1), **row})
        with log_path.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=sorted({k for r in rows for k in r}))
            w.writeheader()
            w.writerows(rows)

    t0 = time.time()
    seed = cfg.seed * 1_000_003
    for rnd in range(cfg.bc_rounds + 1):
        n_ep = cfg.bc_episodes if rnd == 0 else cfg.bc_round_episodes
        beta = 0.5 ** rnd
        stats = collect_episodes(env, expert, None if rnd == 0 else net, n_ep, beta, data, cfg.gamma, rng,
                                 seed, device, temperature=cfg.bc_temperature)
        seed += n_ep
        say(f"warm start round {rnd}: {stats['episodes']} episodes (beta {beta:.2f}), {len(data)} samples, "
            f"final ROI uncertainty reduction of the flown paths {stats['unc_red_final']:.1f}%")
        log({"phase": "collect", **stats})
        fit_bc(net, data, cfg.bc_epochs, cfg.bc_lr, cfg.batch_size, rng, device,
               log=lambda r: (log({"phase": "fit", **r}),
                              say(f"  epoch {r['epoch']}: loss_pi {r['loss_pi']:.3f} loss_v {r['loss_v']:.3f} "
                                  f"acc {r['acc']:.3f} target_p {r['target_p']:.3f}")))
    val = _validation(net, cfg, device)
    log({"phase": "validate", **val})
    say(f"warm start done in {time.time() - t0:.0f} s; validation: {_fmt(val)}")
    save_checkpoint(net, out / "bc.pt", meta={"task": cfg.task, "phase": "warm start",
                                               "expert": cfg.warm_start, "samples": len(data),
                                               "wall_s": time.time() - t0, **val})
    return net, val


# ------------------------------------------------------------------------------------------------
# PPO
# ------------------------------------------------------------------------------------------------
def _fmt(d: dict) -> str:
    return ", ".join(f"{k.split('/')[-1]} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


def _logger(run: Path):
    from stable_baselines3.common.logger import CSVOutputFormat, Logger, TensorBoardOutputFormat

    class AppendingCSV(CSVOutputFormat):
        """SB3's CSV output, keeping the rows of earlier sessions of the run."""

        def __init__(self, filename: str) -> None:
            old = Path(filename).read_text() if Path(filename).is_file() else ""
            super().__init__(filename)
            if old.strip():
                self.file.write(old if old.endswith("\n") else old + "\n")
                self.file.flush()
                self.keys = old.splitlines()[0].split(self.separator)

    formats = [AppendingCSV(str(run / "progress.csv"))]
    try:
        formats.append(TensorBoardOutputFormat(str(run / "tb")))
    except (ImportError, AssertionError):
        print("tensorboard is not installed: no TensorBoard logs (pip install tensorboard)", file=sys.stderr)
    return Logger(str(run), formats)


def _make_callback(cfg: TrainArgs, run: Path, device: torch.device, state: dict, say: Callable[[str], None]):
    from stable_baselines3.common.callbacks import BaseCallback

    class TrainCallback(BaseCallback):
        """Checkpoint after every update, validation, progress bar, throughput."""

        def __init__(self) -> None:
            super().__init__()
            self.bar = None
            self.t_last = time.time()
            self.steps_last = 0

        def _on_training_start(self) -> None:
            self.steps_last = self.num_timesteps
            self.t_last = time.time()
            if cfg.progress:
                from tqdm.auto import tqdm

                tty = sys.stderr.isatty()
                self.bar = tqdm(total=cfg.total_steps, initial=self.num_timesteps, unit="step",
                                dynamic_ncols=True, mininterval=0.5 if tty else 30.0, desc="PPO")

        def _on_step(self) -> bool:
            if self.bar is not None:
                self.bar.update(self.training_env.num_envs)
            return True

        def _on_rollout_start(self) -> None:
            # Called after each update (and once at the start): the model holds every trained step.
            self.after_update()

        def after_update(self) -> None:
            """Checkpoint (and validate when due) a model whose weights include every step counted."""
            n = self.model.num_timesteps
            if n == state.get("ppo_steps", 0) and (run / "checkpoints" / "latest.zip").is_file():
                return
            now = time.time()
            state["ppo_wall_s"] = state.get("ppo_wall_s", 0.0) + (now - self.t_last)
            fps = (n - self.steps_last) / max(now - self.t_last, 1e-9)
            self.logger.record("time/steps_per_s", fps)
            self.t_last, self.steps_last = now, n
            ck = run / "checkpoints"
            _atomic_save(self.model, ck / "latest.zip")
            if n // cfg.checkpoint_every > state.get("ppo_steps", 0) // cfg.checkpoint_every:
                _atomic_save(self.model, ck / f"step_{n:09d}.zip")
            if n // cfg.eval_every > state.get("ppo_steps", 0) // cfg.eval_every or n >= cfg.total_steps:
                self.validate(n)
            state["ppo_steps"] = n
            _write_state(run, state)

        def validate(self, n: int) -> None:
            net = self.model.policy.attention_net()
            val = _validation(net, cfg, device)
            self.model.policy.set_training_mode(False)
            for key, v in val.items():
                self.logger.record(key, v)
            best = state.get("best_score", -math.inf)
            msg = f"step {n}: validation {_fmt(val)}"
            if val["val/score"] > best:
                state["best_score"], state["best_step"] = val["val/score"], n
                _atomic_save(self.model, run / "checkpoints" / "best.zip")
                save_checkpoint(net, run / "export.pt", meta=_meta(cfg, state, n, val))
                msg += " (best)"
            say(msg)
            self.logger.dump(n)

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()

    return TrainCallback()


def _atomic_save(model, path: Path) -> None:
    """``model.save`` to a temporary file, then rename: an interrupt never leaves a broken archive."""
    tmp = path.with_name(path.stem + ".tmp.zip")
    model.save(tmp)
    tmp.replace(path)


def _meta(cfg: TrainArgs, state: dict, steps: int, val: dict) -> dict:
    return {"task": cfg.task, "ppo_steps": steps, "warm_start": cfg.warm_start,
            "command": command_line(cfg), "train_config": asdict(cfg) | {"out": ""},
            "ppo_wall_s": round(state.get("ppo_wall_s", 0.0), 1),
            "warm_start_wall_s": round(state.get("bc_wall_s", 0.0), 1), **val}


def _write_state(run: Path, state: dict) -> None:
    tmp = run / "state.json.tmp"
    tmp.write_text(json.dumps(state, indent=2, sort_keys=True) + "\n")
    tmp.replace(run / "state.json")


def _vec_env(cfg: TrainArgs):
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    def thunk(i: int):
        def make():
            return Monitor(make_train_env(cfg))
        return make

    # Envs step in ~1 ms; the network dominates, so they run in this process (no subprocesses).
    venv = DummyVecEnv([thunk(i) for i in range(cfg.n_envs)])
    return venv


def ppo(cfg: TrainArgs, run: Path, device: torch.device, state: dict, bc_path: Path | None,
        say: Callable[[str], None]) -> None:
    from sb3_contrib import MaskablePPO

    from ipp_bench.policies.sb3 import AttentionPolicy

    venv = _vec_env(cfg)
    latest = run / "checkpoints" / "latest.zip"
    (run / "checkpoints").mkdir(exist_ok=True)
    if latest.is_file():
        model = MaskablePPO.load(latest, env=venv, device=device)
        say(f"resuming PPO from {latest} at step {model.num_timesteps}")
    else:
        model = MaskablePPO(
            AttentionPolicy, venv, learning_rate=cfg.learning_rate, n_steps=cfg.n_steps,
            batch_size=cfg.batch_size, n_epochs=cfg.n_epochs, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda,
            clip_range=cfg.clip_range, ent_coef=cfg.ent_coef, vf_coef=cfg.vf_coef,
            max_grad_norm=cfg.max_grad_norm, target_kl=cfg.target_kl or None,
            policy_kwargs={"net_config": cfg.net_config().to_dict()}, seed=cfg.seed, device=device, verbose=0)
        if bc_path is not None:
            net, _ = load_checkpoint(bc_path, device=device)
            model.policy.attention_net().load_state_dict(net.state_dict())
            say(f"PPO starts from the warm-start weights {bc_path}")
        state["ppo_steps"] = 0
    model.set_logger(_logger(run))
    remaining = cfg.total_steps - model.num_timesteps
    if remaining <= 0:
        say(f"PPO already has {model.num_timesteps} >= --total-steps {cfg.total_steps} steps")
    else:
        callback = _make_callback(cfg, run, device, state, say)
        model.learn(total_timesteps=remaining, callback=callback, reset_num_timesteps=False)
        callback.after_update()  # the last update is followed by no rollout
    net = model.policy.attention_net()
    save_checkpoint(net, run / "last.pt", meta=_meta(cfg, state, model.num_timesteps, {}))
    if not (run / "export.pt").is_file():
        save_checkpoint(net, run / "export.pt", meta=_meta(cfg, state, model.num_timesteps, {}))
    venv.close()


# ------------------------------------------------------------------------------------------------
# Entry points
# ------------------------------------------------------------------------------------------------
def export_zip(zip_path: str | Path, out: str | Path | None = None) -> Path:
    """Convert an SB3 MaskablePPO archive of AttentionPolicy to the shipped ``.pt`` format."""
    from sb3_contrib import MaskablePPO

    zip_path = Path(zip_path)
    model = MaskablePPO.load(zip_path, device="cpu")
    if not hasattr(model.policy, "attention_net"):
        raise CheckpointError(f"{zip_path} holds a {type(model.policy).__name__}, not an AttentionPolicy")
    return save_checkpoint(model.policy.attention_net(), out or zip_path.with_suffix(".pt"),
                           meta={"source": str(zip_path), "ppo_steps": int(model.num_timesteps)})


def _resolve_config(ns: argparse.Namespace) -> tuple[TrainArgs, Path]:
    given = _explicit(ns)
    if ns.resume:
        if not given.get("out"):
            raise ValueError("--resume needs --out DIR: the run folder to continue")
        run = Path(given["out"])
        cfg_file = run / "config.json"
        if not cfg_file.is_file():
            raise ValueError(f"--resume: {cfg_file} not found; is {run} a run folder of `ipp-bench train`?")
        saved = json.loads(cfg_file.read_text())["args"]
        changed = {k: v for k, v in given.items() if k not in _RESUMABLE and saved.get(k) != v}
        if changed:
            raise ValueError(f"--resume cannot change {sorted(changed)}: the run was started with "
                             + ", ".join(f"{k}={saved.get(k)!r}" for k in sorted(changed)))
        cfg = TrainArgs(**{**saved, **{k: v for k, v in given.items() if k in _RESUMABLE}})
        cfg.out = str(run)
    else:
        cfg = TrainArgs(**given)
        if not cfg.out:
            slug = cfg.task.replace("/", "-")
            cfg.out = str(Path("runs") / f"{slug}__attention__{cfg.seed}__{time.strftime('%Y%m%d-%H%M%S')}")
        run = Path(cfg.out)
        if (run / "config.json").is_file():
            raise ValueError(f"{run} already holds a run: pass --resume to continue it, or choose another --out")
    _check(cfg)
    return cfg, run


def run_train(args: argparse.Namespace) -> int:
    """Run ``ipp-bench train`` with parsed arguments; returns the exit code."""
    if getattr(args, "export", None):
        path = export_zip(args.export)
        print(f"wrote {path}")
        return 0
    try:
        cfg, run = _resolve_config(args)
    except ValueError as err:
        print(f"ipp-bench train: error: {err}", file=sys.stderr)
        return 2
    run.mkdir(parents=True, exist_ok=True)
    threads = set_threads(cfg.threads)
    device = _resolve_device(cfg.device)
    cfg_file = run / "config.json"
    if not cfg_file.is_file():
        cfg_file.write_text(json.dumps({"args": asdict(cfg), "command": command_line(cfg)}, indent=2) + "\n")
    state = json.loads((run / "state.json").read_text()) if (run / "state.json").is_file() else {}
    log_file = (run / "train.log").open("a")

    def say(msg: str) -> None:
        from tqdm.auto import tqdm

        line = f"[{time.strftime('%H:%M:%S')}] {msg}"
        tqdm.write(line)  # keeps progress bars intact
        sys.stdout.flush()
        log_file.write(line + "\n")
        log_file.flush()

    say(f"training {cfg.task} in {run} on {device} with {threads} torch threads")
    say(f"command: {command_line(cfg)}")

    def on_term(signum, frame):  # SIGTERM behaves like Ctrl-C: the last checkpoint stays valid
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        bc_path = None
        if cfg.warm_start != "none":
            bc_path = run / "warmstart" / "bc.pt"
            if not state.get("bc_done"):
                t0 = time.time()
                net, val = warm_start(cfg, run, device, say)
                state.update(bc_done=True, bc_wall_s=time.time() - t0)
                # The warm-start policy is the first candidate for export.pt; PPO must beat it.
                state.update(best_score=val["val/score"], best_step=0)
                save_checkpoint(net, run / "export.pt", meta=_meta(cfg, state, 0, val))
                _write_state(run, state)
        ppo(cfg, run, device, state, bc_path, say)
    except KeyboardInterrupt:
        say(f"interrupted; continue with: ipp-bench train --out {shlex.quote(str(run))} --resume")
        return 130
    finally:
        signal.signal(signal.SIGTERM, old)
        _write_state(run, state)
    say(f"done: {state.get('ppo_steps', 0)} PPO steps, best validation {state.get('best_score', float('nan')):.2f} "
        f"at step {state.get('best_step')}; policy in {run / 'export.pt'}")
    log_file.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="ipp-bench train", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_train_arguments(parser)
    return run_train(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
