"""Validation: argmax episodes of the training tasks on seeds held out of training.

A network is validated exactly as the leaderboard plays it: the ``attention`` planner
(:class:`~ipp_bench.policies.planner.AttentionPlanner`) through the one episode loop
(:func:`ipp_bench.planners.episode.fly_episode`), on seeds ``VAL_SEED0 + i`` (10 000 000 on) of
training tasks, which neither training nor the leaderboard's evaluation tasks ever use. The score is
the mean ROI uncertainty reduction [%] over the report times (and over the validation tasks), and
greedy's on the same episodes is the reference (``minus_greedy``).

:func:`validate_checkpoints` (``ipp-bench train --validate CKPT...``) scores finished checkpoints the
same way, e.g. to choose among a run's numbered checkpoints on every map size.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ipp_bench.envs.registry import make_env, parse_overrides
from ipp_bench.policies.network import AttentionNet
from ipp_bench.train.args import VAL_SEED0, TrainArgs
from ipp_bench.train.files import write_json_atomic

#: ``--validate``'s tasks when no ``--val-task`` is given: the training task of every map size and family
DEFAULT_VALIDATION_TASKS = ("ipp_bench/Grid15Train-v1", "ipp_bench/Hotspots15Train-v2", "ipp_bench/Grid20Train-v1",
                            "ipp_bench/Grid30Train-v1", "ipp_bench/Hotspots30Train-v2")


def evaluate_net(net: AttentionNet, task: str, episodes: int, seed0: int = VAL_SEED0,
                 overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """Argmax episodes of ``task`` on seeds ``seed0 + i`` with the leaderboard's ``attention`` planner.

    Returns:
        ``val/score`` (mean ROI uncertainty reduction over the report times within the budget) and
        ``val/unc_red_<t>s`` per report time.
    """
    from ipp_bench.policies.planner import AttentionPlanner

    planner = AttentionPlanner.from_net(net, next(net.parameters()).device)
    was_training = net.training
    net.eval()
    try:
        return _fly(planner, task, episodes, seed0, overrides)
    finally:
        net.train(was_training)


def evaluate_planner(spec: str, task: str, episodes: int, seed0: int = VAL_SEED0,
                     overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """:func:`evaluate_net`'s figures for a registered planner (the validation's greedy reference)."""
    from ipp_bench.planners import make_planner

    return _fly(make_planner(spec), task, episodes, seed0, overrides)


def _fly(planner: Any, task: str, episodes: int, seed0: int, overrides: dict[str, Any] | None) -> dict[str, float]:
    from ipp_bench.planners.episode import fly_episode

    env = make_env(task, **(overrides or {}))
    reports = [fly_episode(env, planner, seed0 + i).report for i in range(episodes)]
    red = np.asarray([[r["uncertainty_reduction_pct"] for r in rep] for rep in reports])
    out = {"val/score": float(red.mean())}
    for j, row in enumerate(reports[0]):
        out[f"val/unc_red_{int(row['time_s'])}s"] = float(red[:, j].mean())
    return out


def val_tasks(cfg: TrainArgs) -> list[tuple[str, dict[str, Any]]]:
    """The validation tasks with their overrides: ``--val-task``'s, else the training tasks (once each)
    with the run's ``--env``."""
    if cfg.val_task:
        return [(t, {}) for t in cfg.val_task]
    return [(t, parse_overrides(cfg.env)) for t in dict.fromkeys(cfg.tasks)]


def task_key(task: str) -> str:
    return task.split("/")[-1]


def validation(net: AttentionNet, cfg: TrainArgs,
               greedy: dict[str, dict[str, float]] | None = None) -> dict[str, float]:
    """The validation figures (``val/score``: their mean over the validation tasks); with several
    tasks also per task (``val/<task>/...``), and with ``greedy`` (its figures per task on the same
    seeds) the difference to greedy (``val/.../minus_greedy``)."""
    tasks = val_tasks(cfg)
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
            out.update({f"val/{task_key(task)}/{k.split('/', 1)[1]}": v for k, v in val.items()})
    if len(tasks) > 1:
        out["val/score"] = float(np.mean(scores))
    return out


def greedy_reference(cfg: TrainArgs) -> dict[str, dict[str, float]]:
    """Greedy's validation figures on each validation task (the same seeds as the network's)."""
    return {task: evaluate_planner("greedy", task, cfg.eval_episodes, overrides=ov) for task, ov in val_tasks(cfg)}


