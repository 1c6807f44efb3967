"""The validation curve of an `ipp-bench train` run: every task and report time, against greedy.

Reads a run folder: ``progress.csv`` (the PPO validations, SB3's logger), ``warmstart/bc.json`` (the
warm start's validation, plotted at step 0; for a run started with ``--init``, the validation in
that checkpoint's ``.json``) and ``state.json`` (greedy's figures on the same
validation episodes, ``greedy_val``). Draws one panel per (task, report time): the network's ROI
uncertainty reduction over PPO environment steps, greedy dashed, the wall time of training on a
second axis on top; prints the same as a markdown table.

    python benchmarks/plot_training.py runs/inv15 --out benchmarks/training_curve.png

A run validates only every ``--eval-every`` steps; ``--validation`` takes the curve instead from
``validate_checkpoints.py --json`` over the run's checkpoints (``step_N_steps.zip`` at step N, the
run's ``--init`` weights at step 0; greedy from the same file), with the wall time from the run:

    python benchmarks/validate_checkpoints.py START.pt runs/r/checkpoints/step_*.zip --tasks T1 T2 \
        --episodes 64 --json runs/r/val.json
    python benchmarks/plot_training.py runs/r --validation runs/r/val.json --out benchmarks/r.png

Several ``--validation`` files (validations of the same run made at different times, say) are read
as one curve; they must hold the same tasks, episode count and greedy figures (the same seeds).
"""

from __future__ import annotations

import argparse
import csv
import json
import re
from pathlib import Path

import numpy as np


def read_run(run: Path) -> tuple[list[str], list[int], dict, list[float], list[float], dict]:
    """(tasks, report times, {(task, t): [(step, value)]}, steps, wall seconds, greedy figures)."""
    state = json.loads((run / "state.json").read_text())
    greedy = state.get("greedy_val", {})
    tasks = [t.split("/")[-1] for t in greedy] or ["(task)"]
    rows = list(csv.DictReader((run / "progress.csv").open()))
    keys = [k for k in rows[0] if k.startswith("val/") and "/unc_red_" in k] if rows else []
    times = sorted({int(k.rsplit("_", 1)[1].rstrip("s")) for k in keys})
    curves: dict = {}
    bc = run / "warmstart" / "bc.json"
    if not bc.is_file():  # a run started from --init: its starting weights' own validation
        init = json.loads((run / "config.json").read_text())["args"].get("init") or ""
        bc = Path(init).with_suffix(".json") if init else bc
    if bc.is_file():
        meta = json.loads(bc.read_text())["meta"]
        for task in tasks:
            for t in times:
                v = meta.get(f"val/{task}/unc_red_{t}s", meta.get(f"val/unc_red_{t}s"))
                if v is not None:
                    curves.setdefault((task, t), []).append((0, float(v)))
    steps, walls = [0.0], [0.0]
    wall = 0.0
    last = None
    n = 0
    for r in rows:  # a validation row has no step of its own: it follows the update it validates
        if r.get("time/total_timesteps"):
            n = int(float(r["time/total_timesteps"]))
            sps = r.get("time/steps_per_s") or ""
            if sps and last is not None and float(sps) > 0:
                wall += (n - last) / float(sps)
            last = n
            steps.append(float(n))
            walls.append(wall)
        for task in tasks:
            for t in times:
                v = r.get(f"val/{task}/unc_red_{t}s") or r.get(f"val/unc_red_{t}s") or ""
                if v:
                    curves.setdefault((task, t), []).append((n, float(v)))
    return tasks, times, curves, steps, walls, {k.split("/")[-1]: v for k, v in greedy.items()}


