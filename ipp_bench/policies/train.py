"""``ipp-bench train``: train the attention policy (behaviour-cloning warm start + MaskablePPO).

A thin script in the cleanrl manner: :class:`TrainArgs` is the one list of options (the command
line is generated from its fields), the warm start lives in :mod:`ipp_bench.policies.warmstart`,
and stable-baselines3 does the rest through its own pieces.

Two phases, both resumable, in one run folder:

1. **Warm start** (``--warm-start greedy``, optional): DAgger-style behaviour cloning from a
   roadmap planner of the registry (:mod:`~ipp_bench.policies.warmstart`).
2. **PPO** (sb3-contrib ``MaskablePPO`` with :class:`~ipp_bench.policies.sb3.AttentionPolicy`)
   for ``--total-steps`` environment steps, validating the deterministic policy every
   ``--eval-every`` steps on held-out episodes of the training task (seeds 10,000,000 onwards;
   never an evaluation task's seeds).

SB3's callbacks do what they were written for: ``CheckpointCallback`` keeps the numbered
checkpoints and ``learn(progress_bar=True)`` (``ProgressBarCallback``) draws the bar. One small
callback of ours runs after every PPO update, where SB3 has none: it writes ``latest.zip`` (so
that an interrupt loses at most the rollout being collected) and validates when due. SB3's
``EvalCallback`` is not used: it fires mid-rollout and scores episode returns, while validation
here scores the ROI uncertainty reduction at the report times of the shared episode loop
(:func:`ipp_bench.planners.episode.fly_episode` with the ``attention`` planner, exactly as the
leaderboard plays it).

Defaults are the paper's PPO settings and network (Adam, lr 1e-5, batch 128, gamma 0.99, one-step
TD advantages = GAE lambda 0, d 128 / feed-forward 512) and no warm start, except where they set
the speed: 16 environments x 64 steps per rollout (paper: 5 instances) and one epoch per rollout
(paper: 8), with the environments in one worker process per CPU. The fastest configuration
measured adds ``--embed-dim 64 --ff-dim 256`` (``benchmarks/RESULTS.md``, "Training throughput",
with the learning checks of both). See ``ipp_bench/policies/checkpoints/README.md`` for the
settings of the shipped checkpoint and why they differ.

Run folder (``--out DIR``, default ``runs/<task>__attention__<seed>__<time>``)::

    config.json      the arguments and the exact command
    state.json       phase bookkeeping (warm start done, steps trained)
    train.log        what was printed
    progress.csv     SB3 training log (appended across resumes), validation included
    tb/              TensorBoard logs (if tensorboard is installed)
    warmstart/       bc.pt (warm-start weights), bc_log.csv, progress.json (rounds done)
    checkpoints/     latest.zip (after every PPO update), step_<n>_steps.zip, best.zip (validation)
    export.pt        best validated policy in the shipped checkpoint format (+ export.json)
    last.pt          final policy in the same format

``--resume`` continues a run: the warm start from its last completed round, PPO from
``latest.zip``; the step counter continues from the checkpoint.

Why this module is long (about 650 lines): it is the whole ``ipp-bench train`` command in one
place, cleanrl-style: the argument dataclass from which the options are generated, the checks
that run before a run folder exists, the run folder's bookkeeping (config, state, resume, export)
and the PPO phase. The parts that stand on their own live beside it: the warm start
(``warmstart.py``), the look-gain feature (``features.py``), the SB3 policy (``sb3.py``), the
vectorised environments and what crosses from them to the policy (``vec.py``).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ipp_bench._threads import available_cpus, keep_freed_memory
from ipp_bench.config import check_integer, check_number
from ipp_bench.data import check_output_dir
from ipp_bench.envs.registry import make_env, parse_overrides
from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from ipp_bench.policies.features import BASE_NODE_DIM, GAIN_NODE_DIM, RATE_NODE_DIM, SKIP_TEACHERS, gain_feature_wrapper
from ipp_bench.policies.network import AttentionNet, NetConfig
from ipp_bench.policies.vec import REWARDS, VEC_ENVS
from ipp_bench.policies.warmstart import check_expert, check_expert_on, warm_start, warm_start_seeds

VAL_SEED0 = 10_000_000  # validation episodes use seeds VAL_SEED0 + i of the validation task


def opt(default: Any, help: str, group: str = "", **argparse_kwargs: Any) -> Any:  # noqa: A002
    """A field of :class:`TrainArgs` with its command-line help (``%(default)s`` is filled in)."""
    meta = {"help": help, "group": group, **argparse_kwargs}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


PPO, NET, WARM, VAL = "PPO (paper values as defaults)", "network", "warm start (behaviour cloning / DAgger)", \
    "validation and checkpoints"


@dataclass
class TrainArgs:
    """Every option of ``ipp-bench train`` (the paper's values where it has one).

    The command line is generated from these fields: ``--total-steps`` for ``total_steps``, the
    help from the metadata; a ``bool`` field that defaults to True becomes ``--no-<name>``.
    """

    task: str = opt("ipp_bench/Grid15Train-v1", "task id to train on (prefix optional), or a task file "
                                                "path/to/mine.toml (a training task: its seeds are disjoint from "
                                                "the leaderboard's)")
    mix: list[str] = opt([], "another task to train on, on the same roadmap as --task (e.g. the v2 task of the "
                             "map size; repeatable): environment i trains on [task, *mix][i %% n]; validated on each",
                         metavar="TASK")
    env: list[str] = opt([], "override a field of the task config for training, e.g. --env budget_s=200 "
                             "(repeatable; values are read as JSON where they parse)", metavar="KEY=VALUE")
    total_steps: int = opt(200_000, "PPO environment steps (the warm start comes on top)")
    n_envs: int = opt(16, "parallel environments (paper: five instances; 16 batch the rollout's forward passes)")
    device: str = opt("auto", "torch device: auto, cpu, cuda or cuda:<n>")
    seed: int = opt(0, "seed of the network, the environments and the warm start")
    threads: int = opt(0, "torch intra-op threads; 0 = half the CPUs available, at least 1 (1 on 2 cores)")
    vec_env: str = opt("subproc", "where the PPO environments step: subproc (one worker process each, on all "
                                  "cores) or dummy (one after the other in this process); same transitions",
                       choices=VEC_ENVS)
    out: str = opt("", "run folder; '' = runs/<task>__attention__<seed>__<time>")
    n_steps: int = opt(64, "steps per env per rollout (16 x 64 = 1024 per update)", PPO)
    batch_size: int = opt(128, "minibatch size (paper)", PPO)
    n_epochs: int = opt(1, "epochs per rollout (paper: eight; each epoch costs as much as all the rest of a step)", PPO)
    learning_rate: float = opt(1e-5, "Adam learning rate (paper)", PPO)
    gamma: float = opt(0.99, "discount (paper)", PPO)
    reward: str = opt("paper", "paper: the env's (the step's belief-ROI trace reduction relative to the trace "
                               "before it, paper eq. 9); metric: the change of the leaderboard's metric (mean ROI "
                               "uncertainty reduction over the report times, policies.vec.MetricReward)", PPO,
                      choices=REWARDS)
    reward_last: float = opt(1.0, "with --reward metric: the weight of the last report time within the budget "
                                  "against 1 for each earlier one (1 = the leaderboard's mean; 3 = the end of the "
                                  "mission counts three times; in (0, 100])", PPO)
    gae_lambda: float = opt(0.0, "GAE lambda (0 = the paper's one-step TD advantage)", PPO)
    clip_range: float = opt(0.2, "PPO clip", PPO)
    ent_coef: float = opt(0.0, "entropy bonus", PPO)
    vf_coef: float = opt(0.5, "value loss weight", PPO)
    max_grad_norm: float = opt(0.5, "gradient clip", PPO)
    target_kl: float = opt(0.0, "early-stop an update past this KL (0 = off)", PPO)
    embed_dim: int = opt(128, "d, the embedding size (CAtNIPP / paper; 64 with --ff-dim 256 trains about 1.5x as "
                              "fast per step)", NET)
    n_heads: int = opt(4, "attention heads", NET)
    ff_dim: int = opt(512, "feed-forward width (CAtNIPP / paper)", NET)
    gain_feature: bool = opt(False, "add the look-gain node feature (ipp_bench.policies.features): the predicted "
                                    "ROI trace reduction of one look from every node", NET)
    invariant: bool = opt(False, "node features that mean the same on every map size and task family (relative "
                                 "metric x, y, mean and std over the prior's, look gain over the mean ROI cell "
                                 "variance: features.invariant_features; implies the look-gain feature)", NET)
    rate_skip: bool = opt(False, "also add greedy's score of each neighbour over the best one as a node feature "
                                 "and to the pointer logits times a learned weight (the network starts as a "
                                 "softened greedy; implies --gain-feature)", NET)
    rate_skip_init: float = opt(20.0, "the weight alpha of greedy's score at initialisation (with --rate-skip)", NET)
    skip_teacher: str = opt("greedy", "whose score --rate-skip adds: greedy's, or far (greedy's legs and the best "
                                      "far target on the belief's ROI, planners.far.far_scores)", NET,
                            choices=SKIP_TEACHERS)
    init: str = opt("", "start from the weights of this exported checkpoint (.pt, e.g. an earlier run's "
                        "warmstart/bc.pt): the warm start fine-tunes them, or PPO starts from them", NET)
    warm_start: str = opt("none", "roadmap planner to imitate before PPO, e.g. greedy (the oracle reference "
                                     "teaches from the true ROI, the student sees the robot's view); 'none' to skip",
                          WARM)
    warm_start_for: list[str] = opt([], "another expert on one training task's environments, e.g. "
                                        "ipp_bench/Hotspots30Train-v2=attention:checkpoint=PATH (repeatable; the "
                                        "other tasks use --warm-start)", WARM, metavar="TASK=PLANNER")
    bc_episodes: int = opt(100, "expert episodes of round 0", WARM)
    bc_rounds: int = opt(2, "DAgger rounds after round 0", WARM)
    bc_round_episodes: int = opt(50, "student episodes per DAgger round", WARM)
    bc_epochs: int = opt(8, "passes over the data after each round", WARM)
    bc_lr: float = opt(3e-4, "warm-start learning rate", WARM)
    bc_temperature: float = opt(0.1, "soft targets p ~ exp((score/best - 1)/T) from the expert's scores; "
                                     "0 = one-hot on its action", WARM)
    bc_distill: bool = opt(False, "a network teacher (--warm-start attention:...) labels with its policy, "
                                  "softmax(logits / --bc-temperature) over the neighbours it allows (1 = its own), "
                                  "instead of one-hot on its move", WARM)
    val_task: list[str] = opt([], "a task of the validation episodes (seeds 10,000,000 onwards, held out of "
                                  "training; repeatable, e.g. a training task of every map size: the "
                                  "network is exported at the best mean over them); none = the training tasks", VAL)
    eval_every: int = opt(20_000, "validation period [steps] (also after the warm start)", VAL)
    eval_episodes: int = opt(16, "validation episodes", VAL)
    checkpoint_every: int = opt(20_000, "keep a numbered checkpoint every this many steps", VAL)
    progress: bool = opt(True, "draw a progress bar (SB3's ProgressBarCallback)", VAL)

    def __post_init__(self) -> None:
        # a run folder of an earlier version holds one task or '' (the recorded commands: --val-task '')
        given = [self.val_task] if isinstance(self.val_task, str) else list(self.val_task)
        self.val_task = [t for t in given if t]

    def net_config(self) -> NetConfig:
        if self.rate_skip:
            return NetConfig(node_dim=RATE_NODE_DIM, rate_skip=True, rate_skip_init=self.rate_skip_init,
                             skip_teacher=self.skip_teacher, embed_dim=self.embed_dim,
                             n_heads=self.n_heads, ff_dim=self.ff_dim)
        if self.invariant:
            return NetConfig(node_dim=GAIN_NODE_DIM, invariant=True, embed_dim=self.embed_dim,
                             n_heads=self.n_heads, ff_dim=self.ff_dim)
        return NetConfig(node_dim=GAIN_NODE_DIM if self.gain_feature else BASE_NODE_DIM,
                         embed_dim=self.embed_dim, n_heads=self.n_heads, ff_dim=self.ff_dim)

    @property
    def tasks(self) -> list[str]:
        """The training tasks: ``task`` and ``mix``, in environment order."""
        return [self.task, *self.mix]

    def experts(self) -> list[str]:
        """The warm start's expert of every training task (``--warm-start``, or ``--warm-start-for``'s)."""
        given = dict(item.partition("=")[::2] for item in self.warm_start_for)
        return [given.get(task, self.warm_start) for task in self.tasks]


# Options that may change when resuming a run; all others must match the saved config.
_RESUMABLE = {"total_steps", "device", "threads", "vec_env", "progress", "out"}
_NOT_IN_COMMAND = {"out", "device", "threads", "vec_env"}  # where and on what a run went, not what it is


def add_train_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of ``ipp-bench train`` to ``parser``, generated from :class:`TrainArgs`.

    Every option defaults to None so that the options given explicitly can be told apart (a
    resumed run may change only some of them).
    """
    groups: dict[str, Any] = {"": parser}
    for f in fields(TrainArgs):
        meta = dict(f.metadata)
        group = meta.pop("group", "")
        if group not in groups:
            groups[group] = parser.add_argument_group(group)
        default = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
        flag = "--" + f.name.replace("_", "-")
        kwargs: dict[str, Any] = {"default": None, "dest": f.name, **meta}
        if f.type in ("bool", bool):  # --name when it defaults to False, --no-name when to True
            if default:
                flag = "--no-" + f.name.replace("_", "-")
            kwargs.update(action="store_false" if default else "store_true",
                          help=f"do not {meta['help']}" if default else meta["help"])
        elif f.type in ("list[str]",):
            kwargs.update(action="append", help=meta["help"])
        else:
            typ = {"int": int, "float": float, "str": str}[str(f.type)]
            kwargs.update(type=typ, help=f"{meta['help']} (default {default!r})")
        groups[group].add_argument(flag, **kwargs)
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    parser.add_argument("--export", metavar="ZIP", default=None,
                        help="only convert an SB3 checkpoint (.zip) of a run to the shipped .pt format "
                             "(written beside it) and exit")
    return parser


