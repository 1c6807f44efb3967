"""Validate several attention checkpoints on the held-out validation seeds of several tasks, next
to greedy on the same episodes, and name the best by the mean over the tasks.

``ipp-bench train`` validates on its own training tasks; a network meant for every map size is
chosen here on the validation tasks of every size (seeds 10 000 000.., disjoint from training and
from the leaderboard's), so the choice never looks at the leaderboard's episodes.

    python benchmarks/validate_checkpoints.py runs/v2to30/checkpoints/step_*.zip \
        ipp_bench/policies/checkpoints/attention_v2.pt --episodes 16 --json runs/v2to30/val_all.json

Prints a markdown table: per checkpoint and task the ROI uncertainty reduction at each report time
(minus greedy's in brackets) and the mean score minus greedy's over the tasks.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

DEFAULT_TASKS = ("ipp_bench/Grid15Train-v1", "ipp_bench/Hotspots15Train-v2",
                 "ipp_bench/Grid30Train-v1", "ipp_bench/Hotspots30Train-v2")


def _load(path: Path, tmp: Path):
    from ipp_bench.policies.checkpoint import load_checkpoint
    from ipp_bench.policies.train import export_zip

    if path.suffix == ".zip":  # an SB3 archive of a run: its policy in the shipped format
        path = export_zip(path, tmp / f"{path.stem}.pt")
    net, meta = load_checkpoint(path)
    return net, meta


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", nargs="+", type=Path, help="exported .pt files or a run's SB3 .zip archives")
    ap.add_argument("--tasks", nargs="+", default=list(DEFAULT_TASKS), help="validation tasks (training tasks: "
                    "their validation seeds are held out of training)")
    ap.add_argument("--episodes", type=int, default=16, help="argmax episodes per task (seeds 10 000 000..)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args(argv)
    missing = [str(p) for p in args.checkpoints if not p.is_file()]
    if missing:
        print(f"error: no such checkpoint: {', '.join(missing)}", file=sys.stderr)
        return 2
    if args.episodes < 1:
        print(f"error: --episodes {args.episodes} is invalid: expected an integer >= 1", file=sys.stderr)
        return 2

    import torch

    from ipp_bench.envs import resolve_task
    from ipp_bench.policies.train import evaluate_net, evaluate_planner

    torch.set_num_threads(1)
    tasks = [resolve_task(t) for t in args.tasks]
    greedy = {t: evaluate_planner("greedy", t, args.episodes) for t in tasks}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.checkpoints:
            net, meta = _load(path, Path(tmp))
            figures = {t: evaluate_net(net, t, args.episodes) for t in tasks}
            minus = [figures[t]["val/score"] - greedy[t]["val/score"] for t in tasks]
            rows.append({"checkpoint": str(path), "ppo_steps": meta.get("ppo_steps"), "figures": figures,
                         "mean_minus_greedy": sum(minus) / len(minus)})
            print(f"{path}: mean minus greedy {rows[-1]['mean_minus_greedy']:+.2f}", file=sys.stderr, flush=True)

    times = [k for k in greedy[tasks[0]] if k.startswith("val/unc_red_")]
    short = [t.split("/")[-1] for t in tasks]
    print("| checkpoint | " + " | ".join(short) + " | mean score minus greedy |")
    print("|---" * (len(tasks) + 2) + "|")
    for row in rows:
        cells = []
        for t in tasks:
            f, g = row["figures"][t], greedy[t]
            cells.append(" / ".join(f"{f[k]:.1f} ({f[k] - g[k]:+.1f})" for k in times if k in f))
        print(f"| `{row['checkpoint']}` | " + " | ".join(cells) + f" | {row['mean_minus_greedy']:+.2f} |")
    print("| greedy | " + " | ".join(" / ".join(f"{greedy[t][k]:.1f}" for k in times if k in greedy[t])
                                      for t in tasks) + " | |")
    best = max(rows, key=lambda r: r["mean_minus_greedy"])
    print(f"\nbest by the mean over {len(tasks)} tasks: {best['checkpoint']} ({best['mean_minus_greedy']:+.2f})")
    if args.json:
        args.json.write_text(json.dumps({"tasks": tasks, "episodes": args.episodes, "greedy": greedy,
                                         "rows": rows, "best": best["checkpoint"]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
