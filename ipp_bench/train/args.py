"""The options of ``ipp-bench train``: one dataclass, the command line generated from it, the checks.

:class:`TrainArgs` is the one list of a run's settings (cleanrl's habit): the command line is
generated from its fields (``--total-steps`` for ``total_steps``, the help from the metadata, a
``bool`` that defaults to True becomes ``--no-<name>``), a recipe stage is one of them
(:mod:`ipp_bench.train.recipe`), and :func:`command_line` writes any of them back as the exact
command. :func:`check_args` refuses a bad one with one line before a run folder exists.

The defaults are the settings that trained the shipped checkpoint's PPO stages and its first warm
start (``recipes/attention_v6.toml``): d 64 / feed-forward 256, node features that mean the same on
every map size, a greedy DAgger warm start, then MaskablePPO with the leaderboard's metric as the
reward, lr 3e-5, GAE lambda 0.95, clip 0.1, 16 environments x 64 steps, one epoch per rollout. The
paper's settings (d 128 / 512, lr 1e-5, lambda 0, the paper's reward, no warm start) are spelled out
in the help of each option.
"""

from __future__ import annotations

import argparse
import shlex
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

import numpy as np

from ipp_bench.core.config import check_integer, check_number
from ipp_bench.policies.features import BASE_NODE_DIM, GAIN_NODE_DIM
from ipp_bench.policies.network import NetConfig
from ipp_bench.train.vec import REWARDS, VEC_ENVS

VAL_SEED0 = 10_000_000  # validation episodes use seeds VAL_SEED0 + i of the validation tasks
WARM_SEED_STRIDE = 1_000_003  # a warm start's episode seeds start at seed x this


def opt(default: Any, help: str, group: str = "", **argparse_kwargs: Any) -> Any:
    """A field of :class:`TrainArgs` with its command-line help."""
    meta = {"help": help, "group": group, **argparse_kwargs}
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


PPO, NET, WARM, VAL = "PPO", "network", "warm start (behaviour cloning / DAgger)", "validation and checkpoints"