def _explicit(ns: argparse.Namespace) -> dict[str, Any]:
    names = {f.name for f in fields(TrainArgs)}
    return {k: v for k, v in vars(ns).items() if k in names and v is not None}


def command_line(cfg: TrainArgs) -> str:
    """The exact ``ipp-bench train`` command for ``cfg`` (every option spelled out)."""
    parts = ["ipp-bench", "train"]
    for f in fields(TrainArgs):
        val = getattr(cfg, f.name)
        if f.name in _NOT_IN_COMMAND:
            continue
        flag = "--" + f.name.replace("_", "-")
        if isinstance(val, bool):
            if val != f.default:
                parts.append(flag if val else "--no-" + f.name.replace("_", "-"))
        elif isinstance(val, list):
            for item in val:
                parts += [flag, str(item)]
        else:
            parts += [flag, str(val)]
    return shlex.join(parts)


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


# The bounds of every numeric option (the run refuses anything else before its folder is made).
_MAX_STEPS = 10**10
_INTEGER_RANGES: dict[str, tuple[int, int | None]] = {
    "total_steps": (1, _MAX_STEPS), "n_envs": (1, 256), "n_steps": (1, 100_000), "batch_size": (1, 1_000_000),
    "n_epochs": (1, 1000), "eval_episodes": (1, 100_000), "checkpoint_every": (1, None), "eval_every": (1, None),
    "embed_dim": (1, 4096), "n_heads": (1, 256), "ff_dim": (1, 65536), "seed": (0, 2**32 - 1),
    "bc_episodes": (0, 1_000_000), "bc_rounds": (0, 1000), "bc_round_episodes": (0, 1_000_000),
    "bc_epochs": (0, 10_000), "threads": (0, 1024),
}
_NUMBER_RANGES: dict[str, tuple[float | None, float | None, bool, bool]] = {  # low, high, open below, open above
    "learning_rate": (0, 1, True, True), "bc_lr": (0, 1, True, True), "gamma": (0, 1, False, False),
    "gae_lambda": (0, 1, False, False), "clip_range": (0, None, True, False), "ent_coef": (0, None, False, False),
    "vf_coef": (0, None, False, False), "max_grad_norm": (0, None, True, False),
    "target_kl": (0, None, False, False), "bc_temperature": (0, None, False, False),
    "rate_skip_init": (0, None, True, False), "reward_last": (0, 100, True, False),
}


