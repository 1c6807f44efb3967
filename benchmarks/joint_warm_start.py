"""One DAgger warm start over the 15, 20 and 30 x 30 training tasks with two teachers (issue 17).

Greedy labels the v1 tasks' states (``Grid15Train-v1``, ``Grid20Train-v1``, ``Grid30Train-v1``);
the starting network's own argmax (or ``--teacher``'s) labels the hotspot tasks' (``Hotspots15Train-v2``,
``Hotspots30Train-v2``), so that the fit keeps what PPO learned there while it moves the v1
behaviour to greedy's. One fit sees every size (the DAgger batches hold one roadmap each), which
``ipp-bench train`` cannot do because its PPO phase holds one roadmap. Writes ``OUT/warmstart/bc.pt``
(resumable like ``ipp-bench train``'s warm start) and prints the validation figures (16 argmax
episodes per task on the validation seeds).

    python benchmarks/joint_warm_start.py --out runs/joint   # about 8 minutes on one core

``ipp_bench/policies/checkpoints/attention_v4.pt`` is its output with the defaults, from
``attention_v3.pt`` (averaged with it into ``attention_v5.pt``; ``benchmarks/RESULTS.md``,
"Attention at the frontier, third session" and "fourth session", with the variants tried). The
default, ``attention_v6.pt``, is its output with ``Grid20Train-v1`` and ``Grid30Train-v1`` named twice
each, ``--episodes 140 --round-episodes 70`` (the exact command: the checkpoint README; RESULTS,
"sixth" and "seventh session").

``--teacher-for TASK=PLANNER`` gives one task another teacher, any roadmap planner of the registry or a
probe of ``benchmarks/bench_teachers.py``: expert iteration, the network distilled from its own search
(issue 17, tenth session; the teacher sees the environment's observation, as in a leaderboard episode)::

    python benchmarks/joint_warm_start.py --out runs/ei/b --init ipp_bench/policies/checkpoints/attention_v6.pt \
        --tasks ipp_bench/Grid20Train-v1 ipp_bench/Hotspots30Train-v2 ipp_bench/Grid30Train-v1 \
        ipp_bench/Hotspots15Train-v2 ipp_bench/Grid20Train-v1 ipp_bench/Hotspots30Train-v2 ipp_bench/Grid15Train-v1 \
        --teacher-for ipp_bench/Grid20Train-v1=latesample:switch_s=50 ipp_bench/Hotspots30Train-v2=latesample:switch_s=50 \
        --episodes 105 --round-episodes 35   # variant B, about an hour on one core
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from ipp_bench.envs.registry import task_spec
from ipp_bench.policies.train import (TrainArgs, _validation, check_warm_start_seeds, load_init, make_train_env,
                                      set_threads)
from ipp_bench.policies.warmstart import check_expert, check_expert_on, warm_start

try:  # the probes of bench_teachers.py as teachers (this script's folder is on sys.path when run)
    from bench_teachers import register_probes
except ImportError:  # imported from elsewhere: the registry's planners only
    def register_probes() -> None:
        pass


def check_expert_specs(cfg: TrainArgs) -> None:
    """Every teacher builds (under --distill, with a policy to distil) and starts an episode of its task
    before the first episode (ValueError with the planner's message)."""
    register_probes()
    for name in dict.fromkeys(cfg.experts()):  # no environment needed: before the ones below are built
        check_expert(name, cfg.bc_distill)
    for i, (task, name) in enumerate(zip(cfg.tasks, cfg.experts())):
        env = make_train_env(cfg, i)
        try:
            check_expert_on(name, env.unwrapped, task)
        finally:
            env.close()


TASKS = ["ipp_bench/Grid30Train-v1", "ipp_bench/Hotspots30Train-v2", "ipp_bench/Grid15Train-v1",
         "ipp_bench/Hotspots15Train-v2", "ipp_bench/Grid20Train-v1"]
VAL = ["ipp_bench/Grid15Train-v1", "ipp_bench/Hotspots15Train-v2", "ipp_bench/Grid30Train-v1",
       "ipp_bench/Hotspots30Train-v2"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="run folder (warmstart/ goes in it)")
    ap.add_argument("--init", default="ipp_bench/policies/checkpoints/attention_v3.pt",
                    help="the starting weights ('none': a fresh network), also the hotspot tasks' teacher "
                         "unless --teacher")
    ap.add_argument("--teacher", default=None,
                    help="the hotspot tasks' teacher: a checkpoint, or 'greedy' (greedy labels every task); "
                         "default: --init")
    ap.add_argument("--teacher-for", nargs="+", default=[], metavar="TASK=PLANNER",
                    help="another teacher for one task, a planner of the registry or a probe of "
                         "benchmarks/bench_teachers.py (e.g. ipp_bench/Grid20Train-v1=latesample:switch_s=50)")
    ap.add_argument("--rounds", type=int, default=1, help="DAgger rounds after round 0")
    ap.add_argument("--tasks", nargs="+", default=TASKS, metavar="TASK",
                    help="training tasks, the first the main one; a task named twice gets twice the episodes "
                         "(greedy labels the v1 tasks, --teacher the hotspot ones)")
    ap.add_argument("--episodes", type=int, default=100, help="round 0's episodes, split over --tasks in turn")
    ap.add_argument("--round-episodes", type=int, default=50, help="each DAgger round's episodes")
    ap.add_argument("--epochs", type=int, default=4, help="fitting epochs per round")
    ap.add_argument("--lr", type=float, default=1e-4, help="the fit's learning rate")
    ap.add_argument("--distill", action="store_true",
                    help="every teacher is a network (give each task one with --teacher-for, or the hotspot tasks "
                         "--teacher's and no v1 task) and labels with its policy: ipp-bench train's --bc-distill at "
                         "temperature 1 (issue 17, twentieth session)")
    ap.add_argument("--seed", type=int, default=0,
                    help="seed of the episodes (seeds SEED * 1 000 003 on), the sampling and the fit's batches; "
                         "0 made the shipped checkpoints")
    args = ap.parse_args(argv)
    for name, value in (("--episodes", args.episodes), ("--round-episodes", args.round_episodes)):
        if value < len(args.tasks):
            ap.error(f"{name} {value}: at least one episode per task ({len(args.tasks)} tasks)")
    teacher = args.teacher or args.init
    if teacher == "none":
        ap.error("--teacher: a fresh network (--init none) cannot teach; give --teacher greedy or a checkpoint")
    for name, path in (("--init", args.init), ("--teacher", teacher)):
        if path not in ("none", "greedy") and not Path(path).is_file():
            ap.error(f"{name} {path}: not found")
    if args.init == "greedy":
        ap.error("--init greedy: --init takes a checkpoint or 'none'")
    if args.rounds < 0:
        ap.error(f"--rounds {args.rounds}: must be 0 or more")
    if args.epochs < 1:
        ap.error(f"--epochs {args.epochs}: must be 1 or more")
    if not args.lr > 0:
        ap.error(f"--lr {args.lr}: must be above 0")
    if not 0 <= args.seed < 2**32:
        ap.error(f"--seed {args.seed}: must be in [0, 2**32 - 1]")
    for task in args.tasks:
        try:
            task_spec(task)
        except ValueError as err:
            ap.error(f"--tasks: {err}")
    given = {}
    for item in args.teacher_for:
        task, sep, planner = item.partition("=")
        if not sep or task not in args.tasks:
            ap.error(f"--teacher-for {item}: expected TASK=PLANNER with TASK one of --tasks")
        given[task] = planner
    cfg = TrainArgs(task=args.tasks[0], mix=args.tasks[1:], invariant=True, embed_dim=64, ff_dim=256, reward="metric",
                    init="" if args.init == "none" else args.init, warm_start="greedy",
                    warm_start_for=[f"{t}={given[t]}" if t in given else
                                    # the teacher is the network alone (stall_legs=0), as when attention_v4.pt
                                    # was made, before the planner's stall guard existed: with the guard its
                                    # labels would differ
                                    f"{t}=attention:checkpoint={teacher},stall_legs=0"
                                    for t in dict.fromkeys(args.tasks)
                                    if t in given or ("Hotspots" in t and teacher != "greedy")],
                    bc_episodes=args.episodes, bc_rounds=args.rounds, bc_round_episodes=args.round_episodes,
                    bc_epochs=args.epochs, bc_lr=args.lr,
                    bc_temperature=1.0 if args.distill else 0.05, bc_distill=args.distill, gamma=0.99, batch_size=128,
                    eval_episodes=16, val_task=VAL,
                    seed=args.seed)
    set_threads(1)
    try:
        check_warm_start_seeds(cfg)
        check_expert_specs(cfg)
    except ValueError as err:
        ap.error(str(err))
    run = Path(args.out)
    run.mkdir(parents=True, exist_ok=True)
    _, val = warm_start(cfg, run, torch.device("cpu"), lambda m: print(m, flush=True),
                        make_env=lambda i=0: make_train_env(cfg, i), validate=lambda n: _validation(n, cfg),
                        net_config=cfg.net_config(), init=load_init(cfg) if cfg.init else None)
    print(json.dumps(val, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