@dataclass
class TrainArgs:
    """Every setting of one ``ipp-bench train`` run (a warm start, PPO, or both, in one run folder)."""

    task: str = opt("ipp_bench/Grid15Train-v1", "task id to train on (prefix optional), or a task file "
                                                "path/to/mine.toml (a training task: its seeds are disjoint from "
                                                "the leaderboard's)")
    mix: list[str] = opt([], "another task to train on (repeatable): environment i trains on [task, *mix][i %% n]; "
                             "PPO needs them on one roadmap; a warm start alone (--total-steps 0) may mix map sizes "
                             "and name a task twice (twice its episodes)", metavar="TASK")
    env: list[str] = opt([], "override a field of the task config for training, e.g. --env budget_s=200 "
                             "(repeatable; values are read as JSON where they parse)", metavar="KEY=VALUE")
    total_steps: int = opt(200_000, "PPO environment steps (the warm start comes on top; 0: the warm start alone)")
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
    n_epochs: int = opt(1, "epochs per rollout (paper: 8; each epoch costs as much as all the rest of a step)", PPO)
    learning_rate: float = opt(3e-5, "Adam learning rate (paper: 1e-5, from scratch)", PPO)
    gamma: float = opt(0.99, "discount (paper)", PPO)
    reward: str = opt("metric", "metric: the change of the leaderboard's metric (mean ROI uncertainty reduction "
                                "over the report times, train.vec.MetricReward); paper: the env's (the step's "
                                "belief-ROI trace reduction relative to the trace before it, paper eq. 9)", PPO,
                      choices=REWARDS)
    gae_lambda: float = opt(0.95, "GAE lambda (paper: 0, the one-step TD advantage)", PPO)
    clip_range: float = opt(0.1, "PPO clip (SB3's default: 0.2)", PPO)
    ent_coef: float = opt(0.0, "entropy bonus", PPO)
    vf_coef: float = opt(0.5, "value loss weight", PPO)
    max_grad_norm: float = opt(0.5, "gradient clip", PPO)
    target_kl: float = opt(0.0, "early-stop an update past this KL (0 = off)", PPO)
    embed_dim: int = opt(64, "d, the embedding size (paper: 128; 64 with --ff-dim 256 trains about 1.5x as fast "
                             "per step)", NET)
    n_heads: int = opt(4, "attention heads", NET)
    ff_dim: int = opt(256, "feed-forward width (paper: 512)", NET)
    invariant: bool = opt(True, "use node features that mean the same on every map size and task family "
                                "(relative metric x, y, mean and std over the prior's, look gain over the mean ROI "
                                "cell variance: features.invariant_features); without: the paper's five",
                          NET)
    gain_feature: bool = opt(False, "with --no-invariant: add the look-gain node feature (the predicted ROI trace "
                                    "reduction of one look from every node)", NET)
    init: str = opt("", "start from the weights of this checkpoint (.pt, e.g. an earlier run's warmstart/bc.pt): "
                        "the warm start fine-tunes them, or PPO starts from them", NET)
    warm_start: str = opt("greedy", "roadmap planner to imitate before PPO (the paper has none; the oracle "
                                    "teaches from the true ROI, the student sees the robot's view); 'none' to skip",
                          WARM)
    warm_start_for: list[str] = opt([], "another teacher for one training task, e.g. "
                                        "ipp_bench/Hotspots30Train-v2=attention:checkpoint=PATH,stall_legs=0 "
                                        "(repeatable; the other tasks use --warm-start)", WARM,
                                    metavar="TASK=PLANNER")
    bc_episodes: int = opt(80, "teacher episodes of round 0", WARM)
    bc_rounds: int = opt(2, "DAgger rounds after round 0", WARM)
    bc_round_episodes: int = opt(40, "student episodes per DAgger round", WARM)
    bc_epochs: int = opt(6, "passes over the data after each round", WARM)
    bc_lr: float = opt(3e-4, "warm-start learning rate", WARM)
    bc_temperature: float = opt(0.05, "soft targets p ~ exp((score/best - 1)/T) from the teacher's scores; "
                                      "0 = one-hot on its action", WARM)
    val_task: list[str] = opt([], "a task of the validation episodes (seeds 10,000,000 onwards, held out of "
                                  "training; repeatable: the network is exported at the best mean over them); "
                                  "none = the training tasks", VAL)
    eval_every: int = opt(20_000, "validation period [steps] (also after the warm start)", VAL)
    eval_episodes: int = opt(16, "validation episodes per validation task", VAL)
    checkpoint_every: int = opt(20_000, "keep a numbered checkpoint every this many steps", VAL)
    progress: bool = opt(True, "draw a progress bar (SB3's ProgressBarCallback)", VAL)

    def __post_init__(self) -> None:
        # a run folder of an earlier version holds one task or '' (the recorded commands: --val-task '')
        given = [self.val_task] if isinstance(self.val_task, str) else list(self.val_task)
        self.val_task = [t for t in given if t]

    def net_config(self) -> NetConfig:
        """The network of the run (ValueError naming the field if a size is out of range)."""
        node_dim = GAIN_NODE_DIM if (self.invariant or self.gain_feature) else BASE_NODE_DIM
        return NetConfig(node_dim=node_dim, invariant=self.invariant, embed_dim=self.embed_dim,
                         n_heads=self.n_heads, ff_dim=self.ff_dim)

    @property
    def tasks(self) -> list[str]:
        """The training tasks: ``task`` and ``mix``, in environment order."""
        return [self.task, *self.mix]

    def experts(self) -> list[str]:
        """The warm start's teacher of every training task (``--warm-start``, or ``--warm-start-for``'s)."""
        given = dict(item.partition("=")[::2] for item in self.warm_start_for)
        return [given.get(task, self.warm_start) for task in self.tasks]