def _read_json(path: Path, what: str) -> dict:
    """``path``'s JSON object, or one line naming the file and what is wrong with it."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"--resume: {path} is damaged ({' '.join(str(err).split())}); it holds the run's "
                         f"{what}: restore it, or start a new --out") from None
    if not isinstance(data, dict):
        raise ValueError(f"--resume: {path} is damaged (a JSON {type(data).__name__}, expected an object); it "
                         f"holds the run's {what}: restore it, or start a new --out")
    return data


def _check_resume_files(run: Path) -> None:
    """The files a resumed run reads, checked before it starts: ``state.json`` and ``latest.zip``."""
    import zipfile

    if (run / "state.json").is_file():
        _read_json(run / "state.json", "progress (steps, best validation)")
    latest = run / "checkpoints" / "latest.zip"
    if latest.is_file():
        try:
            with zipfile.ZipFile(latest) as z:
                bad = z.testzip()
                names = set(z.namelist())
        except (OSError, zipfile.BadZipFile) as err:
            bad, names = str(err), set()
        if bad is not None or not {"data", "policy.pth"} <= names:
            numbered = sorted((run / "checkpoints").glob("step_*_steps.zip"))
            hint = (f"replace it with a numbered checkpoint (newest: {numbered[-1].name})" if numbered
                    else "remove it to restart PPO from its start")
            raise ValueError(f"--resume: {latest} is corrupt (not a complete SB3 archive: "
                             f"{bad or 'data or policy.pth missing'}); {hint}")


def _check(cfg: TrainArgs) -> None:
    """Validate every option before anything is written (the run folder included)."""
    for name, (low, high) in _INTEGER_RANGES.items():
        check_integer(_flag(name), getattr(cfg, name), low, high)
    for name, (low, high, low_open, high_open) in _NUMBER_RANGES.items():
        check_number(_flag(name), getattr(cfg, name), low, high, low_open=low_open, high_open=high_open)
    if cfg.reward_last != 1.0 and cfg.reward != "metric":
        raise ValueError(f"--reward-last {cfg.reward_last:g} weighs the metric reward's report times: it needs "
                         f"--reward metric (given --reward {cfg.reward})")
    if cfg.vec_env not in VEC_ENVS:
        raise ValueError(f"--vec-env {cfg.vec_env!r} is invalid: expected one of {', '.join(VEC_ENVS)}")
    if cfg.device not in ("auto", "cpu") and not cfg.device.startswith("cuda"):
        raise ValueError(f"--device {cfg.device!r} is invalid: expected auto, cpu, cuda or cuda:<n>")
    if cfg.device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"--device {cfg.device} asked for but torch sees no CUDA device; use --device cpu")
    cfg.net_config()  # validates the network sizes
    if cfg.init:
        init_net = load_init(cfg)
        if init_net.cfg != cfg.net_config():
            raise ValueError(f"--init {cfg.init}: its network is {init_net.cfg}, the options give "
                             f"{cfg.net_config()} (match --embed-dim, --n-heads, --ff-dim, --gain-feature)")
    if cfg.warm_start != "none":
        check_expert(cfg.warm_start, cfg.bc_distill)
        check_warm_start_seeds(cfg)
    elif cfg.bc_distill:
        raise ValueError("--bc-distill needs --warm-start attention:... "
                         "(the network teacher whose policy is distilled)")
    for item in cfg.warm_start_for:
        task, sep, expert = item.partition("=")
        if not sep or task not in cfg.tasks:
            raise ValueError(f"--warm-start-for {item!r} is invalid: expected TASK=PLANNER with TASK one of the "
                             f"training tasks {cfg.tasks}")
        if cfg.warm_start == "none":
            raise ValueError(f"--warm-start-for {item!r} needs --warm-start (the expert of the other tasks)")
        check_expert(expert, cfg.bc_distill)
    from ipp_bench.envs import resolve_task

    resolved: dict[str, str] = {}
    for flag, task in ([("--task", cfg.task)] + [("--mix", t) for t in cfg.mix]
                       + [("--val-task", t) for t in cfg.val_task]):
        try:
            resolved[task] = resolve_task(task)  # an id (prefix optional) or a task file, which this registers
        except ValueError as err:
            raise ValueError(f"{flag} {task!r}: {err}") from None
    if cfg.invariant and cfg.rate_skip:
        raise ValueError("--invariant and --rate-skip cannot be combined: the rate feature is the last column of "
                         "the v1 inputs")
    if cfg.skip_teacher != "greedy" and not cfg.rate_skip:
        raise ValueError(f"--skip-teacher {cfg.skip_teacher} needs --rate-skip (the score is the rate feature)")
    if len({resolved[t] for t in cfg.tasks}) != len(cfg.tasks):
        raise ValueError(f"--mix {cfg.mix}: a task is named twice (with --task {cfg.task})")
    roadmap = None
    for i, task in enumerate(cfg.tasks):
        try:
            env = make_train_env(cfg, i)  # a bad override fails now, with the config's message
        except (ValueError, TypeError) as err:
            raise ValueError(f"--task {task} with --env {cfg.env}: {err}") from None
        rm = env.unwrapped.roadmap
        if cfg.warm_start != "none":
            check_expert_on(cfg.experts()[i], env.unwrapped, task)
        env.close()
        if roadmap is None:
            roadmap = rm
        elif not (rm.positions.shape == roadmap.positions.shape and np.array_equal(rm.positions, roadmap.positions)
                  and np.array_equal(rm.neighbours, roadmap.neighbours)):
            raise ValueError(f"--mix {task}: its roadmap ({rm.n_nodes} nodes) is not --task {cfg.task}'s "
                             f"({roadmap.n_nodes} nodes); one PPO run holds one roadmap: mix tasks of one map size")


def load_init(cfg: TrainArgs, device: str | torch.device = "cpu") -> AttentionNet:
    """The network of ``--init`` (ValueError with the checkpoint's own message if unreadable)."""
    try:
        net, _ = load_checkpoint(cfg.init, device=device)
    except CheckpointError as err:
        raise ValueError(f"--init: {err}") from None
    if not isinstance(net, AttentionNet):
        raise ValueError(f"--init {cfg.init} is an ensemble of {len(net.members)} networks (a teacher or a reference "
                         "row); training starts from one network: pass one of its members' checkpoints")
    return net


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
def make_train_env(cfg: TrainArgs, index: int = 0):
    """Environment ``index``'s training task (``cfg.tasks[index % n]``) with the run's ``--env``
    overrides (and the look-gain, or rate, feature if asked for)."""
    env = make_env(cfg.tasks[index % len(cfg.tasks)], **parse_overrides(cfg.env))
    if cfg.reward == "metric":
        from ipp_bench.policies.vec import MetricReward

        env = MetricReward(env, last_weight=cfg.reward_last)
    if cfg.invariant:
        return gain_feature_wrapper(env, invariant=True)
    if cfg.rate_skip:
        return gain_feature_wrapper(env, rate=True, teacher=cfg.skip_teacher)
    return gain_feature_wrapper(env) if cfg.gain_feature else env


def evaluate_net(net: AttentionNet, task: str, episodes: int, seed0: int = VAL_SEED0,
                 overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """Deterministic (argmax) episodes of ``task`` on seeds ``seed0 + i``, through the episode loop
    and the planner class the leaderboard uses (:class:`~ipp_bench.policies.planner.AttentionPlanner`).

    Returns:
        ``val/score`` (mean ROI uncertainty reduction over the report times within the budget),
        ``val/unc_red_<t>s`` per report time.
    """
    from ipp_bench.policies.planner import AttentionPlanner

    planner = AttentionPlanner.from_net(net, next(net.parameters()).device)
    was_training = net.training
    net.eval()
    try:
        return _fly_validation(planner, task, episodes, seed0, overrides)
    finally:
        net.train(was_training)


def evaluate_planner(spec: str, task: str, episodes: int, seed0: int = VAL_SEED0,
                     overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """:func:`evaluate_net`'s figures for a registered planner (the validation's greedy reference)."""
    from ipp_bench.planners import make_planner

    return _fly_validation(make_planner(spec), task, episodes, seed0, overrides)


def _fly_validation(planner: Any, task: str, episodes: int, seed0: int,
                    overrides: dict[str, Any] | None) -> dict[str, float]:
    from ipp_bench.planners.episode import fly_episode

    env = make_env(task, **(overrides or {}))
    return _val_figures([fly_episode(env, planner, seed0 + i).report for i in range(episodes)])


def _val_figures(reports: list) -> dict[str, float]:
    red_arr = np.asarray([[r["uncertainty_reduction_pct"] for r in rep] for rep in reports])
    out = {"val/score": float(red_arr.mean())}
    for j, row in enumerate(reports[0]):
        out[f"val/unc_red_{int(row['time_s'])}s"] = float(red_arr[:, j].mean())
    return out


def _val_tasks(cfg: TrainArgs) -> list[tuple[str, dict[str, Any]]]:
    if cfg.val_task:
        return [(t, {}) for t in cfg.val_task]
    return [(t, parse_overrides(cfg.env)) for t in cfg.tasks]


def _task_key(task: str) -> str:
    return task.split("/")[-1]


def _validation(net: AttentionNet, cfg: TrainArgs, greedy: dict[str, dict[str, float]] | None = None) -> dict[str, float]:
    """The validation figures (``val/score``: their mean over the validation tasks); with several
    tasks also per task (``val/<task>/...``), and with ``greedy`` (its figures per task on the same
    seeds) the difference to greedy (``val/.../minus_greedy``)."""
    tasks = _val_tasks(cfg)
    out: dict[str, float] = {}
    scores = []
    for task, overrides in tasks:
        val = evaluate_net(net, task, cfg.eval_episodes, overrides=overrides)
        ref = (greedy or {}).get(task)
        if ref is not None:
            val["val/minus_greedy"] = val["val/score"] - ref["val/score"]
        scores.append(val["val/score"])
        if len(tasks) == 1:
            out.update(val)
        else:
            out.update({f"val/{_task_key(task)}/{k.split('/', 1)[1]}": v for k, v in val.items()})
    if len(tasks) > 1:
        out["val/score"] = float(np.mean(scores))
    return out


def greedy_reference(cfg: TrainArgs) -> dict[str, dict[str, float]]:
    """Greedy's validation figures on each validation task (the same seeds as the network's)."""
    return {task: evaluate_planner("greedy", task, cfg.eval_episodes, overrides=ov) for task, ov in _val_tasks(cfg)}


# ------------------------------------------------------------------------------------------------
# PPO
# ------------------------------------------------------------------------------------------------
def _fmt(d: dict) -> str:
    return ", ".join(f"{k.split('/', 1)[-1]} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


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


def _after_update_callback(cfg: TrainArgs, run: Path, state: dict, say: Callable[[str], None]):
    """``latest.zip`` after every PPO update, validation when due, throughput in the log."""
    from stable_baselines3.common.callbacks import BaseCallback

    class AfterUpdate(BaseCallback):
        def _on_training_start(self) -> None:
            self.t_last, self.steps_last = time.time(), self.num_timesteps

        def _on_step(self) -> bool:
            return True

        def _on_rollout_start(self) -> None:
            # Called after each update (and once at the start): the model holds every step counted.
            self.after_update()

        def after_update(self) -> None:
            n = self.model.num_timesteps
            if n == state.get("ppo_steps", 0) and (run / "checkpoints" / "latest.zip").is_file():
                return
            now = time.time()
            state["ppo_wall_s"] = state.get("ppo_wall_s", 0.0) + (now - self.t_last)
            self.logger.record("time/steps_per_s", (n - self.steps_last) / max(now - self.t_last, 1e-9))
            self.t_last, self.steps_last = now, n
            _atomic_save(self.model, run / "checkpoints" / "latest.zip")
            if n // cfg.eval_every > state.get("ppo_steps", 0) // cfg.eval_every or n >= cfg.total_steps:
                self.validate(n)
            state["ppo_steps"] = n
            _write_state(run, state)
            self.t_last = time.time()  # validation time is not training time

        def validate(self, n: int) -> None:
            net = self.model.policy.attention_net()
            if "greedy_val" not in state:
                state["greedy_val"] = greedy_reference(cfg)
            val = _validation(net, cfg, state["greedy_val"])
            self.model.policy.set_training_mode(False)
            for key, v in val.items():
                self.logger.record(key, v)
            msg = f"step {n}: validation {_fmt(val)}"
            if val["val/score"] > state.get("best_score", -math.inf):
                state["best_score"], state["best_step"] = val["val/score"], n
                _atomic_save(self.model, run / "checkpoints" / "best.zip")
                save_checkpoint(net, run / "export.pt", meta=_meta(cfg, state, n, val))
                msg += " (best)"
            say(msg)
            self.logger.dump(n)

    return AfterUpdate()


def _atomic_save(model, path: Path) -> None:
    """``model.save`` to a temporary file, then rename: an interrupt never leaves a broken archive."""
    tmp = path.with_name(path.stem + ".tmp.zip")
    model.save(tmp)
    tmp.replace(path)


def versions() -> dict[str, str]:
    """Versions of what a checkpoint was trained with."""
    import platform

    import sb3_contrib
    import stable_baselines3

    import ipp_bench

    return {"torch": str(torch.__version__), "stable_baselines3": str(stable_baselines3.__version__),
            "sb3_contrib": str(sb3_contrib.__version__), "numpy": str(np.__version__), "python": platform.python_version(),
            "ipp_bench": getattr(ipp_bench, "__version__", "")}


def _meta(cfg: TrainArgs, state: dict, steps: int, val: dict) -> dict:
    return {"task": cfg.task, "mix": list(cfg.mix), "ppo_steps": steps, "warm_start": cfg.warm_start,
            "warm_start_for": list(cfg.warm_start_for),
            "command": command_line(cfg), "train_config": asdict(cfg) | {"out": ""},
            "seeds": {"seed": cfg.seed, "warm_start_episode_seeds": _warm_start_seeds(cfg),
                      "ppo_episode_seeds": "drawn by the environments' generators, seeded by --seed (SB3 set_random_seed)",
                      "validation_seeds": f"{VAL_SEED0}..{VAL_SEED0 + cfg.eval_episodes - 1} of "
                                          f"{', '.join(cfg.val_task or cfg.tasks)}"},
            "versions": versions(), "device": cfg.device, "threads": cfg.threads,
            "ppo_wall_s": round(state.get("ppo_wall_s", 0.0), 1),
            "warm_start_wall_s": round(state.get("bc_wall_s", 0.0), 1), **val}


def check_warm_start_seeds(cfg: TrainArgs) -> None:
    """The warm start's episodes (seeds ``seed * 1 000 003`` on) never reach the validation episodes
    (``VAL_SEED0`` on): with ``--seed 10`` they would, and the validation would score training episodes."""
    seeds = warm_start_seeds(cfg)
    if seeds and seeds.start < VAL_SEED0 + cfg.eval_episodes and VAL_SEED0 < seeds.stop:
        raise ValueError(f"--seed {cfg.seed}: the warm start's episodes (seeds {seeds.start}..{seeds.stop - 1}) "
                         "would include "
                         f"validation episodes (seeds {VAL_SEED0}..{VAL_SEED0 + cfg.eval_episodes - 1}); "
                         "choose another seed")


def _warm_start_seeds(cfg: TrainArgs) -> str:
    if cfg.warm_start == "none":
        return ""
    seeds = warm_start_seeds(cfg)
    if cfg.mix:
        return (f"{seeds.start}..{seeds.stop - 1}, each round's episodes split over {', '.join(cfg.tasks)} in turn "
                "(consecutive seeds)")
    return f"{seeds.start}..{seeds.stop - 1} of {cfg.task}"


def _write_state(run: Path, state: dict) -> None:
    tmp = run / "state.json.tmp"
    tmp.write_text(json.dumps(state, indent=2, sort_keys=True) + "\n")
    tmp.replace(run / "state.json")


def _vec_env(cfg: TrainArgs):
    """The PPO environments (:func:`ipp_bench.policies.vec.make_vec_env`): no positional encoding in
    the observations (see :func:`policy_kwargs`), masks from the observations."""
    from stable_baselines3.common.monitor import Monitor

    from ipp_bench.policies.vec import make_vec_env

    def maker(i: int):
        return lambda: Monitor(make_train_env(cfg, i))

    return make_vec_env([maker(i) for i in range(cfg.n_envs)], cfg.n_envs, cfg.vec_env)


def policy_kwargs(cfg: TrainArgs) -> dict[str, Any]:
    """``AttentionPolicy`` arguments: the network sizes and the training roadmap's positional encoding."""
    from ipp_bench.policies.vec import roadmap_pos_encoding

    env = make_env(cfg.task, **parse_overrides(cfg.env))
    pe = roadmap_pos_encoding(env)
    env.close()
    return {"net_config": cfg.net_config().to_dict(), "pos_encoding": pe}


class ResumeError(ValueError):
    """A run folder's PPO checkpoint cannot be continued by this version."""


def ppo(cfg: TrainArgs, run: Path, device: torch.device, state: dict, bc_path: Path | None,
        say: Callable[[str], None]) -> None:
    from sb3_contrib import MaskablePPO
    from stable_baselines3.common.callbacks import CheckpointCallback

    from ipp_bench.policies.sb3 import AttentionPolicy

    venv = _vec_env(cfg)
    latest = run / "checkpoints" / "latest.zip"
    (run / "checkpoints").mkdir(exist_ok=True)
    if latest.is_file():
        try:
            model = MaskablePPO.load(latest, env=venv, device=device)
        except ValueError as err:  # e.g. an archive of a version that kept pos_encoding in the observations
            venv.close()
            raise ResumeError(f"--resume: {latest} does not fit this version's training environments ({err}); "
                              "finish that run with the ipp-bench version that started it, or start a new --out") from None
        say(f"resuming PPO from {latest} at step {model.num_timesteps}")
    else:
        model = MaskablePPO(
            AttentionPolicy, venv, learning_rate=cfg.learning_rate, n_steps=cfg.n_steps,
            batch_size=cfg.batch_size, n_epochs=cfg.n_epochs, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda,
            clip_range=cfg.clip_range, ent_coef=cfg.ent_coef, vf_coef=cfg.vf_coef,
            max_grad_norm=cfg.max_grad_norm, target_kl=cfg.target_kl or None,
            policy_kwargs=policy_kwargs(cfg), seed=cfg.seed, device=device, verbose=0)
        start = bc_path if bc_path is not None else (Path(cfg.init) if cfg.init else None)
        if start is not None:
            net, _ = load_checkpoint(start, device=device)
            model.policy.attention_net().load_state_dict(net.state_dict())
            say(f"PPO starts from the weights {start}")
        state["ppo_steps"] = 0
    model.set_logger(_logger(run))
    remaining = cfg.total_steps - model.num_timesteps
    if remaining <= 0:
        say(f"PPO already has {model.num_timesteps} >= --total-steps {cfg.total_steps} steps")
    else:
        after = _after_update_callback(cfg, run, state, say)
        numbered = CheckpointCallback(save_freq=max(cfg.checkpoint_every // cfg.n_envs, 1),
                                      save_path=str(run / "checkpoints"), name_prefix="step")
        model.learn(total_timesteps=remaining, callback=[after, numbered], reset_num_timesteps=False,
                    progress_bar=cfg.progress)
        after.after_update()  # the last update is followed by no rollout
    net = model.policy.attention_net()
    save_checkpoint(net, run / "last.pt", meta=_meta(cfg, state, model.num_timesteps, {}))
    if not (run / "export.pt").is_file():
        save_checkpoint(net, run / "export.pt", meta=_meta(cfg, state, model.num_timesteps, {}))
    venv.close()


# ------------------------------------------------------------------------------------------------
# Entry points
# ------------------------------------------------------------------------------------------------
def export_zip(zip_path: str | Path, out: str | Path | None = None) -> Path:
    """Convert an SB3 MaskablePPO archive of AttentionPolicy to the shipped ``.pt`` format.

    Raises:
        CheckpointError: the file is missing or is not an SB3 archive of an AttentionPolicy.
    """
    import zipfile

    zip_path = Path(zip_path)
    expected = "an SB3 archive (.zip) of a MaskablePPO AttentionPolicy, e.g. <run>/checkpoints/best.zip"
    if not zip_path.is_file():
        raise CheckpointError(f"--export {zip_path}: no such file; expected {expected}")
    if not zipfile.is_zipfile(zip_path):
        raise CheckpointError(f"--export {zip_path}: not a zip archive; expected {expected}")
    from sb3_contrib import MaskablePPO

    try:
        model = MaskablePPO.load(zip_path, device="cpu")
    except Exception as err:  # noqa: BLE001 - any unreadable archive gets the same message
        raise CheckpointError(f"--export {zip_path}: could not be read as a MaskablePPO archive "
                              f"({type(err).__name__}); expected {expected}") from None
    if not hasattr(model.policy, "attention_net"):
        raise CheckpointError(f"--export {zip_path}: holds a {type(model.policy).__name__}, not an AttentionPolicy")
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
        saved = _read_json(cfg_file, "options").get("args")
        known = {f.name for f in fields(TrainArgs)}
        if not isinstance(saved, dict) or set(saved) - known:
            raise ValueError(f"--resume: {cfg_file} is damaged (its 'args' are not the options of ipp-bench train"
                             + (f": unknown {sorted(set(saved) - known)}" if isinstance(saved, dict) else "")
                             + "); restore it, or start a new --out")
        changed = {k: v for k, v in given.items() if k not in _RESUMABLE and saved.get(k) != v}
        if changed:
            raise ValueError(f"--resume cannot change {sorted(changed)}: the run was started with "
                             + ", ".join(f"{k}={saved.get(k)!r}" for k in sorted(changed)))
        cfg = TrainArgs(**{**saved, **{k: v for k, v in given.items() if k in _RESUMABLE}})
        cfg.out = str(run)
        _check_resume_files(run)
    else:
        cfg = TrainArgs(**given)
        if not cfg.out:
            slug = Path(cfg.task).stem if cfg.task.endswith(".toml") else cfg.task.replace("/", "-")
            cfg.out = str(Path("runs") / f"{slug}__attention__{cfg.seed}__{time.strftime('%Y%m%d-%H%M%S')}")
        run = Path(cfg.out)
        check_output_dir(run)  # a file in the way, or not writable: one line, before any work
        if (run / "config.json").is_file():
            raise ValueError(f"{run} already holds a run: pass --resume to continue it, or choose another --out")
    _check(cfg)
    return cfg, run


def run_train(args: argparse.Namespace) -> int:
    """Run ``ipp-bench train`` with parsed arguments; returns the exit code."""
    if getattr(args, "export", None):
        try:
            path = export_zip(args.export)
        except CheckpointError as err:
            print(f"ipp-bench train: error: {err}", file=sys.stderr)
            return 2
        print(f"wrote {path}")
        return 0
    try:
        cfg, run = _resolve_config(args)
    except ValueError as err:
        print(f"ipp-bench train: error: {err}", file=sys.stderr)
        return 2
    run.mkdir(parents=True, exist_ok=True)
    threads = set_threads(cfg.threads)
    kept = keep_freed_memory()  # before the vec env's worker processes fork: they inherit it
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

    say(f"training {cfg.task} in {run} on {device} with {threads} torch threads, {cfg.vec_env} vec env"
        + (", freed memory kept for reuse (glibc)" if kept else ""))
    say(f"command: {command_line(cfg)}")
    val_tasks = ", ".join(t for t, _ in _val_tasks(cfg))
    say(f"validation: {cfg.eval_episodes} argmax episodes on seeds {VAL_SEED0}.. (held out of training) of "
        f"{val_tasks} every {cfg.eval_every} steps; score = the mean ROI uncertainty reduction [%] over the "
        "report times" + (" and the tasks" if len(_val_tasks(cfg)) > 1 else "")
        + "; minus_greedy = score - greedy's on the same episodes")

    def on_term(signum, frame):  # SIGTERM behaves like Ctrl-C: the last checkpoint stays valid
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        bc_path = None
        if cfg.warm_start != "none":
            bc_path = run / "warmstart" / "bc.pt"
            if not state.get("bc_done"):
                init = load_init(cfg, device) if cfg.init else None
                net, val = warm_start(cfg, run, device, say, make_env=lambda i=0: make_train_env(cfg, i),
                                      validate=lambda n: _validation(n, cfg), net_config=cfg.net_config(),
                                      init=init)
                progress = json.loads((run / "warmstart" / "progress.json").read_text())
                state.update(bc_done=True, bc_wall_s=progress["wall_s"])
                # The warm-start policy is the first candidate for export.pt; PPO must beat it.
                state.update(best_score=val["val/score"], best_step=0)
                save_checkpoint(net, run / "export.pt", meta=_meta(cfg, state, 0, val))
                _write_state(run, state)
        ppo(cfg, run, device, state, bc_path, say)
    except KeyboardInterrupt:
        say(f"interrupted; continue with: ipp-bench train --out {shlex.quote(str(run))} --resume")
        return 130
    except ResumeError as err:
        print(f"ipp-bench train: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 2
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