def validate_checkpoints(paths: list[str], tasks: list[str], episodes: int, json_path: str | None = None) -> int:
    """``ipp-bench train --validate``: score checkpoints (.pt, or a run's SB3 .zip) on the validation
    seeds of ``tasks`` next to greedy on the same episodes; prints a markdown table (per task the ROI
    uncertainty reduction at each report time, minus greedy's in brackets) and the best by the mean
    score minus greedy over the tasks. Returns the exit code (2: a checkpoint or task is unusable)."""
    from ipp_bench.envs import resolve_task
    from ipp_bench.policies.checkpoint import CheckpointError, load_checkpoint
    from ipp_bench.train.export import export_zip

    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        print(f"ipp-bench train: error: --validate: no such checkpoint: {', '.join(missing)}", file=sys.stderr)
        return 2
    try:
        tasks = [resolve_task(t) for t in tasks]
    except ValueError as err:
        print(f"ipp-bench train: error: --val-task: {err}", file=sys.stderr)
        return 2
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        # Every checkpoint is read (and an unsafe or foreign archive refused) before any episode is flown.
        nets = []
        for path in paths:
            try:
                out = Path(tmp) / f"{len(nets)}_{Path(path).stem}.pt"
                pt = export_zip(path, out) if path.endswith(".zip") else path
                nets.append(load_checkpoint(pt))
            except CheckpointError as err:
                print(f"ipp-bench train: error: --validate: {err}", file=sys.stderr)
                return 2
    print(f"validating {len(paths)} checkpoint(s) and greedy on {len(tasks)} task(s), {episodes} episodes each",
          file=sys.stderr, flush=True)
    greedy = {t: evaluate_planner("greedy", t, episodes) for t in tasks}
    for path, (net, meta) in zip(paths, nets):
        figures = {t: evaluate_net(net, t, episodes) for t in tasks}
        minus = [figures[t]["val/score"] - greedy[t]["val/score"] for t in tasks]
        rows.append({"checkpoint": path, "ppo_steps": meta.get("ppo_steps"), "figures": figures,
                     "mean_minus_greedy": float(np.mean(minus))})
        print(f"{path}: mean minus greedy {rows[-1]['mean_minus_greedy']:+.2f}", file=sys.stderr, flush=True)
    times = [k for k in greedy[tasks[0]] if k.startswith("val/unc_red_")]
    print("| checkpoint | " + " | ".join(task_key(t) for t in tasks) + " | mean score minus greedy |")
    print("|---" * (len(tasks) + 2) + "|")
    for row in rows:
        cells = [" / ".join(f"{row['figures'][t][k]:.1f} ({row['figures'][t][k] - greedy[t][k]:+.1f})"
                            for k in times if k in row["figures"][t]) for t in tasks]
        print(f"| `{row['checkpoint']}` | " + " | ".join(cells) + f" | {row['mean_minus_greedy']:+.2f} |")
    print("| greedy | " + " | ".join(" / ".join(f"{greedy[t][k]:.1f}" for k in times if k in greedy[t])
                                      for t in tasks) + " | |")
    best = max(rows, key=lambda r: r["mean_minus_greedy"])
    print(f"\nbest by the mean over {len(tasks)} tasks: {best['checkpoint']} ({best['mean_minus_greedy']:+.2f})")
    spread = over_checkpoints(rows, greedy, tasks, times) if len(rows) > 1 else None
    if spread is not None:
        print(f"\nover the {len(rows)} checkpoints (e.g. a method's training seeds): per task and report time, the "
              "mean and standard deviation over checkpoints of the ROI uncertainty reduction minus greedy's [points]")
        print("| task | " + " | ".join(f"{k.removeprefix('val/unc_red_')}" for k in times) + " |")
        print("|---" * (len(times) + 1) + "|")
        for t in tasks:
            print(f"| {task_key(t)} | " + " | ".join(
                f"{spread[t][k]['mean']:+.1f} ± {spread[t][k]['sd']:.1f}" if k in spread[t] else "-"
                for k in times) + " |")
    if json_path:
        write_json_atomic(Path(json_path), {"tasks": tasks, "episodes": episodes, "seed0": VAL_SEED0,
                                            "greedy": greedy, "rows": rows, "best": best["checkpoint"],
                                            "over_checkpoints": spread})
    return 0


def over_checkpoints(rows: list[dict[str, Any]], greedy: dict[str, dict[str, float]], tasks: list[str],
                     times: list[str]) -> dict[str, dict[str, dict[str, float]]]:
    """Per task and report time, the mean and the sample standard deviation (n - 1) over the checkpoints of
    each one's figure minus greedy's (rl-baselines3-zoo's benchmark table, over training seeds)."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for t in tasks:
        out[t] = {}
        for k in times:
            diffs = [row["figures"][t][k] - greedy[t][k] for row in rows if k in row["figures"][t]]
            if len(diffs) == len(rows):
                out[t][k] = {"mean": float(np.mean(diffs)), "sd": float(np.std(diffs, ddof=1)), "n": len(diffs)}
    return out