DEFAULTS_TEXT = """\
The defaults are the settings that trained the shipped checkpoint (ipp-bench train --recipe attention_v6
--dry-run prints its stages): d 64 / feed-forward 256, node features that mean the same on every map
size, a greedy DAgger warm start (80 + 2 x 40 episodes, soft targets at temperature 0.05), then
MaskablePPO with the leaderboard's metric as the reward, lr 3e-5, GAE lambda 0.95, clip 0.1, 16
environments x 64 steps, batch 128, one epoch per rollout. The paper's method: --embed-dim 128
--ff-dim 512 --no-invariant --warm-start none --reward paper --learning-rate 1e-5 --gae-lambda 0
--n-epochs 8 --n-envs 5."""

# Options that may change when resuming a run; all others must match the saved config.
RESUMABLE = {"total_steps", "device", "threads", "vec_env", "progress", "out"}
NOT_IN_COMMAND = {"out", "device", "threads", "vec_env"}  # where and on what a run went, not what it is


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_train_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of ``ipp-bench train`` to ``parser``: one per :class:`TrainArgs` field, and the
    modes (``--recipe``, ``--resume``, ``--export``, ``--validate``).

    Every field's option defaults to None so that the options given explicitly can be told apart (a
    resumed run may change only some of them).
    """
    parser.epilog = DEFAULTS_TEXT
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    groups: dict[str, Any] = {"": parser}
    for f in fields(TrainArgs):
        meta = dict(f.metadata)
        group = meta.pop("group", "")
        if group not in groups:
            groups[group] = parser.add_argument_group(group)
        default = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
        name = flag(f.name)
        kwargs: dict[str, Any] = {"default": None, "dest": f.name, **meta}
        if f.type in ("bool", bool):  # --name when it defaults to False, --no-name when to True
            if default:
                name = "--no-" + f.name.replace("_", "-")
            kwargs.update(action="store_false" if default else "store_true",
                          help=f"do not {meta['help']}" if default else meta["help"])
        elif f.type in ("list[str]",):
            kwargs.update(action="append", help=meta["help"])
        else:
            typ = {"int": int, "float": float, "str": str}[str(f.type)]
            kwargs.update(type=typ, help=f"{meta['help']} (default {default!r})")
        groups[group].add_argument(name, **kwargs)
    modes = parser.add_argument_group("modes")
    modes.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    modes.add_argument("--recipe", metavar="NAME", default=None,
                       help="run every stage of a shipped recipe (attention_v6: the shipped checkpoint) or of a "
                            "recipe file (.toml) into --out DIR/<stage>/, skipping finished stages and resuming an "
                            "interrupted one; the result is DIR/attention.pt")
    modes.add_argument("--dry-run", action="store_true", help="with --recipe: print its stages' commands and exit")
    modes.add_argument("--from-stage", metavar="STAGE", default=None,
                       help="with --recipe: start at this stage, from --init's weights (the stages before it are "
                            "not run)")
    modes.add_argument("--export", metavar="ZIP", default=None,
                       help="only convert an SB3 checkpoint (.zip) of a run to the shipped .pt format "
                            "(written beside it) and exit")
    modes.add_argument("--validate", metavar="CKPT", nargs="+", default=None,
                       help="only score checkpoints (.pt or a run's .zip) on the validation episodes of --val-task "
                            "(default: the five training tasks), --eval-episodes each, against greedy, and exit")
    modes.add_argument("--json", metavar="PATH", default=None, help="with --validate: also write the figures here")
    return parser


def explicit(ns: argparse.Namespace) -> dict[str, Any]:
    """The :class:`TrainArgs` fields given on the command line."""
    names = {f.name for f in fields(TrainArgs)}
    return {k: v for k, v in vars(ns).items() if k in names and v is not None}


def command_line(cfg: TrainArgs, where: bool = False) -> str:
    """The exact ``ipp-bench train`` command for ``cfg``: every option that acts on the run (a warm
    start alone leaves out the PPO options, a run without one the warm start's); with ``where`` also
    ``--out`` and the ``--device``, ``--threads``, ``--vec-env`` that differ from their defaults."""
    parts = ["ipp-bench", "train"]
    idle = {f.name for f in fields(TrainArgs)
            if (cfg.total_steps == 0 and f.name not in ("batch_size", "gamma")  # the warm start's fit uses both
                and (f.metadata.get("group") == PPO
                     or f.name in ("n_envs", "vec_env", "checkpoint_every", "eval_every", "progress")))
            or (cfg.warm_start == "none" and f.metadata.get("group") == WARM
                and f.name not in ("init", "warm_start"))}
    for f in fields(TrainArgs):
        val = getattr(cfg, f.name)
        if f.name in idle or (f.name in NOT_IN_COMMAND and not (where and val and val != f.default)):
            continue
        if isinstance(val, bool):
            if val != f.default:
                parts.append(flag(f.name) if val else "--no-" + f.name.replace("_", "-"))
        elif isinstance(val, list):
            for item in val:
                parts += [flag(f.name), str(item)]
        elif val != "" or f.default != "":
            parts += [flag(f.name), str(val)]
    return shlex.join(parts)


def warm_start_seeds(cfg: TrainArgs) -> range:
    """The episode seeds of a warm start (``seed x 1 000 003`` on, round 0's episodes then each DAgger
    round's); empty without one."""
    n = cfg.bc_episodes + cfg.bc_rounds * cfg.bc_round_episodes if cfg.warm_start != "none" else 0
    return range(cfg.seed * WARM_SEED_STRIDE, cfg.seed * WARM_SEED_STRIDE + n)


# The bounds of every numeric option (the run refuses anything else before its folder is made).
_MAX_STEPS = 10**10
_INTEGER_RANGES: dict[str, tuple[int, int | None]] = {
    "total_steps": (0, _MAX_STEPS), "n_envs": (1, 256), "n_steps": (1, 100_000), "batch_size": (1, 1_000_000),
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
}


def check_args(cfg: TrainArgs, deep: bool = True) -> None:
    """Validate every setting before anything is written (ValueError, one line naming the option);
    ``deep=False`` leaves out what reads files or builds environments (``--init``, the teachers)."""
    import torch

    from ipp_bench.envs import resolve_task
    from ipp_bench.train.teachers import check_expert, check_expert_on

    for name, (low, high) in _INTEGER_RANGES.items():
        check_integer(flag(name), getattr(cfg, name), low, high)
    for name, (low, high, low_open, high_open) in _NUMBER_RANGES.items():
        check_number(flag(name), getattr(cfg, name), low, high, low_open=low_open, high_open=high_open)
    if cfg.reward not in REWARDS:
        raise ValueError(f"--reward {cfg.reward!r} is invalid: expected one of {', '.join(REWARDS)}")
    if cfg.vec_env not in VEC_ENVS:
        raise ValueError(f"--vec-env {cfg.vec_env!r} is invalid: expected one of {', '.join(VEC_ENVS)}")
    if cfg.device not in ("auto", "cpu") and not cfg.device.startswith("cuda"):
        raise ValueError(f"--device {cfg.device!r} is invalid: expected auto, cpu, cuda or cuda:<n>")
    if cfg.device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"--device {cfg.device} asked for but torch sees no CUDA device; use --device cpu")
    if cfg.total_steps == 0 and cfg.warm_start == "none":
        raise ValueError("--total-steps 0 with --warm-start none: the run would train nothing")
    cfg.net_config()  # validates the network sizes
    if deep and cfg.init:
        init_net = load_init(cfg)
        if init_net.cfg != cfg.net_config():
            raise ValueError(f"--init {cfg.init}: its network is {init_net.cfg}, the options give "
                             f"{cfg.net_config()} (match --embed-dim, --n-heads, --ff-dim, --no-invariant)")
    if cfg.warm_start != "none":
        check_expert(cfg.warm_start)
        check_warm_start_seeds(cfg)
    for item in cfg.warm_start_for:
        task, sep, expert = item.partition("=")
        if not sep or task not in cfg.tasks:
            raise ValueError(f"--warm-start-for {item!r} is invalid: expected TASK=PLANNER with TASK one of the "
                             f"training tasks {cfg.tasks}")
        if cfg.warm_start == "none":
            raise ValueError(f"--warm-start-for {item!r} needs --warm-start (the teacher of the other tasks)")
        if deep:
            check_expert(expert)
    resolved: dict[str, str] = {}
    for name, task in ([("--task", cfg.task)] + [("--mix", t) for t in cfg.mix]
                       + [("--val-task", t) for t in cfg.val_task]):
        try:
            resolved[task] = resolve_task(task)  # an id (prefix optional) or a task file, which this registers
        except ValueError as err:
            raise ValueError(f"{name} {task!r}: {err}") from None
    if cfg.total_steps and len({resolved[t] for t in cfg.tasks}) != len(cfg.tasks):
        raise ValueError(f"--mix {cfg.mix}: a task is named twice (with --task {cfg.task}); only a warm start "
                         "alone (--total-steps 0) may weigh a task twice")
    if deep:
        _check_envs(cfg, check_expert_on)


def _check_envs(cfg: TrainArgs, check_expert_on: Any) -> None:
    """Every training task builds with the overrides, its teacher can start an episode of it, and
    (for PPO) all lie on one roadmap."""
    from ipp_bench.train.vec import make_train_env

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
        elif cfg.total_steps and not (rm.positions.shape == roadmap.positions.shape
                                      and np.array_equal(rm.positions, roadmap.positions)
                                      and np.array_equal(rm.neighbours, roadmap.neighbours)):
            raise ValueError(f"--mix {task}: its roadmap ({rm.n_nodes} nodes) is not --task {cfg.task}'s "
                             f"({roadmap.n_nodes} nodes); PPO holds one roadmap: mix tasks of one map size "
                             "(a warm start alone, --total-steps 0, may mix them)")


def evaluation_task_warnings(cfg: TrainArgs) -> list[str]:
    """One line per training task (``--task``, ``--mix``) that is one of the suite's evaluation
    tasks (a built-in task without the ``train`` tag): training on it draws episodes from the seeds
    its leaderboard flies, so the leaderboard would no longer score held-out episodes."""
    from ipp_bench.envs import resolve_task
    from ipp_bench.envs.registry import TASKS

    lines = []
    for task in dict.fromkeys(cfg.tasks):
        spec = TASKS.get(resolve_task(task))
        if spec is None or not spec.builtin or "train" in spec.tags:
            continue
        train = [t.id for t in TASKS.values() if "train" in t.tags and t.id == spec.id.replace("Eval-", "Train-")]
        lines.append(f"warning: {spec.id} is an evaluation task (tags {', '.join(spec.tags)}): training on it "
                     "draws episodes from the seeds its leaderboard flies, so that leaderboard no longer scores "
                     "held-out episodes" + (f"; its training task is {train[0]}" if train else ""))
    return lines


def check_warm_start_seeds(cfg: TrainArgs) -> None:
    """The warm start's episodes (seeds ``seed x 1 000 003`` on) never reach the validation episodes
    (``VAL_SEED0`` on): with ``--seed 10`` they would, and the validation would score training episodes."""
    seeds = warm_start_seeds(cfg)
    if seeds and seeds.start < VAL_SEED0 + cfg.eval_episodes and VAL_SEED0 < seeds.stop:
        raise ValueError(f"--seed {cfg.seed}: the warm start's episodes (seeds {seeds.start}..{seeds.stop - 1}) "
                         f"would include validation episodes (seeds {VAL_SEED0}..{VAL_SEED0 + cfg.eval_episodes - 1}); "
                         "choose another seed")


def load_init(cfg: TrainArgs, device: Any = "cpu") -> Any:
    """The network of ``--init`` (ValueError with the checkpoint's own message if unreadable)."""
    from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint
    from ipp_bench.policies.network import AttentionNet

    try:
        net, _ = load_checkpoint(cfg.init, device=device)
    except CheckpointError as err:
        raise ValueError(f"--init: {err}") from None
    if not isinstance(net, AttentionNet):
        raise ValueError(f"--init {cfg.init} is an ensemble of {len(net.members)} networks; training starts "
                         "from one network: pass one of its members' checkpoints")
    return net