def read_validation(paths: list[Path], run: Path) -> tuple[list[str], list[int], dict, dict]:
    """(tasks, report times, curves, greedy) from ``validate_checkpoints.py --json`` over a run's checkpoints."""
    data = json.loads(paths[0].read_text())
    for path in paths[1:]:  # more validations of the same run: same tasks, episodes and greedy figures
        more = json.loads(path.read_text())
        for key in ("tasks", "episodes", "greedy"):
            if more[key] != data[key]:
                raise ValueError(f"its {key} differ from {paths[0]}'s: not validations on the same episodes")
        data["rows"] = data["rows"] + more["rows"]
    init = json.loads((run / "config.json").read_text())["args"].get("init") or ""
    tasks = [t.split("/")[-1] for t in data["tasks"]]
    greedy = {t.split("/")[-1]: v for t, v in data["greedy"].items()}
    times = sorted({int(k.rsplit("_", 1)[1].rstrip("s")) for k in next(iter(greedy.values()))
                    if k.startswith("val/unc_red_")})
    curves: dict = {}
    for row in data["rows"]:
        m = re.search(r"step_(\d+)_steps\.zip$", row["checkpoint"])
        if m:
            step = int(m.group(1))
        elif init and Path(row["checkpoint"]) == Path(init):
            step = 0
        else:  # another checkpoint (an export of the run, say): no step on the curve
            print(f"note: {row['checkpoint']} is neither the run's --init nor a step_N_steps.zip; left off the curve")
            continue
        for full, task in zip(data["tasks"], tasks):
            for t in times:
                curves.setdefault((task, t), []).append((step, float(row["figures"][full][f"val/unc_red_{t}s"])))
    for pts in curves.values():
        pts.sort()
    return tasks, times, curves, greedy


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, default=None, help="PNG to write (default: <run>/validation.png)")
    parser.add_argument("--title", default="")
    parser.add_argument("--validation", type=Path, nargs="+", default=None,
                        help="validate_checkpoints.py --json over the run's checkpoints (one or more files of "
                             "the same tasks and episodes): the curve from them")
    args = parser.parse_args(argv)
    tasks, times, curves, steps, walls, greedy = read_run(args.run)
    if args.validation is not None:
        try:
            tasks, times, curves, greedy = read_validation(args.validation, args.run)
        except (OSError, ValueError, KeyError, TypeError, StopIteration) as err:
            names = " ".join(str(p) for p in args.validation)
            parser.error(f"--validation {names}: not the --json of validate_checkpoints.py over "
                         f"{args.run}'s checkpoints ({type(err).__name__}: {err})")
    print("| PPO steps | wall [min] | " + " | ".join(f"{task} {t} s" for task in tasks for t in times) + " |")
    print("|---|---|" + "---|" * (len(tasks) * len(times)))
    all_steps = sorted({s for c in curves.values() for s, _ in c})
    for s in all_steps:
        cells = []
        for task in tasks:
            for t in times:
                v = dict(curves.get((task, t), [])).get(s)
                g = greedy.get(task, {}).get(f"val/unc_red_{t}s")
                cells.append("" if v is None else f"{v:.1f}" + (f" ({v - g:+.1f})" if g is not None else ""))
        print(f"| {s:,} | {np.interp(s, steps, walls) / 60:.0f} | " + " | ".join(cells) + " |")
    print("| greedy | | " + " | ".join(f"{greedy.get(task, {}).get(f'val/unc_red_{t}s', float('nan')):.1f}"
                                      for task in tasks for t in times) + " |")
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    fig = Figure(figsize=(3.2 * len(times), 2.6 * len(tasks) + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(tasks), len(times), squeeze=False))
    for i, task in enumerate(tasks):
        for j, t in enumerate(times):
            ax = axes[i, j]
            pts = curves.get((task, t), [])
            if pts:
                x, y = zip(*pts)
                ax.plot(x, y, marker="o", ms=3, label="network (argmax)")
            g = greedy.get(task, {}).get(f"val/unc_red_{t}s")
            if g is not None:
                ax.axhline(g, color="k", linestyle="--", linewidth=1, label="greedy, same episodes")
            ax.set_title(f"{task}, {t} s", fontsize="small")
            ax.set_xlabel("PPO environment steps")
            ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1e6:g}M" if v >= 1e6 else f"{v / 1e3:g}k"))
            ax.xaxis.set_major_locator(MaxNLocator(5))
            if j == 0:
                ax.set_ylabel("ROI uncertainty reduction [%]")
            ax.grid(alpha=0.3)
            if steps[-1] > 0 and walls[-1] > 0:
                top = ax.secondary_xaxis("top", functions=(lambda s: np.interp(s, steps, walls) / 60,
                                                           lambda m: np.interp(m * 60, walls, steps)))
                top.set_xlabel("PPO wall time [min] (validations excluded)", fontsize="small")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=2, fontsize="small")
    fig.suptitle(args.title or f"validation of {args.run}: held-out seeds 10,000,000..")
    out = args.out or args.run / "validation.png"
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
